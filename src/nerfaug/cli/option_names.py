"""The capture commands' refusals in the words of their command line: a schema's field as the
option that sets it, and a `RequestError` as `--option value: problem`. Light (no torch): both the
commands' options (`nerfaug.cli.train`) and their work (`nerfaug.cli.train_work`) use it.
"""

from __future__ import annotations

import contextlib
import dataclasses

from nerfaug.capture.requests import RequestError, words
from nerfaug.nerf.engine import Engine
from nerfaug.nerf.footprint import check_engine_fits


def option(field: str) -> str:
    """A schema's field as the option that sets it: "estimate_up" -> "--estimate-up"."""
    return "--" + field.replace("_", "-")


@contextlib.contextmanager
def as_options(omitted: tuple[str, ...] = ()):
    """Show a `RequestError` as this command's option and value: `--n-candidates 0: must be >= 1`
    (fields under `omitted`, e.g. "constraints.", are options without that prefix)."""
    try:
        yield
    except RequestError as error:
        name = error.argument
        for prefix in omitted:
            name = name.removeprefix(prefix)
        value = "" if dataclasses.is_dataclass(error.value) else f" {words(error.value)}"  # a group of options
        raise ValueError(f"{option(name.partition('[')[0])}{value}: {error.problem}") from None


def checked(request):
    """`request.checked()`, a refused value shown as its option."""
    with as_options(omitted=("constraints.",)):
        return request.checked()


def engine_refusal(error: ValueError) -> str:
    """An engine setting's refusal as the option that sets it: `--engine.field.hidden-dim 0: must
    be >= 1` (a refusal of settings together, or of the name: `--engine: ...`)."""
    if isinstance(error, RequestError) and error.argument:
        return f"--engine.{error.argument.replace('_', '-')} {words(error.value)}: {error.problem}"
    return f"--engine: {error}"


def engine_with(engine, settings: dict) -> Engine:
    """The engine `engine` (an `Engine`, or a name) with the --engine.GROUP.SETTING given
    (`settings`, nested) changed, read and checked once; one line naming the option (SystemExit)
    when a setting is refused or makes a run too large for this machine's memory."""
    try:
        return check_engine_fits(Engine.read(engine).with_settings(settings))
    except ValueError as error:
        raise SystemExit(engine_refusal(error)) from None
