"""A `NerfConfig`'s settings by name, and its component choices as types.

A component chosen among alternatives (the field's encoding: a hash grid or K-planes; the sampler:
an occupancy grid or proposal networks) is a field whose type is the union of the alternatives'
settings types, `FieldConfig.encoding: HashGridConfig | PlanesConfig`, as gsplat's
`strategy: DefaultStrategy | MCMCStrategy`: an engine holds the settings of the part it uses and
no other, so it cannot carry a setting it does not read.

By name a choice is what it always was: the chooser ("field.encoding", its value the chosen type's
`NAME`, "hash") and the chosen part's settings under its type's `GROUP` ("field.hash.levels"). The
other parts' names stay names (they are settings of other engines), but an engine that chose
otherwise has no such setting, and a change to one is refused (`unused`). Records written before
the choice was a type hold every part's settings; reading them (`build`) skips the parts not chosen.

Light: dataclasses only.
"""

from __future__ import annotations

from dataclasses import fields, is_dataclass
from functools import cache
from types import UnionType
from typing import Any, get_args, get_type_hints

from nerfaug.registry import lookup, unknown


@cache
def hints(cls: type) -> dict[str, Any]:
    """The type of each field of the dataclass `cls`."""
    return get_type_hints(cls)


def choice(cls: type, name: str) -> tuple[type, ...]:
    """The alternatives of the field `name` of `cls` when it is a component choice, else ()."""
    kind = hints(cls).get(name)
    parts = get_args(kind) if isinstance(kind, UnionType) else ()
    return parts if parts and all(is_dataclass(p) for p in parts) else ()


def _flat(f, prefix: str) -> str:
    return f.metadata.get("flat", prefix + f.name)


def leaves(cls: type, path: tuple[str, ...] = (), prefix: str = "") -> dict[str, tuple[str, ...]]:
    """flat name -> nested name (a path) of every setting under the dataclass `cls`, each part of
    each choice included. The order is that of the settings when every engine held every part's
    (variant names list their changes in it): a part's settings follow its chooser, or, where the
    chooser's metadata says "parts_last", the group's own settings."""
    names: dict[str, tuple[str, ...]] = {}
    last: dict[str, tuple[str, ...]] = {}
    for f in fields(cls):
        kind = hints(cls)[f.name]
        if parts := choice(cls, f.name):
            names[_flat(f, prefix)] = (*path, f.name)
            groups = {}
            for part in parts:
                groups |= leaves(part, (*path, part.GROUP), part.FLAT_PREFIX)
            (last if f.metadata.get("parts_last") else names).update(groups)
        elif is_dataclass(kind):
            names |= leaves(kind, (*path, f.name), getattr(kind, "FLAT_PREFIX", ""))
        else:
            names[_flat(f, prefix)] = (*path, f.name)
    return names | last


class Unused(LookupError):
    """A setting of a part the engine did not choose."""

    def __init__(self, chooser: str, chosen: Any, part: type):
        self.part = part
        super().__init__(
            f"not used by this engine: its {chooser} is {chosen.NAME!r} (this setting is read with {part.NAME!r})"
        )


def _step(node: Any, name: str, path: tuple[str, ...]) -> Any:
    """The value `name` names in the dataclass `node` (at `path`): a setting, a group, or a part."""
    for f in fields(node):
        for part in choice(type(node), f.name):
            if part.GROUP == name:
                chosen = getattr(node, f.name)
                if not isinstance(chosen, part):
                    raise Unused(".".join((*path, f.name)), chosen, part)
                return chosen
    value = getattr(node, name)
    return value.NAME if choice(type(node), name) else value


def get(config: Any, path: tuple[str, ...]) -> Any:
    """The setting at `path` of `config` (a `NerfConfig`): get(config, ("field", "hash", "levels"));
    the chooser's value is the part's name: get(config, ("field", "encoding")) == "hash".

    Raises:
        Unused: a setting of a part `config` did not choose.
    """
    for at, name in enumerate(path):
        config = _step(config, name, path[:at])
    return config


def unused(config: Any, path: tuple[str, ...]) -> str | None:
    """Why `config` has no setting at `path` (one of a part it did not choose: "not used by this
    engine: its field.encoding is 'kplanes' (...)"), or None when it has."""
    try:
        get(config, path)
    except Unused as why:
        return str(why)
    return None


def part_default(cls: type, path: tuple[str, ...]) -> Any:
    """The default of the setting at `path` under the dataclass `cls` in its own type (a part's
    setting: its default in that part's type, whichever part the defaults choose)."""
    default: Any = cls()
    for at, name in enumerate(path):
        try:
            default = _step(default, name, path[:at])
        except Unused as other:
            default = other.part()
    return default


def kind(cls: type, path: tuple[str, ...]) -> Any:
    """The type of the setting at `path` under the dataclass `cls`, or None for no setting."""
    for name in path:
        if not is_dataclass(cls):
            return None
        groups = {p.GROUP: p for f in fields(cls) for p in choice(cls, f.name)}
        if name in groups:
            cls = groups[name]
        elif name in hints(cls):
            cls = str if choice(cls, name) else hints(cls)[name]
        else:
            return None
    return cls


def to_names(node: Any) -> dict:
    """The settings of the dataclass `node`, nested by name: a choice as its chooser's name and the
    chosen part's settings ({"encoding": "hash", "hash": {"levels": 16, ...}})."""
    data: dict[str, Any] = {}
    for f in fields(node):
        value = getattr(node, f.name)
        if choice(type(node), f.name):
            data[f.name], data[value.GROUP] = value.NAME, to_names(value)
        else:
            data[f.name] = to_names(value) if is_dataclass(value) else value
    return data


def build(cls: type, data: dict, where: str) -> Any:
    """A `cls` (a dataclass) from its settings nested by name, missing ones at their defaults; a
    chooser not given keeps the default part. A group of a part not chosen is checked for unknown
    names and skipped: records written before the choice was a type hold every part's settings.
    Lists (from JSON) become tuples.

    Raises:
        ValueError: an unknown name (with its group) or part, or a value the dataclass refuses.
    """
    known, groups, values = set(hints(cls)), {}, {}
    for f in fields(cls):
        if parts := choice(cls, f.name):
            groups |= {p.GROUP: (f, p) for p in parts}
    extra = set(data) - known - set(groups)
    if extra:
        raise ValueError(f"{where}: {unknown('setting', sorted(extra)[0], sorted(known | set(groups)))}")
    chosen = {}
    for f in fields(cls):
        if parts := choice(cls, f.name):
            default = f.default
            name = data.get(f.name, default.NAME)
            chosen[f.name] = lookup({p.NAME: p for p in parts}, f.metadata.get("flat", f.name), name)
    for name, value in data.items():
        if name in groups:
            f, part = groups[name]
            if not isinstance(value, dict):
                raise ValueError(f"{where}.{name}: {value!r} is not a group of settings")
            if chosen[f.name] is part:
                values[f.name] = build(part, value, f"{where}.{name}")
            elif extra := set(value) - set(hints(part)):  # another part's: its names checked, no more
                raise ValueError(f"{where}.{name}: {unknown('setting', sorted(extra)[0], sorted(hints(part)))}")
        elif choice(cls, name):
            continue
        elif is_dataclass(hints(cls)[name]):
            values[name] = build(hints(cls)[name], value, f"{where}.{name}")
        else:
            values[name] = tuple(value) if isinstance(value, list) else value
    for field_name, part in chosen.items():
        default = next(f.default for f in fields(cls) if f.name == field_name)
        values.setdefault(field_name, default if type(default) is part else part())
    return cls(**values)
