"""What nerfaug may delete or overwrite: only folders it created, proved by a marker file.

Every folder nerfaug creates and may later remove or rewrite (a session's run folder and its
dataset copy, an export, a results folder's run folders) gets a small JSON marker, `.nerfaug`,
written before anything else goes in. A folder without it is the user's and is never removed
or written over; the error says which folder and how to proceed.
"""

from __future__ import annotations

import datetime
import json
import shutil
from pathlib import Path

from nerfaug.errors import FolderRefused
from nerfaug.jsonio import atomic_write_json

MARKER = ".nerfaug"


def mark(folder: Path, kind: str) -> Path:
    """Create `folder` (if needed) and record that nerfaug made it, for `kind` of content."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    created = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    atomic_write_json(folder / MARKER, {"kind": kind, "created": created})
    return folder


def marked(folder: Path, kind: str | None = None) -> bool:
    """Whether `folder` holds nerfaug's marker (of `kind`, when given)."""
    try:
        data = json.loads((Path(folder) / MARKER).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and (kind is None or data.get("kind") == kind)


def is_empty(folder: Path) -> bool:
    """Whether `folder` is missing or holds nothing."""
    folder = Path(folder)
    return not folder.exists() or (folder.is_dir() and not any(folder.iterdir()))


def remove_owned(folder: Path, kind: str, what_to_do: str) -> bool:
    """Remove `folder` if nerfaug made it (its marker is of `kind`); refuse otherwise.

    Returns whether anything was removed.

    Raises:
        FolderRefused: `folder` exists without the marker; the message ends with `what_to_do`.
    """
    folder = Path(folder)
    if not folder.exists():
        return False
    if not marked(folder, kind):
        raise FolderRefused(
            f"{folder}: not written by nerfaug (no {MARKER} marker of kind '{kind}'), so it is "
            f"left untouched; {what_to_do}"
        )
    shutil.rmtree(folder)
    return True


def overlaps(a: Path, b: Path) -> bool:
    """Whether one of two paths lies inside the other (or they are the same)."""
    a, b = Path(a).resolve(), Path(b).resolve()
    return a == b or a in b.parents or b in a.parents
