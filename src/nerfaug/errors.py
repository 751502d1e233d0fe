"""The project's errors: each message is complete (which file, field and value, and what to do),
so the CLI prints it as one line without a traceback.

`exit_code` is what the `nerfaug` command exits with: 2 for bad input (a value, a file, a folder
the user gave), 1 for a failure of the work itself. `DatasetError` (`nerfaug.data`) is a
`ValueError` and also means bad input.
"""

from __future__ import annotations


class NerfaugError(Exception):
    """Base of the project's own errors; the message says what to do."""

    exit_code = 2


class FolderRefused(NerfaugError):
    """An operation would delete or overwrite files that nerfaug cannot prove it wrote."""


class Interrupted(NerfaugError):
    """Ctrl-C, with one line saying what was kept."""

    exit_code = 130
