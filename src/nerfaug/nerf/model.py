"""`NerfModel`: a field, a sampler and volume rendering, from rays to colours.

Rays are in world space (unit directions). The scene is the box [-h, h]^3 with h =
`config.scene.box_half_size`, seen between `near` and `far` along each ray; nothing outside it has
density. In training mode the samples are jittered (from the generator passed in); in eval mode
rendering is deterministic and still differentiable with respect to every field parameter.
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Iterator

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras, image_rays
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.encoding import spherical_harmonics
from nerfaug.nerf.field import NerfField
from nerfaug.nerf.registry import build_field, build_sampler
from nerfaug.nerf.sampling import ray_box_span, unit_cube
from nerfaug.nerf.volrend import RenderOutput, composite

# Most samples one network pass evaluates when rendering without gradients on the CPU: passes
# this size keep their intermediate tensors in the cache. Measured (100x100 image, 1 thread):
# nerfacto-cpu 0.30 s an image against 0.45 s in one pass of 16384 rays, cpu 0.13 against 0.19 s.
# Each ray is computed alone, so the pixels are the same, but for the last bit of a rare one: a
# network's matrix product may round a row differently in a pass of another size (seen: 1 pixel
# in 50 views of 100x100, by 6e-8).
CPU_PASS_SAMPLES = 65536
# State-dict prefixes of models saved before samplers were modules of their own.
_RENAMED_KEYS = (("occupancy.", "sampler.grid."), ("proposals.", "sampler.networks."), ("anneal", "sampler.anneal"))


class NerfModel(nn.Module):
    """A NeRF: `forward(origins, directions)` renders rays differentiably.

    Args:
        config: the hyperparameters.
        background: the colour behind the scene when none is passed (with
            `config.renderer.background_mode == "fixed"`).
        field: the radiance field (`density(x) -> (density, geometry)`,
            `color(geometry, directions) -> rgb`, points in [0, 1]^3); None builds the registry's
            default from `config` (`nerfaug.nerf.registry.build_field`).

    Attributes:
        config: the hyperparameters.
        field: the field (density and colour).
        sampler: the `Sampler` `config.sampler.kind` chooses (occupancy grid or proposal networks).
        background: buffer with shape (3,).
    """

    def __init__(self, config: NerfConfig, background=(1.0, 1.0, 1.0), field: nn.Module | None = None):
        super().__init__()
        self.config = config
        self.field = build_field(config) if field is None else field
        self.sampler = build_sampler(config)
        self.register_buffer("background", torch.as_tensor(background, dtype=torch.float32).reshape(3))
        self.register_load_state_dict_pre_hook(_rename_old_keys)

    def param_groups(self) -> dict[str, list[nn.Parameter]]:
        """Trainable parameters by optimiser group: "field" and, if the sampler has any
        (proposal networks), "proposal"."""
        groups = {"field": list(self.field.parameters())}
        sampler_params = list(self.sampler.parameters())
        if sampler_params:
            groups["proposal"] = sampler_params
        return groups

    def _unit(self, points: Tensor) -> Tensor:
        """World points (n, 3) -> the field's unit cube [0, 1]^3."""
        return unit_cube(points, self.config.scene.box_half_size)

    def density(self, points: Tensor) -> Tensor:
        """Density of the field at world points (n, 3) -> (n,); 0 outside the box."""
        h = self.config.scene.box_half_size
        inside = (points.abs() <= h).all(dim=-1)
        return self.field.density(self._unit(points))[0] * inside

    def before_step(self, step: int, generator: torch.Generator | None = None) -> None:
        """The sampler's bookkeeping before training step `step` (refresh the occupancy grid,
        anneal the proposal weights)."""
        self.sampler.before_step(step, self.density, generator)

    def forward(
        self,
        origins: Tensor,
        directions: Tensor,
        background: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> RenderOutput:
        """Render rays.

        Args:
            origins, directions: Tensors with shape (n_rays, 3), world space, unit directions.
            background: Tensor with shape (3,) or (n_rays, 3); None for the configured
                background (`self.background`, or the field's colour at the box exit with
                `config.renderer.background_mode == "last_sample"`, or the last composited sample's
                colour with "last_composited").
            generator: source of the sample jitter in training mode (None: global RNG).

        Returns:
            RenderOutput with n_samples = config.sampler.num_samples; in `extras` what the sampler's
            `auxiliary_losses` needs (the proposal histograms).
        """
        edges, extras = self._sample(origins, directions, generator)
        t_starts, t_ends = edges[:, :-1], edges[:, 1:]
        weights, rgbs = self._shade(origins, directions, t_starts, t_ends)
        if background is None and self.config.renderer.background_mode == "last_sample":
            background = self._last_sample_colour(origins, directions, t_ends[:, -1])
        elif background is None and self.config.renderer.background_mode == "last_composited":
            # nerfacto's "last_sample": the last sample's colour (0 where it lies behind opaque
            # matter, `_shade`, where the background's weight is below transmittance_eps anyway).
            background = rgbs[:, -1]
        background = (self.background if background is None else background).to(weights)
        rgb, accumulation, depth = composite(weights, rgbs, t_starts, t_ends, background)
        return RenderOutput(rgb, accumulation, depth, weights, t_starts, t_ends, extras)

    def _sample(self, origins: Tensor, directions: Tensor, generator: torch.Generator | None) -> tuple[Tensor, dict]:
        """Edges (n_rays, num_samples + 1) of the final samples, and the sampler's extras."""
        config = self.config
        t_min, t_max = ray_box_span(
            origins, directions, config.scene.box_half_size, config.scene.near, config.scene.far
        )
        return self.sampler.sample(origins, directions, t_min, t_max, generator)

    def _last_sample_colour(self, origins: Tensor, directions: Tensor, t_far: Tensor) -> Tensor:
        """The field's colour at the far end of each ray, nerfacto's "last_sample" background.
        Shapes: (n_rays, 3), (n_rays, 3), (n_rays,) -> (n_rays, 3)."""
        _, geometry = self.field.density(self._unit(origins + directions * t_far[:, None]))
        return self.field.color(geometry, directions)

    def _densities(
        self, origins: Tensor, directions: Tensor, t_starts: Tensor, t_ends: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Weights of the final samples, from the field's density where it may matter.

        The field sees only samples inside a non-empty interval that the sampler calls live
        (e.g. in an occupied cell of the occupancy grid); the rest keep density 0. They are gathered out of the dense
        (n_rays, n) layout and their densities scattered back.

        Returns:
            weights, transmittance: Tensors with shape (n_rays, n).
            index: Tensor with shape (m,), flat indices of the m evaluated samples.
            geometry: Tensor with shape (m, geo_feat_dim), their features for `color`.
        """
        n_rays, n = t_starts.shape
        mids = 0.5 * (t_starts + t_ends)
        points = (origins[:, None, :] + directions[:, None, :] * mids[..., None]).reshape(-1, 3)
        live = (t_ends > t_starts).reshape(-1)
        sampler_live = self.sampler.live(points)
        if sampler_live is not None:
            live = live & sampler_live
        index = live.nonzero().squeeze(-1)
        density, geometry = self.field.density(self._unit(points[index]))
        sigma = density.new_zeros(n_rays * n).index_put((index,), density).reshape(n_rays, n)
        weights, transmittance = self.sampler.render_weights(sigma, t_ends - t_starts)
        return weights, transmittance, index, geometry

    def _shade(self, origins: Tensor, directions: Tensor, t_starts: Tensor, t_ends: Tensor) -> tuple[Tensor, Tensor]:
        """Weights (n_rays, n) and colours (n_rays, n, 3) of the final samples. Colour is only
        evaluated where the transmittance exceeds `config.sampler.transmittance_eps` (0 elsewhere)."""
        n_rays, n = t_starts.shape
        weights, transmittance, index, geometry = self._densities(origins, directions, t_starts, t_ends)
        visible = transmittance.detach().reshape(-1)[index] > self.config.sampler.transmittance_eps
        if isinstance(self.field, NerfField) and self.sampler.fused_cpu(geometry, directions):
            # cpu-fused-3: each ray's harmonics once for its samples, rows picked by index (the
            # gradient's scatter then writes each row once, where a mask's accumulates).
            rows = visible.nonzero().squeeze(-1)
            colour_index = index.index_select(0, rows)
            encoded = spherical_harmonics(directions, self.field.sh_levels).index_select(0, colour_index // n)
            colours = self.field.color_of_encoded(geometry.index_select(0, rows), encoded)
        else:
            colour_index = index[visible]
            colours = self.field.color(geometry[visible], directions[colour_index // n])
        rgbs = colours.new_zeros(n_rays * n, 3).index_put((colour_index,), colours).reshape(n_rays, n, 3)
        return weights, rgbs

    def losses(self, output: RenderOutput, target: Tensor) -> dict[str, Tensor]:
        """The training losses of a pass, each named (scalar Tensors): "rgb", the mean squared
        error against `target` (n_rays, 3), then the sampler's (the proposal sampler's
        "distortion" and "interlevel"; none for the occupancy grid). Their sum is the loss."""
        return {
            "rgb": torch.nn.functional.mse_loss(output.rgb.float(), target),
            **self.sampler.auxiliary_losses(output),
        }

    def auxiliary_loss(self, output: RenderOutput) -> Tensor:
        """The sampler's losses summed (0 without any), in the order they are named."""
        parts = list(self.sampler.auxiliary_losses(output).values())
        return functools.reduce(operator.add, parts) if parts else output.rgb.new_zeros(())

    def _eval_slices(
        self, origins: Tensor, directions: Tensor, chunk: int | None
    ) -> Iterator[tuple[int, int, Tensor, Tensor]]:
        """(start, stop, origins, directions) of consecutive ray chunks on the model's device, in
        eval mode without gradients (the mode is restored after). On the CPU a chunk holds at
        most `CPU_PASS_SAMPLES` samples per network pass."""
        device = self.background.device
        chunk = chunk or self.config.renderer.render_chunk
        per_ray = self.sampler.samples_per_ray
        if device.type == "cpu" and per_ray:
            chunk = min(chunk, max(1, CPU_PASS_SAMPLES // per_ray))
        was_training = self.training
        self.eval()
        try:
            with torch.no_grad():
                for start in range(0, origins.shape[0], chunk):
                    stop = start + chunk
                    yield start, stop, origins[start:stop].to(device), directions[start:stop].to(device)
        finally:
            self.train(was_training)

    def _chunks(
        self, origins: Tensor, directions: Tensor, background: Tensor | None, chunk: int | None
    ) -> Iterator[RenderOutput]:
        """Render rays chunk by chunk in eval mode without gradients."""
        for start, stop, o, d in self._eval_slices(origins, directions, chunk):
            bg = background
            if bg is not None and bg.ndim == 2:
                bg = bg[start:stop]
            yield self(o, d, None if bg is None else bg.to(o.device))

    def render_rays(
        self, origins: Tensor, directions: Tensor, background: Tensor | None = None, chunk: int | None = None
    ) -> RenderOutput:
        """Render rays in eval mode without gradients, `chunk` rays at a time.

        Args:
            origins, directions: Tensors with shape (n_rays, 3).
            background: Tensor with shape (3,) or (n_rays, 3); None for the configured one.
            chunk: rays per forward pass (None: `config.renderer.render_chunk`); bounds peak memory. On
                the CPU, smaller chunks may be used (`CPU_PASS_SAMPLES`).

        Returns:
            RenderOutput (extras None) on the model's device.
        """
        return RenderOutput.cat([out.detach() for out in self._chunks(origins, directions, background, chunk)])

    def render_weights_only(self, origins: Tensor, directions: Tensor, chunk: int | None = None) -> Tensor:
        """The final samples' weights alone (no colour network), in eval mode without
        gradients, `chunk` rays at a time: what ray entropy needs, at about half the cost.

        Args:
            origins, directions: Tensors with shape (n_rays, 3).

        Returns:
            Tensor with shape (n_rays, num_samples), equal to `render_rays(...).weights`.
        """
        parts = []
        for _, _, o, d in self._eval_slices(origins, directions, chunk):
            edges, _ = self._sample(o, d, None)
            parts.append(self._densities(o, d, edges[:, :-1], edges[:, 1:])[0])
        return torch.cat(parts)

    def render_image(self, cameras: Cameras, index: int, background: Tensor | None = None) -> dict[str, Tensor]:
        """Render view `index` of `cameras` (eval mode, no gradients).

        Returns:
            {"rgb": (H, W, 3), "accumulation": (H, W), "depth": (H, W)}, on the model's device.
        """
        origins, directions = image_rays(cameras, index)
        parts = {"rgb": [], "accumulation": [], "depth": []}
        for out in self._chunks(origins, directions, background, None):
            for key in parts:
                parts[key].append(getattr(out, key))
        height, width = cameras.height, cameras.width
        return {
            "rgb": torch.cat(parts["rgb"]).reshape(height, width, 3),
            "accumulation": torch.cat(parts["accumulation"]).reshape(height, width),
            "depth": torch.cat(parts["depth"]).reshape(height, width),
        }


def _rename_old_keys(module, state_dict, prefix, *args) -> None:
    """Load-state-dict pre-hook: rename the keys of a model saved before samplers were modules
    of their own (e.g. a capture session's checkpoint) to today's."""
    for key in [k for k in state_dict if k.startswith(prefix)]:
        local = key[len(prefix) :]
        for old, new in _RENAMED_KEYS:
            if local.startswith(old):
                state_dict[prefix + new + local[len(old) :]] = state_dict.pop(key)
                break


def total_loss(losses: dict[str, Tensor]) -> Tensor:
    """The first loss ("rgb") plus the others summed in their order: "rgb" + ("distortion" +
    "interlevel") keeps the sum's rounding as it was when the sampler returned one summed loss."""
    first, *others = losses.values()
    return first + functools.reduce(operator.add, others) if others else first
