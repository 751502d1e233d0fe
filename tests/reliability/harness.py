"""Running `nerfaug` in-process on bad input and classifying what happened.

Imports nothing of nerfaug beyond `nerfaug.cli.main` and `nerfaug.data.write_blender_split`, so
the same cases also run against older versions of the code (`count.py` measures both).
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import shutil
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch


@dataclass
class Outcome:
    """What one command did: its exit code (None: an exception escaped), stdout and stderr."""

    code: int | None
    out: str
    err: str
    escaped: str | None = None  # the traceback of an exception that escaped main()

    @property
    def traceback(self) -> bool:
        return self.escaped is not None or "Traceback (most recent call last)" in self.out + self.err

    def error_lines(self) -> list[str]:
        return [line for line in self.err.splitlines() if line.startswith("nerfaug:")]


def run_cli(argv: list[str], cwd: Path | None = None) -> Outcome:
    """`nerfaug ARGV` in this process, in `cwd`; never raises."""
    from nerfaug.cli import main

    out, err = io.StringIO(), io.StringIO()
    code, escaped = 0, None
    previous = os.getcwd()
    env = os.environ.pop("NERFAUG_DEBUG", None)
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                main([str(a) for a in argv])
            except SystemExit as done:
                if isinstance(done.code, str):  # Python prints such a message and exits 1
                    err.write(done.code + "\n")
                    code = 1
                else:
                    code = int(done.code or 0)
            except BaseException:  # noqa: BLE001 -- any escape is what is being measured
                escaped = traceback.format_exc()
                code = None
    finally:
        os.chdir(previous)
        if env is not None:
            os.environ["NERFAUG_DEBUG"] = env
    return Outcome(code, out.getvalue(), err.getvalue(), escaped)


# A session's lock file says who last took the session's lock (`nerfaug.capture.lock`): a
# command takes it before it reads the session, so it is not the session's data and not compared.
LOCK_FILE = ".lock"


def tree_hash(folder: Path) -> dict[str, str]:
    """Every file and folder under `folder` (relative path -> sha256, or "dir"), but a session's
    lock file; {} if absent."""
    folder = Path(folder)
    if folder.is_file():
        return {".": hashlib.sha256(folder.read_bytes()).hexdigest()}
    found = {}
    for path in sorted(folder.rglob("*")) if folder.exists() else []:
        if path.name == LOCK_FILE:
            continue
        rel = str(path.relative_to(folder))
        found[rel] = "dir" if path.is_dir() else hashlib.sha256(path.read_bytes()).hexdigest()
    return found


# ---- tiny inputs -------------------------------------------------------------------------------

SIZE = 8


def _views(n: int, seed: int, size: int = SIZE):
    from nerfaug.cameras import Cameras
    from nerfaug.data import Views
    from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

    generator = torch.Generator().manual_seed(seed)
    poses = sample_uniform_poses(n, generator)
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)
    images = (torch.rand(n, size, size, 3, generator=generator) * 255).round() / 255
    return Views(cameras, images, [f"./x/r_{i}" for i in range(n)])


def make_dataset(root: Path, train: int = 10, test: int = 3, initial: int | None = 3, size: int = SIZE) -> Path:
    """A Blender-format dataset of random images at poses on the hemisphere (train, test, initial)."""
    from nerfaug.data import write_blender_split

    root = Path(root)
    write_blender_split(root, "train", _views(train, 0, size))
    if test:
        write_blender_split(root, "test", _views(test, 1, size))
    if initial:
        write_blender_split(root, "initial", _views(initial, 2, size))
    return root


def write_images(folder: Path, names: list[str], size: int = SIZE, channels: int = 3) -> Path:
    """PNG captures named after `names` (random pixels)."""
    import imageio.v3 as iio

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for name in names:
        iio.imwrite(folder / f"{name}.png", rng.integers(0, 255, (size, size, channels), dtype=np.uint8))
    return folder


def copy(source: Path, target: Path) -> Path:
    shutil.copytree(source, target)
    return target


@dataclass
class Case:
    """A bad input: the command, the folders it must leave unchanged, and what it must say."""

    argv: list
    inputs: list[Path] = field(default_factory=list)
    code: int = 2
    says: tuple[str, ...] = ()  # substrings the one-line error must contain (file, field, value)
    cwd: Path | None = None
    usage: bool = False  # refused by the argument parser (its usage text, exit 2)


def classify(case: Case, outcome: Outcome, before: dict, after: dict) -> str:
    """lost (a file of an input folder deleted or changed), wrote (files added to an input
    folder), traceback, silent (exit 0), unclear, or clear."""
    if any(after[k].get(rel) != digest for k in before for rel, digest in before[k].items()):
        return "lost"
    if any(before[k] != after[k] for k in before):
        return "wrote"
    if outcome.traceback:
        return "traceback"
    if outcome.code == 0:
        return "silent"
    lines = outcome.error_lines()
    text = " ".join(lines) if lines and not case.usage else outcome.err
    one_line = len(lines) == 1 or case.usage
    if outcome.code != case.code or not one_line or not all(s in text for s in case.says):
        return "unclear"
    return "clear"


def make_bases(root: Path):
    """The shared inputs of the cases (`cases.Bases`), made through the CLI itself."""
    from cases import TINY, Bases

    root = Path(root)
    dataset = make_dataset(root / "dataset")
    session, results = root / "session", root / "results"
    for argv in (
        ["train", dataset, "--out", session, "--engine", "test", "--steps", "3", "--device", "cpu"],
        ["run", "--data", dataset, "--out", results, *TINY],
    ):
        outcome = run_cli(argv)
        if outcome.code != 0:
            raise RuntimeError(f"making the inputs failed: nerfaug {argv}: {outcome.err}{outcome.escaped or ''}")
    return Bases(dataset, session, results)
