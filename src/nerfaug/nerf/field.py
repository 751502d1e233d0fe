"""Radiance fields: density and view-dependent colour at points (nerfacto-style, without
per-image appearance embeddings), and the density-only fields of the proposal sampler.

Fields take positions normalised to the unit cube [0, 1]^3 (the scene box mapped onto it);
the model does that mapping.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from nerfaug.nerf import mlp_cpu, sampler_cpu
from nerfaug.nerf.config import NerfConfig, ProposalConfig
from nerfaug.nerf.encoding import HashEncoding, spherical_harmonics


class _TruncExp(torch.autograd.Function):
    """exp whose gradient is clamped at exp(15), so one large pre-activation cannot blow up
    the step (Instant-NGP / nerfacto)."""

    @staticmethod
    def forward(ctx, x: Tensor) -> Tensor:
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, grad: Tensor) -> Tensor:
        (x,) = ctx.saved_tensors
        return grad * torch.exp(x.clamp(max=15.0))


def trunc_exp(x: Tensor) -> Tensor:
    """exp(x) with the gradient of exp(min(x, 15)). Any shape."""
    return _TruncExp.apply(x)


def density_activation(raw: Tensor, kind: str, average_init_density: float) -> Tensor:
    """Density >= 0 from a raw network output, equal to `average_init_density` at raw = 0.

    Args:
        raw: Tensor of any shape.
        kind: "trunc_exp" (nerfacto: average_init_density * exp(raw)) or "softplus"
            (softplus shifted so that softplus(0 + shift) = average_init_density).
    """
    # float32 even under autocast (nerfacto does the same): exp of a float16 overflows above 11.
    raw = raw.float()
    if kind == "trunc_exp":
        return average_init_density * trunc_exp(raw)
    if kind == "softplus":
        return nn.functional.softplus(raw + math.log(math.expm1(average_init_density)))
    raise ValueError(f"density_activation must be 'trunc_exp' or 'softplus', got {kind!r}")


def mlp(in_dim: int, hidden_dim: int, out_dim: int, hidden_layers: int) -> nn.Sequential:
    """A ReLU MLP with `hidden_layers` hidden layers of width `hidden_dim` and a linear output."""
    layers: list[nn.Module] = []
    width = in_dim
    for _ in range(hidden_layers):
        layers += [nn.Linear(width, hidden_dim), nn.ReLU()]
        width = hidden_dim
    layers.append(nn.Linear(width, out_dim))
    return nn.Sequential(*layers)


class NerfField(nn.Module):
    """Density from position; colour from a geometry feature and the viewing direction.

    position -> encoding -> density MLP -> (density, geometry feature)
    (SH(direction), geometry feature) -> colour MLP -> sigmoid -> rgb

    The interface the model renders with (any field passed to `NerfModel` has it):
    `density(x) -> (density, geometry)` and `color(geometry, directions) -> rgb`.

    Args:
        config: the MLP widths, direction encoding and density activation.
        encoding: the position encoding, built before the field (see
            `nerfaug.nerf.registry.build_field`): points (n, 3) in [0, 1]^3 -> (n, output_dim).
    """

    def __init__(self, config: NerfConfig, encoding: nn.Module):
        super().__init__()
        field = config.field
        self.density_kind, self.average_init_density = field.density_activation, field.average_init_density
        self.sh_levels, self.geo_feat_dim = field.sh_levels, field.geo_feat_dim
        self.encoding = encoding
        self.density_mlp = mlp(self.encoding.output_dim, field.hidden_dim, 1 + field.geo_feat_dim, 1)
        self.color_mlp = mlp(field.sh_levels**2 + field.geo_feat_dim, field.color_hidden_dim, 3, field.color_layers)
        # cpu-fused-3 (`mlp_cpu`): the MLPs in one C pass where the CPU loops are chosen, for the
        # engines that version is recorded for (those with proposal networks)
        self.fused_mlps = isinstance(config.sampler.kind, ProposalConfig)
        # Zero bias on the density output: a fresh field then has about the configured density.
        with torch.no_grad():
            self.density_mlp[-1].bias.zero_()

    def density(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Args: x: Tensor with shape (n, 3) in [0, 1]^3.

        Returns:
            density: Tensor with shape (n,), >= 0, per world unit.
            geometry: Tensor with shape (n, geo_feat_dim), input to `color`.
        """
        raw = mlp_cpu.run(self.density_mlp, self.encoding(x), self.fused_mlps and sampler_cpu.selected())
        raw, geometry = raw.split([1, self.geo_feat_dim], dim=-1)
        return density_activation(raw[:, 0], self.density_kind, self.average_init_density), geometry

    def color(self, geometry: Tensor, directions: Tensor) -> Tensor:
        """Args: geometry (n, geo_feat_dim) from `density`; directions (n, 3) unit.

        Returns: Tensor with shape (n, 3) in [0, 1].
        """
        return self.color_of_encoded(geometry, spherical_harmonics(directions, self.sh_levels))

    def color_of_encoded(self, geometry: Tensor, encoded: Tensor) -> Tensor:
        """`color` with the directions' spherical harmonics given: (n, sh_levels ** 2), e.g. one
        ray's computed once for all its samples. Returns: Tensor with shape (n, 3) in [0, 1]."""
        fused = self.fused_mlps and sampler_cpu.selected()
        return torch.sigmoid(mlp_cpu.run(self.color_mlp, torch.cat([encoded, geometry], dim=-1), fused))


class DensityField(nn.Module):
    """A small hash-grid density network, one per proposal level (nerfacto's HashMLPDensityField)."""

    def __init__(self, config: NerfConfig, max_resolution: int):
        super().__init__()
        field = config.field
        self.density_kind, self.average_init_density = field.density_activation, field.average_init_density
        proposal = config.sampler.kind  # a `ProposalConfig`
        self.encoding = HashEncoding(proposal.hash_levels, 2, proposal.log2_table_size, 16, max_resolution)
        self.mlp = mlp(self.encoding.output_dim, proposal.hidden_dim, 1, 1)
        with torch.no_grad():
            self.mlp[-1].bias.zero_()

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (n, 3) in [0, 1]^3. Returns: density, shape (n,)."""
        # cpu-fused-3: the network in one C pass (`mlp_cpu`) where the CPU loops are chosen
        raw = mlp_cpu.run(self.mlp, self.encoding(x), fused=sampler_cpu.selected())
        return density_activation(raw[:, 0], self.density_kind, self.average_init_density)
