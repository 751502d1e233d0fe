"""The one containment rule: a path nerfaug opens or writes for a user lies inside the folder it was given.

`inside(root, path, what)` resolves `path` (symbolic links followed, `..` folded) and returns it
when it lies inside `root` (resolved too); otherwise it raises `PathRefused`, one line naming the
path and the folder. The refusal comes before anything at the path is opened and reads the same
whether or not what the path leads to exists, so a refusal tells nothing of the files outside.

Callers open or write the path `inside` returns, never the one they were given: a link swapped
after the check is not followed again. A hard link cannot be told from a file (both names are the
file); nerfaug never writes into an existing file but replaces it (`nerfaug.jsonio`'s atomic
writes) and removes only names, so the other name of a hard link keeps its bytes.
"""

from __future__ import annotations

from pathlib import Path

from nerfaug.errors import PathRefused


def inside(
    root: str | Path,
    path: str | Path,
    what: str,
    *,
    listed_in: str | Path | None = None,
    field: str | None = None,
    value=None,
) -> Path:
    """`path` resolved, when it lies inside the folder `root` (or is `root`).

    Args:
        root: the folder the path was given in (a dataset, the service root, a session folder).
        path: the path to check: absolute, or relative to the working directory (join names
            given relative to `root` as `root / name` first).
        what: what the path is, as the refusal names it ("image", "mask", "session 'a1'").
        listed_in, field, value: where the path was read (a listing file and its field) and the
            value as written there; the refusal names them instead of `path` (`DatasetError`'s form).

    Returns:
        The resolved path: the one to open or write.

    Raises:
        PathRefused: `path` leads outside `root` (through a link, `..` or an absolute path), or
            cannot be followed (a link loop).
    """
    root, path = Path(root), Path(path)
    named = listed_in if listed_in is not None else path
    try:
        real_root, real = root.resolve(), path.resolve()
    except (OSError, RuntimeError) as error:  # a link loop (RuntimeError before Python 3.13), a name too long
        reason = getattr(error, "strerror", None) or "a link loop"
        raise PathRefused(named, f"{what} cannot be followed ({reason})", field=field, value=value) from None
    if not real.is_relative_to(real_root):
        raise PathRefused(named, f"{what} leads outside {root}, the folder it must stay in", field=field, value=value)
    return real


def is_inside(root: str | Path, path: str | Path) -> bool:
    """Whether `inside(root, path, ...)` accepts `path` (for listings, which skip what it refuses)."""
    try:
        inside(root, path, "path")
    except PathRefused:
        return False
    return True
