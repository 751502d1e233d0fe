"""A NeRF engine's settings as a command's options: `--engine.field.hidden-dim 32` for every
setting of `NerfConfig`, each unset unless given (`EngineSettings`).

Apart from `nerfaug.nerf.config` because building it reads every setting's docstring (their help),
which takes longer than the rest of that module's import: only a command given an engine setting,
and `nerfaug engines`, build it (`nerfaug.cli.engine_options`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import field, fields, is_dataclass
from typing import Annotated, Any, Literal, get_args, get_origin, get_type_hints

import tyro

from nerfaug.nerf import names
from nerfaug.nerf.config import FLAT_NAMES, NerfConfig


def _given_form(cls: type, path: tuple[str, ...] = ()) -> type:
    """A frozen dataclass with `cls`'s settings by name, each leaf None unless given, for tyro to
    read: a component choice is its chooser (`--engine.field.encoding hash`) and every part's
    settings under its group (`--engine.field.hash.levels 8`), as names give them.

    Hand-written because tyro's own ways to override a preset's fields (subcommands per preset,
    `tyro.extras.overridable_config_cli`) choose the preset by a positional subcommand, and every
    command here takes it as `--engine NAME`: the form below lets `--engine.field.hidden-dim 32`
    sit beside `--engine NAME` in any order and on any command, tyro parsing and checking each value.
    """
    from tyro._docstrings import get_field_docstring  # the settings' docstrings as their help

    hints, form = get_type_hints(cls), []
    for f in fields(cls):
        kind, groups = hints[f.name], []
        if parts := names.choice(cls, f.name):
            groups = [(part.GROUP, _given_form(part, (*path, part.GROUP))) for part in parts]
            kind = Literal[tuple(part.NAME for part in parts)]  # type: ignore[valid-type]
        elif is_dataclass(kind):
            sub = _given_form(kind, (*path, f.name))
            form.append((f.name, sub, field(default_factory=sub)))
            continue
        help_text = " ".join((get_field_docstring(cls, f.name, ()) or "").split())
        marks = tyro.conf.arg(help=help_text, metavar=_metavar(kind), help_behavior_hint="(default: the engine's)")
        form.append((f.name, Annotated[kind | None, marks], None))  # type: ignore[valid-type]
        form += [(group, sub, field(default_factory=sub)) for group, sub in groups]
    namespace = {"__doc__": cls.__doc__}
    if not path:
        namespace["given"] = _given_settings
    return dataclasses.make_dataclass(f"Given{cls.__name__}", form, frozen=True, namespace=namespace)


def _metavar(kind: Any) -> str:
    """How `--help` writes a value of type `kind`: INT, FLOAT, STR, {a,b}, INT [INT ...]."""
    if kind is bool:
        return "{True,False}"
    if get_origin(kind) is Literal:
        return "{" + ",".join(get_args(kind)) + "}"
    if get_origin(kind) is tuple:
        one = _metavar(get_args(kind)[0])
        return f"{one} [{one} ...]"
    return {int: "INT", float: "FLOAT"}.get(kind, "STR")


def _given_settings(form: Any) -> dict[str, Any]:
    """Every setting given in `form` (an `EngineSettings`), nested by component as `NerfConfig`
    nests them: {"field": {"hidden_dim": 32}}."""
    given: dict[str, Any] = {}
    for path in FLAT_NAMES.values():
        value = form
        for name in path:
            value = getattr(value, name)
        if value is not None:
            group = given
            for step in path[:-1]:
                group = group.setdefault(step, {})
            group[path[-1]] = value
    return given


EngineSettings = _given_form(NerfConfig)
"""The engine's settings as options of a command (`--engine.field.hidden-dim 32`), each None unless
given; `EngineSettings().given()` are those given, nested, for `Engine.with_settings`."""
