"""Registries of the engine's swappable parts: position encodings, fields and samplers by name.

`NerfConfig.encoding` and `NerfConfig.sampler` name entries here; an unknown name is an error
that lists the known ones. Adding an encoding is one module defining it (an `nn.Module` with
`output_dim` and `from_config(config)`) and one line in `ENCODINGS`.
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
    """`config`, once its encoding and sampler are names in the registries; a ValueError naming
    the value and the valid choices otherwise (before any part is built or any run starts).

    Example:
        >>> check_names(NerfConfig().with_settings(encoding="nope"))
        Traceback (most recent call last):
        ...
        ValueError: unknown encoding 'nope'; choose one of: hash, kplanes
    """
    lookup(ENCODINGS, "encoding", config.field.encoding)
    lookup(SAMPLERS, "sampler", config.sampler.kind)
    return config


def build_encoding(config: NerfConfig, name: str | None = None) -> nn.Module:
    """The position encoding `name` (default: `config.field.encoding`), sized by `config`."""
    return lookup(ENCODINGS, "encoding", config.field.encoding if name is None else name)(config)


def build_field(config: NerfConfig, name: str = DEFAULT_FIELD, encoding: nn.Module | None = None) -> nn.Module:
    """The field `name` over `encoding` (default: `build_encoding(config)`, built first)."""
    constructor = lookup(FIELDS, "field", name)
    return constructor(config, build_encoding(config) if encoding is None else encoding)


def build_sampler(config: NerfConfig) -> Sampler:
    """The sampler `config.sampler.kind`, sized by `config`."""
    return lookup(SAMPLERS, "sampler", config.sampler.kind)(config)
