"""The one error type for bad dataset input; its message names the file, the field and the value."""

from __future__ import annotations

from pathlib import Path


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
