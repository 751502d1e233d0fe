"""The one place library errors become HTTP status codes: every error is answered as
`{"detail": "one line"}` naming the field and the value (a value the client sent; never what a
file on the server holds)."""

from __future__ import annotations

import re
from pathlib import Path

from nerfaug.capture.lock import SessionBusy
from nerfaug.capture.pool import TrainingFull
from nerfaug.capture.requests import RequestError
from nerfaug.capture.state import SessionError
from nerfaug.data import DatasetError
from nerfaug.errors import FolderRefused
from nerfaug.health import EmptyModel
from nerfaug.nerf.trainer import TrainingDiverged


class ServiceError(Exception):
    """An answer other than success: an HTTP status and one line saying why."""

    def __init__(self, status: int, message: str, headers: dict[str, str] | None = None):
        super().__init__(message)
        self.status = status
        self.message = " ".join(message.split())
        self.headers = headers


def bad_input(message: str) -> ServiceError:
    """422: a value the client sent is wrong (the message names the field)."""
    return ServiceError(422, message)


def field_line(field: str, problem: str, value=None) -> str:
    """A refused value as the service says it, in one line: `n: must be >= 1 (got 0)`."""
    text = f"{field or 'request'}: {problem}" + ("" if value is None else f" (got {str(value)[:80]!r})")
    return " ".join(text.split())


def status_of(error: BaseException) -> tuple[int, str]:
    """The HTTP status and one-line message for an error raised inside a request.

    422: bad input (`DatasetError`, `ValueError`: a value, pose or image the client sent);
    409: the session's folder refuses the operation, is inconsistent, or another process (or a
    training job) is changing it (`FolderRefused`, `SessionError`, `SessionBusy`), or its NeRF is
    empty and the proposal did not say `allow_empty` (`EmptyModel`); 404: a file or
    session the request names does not exist; 503: as many sessions are training as the service
    runs at once (`TrainingFull`, with Retry-After: `headers_of`); 500: anything else, named as an
    internal error.
    """
    if isinstance(error, ServiceError):
        return error.status, error.message
    text = " ".join(str(error).split()) or type(error).__name__
    if isinstance(error, RequestError):
        text = field_line(error.argument, error.problem, error.value)
    if isinstance(error, DatasetError) and error.value is not None:
        # The value may be what a file holds (a dataset's JSON); the file, field and problem say enough.
        field = f", field '{error.field}'" if error.field is not None else ""
        text = " ".join(f"{error.path}{field}: {error.problem}".split())
    if isinstance(error, TrainingFull):
        return 503, text
    if isinstance(error, TrainingDiverged):  # the engine's settings' fault, not the service's
        return 422, f"{text}: the session's engine settings do not train on this data (e.g. a learning rate too large)"
    if isinstance(error, (FolderRefused, SessionError, SessionBusy, EmptyModel)):
        return 409, text
    if isinstance(error, (DatasetError, ValueError)):
        return 422, text
    if isinstance(error, FileNotFoundError):
        return 404, text
    return 500, f"internal error ({type(error).__name__}: {text})"


# An absolute path in a message (not the "//" of a URL, nor the second half of "a/b").
_ABSOLUTE_PATH = re.compile(r"(?<![\w.:/])/(?:[^\s/,;'\"()]+/)*[^\s/,;'\"()]+")


def public_text(text: str, root: Path) -> str:
    """`text` as a client may read it: a path under the service's `root` relative to it (as the
    client names files), any other absolute path by its file name alone (the server's own layout is
    none of the client's business).

    Example:
        >>> public_text("weights from /srv/venv/lpips/alexnet.ckpt; data /srv/root/held-out/test", Path("/srv/root"))
        'weights from alexnet.ckpt; data held-out/test'
    """

    def shown(match: re.Match) -> str:
        path = Path(match.group(0))
        if path.is_relative_to(root):
            return str(path.relative_to(root)) if path != root else "."
        return path.name

    return _ABSOLUTE_PATH.sub(shown, text)


def headers_of(error: BaseException) -> dict[str, str] | None:
    """The headers of the answer to `error`: Retry-After where the client is to ask again later."""
    if isinstance(error, TrainingFull):
        return {"Retry-After": str(error.retry_after)}
    return getattr(error, "headers", None)
