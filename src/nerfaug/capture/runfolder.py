"""A capture session's run folder: the names of what it holds (drawn in `nerfaug.capture.session`),
and which folders may become one (`check_new_run`): never one that holds or hides the dataset, lies
inside it, holds files nerfaug did not write, or is a damaged session. Light: the commands' `--help`
reads these names."""

from __future__ import annotations

import shutil
from pathlib import Path

from nerfaug import owned, runfiles
from nerfaug.errors import FolderRefused

SESSION_FILE = "session.json"
CHECKPOINT_FILE = "checkpoint.pt"
DATASET_DIR = "dataset"
PROPOSALS_DIR = "proposals"
# A sparse start's candidate pool: the dataset's views it did not start from (poses and names).
POOL_FILE = "pool.json"
# Marker kinds (`nerfaug.owned`): the run folder, its dataset copy, and a folder `export` wrote.
RUN_KIND, DATASET_KIND, EXPORT_KIND = "capture-session", "capture-dataset", "capture-export"
# The split the run's dataset copy holds the views in, whatever the source's split was.
DATASET_SPLIT = "train"
# Present while a new session is being created, until its session.json is first written: a folder
# holding it and no session.json was never a session (a creation was stopped, e.g. killed).
UNFINISHED_FILE = ".creating"
# What a stopped creation may have written (`owned.foreign_files` patterns): anything else is a user's.
UNFINISHED_HOLDS = (
    UNFINISHED_FILE,
    POOL_FILE,
    CHECKPOINT_FILE,
    ".lock",
    f"{DATASET_DIR}/{owned.MARKER}",
    *(f"{DATASET_DIR}/*.{kind}" for kind in ("json", "npy", "npz", "png", "jpg", "jpeg", "exr")),
)


def check_new_run(data_dir: Path, run_dir: Path) -> None:
    """Refuse a run folder that would hold or hide the dataset or lie inside it, that holds files
    nerfaug did not write, or that holds anything at all without a session.json: a damaged session
    is never rebuilt over (its dataset may hold captures and the user's own files).

    Raises:
        FolderRefused: saying which folder and what to choose instead.
    """
    run_dir = Path(run_dir)
    data_dir = Path(data_dir).resolve()
    if data_dir == run_dir.resolve() or run_dir.resolve() in data_dir.parents:
        raise FolderRefused(
            f"{run_dir}: the run folder holds the dataset {data_dir}; a session writes "
            f"{runfiles.shown(run_dir, DATASET_DIR)} and more, so choose a run folder outside the dataset"
        )
    if data_dir in run_dir.resolve().parents:
        raise FolderRefused(
            f"{run_dir}: the run folder lies inside the dataset {data_dir}; nothing is written into an "
            "input folder, so choose a run folder outside the dataset"
        )
    if not owned.is_empty(run_dir) and not owned.marked(run_dir, RUN_KIND):
        what = "not a folder" if not run_dir.is_dir() else "not empty and not a nerfaug run folder"
        raise FolderRefused(f"{run_dir}: {what}, so nothing is written there; choose a new or empty folder for --out")
    if runfiles.is_file(run_dir, UNFINISHED_FILE):
        _remove_stopped_creation(run_dir)
        return
    left = sorted(p.name for p in run_dir.iterdir() if p.name != owned.MARKER) if run_dir.is_dir() else []
    if left:
        raise FolderRefused(
            f"{run_dir}: a capture session without its {SESSION_FILE} (damaged or unfinished; it holds "
            f"{', '.join(left[:4])}{', ...' if len(left) > 4 else ''}), so nothing there is changed; restore "
            f"{runfiles.shown(run_dir, SESSION_FILE)}, or choose a new folder for --out"
        )


def _remove_stopped_creation(run_dir: Path) -> None:
    """Remove what a stopped creation left in `run_dir` (never a session: no session.json was
    written), so that the same command creates it anew; refuse when it holds a file nerfaug did
    not write there."""
    foreign = owned.foreign_files(run_dir, UNFINISHED_HOLDS)
    if foreign:
        raise FolderRefused(
            f"{run_dir}: left by the creation of a session that was stopped before its {SESSION_FILE} was "
            f"written, and it holds {foreign[0]}, which nerfaug did not write, so nothing there is changed; "
            "move that file out and run the command again, or choose a new folder for --out"
        )
    remove_unfinished(run_dir, existed=True)


def remove_unfinished(run_dir: Path, existed: bool) -> None:
    """Remove what a failed `create` wrote: the run folder, or its contents when it was there
    before (empty or only nerfaug's marker: `check_new_run` refused anything else)."""
    if not existed:
        shutil.rmtree(run_dir, ignore_errors=True)
        return
    for path in run_dir.iterdir():
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
