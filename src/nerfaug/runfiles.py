"""The one way nerfaug opens a file or folder inside a run folder: a capture session's (its
session.json, checkpoint, pool, proposals, dataset copy, lock, TensorBoard log), an experiment
run's (result, selection, metrics, history and the rest of `experiment.runfolder`), and the
service's own folder under its root (its job records).

Every path into such a folder is made here, from the folder and a name relative to it, and held
to the containment rule (`nerfaug.containment.inside`): resolved, it must lie inside the folder.
A name that leads out (a symbolic link planted in the folder, a `..` or an absolute name written
into a record) is refused in one line naming the file, before anything there is read, written or
created, so nothing outside is touched. Writes replace a file in one step (`nerfaug.jsonio`).

`tests/test_architecture.py` checks that no other module joins a run folder with a name
(`run_dir / SESSION_FILE`): a new file cannot forget the rule.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import IO

from nerfaug import jsonio
from nerfaug.containment import inside
from nerfaug.errors import PathRefused


def shown(run_dir: str | Path, name: str | Path) -> Path:
    """`name` in `run_dir` as a message names it (unresolved, as the user gave the folder); never
    opened: open the path `path_in` returns."""
    return Path(run_dir) / name


def path_in(run_dir: str | Path, name: str | Path) -> Path:
    """The path of `name` (a file or folder, relative to `run_dir`) resolved, when it lies inside
    `run_dir`: the one to open, write or hand to a library that opens it.

    Raises:
        PathRefused: it leads outside `run_dir` (a link, `..`, an absolute name) or cannot be
            followed (a link loop); one line naming `run_dir / name`.
    """
    given = shown(run_dir, name)
    try:
        return inside(run_dir, given, "this path")
    except PathRefused as error:
        raise PathRefused(
            given, f"{error.problem}; nothing is read or written through it: put the run's own file or folder back"
        ) from None


def checked(run_dir: str | Path, name: str | Path) -> Path:
    """`name` in `run_dir` as shown (unresolved, so messages and relative links read as the user
    gave the folder), once `path_in` found it inside `run_dir`: for a path handed on to code that
    opens it later (a run's folder, a figure), where the unresolved form is needed.

    Raises:
        PathRefused: as `path_in`.
    """
    path_in(run_dir, name)
    return shown(run_dir, name)


def exists(run_dir: str | Path, name: str | Path) -> bool:
    """Whether `run_dir` holds the name `name` (a link counts, wherever it leads: opening it then
    says where)."""
    return os.path.lexists(shown(run_dir, name))


def is_file(run_dir: str | Path, name: str | Path) -> bool:
    """Whether `name` is a file inside `run_dir` (False for one that leads outside)."""
    try:
        return path_in(run_dir, name).is_file()
    except PathRefused:
        return False


def folder(run_dir: str | Path, name: str | Path) -> Path:
    """The folder `name` inside `run_dir`, made if missing (with its parents), resolved."""
    path = path_in(run_dir, name)
    path.mkdir(parents=True, exist_ok=True)
    return path


def read_bytes(run_dir: str | Path, name: str | Path) -> bytes:
    """The bytes of `name` in `run_dir` (OSError as `Path.read_bytes` raises it)."""
    return path_in(run_dir, name).read_bytes()


def read_text(run_dir: str | Path, name: str | Path) -> str:
    """The text of `name` in `run_dir`, UTF-8 (OSError, UnicodeDecodeError as `Path.read_text`)."""
    return path_in(run_dir, name).read_text(encoding="utf-8")


def read_json(run_dir: str | Path, name: str | Path) -> dict:
    """The JSON object in `name` (`nerfaug.jsonio.read_json`: a `DatasetError` naming the file)."""
    return jsonio.read_json(path_in(run_dir, name))


def write_bytes(run_dir: str | Path, name: str | Path, data: bytes) -> Path:
    """Replace `name` in `run_dir` with `data` in one step; returns the path written."""
    path = path_in(run_dir, name)
    jsonio.atomic_write_bytes(path, data)
    return path


def write_text(run_dir: str | Path, name: str | Path, text: str) -> Path:
    """`write_bytes` of `text` encoded as UTF-8."""
    return write_bytes(run_dir, name, text.encode("utf-8"))


def write_json(run_dir: str | Path, name: str | Path, data) -> Path:
    """`data` as indented JSON (`nerfaug.jsonio.atomic_write_json`) into `name` in `run_dir`."""
    path = path_in(run_dir, name)
    jsonio.atomic_write_json(path, data)
    return path


def open_lock(run_dir: str | Path, name: str | Path) -> IO[str]:
    """`name` in `run_dir` opened for reading and appending ("a+"), made if missing: a lock file,
    which is locked and rewritten in place (never replaced: the lock is on its inode)."""
    return open(path_in(run_dir, name), "a+")  # noqa: SIM115 -- the caller keeps it open while it holds the lock


__all__ = [
    "checked",
    "exists",
    "folder",
    "is_file",
    "open_lock",
    "path_in",
    "read_bytes",
    "read_json",
    "read_text",
    "shown",
    "write_bytes",
    "write_json",
    "write_text",
]
