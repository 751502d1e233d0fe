"""Things by name: the one look-up of a name among the known ones (an unknown name is one error
that lists them), and presets, complete configs by name.

Every registry of the package (engine parts, selection methods, estimators and selectors, dataset
formats, presets) is looked up here, so an unknown name reads the same wherever it is given.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib
from collections.abc import Iterable, Mapping
from typing import Literal, TypeVar

T = TypeVar("T")
C = TypeVar("C")


def unknown(kind: str, name: object, known: Iterable[str]) -> ValueError:
    """The error for a name that is none of `known`: it names the value, the known names closest to
    it (a typo's likely meaning, by `difflib`) and lists the known ones.

    Example:
        >>> unknown("sampler", "grid", ["occupancy", "proposal"])
        ValueError("unknown sampler 'grid'; choose one of: occupancy, proposal")
        >>> unknown("method", "ourss", ["ours", "uniform", "ours-batch"])
        ValueError("unknown method 'ourss'; did you mean 'ours'? choose one of: ours, uniform, ours-batch")
    """
    known = [str(k) for k in known]
    return ValueError(f"unknown {kind} {name!r}; {did_you_mean(name, known)}choose one of: {', '.join(known)}")


def did_you_mean(name: object, known: Iterable[str]) -> str:
    """ "did you mean 'x'? " naming the known names closest to a mistyped `name` (by `difflib`, at
    most two), or "" when none is close.

    Example:
        >>> did_you_mean("lgo", ["lego", "chair"])
        "did you mean 'lego'? "
    """
    close = difflib.get_close_matches(str(name), [str(k) for k in known], n=2, cutoff=0.75)
    return f"did you mean {' or '.join(repr(c) for c in close)}? " if close else ""


def check_name(kind: str, name: object, known: Iterable[str]) -> None:
    """Nothing when `name` is one of `known`; else `unknown`'s ValueError.

    Example:
        >>> check_name("projection", "polar", ("equal-area", "equidistant"))
        Traceback (most recent call last):
        ...
        ValueError: unknown projection 'polar'; choose one of: equal-area, equidistant
    """
    known = tuple(known)
    if name not in known:
        raise unknown(kind, name, known)


def lookup(registry: Mapping[str, T], kind: str, name: str) -> T:
    """The entry `name` of `registry` (a `kind`, for the error); `unknown`'s ValueError otherwise.

    Example:
        >>> lookup({"hash": 1, "kplanes": 2}, "encoding", "kplanes")
        2
        >>> lookup({"hash": 1, "kplanes": 2}, "encoding", "grid")
        Traceback (most recent call last):
        ...
        ValueError: unknown encoding 'grid'; choose one of: hash, kplanes
    """
    check_name(kind, name, registry)
    return registry[name]


class Presets(dict[str, C]):
    """Complete configs (dataclass instances) by name, in the order a listing shows them.

    A preset is a value: the config a command starts from, handed to its parser (tyro) as the
    default of its options, so an option given on the command line changes that value and one not
    given keeps it. `choose` returns a copy, so no caller changes a preset for the next one.

    Args:
        kind: what a name names, for the error on an unknown one (e.g. "engine preset").
        presets: name -> config.

    Example:
        >>> from dataclasses import dataclass
        >>> @dataclass
        ... class Protocol:
        ...     steps: int = 100
        ...     trials: int = 3
        >>> presets = Presets("protocol", {"short": Protocol(steps=10), "long": Protocol(steps=1000)})
        >>> presets.choose("short", trials=5)
        Protocol(steps=10, trials=5)
        >>> presets.choose("medium")
        Traceback (most recent call last):
        ...
        ValueError: unknown protocol 'medium'; choose one of: short, long
    """

    def __init__(self, kind: str, presets: Mapping[str, C]):
        super().__init__(presets)
        self.kind = kind

    def choose(self, name: str, **changes) -> C:
        """A copy of the preset `name`, with `changes` (field -> value) applied."""
        return dataclasses.replace(copy.deepcopy(lookup(self, self.kind, name)), **changes)

    def name_type(self) -> type:
        """The names as a `Literal` type, for a command-line parser (tyro) to offer and check."""
        return Literal[tuple(self)]  # type: ignore[return-value]


def lazy_exports(package: str, homes: Mapping[str, str], namespace: dict):
    """(`__getattr__`, `__dir__`) for a package whose names are imported on first use (PEP 562),
    so that importing it (e.g. for a command's `--help`) loads none of its heavy modules.

    Args:
        package: the package's `__name__`.
        homes: each exported name -> the module that defines it.
        namespace: the package's `globals()`, where a looked-up name is kept so later look-ups
            skip `__getattr__`.
    """

    def __getattr__(name: str):
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(homes[name]), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(homes))

    return __getattr__, __dir__
