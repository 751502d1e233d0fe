"""Typed requests and their one validator: a dataclass whose fields carry their bounds (`Schema`,
checked by pydantic through `checked()`), and `RequestError`, a refused value as one line naming the
field, its value and the problem.

Shared by every room that takes values from a user: the selection settings
(`nerfaug.selection.config`), the capture core's requests (`nerfaug.capture.requests`) and, through
them, the command line and the service; the settings of a command checked when they are made
(`Settings`: an experiment's protocol, a study's options). Nothing here imports torch or numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from contextvars import ContextVar
from dataclasses import fields, is_dataclass
from functools import cache
from typing import TypeVar

from pydantic import ConfigDict, TypeAdapter, ValidationError, model_validator

T = TypeVar("T")


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


# Set while a `Settings` instance is validated: pydantic builds its checked copy through the
# dataclass's `__post_init__`, which must not validate again.
_VALIDATING: ContextVar[bool] = ContextVar("nerfaug_settings_validating", default=False)


def option_name(argument: str) -> str:
    """A setting's path as its command-line option: "n_initial" -> "--n-initial",
    "selection.min_polar" -> "--selection.min-polar", "methods[1]" -> "--methods"."""
    return "--" + argument.partition("[")[0].replace("_", "-")


class Settings:
    """Base of the dataclasses of a command's settings (an experiment's protocol, a study's
    options): each instance is validated when it is made (also by `dataclasses.replace` and by
    tyro), by pydantic, from the bounds in its fields' annotations and the cross-field rules of its
    `model_validator`s. A refused value is a `RequestError` (a ValueError) of one line naming the
    setting as its option: "--n-initial 0: must be >= 1". A cross-field rule raises its own
    ValueError, which already names the option.

    Its fields' types are strict (`nerfaug.nerf.bounds`): an integer setting refuses 32.0, "32"
    and True; a number refuses NaN, infinities and text.
    """

    def __post_init__(self) -> None:
        if not _VALIDATING.get():
            self.check()

    def check(self) -> None:
        """Validate this instance's fields, each against its annotation, then the rules between them.

        Raises:
            RequestError: a setting out of its bounds, named as its option.
            ValueError: a rule between settings, in its own words.
        """
        token = _VALIDATING.set(True)
        try:
            adapter(type(self)).validate_python({f.name: getattr(self, f.name) for f in fields(self) if f.init})
        except ValidationError as error:
            first = error.errors()[0]
            if not first.get("loc"):  # a cross-field rule: its message names the options
                raise ValueError(problem_text(first)) from None
            refused = RequestError.of(first)
            raise RequestError(option_name(refused.argument), refused.value, refused.problem) from None
        finally:
            _VALIDATING.reset(token)


def unchecked(build: Callable[[], T]) -> T:
    """`build()`, with no `Settings` checked while it makes them: for presets made when a module
    is imported (`--help` then builds no validator; each is checked when it is chosen, and a test
    checks them all)."""
    token = _VALIDATING.set(True)
    try:
        return build()
    finally:
        _VALIDATING.reset(token)


def built_then_checked(build: Callable[[], T]) -> T:
    """`build()` (a command-line parser's, which makes the `Settings` of the options given) with
    no `Settings` checked while it makes them, then each one it returns checked: a refusal is then
    the command's one line, not the parser's box (tyro draws its own around an error raised while
    it makes its root class), and `--help`, which ends inside `build`, builds no validator."""
    built = unchecked(build)
    _check_inside(built)
    return built


def _check_inside(value) -> None:
    if isinstance(value, Settings):
        value.check()  # with the settings inside it
    elif is_dataclass(value) and not isinstance(value, type):
        for f in fields(value):
            _check_inside(getattr(value, f.name))
