"""What nerfaug may delete or overwrite: only folders it created, proved by a marker file.

Every folder nerfaug creates and may later remove or rewrite (a session's run folder and its
dataset copy, an export, a results folder's run folders) gets a small JSON marker, `.nerfaug`,
written before anything else goes in. A folder without it is the user's and is never removed
or written over; the error says which folder and how to proceed.

The marker says the folder is nerfaug's, not that every file in it is: a user may put a file of
their own into it. So a marked folder is removed only when each file in it is one nerfaug writes
into a folder of its kind (`holds`: patterns of paths, besides the marker and the temporary files
of `nerfaug.jsonio`'s atomic writes); otherwise it is left whole and the refusal names the file.
"""

from __future__ import annotations

import datetime
import json
import os
import shutil
from collections.abc import Sequence
from fnmatch import fnmatchcase
from pathlib import Path

from nerfaug import runfiles
from nerfaug.errors import FolderRefused
from nerfaug.jsonio import TEMP_NAME

MARKER = ".nerfaug"


def mark(folder: Path, kind: str) -> Path:
    """Create `folder` (if needed) and record that nerfaug made it, for `kind` of content."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    created = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    runfiles.write_json(folder, MARKER, {"kind": kind, "created": created})
    return folder


def marked(folder: Path, kind: str | None = None) -> bool:
    """Whether `folder` holds nerfaug's marker (of `kind`, when given).

    Raises:
        PathRefused: the marker leads out of `folder` (a link planted in its place, which would
            lend the folder an outside file's ownership): one line naming it; nothing is read.
    """
    path = runfiles.path_in(folder, MARKER)  # before the read: its refusal is not an unreadable marker
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and (kind is None or data.get("kind") == kind)


def is_empty(folder: Path) -> bool:
    """Whether `folder` is missing or holds nothing."""
    folder = Path(folder)
    return not folder.exists() or (folder.is_dir() and not any(folder.iterdir()))


def foreign_files(folder: Path, holds: Sequence[str]) -> list[str]:
    """The files under `folder` nerfaug does not write into a folder of its kind, as sorted paths
    relative to it: every file (or link) whose path matches none of the glob patterns `holds`
    ("prepared.json", "images/*.png"; `*` crosses folders), nor the marker, nor is named as a
    temporary file of an atomic write (`TEMP_NAME`). Links are not followed."""
    folder = Path(folder)
    found = []
    for top, folders, files in os.walk(folder):
        # A link to a folder is a name like a file's (removing the folder removes the link, not what it leads to).
        for name in files + [d for d in folders if (Path(top) / d).is_symlink()]:
            relative = (Path(top) / name).relative_to(folder).as_posix()
            if relative == MARKER or TEMP_NAME.fullmatch(name) or any(fnmatchcase(relative, p) for p in holds):
                continue
            found.append(relative)
    return sorted(found)


def remove_owned(folder: Path, kind: str, what_to_do: str, holds: Sequence[str]) -> bool:
    """Remove `folder` if nerfaug made it (its marker is of `kind`) and it holds only what
    nerfaug writes into such a folder (`holds`, see `foreign_files`); refuse otherwise.

    Returns whether anything was removed.

    Raises:
        FolderRefused: `folder` exists without the marker, or holds a file nerfaug did not write
            (named); nothing is removed; the message ends with `what_to_do`.
    """
    folder = Path(folder)
    if not folder.exists():
        return False
    if not marked(folder, kind):
        raise FolderRefused(
            f"{folder}: not written by nerfaug (no {MARKER} marker of kind '{kind}'), so it is "
            f"left untouched; {what_to_do}"
        )
    foreign = foreign_files(folder, holds)
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise FolderRefused(
            f"{folder}: holds {foreign[0]}{more}, which nerfaug did not write, so nothing there is "
            f"removed; {what_to_do}"
        )
    shutil.rmtree(folder)
    return True


def overlaps(a: Path, b: Path) -> bool:
    """Whether one of two paths lies inside the other (or they are the same)."""
    a, b = Path(a).resolve(), Path(b).resolve()
    return a == b or a in b.parents or b in a.parents
