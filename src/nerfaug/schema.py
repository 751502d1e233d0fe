"""Typed requests and their one validator: a dataclass whose fields carry their bounds (`Schema`,
checked by pydantic through `checked()`), and `RequestError`, a refused value as one line naming the
field, its value and the problem.

Shared by every room that takes values from a user: the selection settings
(`nerfaug.selection.config`), the capture core's requests (`nerfaug.capture.requests`) and, through
them, the command line and the service. Nothing here imports torch or numpy.
"""

from __future__ import annotations

from dataclasses import fields
from functools import cache

from pydantic import ConfigDict, TypeAdapter, ValidationError, model_validator


class RequestError(ValueError):
    """A value of a request is refused: names the field (dotted, items as [i]), its value and why.

    Attributes:
        argument: the field as the library spells it ("n_candidates", "constraints.elevation",
            "candidates[3]"); empty for the request as a whole.
        value: the value given.
        problem: what is wrong with it.
    """

    def __init__(self, argument: str, value, problem: str):
        self.argument, self.value, self.problem = argument, value, problem
        shown = repr(value) if isinstance(value, str) else value
        super().__init__(f"{argument} {shown}: {problem}")

    @classmethod
    def of(cls, error: ValidationError | dict) -> RequestError:
        """The first error pydantic found, as a `RequestError`."""
        first = error.errors()[0] if isinstance(error, ValidationError) else error
        value = None if first.get("type") == "missing" else first.get("input")
        return cls(field_path(first.get("loc", ())), value, problem_text(first))


# Where a service's framework puts a field (FastAPI's "body", "query", ...): not part of its name.
_TRANSPORT = ("body", "query", "path", "form")
# What a field no schema has is refused with (pydantic's "Extra inputs are not permitted",
# "Unexpected keyword argument").
UNKNOWN_FIELD = "unknown field: not one of this request's"
# Fields that were renamed, so that each concept has one name across the command line, the service
# and session.json: old -> new. A request with an old name is refused with the new one.
RENAMED_FIELDS = {"preset": "engine"}
# Pydantic's words for a bound, shorter: "must be >= 1", as the commands have always said it.
_BOUNDS = {"greater_than_equal": ">=", "greater_than": ">", "less_than_equal": "<=", "less_than": "<"}


def field_path(loc) -> str:
    """A pydantic error's location as a field name: ("candidates", 3) -> "candidates[3]"."""
    text = ""
    for part in loc:
        if part in _TRANSPORT:
            continue
        text += f"[{part}]" if isinstance(part, int) else f".{part}" if text else str(part)
    return text


def problem_text(error: dict) -> str:
    """A pydantic error's message, without its "Value error, " prefix and with bounds as ">= 1"."""
    kind, context = error.get("type", ""), error.get("ctx") or {}
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):  # a model's, a dataclass's
        new = RENAMED_FIELDS.get(field_path(error.get("loc", ())))  # a request's own field, not a nested one
        return f"{UNKNOWN_FIELD}; renamed {new}" if new else UNKNOWN_FIELD
    if kind in _BOUNDS and context:
        bound = next(iter(context.values()))
        return f"must be {_BOUNDS[kind]} {bound:g}" if isinstance(bound, float) else f"must be {_BOUNDS[kind]} {bound}"
    return str(error.get("msg", "invalid")).removeprefix("Value error, ")


@cache
def adapter(kind) -> TypeAdapter:
    return TypeAdapter(kind)


def validated(kind, value, field: str = ""):
    """`value` validated as `kind` (a schema class or type); RequestError naming the first
    refused field (prefixed with `field`) otherwise."""
    try:
        return adapter(kind).validate_python(value)
    except ValidationError as error:
        first = error.errors()[0]
        loc = (field, *first.get("loc", ())) if field else first.get("loc", ())
        raise RequestError.of({**first, "loc": loc}) from None


# A dataclass tyro reads: unknown fields and non-finite numbers refused, validated again whenever
# `checked` is called, each field's docstring its description.
SCHEMA = ConfigDict(extra="forbid", allow_inf_nan=False, revalidate_instances="always", use_attribute_docstrings=True)


class Schema:
    """Base of the dataclasses tyro reads: `checked()` is their one validator.

    A value pydantic has validated (through `checked()`, or as a service's request body) is marked
    as checked, so that the layers it then passes through take it as it is: each value is checked
    once, where it enters. Setting a field clears the mark.
    """

    def checked(self):
        """This request validated: numbers in range, names known, defaults filled in (itself
        when it was checked already and not changed since).

        Raises:
            RequestError: naming the first refused field and its value.
        """
        return self if is_checked(self) else validated(type(self), self)

    @model_validator(mode="after")
    def _validated(self):
        # A request inside it was validated too, or is its field's default (pydantic does not
        # validate defaults: they hold by construction).
        for value in [self, *(getattr(self, f.name) for f in fields(self))]:
            if isinstance(value, Schema):
                object.__setattr__(value, _CHECKED, True)
        return self

    def __setattr__(self, name: str, value) -> None:
        self.__dict__.pop(_CHECKED, None)
        super().__setattr__(name, value)


# The mark a validated `Schema` carries (an attribute beside its fields, not one of them).
_CHECKED = "_schema_checked"


def is_checked(value: Schema) -> bool:
    """Whether `value` was validated and neither it nor a request inside it was changed since."""
    return value.__dict__.get(_CHECKED, False) and all(
        is_checked(inner) for f in fields(value) if isinstance(inner := getattr(value, f.name), Schema)
    )
