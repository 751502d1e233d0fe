"""The results folder (its layout: `experiment.layout.ResultsFolder`): one folder per run,
written so that a crash never leaves a half-run that looks complete. A run's result.json is
written last: the run is complete iff it exists and is valid.

Every file is written to a temporary name and renamed into place (atomic on POSIX).

Nothing the user made is deleted or written over, and no finished result is ever deleted: a run
folder is removed only when it has no result and is provably nerfaug's (its marker, or only the
files of the run-folder contract); a results folder whose bookkeeping is missing or unreadable
while runs exist is refused, as are runs made with another configuration or another dataset;
`--force` moves finished results aside into `superseded/` instead of deleting them.
"""

from __future__ import annotations

import datetime
import functools
import hashlib
import json
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from nerfaug import owned, runfiles
from nerfaug.data import detect_format, find_split
from nerfaug.errors import FolderRefused, NerfaugError
from nerfaug.experiment.layout import ResultsFolder

RESULT_FILE = "result.json"
RESULT_KEYS = ("scene", "method", "trial", "seed", "fingerprint", "metrics", "timing", "code_version")
RESULTS_KIND, RUN_KIND = "experiment-results", "experiment-run"
# Files a run folder of an earlier nerfaug (before the marker) may hold; temporary files start with ".".
_RUN_CONTRACT = (
    "result.json",
    "selection.json",
    "metrics.json",
    "history.json",
    "config.json",
    "progress.json",
    "error.json",
    "uncertainty.png",
    "renders",
    "view_uncertainty",
)
# The run folder's subfolders (`runfolder.FILES`) and the one kind of file each holds.
_RUN_SUBFOLDERS = {"renders": ".png", "view_uncertainty": ".npy"}


@dataclass(frozen=True)
class RunKey:
    """Which run: a (scene, method, trial) cell of the sweep."""

    scene: str
    method: str
    trial: int

    def folder(self, root: Path) -> Path:
        """The run's folder under `root`, refused (`PathRefused`, one line) where `runs/`, its
        scene or method folder is a link leading out of `root`: no run is read or made there."""
        root = Path(root)
        return runfiles.checked(root, ResultsFolder(root).run(self.scene, self.method, self.trial).relative_to(root))

    def __str__(self) -> str:
        return f"{self.scene}/{self.method}/trial {self.trial}"


def fingerprint(config: dict) -> str:
    """A short stable hash of the parts of a config that change results."""
    return hashlib.sha256(json.dumps(config, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_fingerprint(sweep_fingerprint: str, method_definition: dict | None) -> str:
    """The fingerprint of one run: its sweep's (every setting of the protocol, the engine and the
    selection options) combined with its method's own definition (estimator, selector and the
    settings it fixes, `MethodSpec.definition`), so a change to one method's settings sets apart
    that method's runs only."""
    return fingerprint({"sweep": sweep_fingerprint, "method": method_definition})


def _git(folder: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(folder), *args], capture_output=True, text=True, timeout=10, check=True
    ).stdout.strip()


def checkout_version(package: Path) -> str | None:
    """The commit of the git checkout holding the folder `package` ("1c94345..."), with "-dirty"
    when a file under `package` differs from that commit (untracked files included, ignored ones
    not); None when `package` is not in a git checkout or git is missing.

    Only `package` counts, not the whole checkout: `git describe --dirty` would call the code dirty
    when a results table or a note beside it changed, which says nothing of the code.
    """
    try:
        top = Path(_git(package, "rev-parse", "--show-toplevel")).resolve()
        if not package.resolve().is_relative_to(top):
            return None
        commit = _git(package, "describe", "--always", "--abbrev=12")
        changed = _git(package, "status", "--porcelain", "--", ".")
    except (OSError, subprocess.SubprocessError, ValueError):
        return None  # also a checkout without a commit: describe fails there
    return f"{commit}-dirty" if changed else commit


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """The version of the code that computes results: the commit of the checkout the package runs
    from, "-dirty" when the package's own files differ from it (e.g. "1c94345" or "1c94345-dirty";
    `checkout_version`), or "nerfaug <version>" when it does not run from a git checkout."""
    from importlib import metadata

    found = checkout_version(Path(__file__).resolve().parents[1])
    if found:
        return found
    try:
        return f"nerfaug {metadata.version('nerfaug')}"
    except metadata.PackageNotFoundError:
        return "nerfaug (unknown version)"


def read_result(folder: Path, expected_fingerprint: str | None = None) -> dict | None:
    """The run's result if the run is complete and valid, else None.

    Invalid means: unreadable or truncated JSON, missing keys, non-finite metrics, or a
    fingerprint that differs from `expected_fingerprint` (the run's `run_fingerprint`: it was
    made with another config or another definition of its method).
    """
    path = runfiles.path_in(folder, RESULT_FILE)  # PathRefused (not None) for a link planted there
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if not isinstance(result, dict) or any(key not in result for key in RESULT_KEYS):
        return None
    if expected_fingerprint is not None and result["fingerprint"] != expected_fingerprint:
        return None
    metrics = result["metrics"]
    if not isinstance(metrics, dict) or not isinstance(metrics.get("psnr"), (int, float)):
        return None
    return result


def is_run_folder(folder: Path) -> bool:
    """Whether `folder` holds only what nerfaug writes into a run folder: the files of the
    run-folder contract (renders holding only PNGs, view_uncertainty only .npy arrays) and its
    marker. A marked folder into which a user put a file of their own is not a run folder any
    more: removing it would lose that file."""
    folder = Path(folder)
    if not folder.is_dir():
        return False
    for entry in folder.iterdir():
        if entry.name.startswith(".") and entry.is_file():
            continue
        if entry.name not in _RUN_CONTRACT:
            return False
        if entry.is_dir():
            suffix = _RUN_SUBFOLDERS.get(entry.name)
            if suffix is None or any(not p.name.endswith(suffix) for p in entry.iterdir()):
                return False
    return True


def start_run_folder(folder: Path) -> None:
    """Create a run folder and mark it as nerfaug's (so that an interrupted run can be redone)."""
    owned.mark(folder, RUN_KIND)


def clear_incomplete(folder: Path) -> bool:
    """Remove a run folder that has no result (a crash or a corrupted file). Returns whether
    anything was removed.

    Raises:
        FolderRefused: the folder holds files nerfaug did not write, or a finished result (of
            another configuration): neither is ever deleted here.
    """
    folder = Path(folder)
    if not folder.exists():
        return False
    if not is_run_folder(folder):
        raise FolderRefused(
            f"{folder}: holds files nerfaug did not write, so it is not redone; move them "
            "elsewhere, or choose a new --out folder"
        )
    if read_result(folder) is not None:
        raise IncompatibleResults(
            f"{folder}: holds a finished run of another configuration; it is not deleted. "
            "Use a new --out folder, or --force to move the old runs aside"
        )
    shutil.rmtree(folder)
    return True


def write_result(folder: Path, result: dict) -> None:
    """Mark a run complete. Call only after every other file of the run is written."""
    missing = [key for key in RESULT_KEYS if key not in result]
    if missing:
        raise ValueError(f"result is missing {missing}")
    runfiles.write_json(folder, RESULT_FILE, result)


class IncompatibleResults(NerfaugError, RuntimeError):
    """The results folder holds runs made with a different configuration or dataset, or its
    bookkeeping is missing; the message says how to proceed."""


def finished_runs(root: Path) -> list[dict]:
    """The results of every finished run under `root/runs`, whatever configuration made them."""
    found = (read_result(folder) for folder in ResultsFolder(Path(root)).run_folders())
    return [r for r in found if r is not None]


def read_sweep(root: Path) -> tuple[dict | None, str | None]:
    """The folder's sweep record, or None and why not ("missing", or what is wrong)."""
    name = ResultsFolder(Path(root)).sweep.name
    if not runfiles.exists(root, name):
        return None, "is missing"
    try:
        data = json.loads(runfiles.read_text(root, name))  # PathRefused for a link leading out
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        return None, f"is unreadable ({error})"
    if not isinstance(data, dict) or not isinstance(data.get("fingerprint"), str):
        return None, "holds no fingerprint"
    return data, None


def move_aside(root: Path) -> Path:
    """Move `root/runs` and `root/sweep.json` into `root/superseded/<UTC time>/`; returns that folder."""
    results = ResultsFolder(Path(root))
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%S%fZ")
    # A link planted as superseded/ is refused; runs/ and sweep.json are renamed, a link as itself.
    name = (results.superseded / stamp).relative_to(results.root)
    runfiles.folder(root, name)
    target = runfiles.shown(root, name)
    for moved in (results.runs, results.sweep):
        if moved.exists():
            moved.rename(target / moved.name)
    return target


def check_sweep(root: Path, sweep: dict, force: bool = False) -> Path | None:
    """Record the sweep's config in `root/sweep.json`, refusing to mix incompatible results.

    Settings that change results (everything in `sweep["fingerprinted"]`) and the user datasets
    (`sweep["datasets"]`, by content) must match the folder's; the list of scenes, methods and
    trials may grow (new runs are added beside old ones). With `force`, existing runs are moved
    aside into `superseded/` (nothing is deleted) and every run is redone.

    Returns:
        The folder old runs were moved into, or None.

    Raises:
        IncompatibleResults: finished runs of another configuration or dataset, or runs without
            a readable sweep.json (without `force`).
        FolderRefused: `root` is not empty and is not a results folder.
    """
    root = Path(root)
    results = ResultsFolder(root)
    if root.exists() and not root.is_dir():
        raise FolderRefused(f"{root}: not a folder; choose a folder for --out")
    path = results.sweep
    previous, problem = read_sweep(root)
    folders = results.run_folders()
    if previous is None and not folders and not owned.is_empty(root) and not owned.marked(root, RESULTS_KIND):
        raise FolderRefused(
            f"{root}: not empty and not a nerfaug results folder (no {path.name}), so nothing is "
            "written there; choose a new or empty folder for --out"
        )
    # datasets/ or its cache leading out (a link): PathRefused, before anything is written.
    runfiles.path_in(root, results.dataset_cache.relative_to(root))
    moved = None
    if force:
        if folders or previous is not None:
            moved = move_aside(root)
    elif previous is not None:
        # Methods may be added over sittings: the record keeps every method's definition, the
        # latest for a method run again (whose earlier runs `_check_compatible` then refuses if
        # that definition changed).
        sweep = {**sweep, "methods": {**previous.get("methods", {}), **sweep.get("methods", {})}}
        _check_compatible(previous, sweep, results)
    elif folders:
        raise IncompatibleResults(
            f"{path} {problem} but {results.runs} holds {len(folders)} run folder(s), so nerfaug cannot tell "
            f"what made them; re-run with --force to move them aside into {results.superseded} (nothing is "
            "deleted), or use another --out folder"
        )
    owned.mark(root, RESULTS_KIND)
    runfiles.write_json(root, path.name, sweep)  # PathRefused for a sweep.json linked out
    return moved


def _check_compatible(previous: dict, sweep: dict, results: ResultsFolder) -> None:
    path = results.sweep
    how = (
        f"Use another --out folder, or --force to move the existing runs aside into {results.superseded} "
        "(nothing is deleted)"
    )
    if previous.get("fingerprint") != sweep["fingerprint"]:
        old, new = previous.get("fingerprinted", {}), sweep["fingerprinted"]
        changed = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
        details = "; ".join(f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in changed[:6])
        raise IncompatibleResults(f"{path}: results there were made with a different configuration ({details}). {how}.")
    old_data, new_data = previous.get("datasets") or {}, sweep.get("datasets") or {}
    for scene in sorted(set(old_data) & set(new_data)):
        old, new = old_data[scene], new_data[scene]
        # "content" (images too) is compared where both records have it (sweep.json of older versions lack it).
        same_content = "content" not in old or "content" not in new or old["content"] == new["content"]
        if old.get("digest") != new.get("digest") or not same_content:
            raise IncompatibleResults(
                f"{path}, scene '{scene}': its runs were made on the dataset {old_data[scene].get('path')!r}, "
                f"this sweep uses {new_data[scene].get('path')!r} with different content. {how}."
            )
    methods = sweep.get("methods", {})
    others = sorted(
        {
            r["scene"] + "/" + r["method"]
            for r in finished_runs(results.root)
            if r["method"] in methods
            and r["fingerprint"] != run_fingerprint(sweep["fingerprint"], methods[r["method"]])
        }
    )
    if others:
        raise IncompatibleResults(
            f"{results.runs}: finished runs of another configuration ({', '.join(others[:4])}) "
            f"although {path} matches. {how}."
        )


LISTED_SPLITS = ("train", "initial", "test", "val")
"""The splits whose listings identify a dataset folder (`dataset_digest`)."""


def dataset_digest(folder: Path) -> str:
    """A short hash of a dataset folder's listings (what its frames and cameras are): every
    `transforms*.json`, and the listing of each split the experiments read in whatever format
    holds it."""
    folder = Path(folder)
    listings = set(folder.glob("transforms*.json"))
    for split in LISTED_SPLITS:
        if (fmt := detect_format(folder, split)) is not None:
            listings.add(fmt.listing(folder, split))
    digest = hashlib.sha256()
    for path in sorted(listings, key=lambda p: p.name):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def dataset_content_digest(folder: Path, splits: tuple[str, ...]) -> str:
    """A short hash of what runs read from a dataset: the listings of `splits` (in whatever
    format holds them) and every image their frames name (relative path and bytes). Other files in
    the folder (notes, a results folder placed inside it) do not count.

    Raises:
        DatasetError: a split or a frame's image is missing, or an image lies outside the folder.
    """
    folder = Path(folder)
    root = folder.resolve()
    digest = hashlib.sha256()
    for split in splits:
        source = find_split(folder, split)
        digest.update(source.listing.name.encode() + b"\0" + source.listing.read_bytes())
        for image in source.frame_files():
            digest.update(image.relative_to(root).as_posix().encode() + b"\0" + image.read_bytes())
    return digest.hexdigest()[:16]
