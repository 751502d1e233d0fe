"""The one place library errors become HTTP status codes: every error is answered as
`{"detail": "one line"}` naming the field and the value (a value the client sent; never what a
file on the server holds)."""

from __future__ import annotations

import dataclasses
import difflib
import re
import types
import typing
from pathlib import Path

from pydantic import BaseModel

from nerfaug.capture.lock import SessionBusy
from nerfaug.capture.pool import TrainingFull
from nerfaug.capture.requests import RequestError
from nerfaug.capture.state import SessionError
from nerfaug.data import DatasetError
from nerfaug.errors import FolderRefused
from nerfaug.health import EmptyModel
from nerfaug.nerf.trainer import TrainingDiverged
from nerfaug.schema import UNKNOWN_FIELD, field_path, problem_text

# How many of a request's problems one answer spells out; beyond them, a count and their fields.
SHOWN_PROBLEMS = 5


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


def problems_line(errors: list[dict], kind=None, field: str = "") -> str:
    """Every problem pydantic found in a request, as one line: the fields it has no place for first
    (each with the field meant, by spelling, or the fields it has), then the rest in pydantic's
    order; past `SHOWN_PROBLEMS`, their count and fields.

    Args:
        errors: pydantic's errors (`ValidationError.errors()`), locations as FastAPI or pydantic give them.
        kind: the request's class (a pydantic model or a dataclass), to name the fields an unknown one
            may have meant; None: unknown fields are named without.
        field: where the request sits in what the client sent ("settings", a form field), prefixed
            to each field.

    Example:
        >>> from pydantic import BaseModel, ConfigDict, TypeAdapter, ValidationError
        >>> class Train(BaseModel):
        ...     model_config = ConfigDict(extra="forbid")
        ...     steps: int
        >>> try:
        ...     TypeAdapter(Train).validate_python({"step": 500})
        ... except ValidationError as error:
        ...     print(problems_line(error.errors(), Train))
        step: unknown field: not one of this request's (did you mean steps?); steps: Field required
    """
    lines, listed = [], set()  # listed: the requests whose fields an answer named already
    for error in sorted(errors, key=lambda e: not _unknown(e)):  # stable: pydantic's order otherwise
        loc = tuple(part for part in error.get("loc", ()) if part not in _TRANSPORT)
        name, problem = field_path((field, *loc) if field else loc), problem_text(error)
        if _unknown(error):  # its value says nothing; the field meant does
            parent = loc[:-1]
            guess = "" if problem != UNKNOWN_FIELD else meant(str(loc[-1]), fields_of(kind, parent), parent in listed)
            listed.add(parent)
            lines.append((name, field_line(name, problem + guess)))
        else:
            value = None if error.get("type") == "missing" else error.get("input")
            lines.append((name, field_line(name, problem, value)))
    shown = [line for _, line in lines[:SHOWN_PROBLEMS]]
    rest = [name or "request" for name, _ in lines[SHOWN_PROBLEMS:]]
    named = ", ".join(rest[:_NAMED]) + (", ..." if len(rest) > _NAMED else "")
    return "; ".join(shown) + (f"; and {len(rest)} more problem{'s' * (len(rest) > 1)} ({named})" if rest else "")


# FastAPI's names for where a field was sent: not part of the field's name.
_TRANSPORT = ("body", "query", "path", "form")
# How many fields of the problems not spelled out an answer names.
_NAMED = 10


def _unknown(error: dict) -> bool:
    """Whether pydantic's `error` is a field the request has no place for."""
    return error.get("type") in ("extra_forbidden", "unexpected_keyword_argument")


def meant(name: str, known: list[str] | None, listed: bool = False) -> str:
    """What an unknown field `name` may have meant among the `known` fields: the closest by spelling,
    else all of them unless `listed` already (nothing when the request's fields are not known)."""
    close = difflib.get_close_matches(name, known or [], n=2)
    if close:
        return f" (did you mean {' or '.join(close)}?)"
    return f" (its fields: {', '.join(known)})" if known and not listed else ""


def fields_of(kind, loc: tuple = ()) -> list[str] | None:
    """The fields of the request at `loc` inside the request class `kind` (a pydantic model or a
    dataclass; through optional, annotated, list and dict types), in their order; None where no
    request class is there.

    Example:
        >>> from nerfaug.capture.proposal_request import ProposalRequest
        >>> fields_of(ProposalRequest, ("constraints",))[:3]
        ['elevation', 'azimuth', 'radius']
    """
    for part in loc:
        kind = _inner(kind, part)
    found = [list(own) for member in _members(kind) if (own := _fields(member)) is not None]
    return found[0] if found else None


def _members(kind) -> list:
    """The classes a type may be: itself, or those of an `Annotated`'s type or of a union's members."""
    if typing.get_origin(kind) is typing.Annotated:
        return _members(typing.get_args(kind)[0])
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return [member for arg in typing.get_args(kind) for member in _members(arg)]
    return [kind]


def _fields(kind) -> dict | None:
    """A request class's fields and their types (None for any other type)."""
    if isinstance(kind, type) and issubclass(kind, BaseModel):
        return {name: info.annotation for name, info in kind.model_fields.items()}
    if isinstance(kind, type) and dataclasses.is_dataclass(kind):
        try:
            hints = typing.get_type_hints(kind, include_extras=True)
        except (NameError, TypeError):  # an annotation not resolvable here: its fields' names alone
            hints = {}
        return {f.name: hints.get(f.name) for f in dataclasses.fields(kind)}
    return None


def _inner(kind, part):
    """The type at `part` (a field's name, a list's index or a dict's key) inside `kind`."""
    for member in _members(kind):
        own = _fields(member)
        if own is not None and part in own:
            return own[part]
        origin, args = typing.get_origin(member), typing.get_args(member)
        if isinstance(part, int) and origin in (list, tuple) and args:
            return args[0]
        if origin is dict and len(args) == 2:
            return args[1]
    return None


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


# An absolute path in a message (not the "//" of a URL, nor the second half of "a/b"), unquoted:
# a quoted one is a value the client sent, shown as sent (`dataset '/etc': give a folder relative...`).
_ABSOLUTE_PATH = re.compile(r"(?<![\w.:/'\"])/(?:[^\s/,;'\"()]+/)*[^\s/,;'\"()]+")


def public_text(text: str, root: Path) -> str:
    """`text` as a client may read it: a path under the service's `root` relative to it (as the
    client names files: sessions and datasets by their names), the root itself as "the service
    root", any other absolute path by its file name alone (the server's own layout is none of the
    client's business); a quoted path is a value the client sent, kept as sent. The root counts
    as given (made absolute) and resolved, so a path shown either way is relativised.

    Example:
        >>> public_text("weights from /srv/venv/lpips/alexnet.ckpt; data /srv/root/held-out/test", Path("/srv/root"))
        'weights from alexnet.ckpt; data held-out/test'
        >>> public_text("/srv/root/s/pool.json: this path leads outside /srv/root/s", Path("/srv/root"))
        's/pool.json: this path leads outside s'
    """
    roots = list(dict.fromkeys([Path(root).absolute(), Path(root).resolve()]))

    def shown(match: re.Match) -> str:
        path = Path(match.group(0))
        for real in roots:
            if path == real:
                return "the service root"
            if path.is_relative_to(real):
                return str(path.relative_to(real))
        return path.name

    text = _ABSOLUTE_PATH.sub(shown, text)
    if not Path(root).is_absolute():  # a root given relative to the server's folder is named so in messages too
        given = re.escape(Path(root).as_posix())
        text = re.sub(rf"(?<![\w./-]){given}/(?=\S)", "", text)
        text = re.sub(rf"(?<![\w./-]){given}(?![\w./-])", "the service root", text)
    return text


def public_answer(error: BaseException, root: Path) -> tuple[int, str]:
    """`status_of(error)` with its line as a client may read it (`public_text`): every answer the
    service gives, a failed training job's record included, goes through here."""
    status, message = status_of(error)
    return status, public_text(message, root)


def headers_of(error: BaseException) -> dict[str, str] | None:
    """The headers of the answer to `error`: Retry-After where the client is to ask again later."""
    if isinstance(error, TrainingFull):
        return {"Retry-After": str(error.retry_after)}
    return getattr(error, "headers", None)
