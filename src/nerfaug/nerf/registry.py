"""Registries of the engine's swappable parts: position encodings, fields and samplers by name.

The parts `NerfConfig.field.encoding` and `NerfConfig.sampler.kind` choose are built from here,
by their types' `NAME`s; a name with no entry is an error that lists the known ones. Adding an
encoding is its settings' type (`nerf.config`, one more alternative of `FieldConfig.encoding`),
one module defining it (an `nn.Module` with `output_dim` and `from_config(config)`) and one line
in `ENCODINGS`.
"""

from __future__ import annotations

from collections.abc import Callable

from torch import nn

from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.encoding import HashEncoding, KPlanesEncoding
from nerfaug.nerf.field import NerfField
from nerfaug.nerf.occupancy import OccupancySampler
from nerfaug.nerf.proposal import ProposalSampler
from nerfaug.nerf.sampler import Sampler
from nerfaug.registry import lookup

ENCODINGS: dict[str, Callable[[NerfConfig], nn.Module]] = {
    "hash": HashEncoding.from_config,
    "kplanes": KPlanesEncoding.from_config,
}
"""Position encodings: name -> constructor from a `NerfConfig`."""

FIELDS: dict[str, Callable[[NerfConfig, nn.Module], nn.Module]] = {
    "nerfacto": NerfField,
}
"""Radiance fields: name -> constructor from a `NerfConfig` and a position encoding."""

SAMPLERS: dict[str, Callable[[NerfConfig], Sampler]] = {
    "occupancy": OccupancySampler.from_config,
    "proposal": ProposalSampler.from_config,
}
"""Samplers: name -> constructor from a `NerfConfig`."""

DEFAULT_FIELD = "nerfacto"


def check_names(config: NerfConfig) -> NerfConfig:
    """`config`, once its encoding and sampler have entries in the registries; a ValueError naming
    the part and the valid choices otherwise (before any part is built or any run starts)."""
    lookup(ENCODINGS, "encoding", config.field.encoding.NAME)
    lookup(SAMPLERS, "sampler", config.sampler.kind.NAME)
    return config


def build_encoding(config: NerfConfig, name: str | None = None) -> nn.Module:
    """The position encoding `name` (default: `config.field.encoding`'s), sized by `config`."""
    return lookup(ENCODINGS, "encoding", config.field.encoding.NAME if name is None else name)(config)


def build_field(config: NerfConfig, name: str = DEFAULT_FIELD, encoding: nn.Module | None = None) -> nn.Module:
    """The field `name` over `encoding` (default: `build_encoding(config)`, built first)."""
    constructor = lookup(FIELDS, "field", name)
    return constructor(config, build_encoding(config) if encoding is None else encoding)


def build_sampler(config: NerfConfig) -> Sampler:
    """The sampler `config.sampler.kind` is, sized by `config`."""
    return lookup(SAMPLERS, "sampler", config.sampler.kind.NAME)(config)
