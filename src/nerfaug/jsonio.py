"""JSON files and atomic writes, without torch or imageio, for every module that stores state.

`read_json` raises `DatasetError` (a `ValueError` naming the file and the problem), as every caller
reads a file a user gave or may have edited. The writers replace a file in one step: a reader sees
the old file or the whole new one, never a part, even if the process dies mid-write.
"""

from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path

from nerfaug.errors import DatasetError

# The process's umask, read once (os.umask can only be read by setting it); written files get
# the permissions a plain open() would give them.
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def read_json(path: str | Path) -> dict:
    """The JSON object in `path`, or a DatasetError saying why not (missing, unreadable, not
    UTF-8, invalid JSON with line and column, or not an object at the top level)."""
    path = Path(path)
    if not path.exists():
        raise DatasetError(path, "file not found")
    try:
        text = path.read_text(encoding="utf-8-sig")  # a leading byte-order mark (Windows editors) is fine
    except UnicodeDecodeError as error:
        raise DatasetError(path, f"not UTF-8 text (invalid byte at offset {error.start})") from None
    except OSError as error:
        raise DatasetError(path, f"cannot read the file: {error.strerror or error}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise DatasetError(path, f"invalid JSON at line {error.lineno} column {error.colno}: {error.msg}") from None
    except (ValueError, RecursionError) as error:  # an integer of > 4300 digits; nesting too deep
        raise DatasetError(path, f"invalid JSON: {str(error).splitlines()[0] or type(error).__name__}") from None
    if not isinstance(data, dict):
        raise DatasetError(path, "expected a JSON object at the top level", value=type(data).__name__)
    return data


# The name of the file `atomic_write_bytes` writes before it replaces NAME: `.NAME.XXXXXXXX.tmp`
# beside it (mkstemp's eight random characters). A killed process leaves it; nothing else has it.
TEMP_NAME = re.compile(r"\..+\.[a-z0-9_]{8}\.tmp")


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write `data` to `path` so that readers see the old file or the whole new one, never a part."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp makes 0600 files; give the usual permissions
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def remove_temp_files(folder: str | Path) -> list[Path]:
    """Remove what a killed `atomic_write_bytes` left directly in `folder`: plain files named as
    its temporary files (`TEMP_NAME`), nothing else. Call it only where no other process writes
    into `folder` at the time (a session's folder, under its lock). Returns the removed paths."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    found = [p for p in folder.iterdir() if TEMP_NAME.fullmatch(p.name) and p.is_file() and not p.is_symlink()]
    for path in found:
        path.unlink(missing_ok=True)
    return sorted(found)


def atomic_write_text(path: str | Path, text: str) -> None:
    """`atomic_write_bytes` of `text` encoded as UTF-8."""
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | Path, data) -> None:
    """`data` as indented JSON (non-finite floats as `Infinity`/`NaN`, which `read_json` reads)."""
    atomic_write_text(path, json.dumps(data, indent=2) + "\n")


__all__ = [
    "TEMP_NAME",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "read_json",
    "remove_temp_files",
]
