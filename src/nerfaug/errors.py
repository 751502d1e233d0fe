"""The project's errors: each message is complete (which file, field and value, and what to do),
so the CLI prints it as one line without a traceback.

`exit_code` is what the `nerfaug` command exits with: 2 for bad input (a value, a file, a folder
the user gave), 1 for a failure of the work itself. `DatasetError` is a `ValueError` and also
means bad input; it lives here, beside the others, so that `nerfaug.jsonio` (a leaf every room
uses) can raise it, and `nerfaug.data` re-exports it.
"""

from __future__ import annotations

from pathlib import Path


class NerfaugError(Exception):
    """Base of the project's own errors; the message says what to do."""

    exit_code = 2


class FolderRefused(NerfaugError):
    """An operation would delete or overwrite files that nerfaug cannot prove it wrote."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, as Ctrl-C is (`nerfaug.cli` installs the handler):
    `finally` blocks run, so a child process (the Blender render worker, a sweep's workers) is
    stopped and what was saved is kept."""


class Interrupted(NerfaugError):
    """Ctrl-C (exit 130) or SIGTERM (exit 143), with one line saying what was kept."""

    exit_code = 130

    def __init__(self, message: str, stop: KeyboardInterrupt | None = None):
        super().__init__(message)
        if isinstance(stop, Terminated):
            self.exit_code = 143

    @staticmethod
    def why(stop: KeyboardInterrupt) -> str:
        """How the program was stopped, as its last line says it."""
        return "stopped (SIGTERM)" if isinstance(stop, Terminated) else "interrupted"


class DatasetError(ValueError):
    """A dataset file is missing or malformed.

    The message always says which file, which frame/field and what value was found, so a user
    can fix the data without reading the code.
    """

    def __init__(self, path: str | Path, problem: str, field: str | None = None, value=None):
        self.path, self.field, self.value, self.problem = Path(path), field, value, problem
        where = f"{path}"
        if field is not None:
            where += f", field '{field}'"
        message = f"{where}: {problem}"
        if value is not None:
            text = repr(value)
            message += f" (got {text[:200] + '...' if len(text) > 200 else text})"
        # One line whatever the file held: a newline in a value or path is shown escaped.
        super().__init__(message.replace("\r", "\\r").replace("\n", "\\n"))


class PathRefused(DatasetError):
    """A path given or listed under a folder leads out of it (a symbolic link, `..`, an absolute
    path) or cannot be followed (a link loop): refused before anything there is opened
    (`nerfaug.containment.inside`). Bad input, as a `DatasetError` is."""
