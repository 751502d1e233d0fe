"""A NeRF engine's settings on the command line, apart from a command's own options, and
`nerfaug engines`, which lists them.

The commands that train (`ENGINE_COMMANDS`) take any setting of the engine as
`--engine.GROUP.SETTING VALUE` beside `--engine NAME`, in any order. Their `--help` names that form
in one line and leaves the list (every setting, by component) to `nerfaug engines`: the
settings are read from the command line here (`split_engine_options`, `engine_settings_given`),
not among the command's options, so a command's help stays short and its parse quick, and the
settings' form (whose help reads their docstrings) is built only when one is given.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Annotated

import tyro

# The commands that build a NeRF engine, and so take its settings.
ENGINE_COMMANDS = ("train", "run", "study", "serve")
PREFIX = "--engine."


def split_engine_options(args: list[str]) -> tuple[list[str], list[str]]:
    """`args` parted into the `--engine.GROUP.SETTING` options with their values, and the rest
    (`--engine NAME` among the rest), each in its order.

    A setting takes the one word after it (`--engine.field.hidden-dim 32`, also written
    `--engine.field.hidden-dim=32`), or, for a list of numbers, every word up to the next option.

    Example:
        >>> split_engine_options(["DATA", "--engine.sampler.proposal.samples", "64", "32", "--engine", "paper"])
        (['--engine.sampler.proposal.samples', '64', '32'], ['DATA', '--engine', 'paper'])
    """
    engine: list[str] = []
    rest: list[str] = []
    at = 0
    while at < len(args):
        word = args[at]
        at += 1
        if word == "--":  # what follows is positional
            rest += args[at - 1 :]
            break
        if not word.startswith(PREFIX):
            rest.append(word)
            continue
        engine.append(word)
        name, equals, _ = word.partition("=")
        many = _takes_a_list(name)
        while not equals and at < len(args) and not args[at].startswith("--") and args[at] != "-h":
            engine.append(args[at])
            at += 1
            if not many:
                break
    return engine, rest


def _takes_a_list(option: str) -> bool:
    """Whether the engine setting `option` (`--engine.sampler.proposal.samples`) is a list of values;
    False for one no engine has (the settings' parser names it)."""
    from nerfaug.nerf import names
    from nerfaug.nerf.config import NerfConfig

    path = tuple(option.removeprefix(PREFIX).replace("-", "_").split("."))
    return typing.get_origin(names.kind(NerfConfig, path)) is tuple


def _options_type() -> type:
    """A dataclass of one field, `engine`: the settings' form (`EngineSettings`), so that tyro reads
    them as `--engine.GROUP.SETTING`."""
    from nerfaug.nerf.engine_form import EngineSettings as form

    return dataclasses.make_dataclass(
        "EngineSettingsOptions",
        [("engine", Annotated[form, tyro.conf.arg(help="")], dataclasses.field(default_factory=form))],
        namespace={"__doc__": f"Every setting of a NeRF engine: an option of {', '.join(ENGINE_COMMANDS)}."},
    )


def engine_settings_given(args: list[str], prog: str) -> dict:
    """The engine settings `args` give (`split_engine_options`'s first part), flat name -> value:
    `{"hidden_dim": 32}`; tyro's refusal (exit 2) for an unknown setting or a value of the wrong type."""
    if not args:
        return {}
    return tyro.cli(_options_type(), args=args, prog=prog).engine.given()


def engines() -> None:
    """List the NeRF engines (--engine NAME) and every engine setting (--engine.GROUP.SETTING VALUE)
    that `nerfaug train`, `run`, `study` and `serve` take."""
    from nerfaug.nerf.config import PRESETS

    print(f"NeRF engines (--engine NAME): {', '.join(PRESETS)}.")
    print(
        "Their settings, by component, as options of `nerfaug train`, `run`, `study` and `serve` "
        "(each over the value the engine gives it):\n"
    )
    try:
        tyro.cli(_options_type(), args=["--help"], prog=f"nerfaug {{{','.join(ENGINE_COMMANDS)}}}")
    except SystemExit as done:
        if done.code not in (0, None):
            raise
