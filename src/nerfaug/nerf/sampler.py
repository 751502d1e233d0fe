"""`Sampler`: the interface of what decides where along each ray the field is evaluated (an
occupancy grid, proposal networks), in the manner of nerfacc's estimators.

A sampler owns its state (grid, networks, schedules) and receives the field as a function, so
the model never branches on which sampler it holds. Intervals are edges with shape
(n_rays, n_samples + 1) as in `nerfaug.nerf.sampling`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable

import torch
from torch import Tensor, nn

from nerfaug.nerf.volrend import RenderOutput, render_weights


class Sampler(nn.Module, ABC):
    """Where to sample, and what that costs besides photometric error.

    Samples are jittered in training mode (`self.training`, which follows the model's mode)
    and deterministic in eval mode.
    """

    @abstractmethod
    def sample(
        self,
        origins: Tensor,
        directions: Tensor,
        t_min: Tensor,
        t_max: Tensor,
        generator: torch.Generator | None = None,
    ) -> tuple[Tensor, dict]:
        """The final samples along each ray.

        Args:
            origins, directions: Tensors with shape (n_rays, 3), world space, unit directions.
            t_min, t_max: Tensors with shape (n_rays,), the ray's span inside the scene.
            generator: source of the jitter in training mode (None: global RNG).

        Returns:
            edges: Tensor with shape (n_rays, n_samples + 1).
            extras: what `auxiliary_losses` needs of this pass (put in `RenderOutput.extras`).
        """

    @property
    def samples_per_ray(self) -> int | None:
        """The most samples along one ray that a network evaluates in one pass (None: not
        known); sizes the chunks of rendering without gradients on the CPU."""
        return None

    def live(self, points: Tensor) -> Tensor | None:
        """Which final samples may hold density: bool Tensor with shape (n,) for world points
        (n, 3), or None when every sample may (the field then sees all of them)."""
        return None

    def fused_cpu(self, *tensors: Tensor) -> bool:
        """Whether a pass of this sampler's engine on `tensors` runs the CPU engine version
        cpu-fused-3's loops (`nerfaug.nerf.sampler_cpu`; the proposal sampler's, where chosen)."""
        return False

    def render_weights(self, sigmas: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
        """The final samples' weights and transmittance from densities (n_rays, n) and interval
        lengths (n_rays, n): `nerfaug.nerf.volrend.render_weights`, unless a sampler computes
        the same otherwise."""
        return render_weights(sigmas, deltas)

    def before_step(
        self, step: int, density_fn: Callable[[Tensor], Tensor], generator: torch.Generator | None = None
    ) -> None:
        """Bookkeeping before training step `step`; `density_fn` maps world points (n, 3) to
        the field's densities (n,)."""

    def auxiliary_losses(self, output: RenderOutput) -> dict[str, Tensor]:
        """The sampler's losses for one rendered batch, each weighted and named (scalar Tensors;
        none by default)."""
        return {}
