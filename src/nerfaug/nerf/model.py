"""`NerfModel`: a field, a sampler (occupancy grid or proposal networks) and volume rendering,
from rays to colours.

Rays are in world space (unit directions). The scene is the box [-h, h]^3 with h =
`config.box_half_size`, seen between `near` and `far` along each ray; nothing outside it has
density. In training mode the samples are jittered (from the generator passed in); in eval mode
rendering is deterministic and still differentiable with respect to every field parameter.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras, image_rays
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.field import DensityField, NerfField
from nerfaug.nerf.occupancy import OccupancyGrid
from nerfaug.nerf.proposal import ProposalSchedule, distortion_loss, interlevel_loss, proposal_anneal
from nerfaug.nerf.sampling import ray_box_span, sample_pdf, stratified_edges
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights


class NerfModel(nn.Module):
    """A NeRF: `forward(origins, directions)` renders rays differentiably.

    Attributes:
        config: the hyperparameters.
        field: the `NerfField` (density and colour).
        occupancy: the `OccupancyGrid` (sampler "occupancy"), else None.
        proposals: the proposal `DensityField`s (sampler "proposal"), else empty.
        background: buffer with shape (3,), the colour behind the scene when none is passed
            (with `config.background_mode == "fixed"`).
    """

    def __init__(self, config: NerfConfig, background=(1.0, 1.0, 1.0)):
        super().__init__()
        self.config = config
        self.field = NerfField(config)
        self.occupancy = None
        self.proposals = nn.ModuleList()
        if config.sampler == "occupancy":
            self.occupancy = OccupancyGrid(
                config.box_half_size, config.occupancy_resolution, config.occupancy_update_every,
                config.occupancy_warmup_steps, config.occupancy_ema_decay, config.occupancy_threshold,
                config.occupancy_update_fraction,
            )
        else:
            self.proposals.extend(DensityField(config, r) for r in config.proposal_max_resolutions)
        self.register_buffer("background", torch.as_tensor(background, dtype=torch.float32).reshape(3))
        if len(self.proposals):
            # Exponent of the proposal weights, annealed from 0 to 1 by `before_step`.
            self.register_buffer("anneal", torch.tensor(1.0))
            self.proposal_schedule = ProposalSchedule(config.proposal_update_every, config.proposal_warmup_steps)
            # Whether this training step's proposal evaluations build a graph (set by `before_step`).
            self.update_proposals = True

    def param_groups(self) -> dict[str, list[nn.Parameter]]:
        """Trainable parameters by optimiser group: "field" and, if any, "proposal"."""
        groups = {"field": list(self.field.parameters())}
        if len(self.proposals):
            groups["proposal"] = list(self.proposals.parameters())
        return groups

    def _unit(self, points: Tensor) -> Tensor:
        """World points (n, 3) -> the field's unit cube [0, 1]^3 (clamped against round-off)."""
        h = self.config.box_half_size
        return ((points + h) / (2.0 * h)).clamp(0.0, 1.0)

    def density(self, points: Tensor) -> Tensor:
        """Density of the field at world points (n, 3) -> (n,); 0 outside the box."""
        h = self.config.box_half_size
        inside = (points.abs() <= h).all(dim=-1)
        return self.field.density(self._unit(points))[0] * inside

    def before_step(self, step: int, generator: torch.Generator | None = None) -> None:
        """Sampler bookkeeping before training step `step`: refresh the occupancy grid, or
        anneal the proposal weights."""
        if self.occupancy is not None:
            # Opacity is judged over the longest sample spacing (the box diagonal's).
            step_size = 2.0 * math.sqrt(3.0) * self.config.box_half_size / self.config.num_samples
            self.occupancy.update(step, self.density, step_size, generator)
        else:
            config = self.config
            self.anneal.fill_(proposal_anneal(step, config.proposal_anneal_steps, config.proposal_anneal_slope))
            self.update_proposals = self.proposal_schedule.updates(step)

    def forward(
        self, origins: Tensor, directions: Tensor, background: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> RenderOutput:
        """Render rays.

        Args:
            origins, directions: Tensors with shape (n_rays, 3), world space, unit directions.
            background: Tensor with shape (3,) or (n_rays, 3); None for the configured
                background (`self.background`, or the last sample's colour if
                `config.background_mode == "last_sample"`).
            generator: source of the sample jitter in training mode (None: global RNG).

        Returns:
            RenderOutput with n_samples = config.num_samples; in `extras` the proposal
            histograms (sampler "proposal") for `auxiliary_loss`.
        """
        edges, extras = self._sample(origins, directions, generator)
        t_starts, t_ends = edges[:, :-1], edges[:, 1:]
        weights, rgbs = self._shade(origins, directions, t_starts, t_ends)
        if background is None and self.config.background_mode == "last_sample":
            background = self._last_sample_colour(origins, directions, t_ends[:, -1])
        background = (self.background if background is None else background).to(weights)
        rgb, accumulation, depth = composite(weights, rgbs, t_starts, t_ends, background)
        return RenderOutput(rgb, accumulation, depth, weights, t_starts, t_ends, extras)

    def _sample(
        self, origins: Tensor, directions: Tensor, generator: torch.Generator | None
    ) -> tuple[Tensor, dict]:
        """Edges (n_rays, num_samples + 1) of the final samples, and the proposal histograms
        (as `extras`; empty for the occupancy sampler, which culls samples in `_densities`)."""
        config = self.config
        jitter = self.training
        t_min, t_max = ray_box_span(origins, directions, config.box_half_size, config.near, config.far)
        if self.occupancy is not None:
            return stratified_edges(t_min, t_max, config.num_samples, jitter, generator), {}
        edges = stratified_edges(t_min, t_max, config.proposal_samples[0], jitter, generator)
        proposal_edges, proposal_weights = [], []
        targets = list(config.proposal_samples[1:]) + [config.num_samples]
        # Samples are placed without gradient, so outside training (e.g. a Fisher information
        # pass in eval mode) and on steps that do not update them the proposal networks need no graph.
        with torch.set_grad_enabled(torch.is_grad_enabled() and self.training and self.update_proposals):
            for proposal, n_next in zip(self.proposals, targets):
                weights = self._proposal_weights(proposal, origins, directions, edges)
                proposal_edges.append(edges)
                proposal_weights.append(weights)
                edges = sample_pdf(edges, weights.detach() ** self.anneal, n_next, jitter, generator)
        return edges, {"proposal_edges": proposal_edges, "proposal_weights": proposal_weights}

    def _last_sample_colour(self, origins: Tensor, directions: Tensor, t_far: Tensor) -> Tensor:
        """The field's colour at the far end of each ray, nerfacto's "last_sample" background.
        Shapes: (n_rays, 3), (n_rays, 3), (n_rays,) -> (n_rays, 3)."""
        _, geometry = self.field.density(self._unit(origins + directions * t_far[:, None]))
        return self.field.color(geometry, directions)

    def _proposal_weights(self, proposal: DensityField, origins: Tensor, directions: Tensor, edges: Tensor) -> Tensor:
        """Volume-rendering weights of one proposal network on intervals `edges` (n_rays, n + 1)."""
        mids = 0.5 * (edges[:, 1:] + edges[:, :-1])
        points = origins[:, None, :] + directions[:, None, :] * mids[..., None]
        sigma = proposal(self._unit(points.reshape(-1, 3))).reshape(mids.shape)
        return render_weights(sigma, edges[:, 1:] - edges[:, :-1])[0]

    def _densities(
        self, origins: Tensor, directions: Tensor, t_starts: Tensor, t_ends: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Weights of the final samples, from the field's density where it may matter.

        The field sees only samples inside a non-empty interval and, with the occupancy sampler,
        in an occupied cell; the rest keep density 0. They are gathered out of the dense
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
        if self.occupancy is not None:
            live = live & self.occupancy.query(points)
        index = live.nonzero().squeeze(-1)
        density, geometry = self.field.density(self._unit(points[index]))
        sigma = density.new_zeros(n_rays * n).index_put((index,), density).reshape(n_rays, n)
        weights, transmittance = render_weights(sigma, t_ends - t_starts)
        return weights, transmittance, index, geometry

    def _shade(self, origins: Tensor, directions: Tensor, t_starts: Tensor, t_ends: Tensor) -> tuple[Tensor, Tensor]:
        """Weights (n_rays, n) and colours (n_rays, n, 3) of the final samples. Colour is only
        evaluated where the transmittance exceeds `config.transmittance_eps` (0 elsewhere)."""
        n_rays, n = t_starts.shape
        weights, transmittance, index, geometry = self._densities(origins, directions, t_starts, t_ends)
        visible = transmittance.detach().reshape(-1)[index] > self.config.transmittance_eps
        colour_index = index[visible]
        colours = self.field.color(geometry[visible], directions[colour_index // n])
        rgbs = colours.new_zeros(n_rays * n, 3).index_put((colour_index,), colours).reshape(n_rays, n, 3)
        return weights, rgbs

    def auxiliary_loss(self, output: RenderOutput) -> Tensor:
        """Losses besides photometric error: the proposal sampler's interlevel and distortion
        losses (weighted by the config); 0 for the occupancy sampler."""
        if self.occupancy is not None:
            return output.rgb.new_zeros(())
        edges = torch.cat([output.t_starts, output.t_ends[:, -1:]], dim=-1)
        extras = output.extras or {}
        loss = self.config.distortion_loss_mult * distortion_loss(edges, output.weights)
        if "proposal_edges" in extras:
            loss = loss + self.config.interlevel_loss_mult * interlevel_loss(
                edges, output.weights, extras["proposal_edges"], extras["proposal_weights"]
            )
        return loss

    def _eval_slices(
        self, origins: Tensor, directions: Tensor, chunk: int | None
    ) -> Iterator[tuple[int, int, Tensor, Tensor]]:
        """(start, stop, origins, directions) of consecutive ray chunks on the model's device, in
        eval mode without gradients (the mode is restored after)."""
        device = self.background.device
        chunk = chunk or self.config.render_chunk
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
            chunk: rays per forward pass (None: `config.render_chunk`); bounds peak memory.

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
