"""`Engine`: the engine a command trains with, as the user names it (a preset and the settings
changed over it, by their nested names) and resolved, once, into its `NerfConfig`.

One name per setting: `--engine.field.hidden-dim 48` on the command line, `{"preset":
"nerfacto-cpu", "field": {"hidden_dim": 48}}` over HTTP and in records. An engine is read once
where it enters (`Engine.read`): an unknown preset or setting, a value out of its bounds, or a
setting the engine does not read (a hash grid's setting on a K-planes engine) is refused there as
one `RequestError` naming the setting by its path; past that the `Engine` is handed on as it is
and its `config` is what trains.

A study names an engine's cell by the same nested names, "nerfacto-cpu+field.hidden_dim=48"
(`Engine.cell_name`). The flat form of earlier records ("nerfacto-cpu+hidden_dim=48",
`nerf.config.parse_variant`) is read here and nowhere else. Light: no torch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from tyro.constructors import PrimitiveConstructorSpec

from nerfaug.nerf import names
from nerfaug.nerf.config import (
    FLAT_NAMES,
    PRESETS,
    VARIANT_SEPARATOR,
    NerfConfig,
    _variant_text,
    parse_variant,
    preset_value,
)
from nerfaug.registry import lookup
from nerfaug.schema import RequestError

PRESET_KEY = "preset"
_FLAT_BY_PATH = {path: flat for flat, path in FLAT_NAMES.items()}
"""Each setting's nested name (its path) -> the flat name earlier records gave it."""


@dataclass(frozen=True, eq=False)
class Engine:
    """A preset with some settings changed, resolved.

    Attributes:
        preset: the preset's name (`nerf.config.PRESETS`).
        settings: the settings changed from the preset's, nested by component as `NerfConfig` is
            ({"field": {"hidden_dim": 48}}); only those that differ from the preset's.
        config: the engine's complete settings.
    """

    preset: str
    settings: dict = field(default_factory=dict)
    config: NerfConfig = field(default=None, repr=False)  # type: ignore[assignment]

    @classmethod
    def read(cls, value: Any) -> Engine:
        """An engine from what a user or a record gives: an `Engine` (as it is), a preset's name,
        `{"preset": NAME, GROUP: {SETTING: VALUE, ...}, ...}`, or an earlier record's flat
        variant name ("nerfacto-cpu+hidden_dim=48").

        Raises:
            RequestError: naming the setting (its path, "field.hidden_dim") and its value; or a
                ValueError naming the preset.
        """
        if isinstance(value, Engine):
            return value
        if isinstance(value, RefusedEngine):
            raise ValueError(f"engine {value.given!r}: {value.why}")
        if isinstance(value, str):
            base, flat = parse_variant(flat_variant(value))
            return cls.of(base, _nested({FLAT_NAMES[name]: v for name, v in flat.items()}))
        if isinstance(value, dict):
            rest = dict(value)
            name = rest.pop(PRESET_KEY, None)
            if not isinstance(name, str):
                raise RequestError(PRESET_KEY, name, f"must name a preset: one of {', '.join(PRESETS)}")
            return cls.of(name, rest)
        raise RequestError("", value, "an engine is a preset's name or {'preset': NAME, GROUP: {SETTING: VALUE}}")

    @classmethod
    def of(cls, preset: str, settings: dict | None = None) -> Engine:
        """The preset `preset` with the nested `settings` changed, checked (see `read`)."""
        base = lookup(PRESETS, PRESETS.kind, preset)
        changes = _leaves(settings or {})
        if not changes:
            return cls(preset, {}, base)
        config = base.changed(changes)  # the one check of names, bounds, types and parts used
        own = {path: names.get(config, path) for path in changes}
        own = {path: value for path, value in own.items() if value != preset_value(base, path)}
        return cls(preset, _nested(own), config)

    def with_settings(self, settings: dict) -> Engine:
        """This engine with the nested `settings` changed too, checked."""
        return Engine.of(self.preset, _merge(self.settings, settings)) if settings else self

    def changes(self) -> dict[tuple[str, ...], Any]:
        """The settings changed from the preset's, path -> value."""
        return _leaves(self.settings)

    def record(self) -> str | dict:
        """As records and the service write it: the preset's name alone, or {"preset": NAME,
        GROUP: {...}} (tuples as lists)."""
        if not self.settings:
            return self.preset
        return {PRESET_KEY: self.preset, **_plain(self.settings)}

    def options(self) -> str:
        """As the command line names it: "--engine test --engine.optimiser.field-lr 1e30"."""
        given = [f"--engine.{'.'.join(path).replace('_', '-')} {_words(v)}" for path, v in self.changes().items()]
        return " ".join([f"--engine {self.preset}", *given])

    def cell_name(self) -> str:
        """The name a study gives this engine's cell, table rows and folder: the preset, then each
        setting changed by its nested name, "nerfacto-cpu+field.hidden_dim=48" (`read` reads it)."""
        return self._variant_name(".".join)

    def flat_name(self) -> str:
        """The name earlier records gave this engine ("nerfacto-cpu+hidden_dim=48"): what a
        fingerprint hashes as "engine" (`experiment.fingerprints`), so that results recorded under
        it keep theirs."""
        return self._variant_name(_FLAT_BY_PATH.__getitem__)

    def _variant_name(self, setting_name) -> str:
        """The preset, then each changed setting as "NAME=VALUE" in the settings' order, NAME being
        `setting_name(path)`."""
        parts = [f"{setting_name(path)}={_text(v)}" for path, v in _in_flat_order(self.changes())]
        return VARIANT_SEPARATOR.join([self.preset, *parts])

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Engine) and (self.preset, self.config) == (other.preset, other.config)

    def __hash__(self) -> int:
        return hash((self.preset, self.config))

    def __str__(self) -> str:
        return self.options().removeprefix("--engine ")


@dataclass(frozen=True)
class RefusedEngine:
    """What `--engine` was given when it names no engine (an unknown preset, or an earlier record's
    flat variant name), with why: handed on by the command-line parser and refused when the
    settings are checked after it (`Engine.read`), so the refusal is the command's one line rather
    than the parser's box."""

    given: str
    why: str

    def __str__(self) -> str:
        return self.given


def _read_words(words: list[str]) -> Engine | RefusedEngine:
    """`--engine NAME`: a preset (an earlier flat variant name is refused with the options it means)."""
    name = words[0]
    try:
        if VARIANT_SEPARATOR in name:
            options = Engine.read(name).options()
            return RefusedEngine(name, f"give the preset and each setting as its own option: {options}")
        return Engine.of(name)
    except ValueError as error:
        return RefusedEngine(name, str(error))


ENGINE_OPTION = PrimitiveConstructorSpec(
    nargs=1,
    metavar="{" + ",".join(PRESETS) + "}",
    instance_from_str=_read_words,
    is_instance=lambda value: value is None or isinstance(value, Engine | RefusedEngine),
    str_from_instance=lambda value: [str(value)],
)
"""How tyro reads `--engine NAME` as an `Engine` (its settings are the --engine.GROUP.SETTING
options, read apart: `cli.engine_options`)."""


def flat_variant(name: str) -> str:
    """A cell's name with each setting by its flat name, as `parse_variant` reads it:
    "nerfacto-cpu+field.hidden_dim=48" -> "nerfacto-cpu+hidden_dim=48" (a flat part, of an earlier
    record, as it is; "-" in a nested name read as "_", as on the command line).

    Raises:
        ValueError: a nested name that is no setting's, naming the cell and the part.
    """
    base, *parts = name.split(VARIANT_SEPARATOR)
    written = []
    for part in parts:
        key, equals, text = part.partition("=")
        if "." in key:
            path = tuple(step.replace("-", "_") for step in key.split("."))
            if path not in _FLAT_BY_PATH:
                known = ", ".join(".".join(p) for p in FLAT_NAMES.values())
                raise ValueError(f"engine {name!r}: {key!r} is no engine setting (one of {known})")
            key = _FLAT_BY_PATH[path]
        written.append(f"{key}{equals}{text}")
    return VARIANT_SEPARATOR.join([base, *written])


def is_flat_variant(name: str) -> bool:
    """Whether the cell name `name` gives a setting by its flat name ("nerfacto-cpu+hidden_dim=48"),
    as records written before nesting did."""
    return any("." not in part.partition("=")[0] for part in name.split(VARIANT_SEPARATOR)[1:])


def _leaves(settings: dict, path: tuple[str, ...] = ()) -> dict[tuple[str, ...], Any]:
    """path -> value of every setting in the nested `settings`."""
    found = {}
    for name, value in settings.items():
        if isinstance(value, dict):
            found |= _leaves(value, (*path, name))
        else:
            found[(*path, name)] = value
    return found


def _nested(changes: dict[tuple[str, ...], Any]) -> dict:
    """The nested settings of path -> value."""
    nested: dict = {}
    for path, value in changes.items():
        group = nested
        for step in path[:-1]:
            group = group.setdefault(step, {})
        group[path[-1]] = value
    return nested


def _merge(ours: dict, theirs: dict) -> dict:
    return _nested(_leaves(ours) | _leaves(theirs))


def _plain(settings: dict) -> dict:
    return {
        k: _plain(v) if isinstance(v, dict) else list(v) if isinstance(v, tuple) else v for k, v in settings.items()
    }


def _in_flat_order(changes: dict[tuple[str, ...], Any]) -> list[tuple[tuple[str, ...], Any]]:
    """`changes` in the order of `FLAT_NAMES`, the settings' order in a `NerfConfig`."""
    order = {path: at for at, path in enumerate(FLAT_NAMES.values())}
    return sorted(changes.items(), key=lambda item: order[item[0]])


_text = _variant_text  # a value as a flat variant name writes it


def _words(value: Any) -> str:
    """A value as the command line writes it: (64, 32) -> "64 32", 1e30 -> "1e30"."""
    if isinstance(value, (tuple, list)):
        return " ".join(_words(v) for v in value)
    return str(value).replace("e+", "e")
