"""Trial batches: K NeRFs of one engine as one model, their parameters stacked so that one kernel
serves all K: the hash tables as one table with a per-run offset, the tri-planes as one batch of
planes, the MLPs as batched matrix products.

Rays and samples are laid out run-major: a Tensor with shape (K, n, ...) holds run k's n items in
row k, and flattened to (K * n, ...) its rows come run by run, so the per-ray functions
(`nerfaug.nerf.sampling`, `volrend`, the proposal losses) serve the K runs unchanged.

A `BatchModel` is built from K `NerfModel`s (each initialised as `Trainer` initialises one, from
its own seed) and gives any run back as a plain `NerfModel` (`copy_run_into`), which selection and
evaluation then use unchanged. Only what the batched engine changes is here: the arithmetic of a
run is that of the same run alone but for rounding (batched products; colours evaluated at every
sample and masked rather than gathered, so that shapes stay fixed from step to step).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from nerfaug.nerf.config import NerfConfig, batch_support
from nerfaug.nerf.encoding import HashEncoding, KPlanesEncoding, _HashInterpolation, spherical_harmonics
from nerfaug.nerf.field import DensityField, NerfField, density_activation
from nerfaug.nerf.model import NerfModel
from nerfaug.nerf.proposal import (
    ProposalSampler,
    ProposalSchedule,
    distortion_per_ray,
    interlevel_loss_per_ray,
    place_samples_of,
    proposal_anneal,
)
from nerfaug.nerf.sampling import RunGenerators, ray_box_span, unit_cube
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights

# The stacked parameters' rows (dim 0) hold the runs in order, in equal contiguous blocks, so
# `param.view(K, -1)[k]` is run k's part of any of them (and of its gradient and Adam state).


class StackedLinear(nn.Module):
    """K `nn.Linear` layers of one shape as one batched matrix product.

    Attributes:
        weight: Parameter with shape (K, in_features, out_features) (each layer's weight, transposed).
        bias: Parameter with shape (K, 1, out_features).
    """

    def __init__(self, layers: list[nn.Linear]):
        super().__init__()
        self.weight = nn.Parameter(torch.stack([layer.weight.detach().T for layer in layers]).contiguous())
        self.bias = nn.Parameter(torch.stack([layer.bias.detach() for layer in layers])[:, None, :].contiguous())

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (K, n, in_features). Returns: (K, n, out_features)."""
        return torch.baddbmm(self.bias, x, self.weight)

    def copy_run_into(self, run: int, layer: nn.Linear) -> None:
        layer.weight.copy_(self.weight[run].T)
        layer.bias.copy_(self.bias[run, 0])


class StackedMLP(nn.Module):
    """K ReLU MLPs of one shape (`nerfaug.nerf.field.mlp`) as batched matrix products."""

    def __init__(self, mlps: list[nn.Sequential]):
        super().__init__()
        for layer in mlps[0]:
            if not isinstance(layer, (nn.Linear, nn.ReLU)):
                raise TypeError(f"a trial batch stacks Linear/ReLU MLPs only, not {type(layer).__name__}")
        linear = [i for i, layer in enumerate(mlps[0]) if isinstance(layer, nn.Linear)]
        self.layers = nn.ModuleList([StackedLinear([mlp[i] for mlp in mlps]) for i in linear])

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (K, n, in_dim). Returns: (K, n, out_dim)."""
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < len(self.layers) - 1:
                x = torch.relu(x)
        return x

    def copy_run_into(self, run: int, mlp: nn.Sequential) -> None:
        for stacked, layer in zip(self.layers, [m for m in mlp if isinstance(m, nn.Linear)]):
            stacked.copy_run_into(run, layer)


class StackedHashEncoding(nn.Module):
    """K `HashEncoding`s of one size as one table: run k's rows follow run k - 1's, and each
    point's rows are its own run's (`HashEncoding.corners` plus the run's offset).

    Its kernels are those of the encodings it stacks (`HashEncoding.kernel`): on a GPU with
    Triton, the fused kernels, one launch each way for every run, each point reading its run's
    block of the table; else the PyTorch path, one pass of ~25 kernels serving every run."""

    # Same index arithmetic per point, and the same kernel choice, as one encoding; they read
    # only the attributes copied below.
    corners = HashEncoding.corners
    fused = HashEncoding.fused

    def __init__(self, encodings: list[HashEncoding]):
        super().__init__()
        first = encodings[0]
        sizes = {(e.num_levels, e.features_per_level, e.table_size, tuple(e.resolutions.tolist())) for e in encodings}
        if len(sizes) != 1:
            raise ValueError(f"a trial batch stacks hash encodings of one size, got {sorted(sizes)}")
        self.kernel = first.kernel
        self.num_levels, self.features_per_level = first.num_levels, first.features_per_level
        self.table_size, self.dense_levels = first.table_size, first.dense_levels
        self.rows_per_run = first.num_levels * first.table_size
        if len(encodings) * self.rows_per_run >= 2**31:
            raise ValueError(
                f"{len(encodings)} runs of {self.rows_per_run} hash-table rows overflow int32 rows: use a smaller batch"
            )
        for name in ("resolutions", "factors", "level_offsets"):
            self.register_buffer(name, getattr(first, name).clone(), persistent=False)
        self.table = nn.Parameter(torch.cat([e.table.detach() for e in encodings]))

    @property
    def output_dim(self) -> int:
        return self.num_levels * self.features_per_level

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (K, n, 3) in [0, 1]. Returns: Tensor with shape (K, n, output_dim)."""
        runs, n, _ = x.shape
        if self.fused(x):
            from nerfaug.nerf.hash_triton import FusedHashInterpolation  # needs Triton, an optional package

            return FusedHashInterpolation.apply(x.reshape(runs * n, 3), self.table, self, n).view(runs, n, -1)
        levels = self.num_levels
        rows, weights = self.corners(x.reshape(runs * n, 3))  # (L, 8, K * n)
        offsets = torch.arange(runs, dtype=torch.int32, device=x.device) * self.rows_per_run
        rows = rows.view(levels, 8, runs, n) + offsets[None, None, :, None]
        # Run-major (K * L "levels" of n points): each pass over a level reads one run's table,
        # which stays in the cache; level-major over K tables missed it (K = 8: a gather 4x slower).
        rows = rows.permute(2, 0, 1, 3).reshape(runs * levels, 8, n)
        weights = weights.view(levels, 8, runs, n).permute(2, 0, 1, 3).reshape(runs * levels, 8, n)
        features = _HashInterpolation.apply(self.table, rows, weights)  # (n, K * L * F)
        return features.view(n, runs, self.output_dim).transpose(0, 1)

    def copy_run_into(self, run: int, encoding: HashEncoding) -> None:
        encoding.table.copy_(self.table[run * self.rows_per_run : (run + 1) * self.rows_per_run])


class StackedKPlanes(nn.Module):
    """K `KPlanesEncoding`s of one size: each scale's planes as one batch of K * 3 planes, sampled
    by one `grid_sample` call."""

    def __init__(self, encodings: list[KPlanesEncoding]):
        super().__init__()
        first = encodings[0]
        shapes = {tuple(tuple(p.shape) for p in e.planes) for e in encodings}
        if len(shapes) != 1:
            raise ValueError(f"a trial batch stacks tri-planes of one size, got {sorted(shapes)}")
        self.features = first.features
        self.planes = nn.ParameterList(
            [nn.Parameter(torch.cat([e.planes[s].detach() for e in encodings])) for s in range(len(first.planes))]
        )

    @property
    def output_dim(self) -> int:
        return self.features * len(self.planes)

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (K, n, 3) in [0, 1]. Returns: Tensor with shape (K, n, output_dim)."""
        runs, n, _ = x.shape
        coords = 2.0 * x - 1.0
        grid = torch.stack([coords[..., [0, 1]], coords[..., [0, 2]], coords[..., [1, 2]]], dim=1)  # (K, 3, n, 2)
        grid = grid.reshape(runs * 3, n, 1, 2)
        outputs = []
        for planes in self.planes:
            sampled = nn.functional.grid_sample(planes, grid, mode="bilinear", align_corners=True)
            xy, xz, yz = sampled.reshape(runs, 3, self.features, n).unbind(1)  # each (K, C, n)
            outputs.append((xy * xz * yz).transpose(1, 2))
        return torch.cat(outputs, dim=-1)

    def copy_run_into(self, run: int, encoding: KPlanesEncoding) -> None:
        for stacked, planes in zip(self.planes, encoding.planes):
            planes.copy_(stacked[run * 3 : (run + 1) * 3])


def stack_encodings(encodings: list[nn.Module]) -> nn.Module:
    """The stacked form of K position encodings of one kind and size."""
    kinds = {type(e) for e in encodings}
    if kinds == {HashEncoding}:
        return StackedHashEncoding(encodings)
    if kinds == {KPlanesEncoding}:
        return StackedKPlanes(encodings)
    names = ", ".join(sorted(k.__name__ for k in kinds))
    raise TypeError(f"a trial batch stacks hash or K-planes encodings of one kind, not {names}")


class StackedField(nn.Module):
    """K `NerfField`s of one configuration: density from positions, colour from a geometry
    feature and the ray's direction, for every run at once."""

    def __init__(self, fields: list[NerfField]):
        super().__init__()
        for f in fields:
            if type(f) is not NerfField:
                raise TypeError(f"a trial batch stacks the nerfacto field only, not {type(f).__name__}")
        first = fields[0]
        self.density_kind, self.average_init_density = first.density_kind, first.average_init_density
        self.sh_levels, self.geo_feat_dim = first.sh_levels, first.geo_feat_dim
        self.encoding = stack_encodings([f.encoding for f in fields])
        self.density_mlp = StackedMLP([f.density_mlp for f in fields])
        self.color_mlp = StackedMLP([f.color_mlp for f in fields])

    def density(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Args: x: Tensor with shape (K, n, 3) in [0, 1]^3.

        Returns:
            density (K, n) and geometry (K, n, geo_feat_dim), as `NerfField.density` per run.
        """
        raw, geometry = self.density_mlp(self.encoding(x)).split([1, self.geo_feat_dim], dim=-1)
        return density_activation(raw[..., 0], self.density_kind, self.average_init_density), geometry

    def color(self, geometry: Tensor, directions: Tensor) -> Tensor:
        """Colours of samples along rays.

        Args:
            geometry: Tensor with shape (K, n_rays, n_samples, geo_feat_dim).
            directions: Tensor with shape (K, n_rays, 3), unit.

        Returns:
            Tensor with shape (K, n_rays, n_samples, 3) in [0, 1].
        """
        runs, n_rays, n_samples, _ = geometry.shape
        # The direction encoding once per ray, not once per sample as a run alone computes it.
        sh = spherical_harmonics(directions.reshape(-1, 3), self.sh_levels).reshape(runs, n_rays, 1, -1)
        features = torch.cat([sh.expand(-1, -1, n_samples, -1), geometry], dim=-1)
        rgb = torch.sigmoid(self.color_mlp(features.reshape(runs, n_rays * n_samples, -1)))
        return rgb.reshape(runs, n_rays, n_samples, 3)

    def copy_run_into(self, run: int, field: NerfField) -> None:
        self.encoding.copy_run_into(run, field.encoding)
        self.density_mlp.copy_run_into(run, field.density_mlp)
        self.color_mlp.copy_run_into(run, field.color_mlp)


class StackedDensityField(nn.Module):
    """K proposal `DensityField`s of one size."""

    def __init__(self, fields: list[DensityField]):
        super().__init__()
        first = fields[0]
        self.density_kind, self.average_init_density = first.density_kind, first.average_init_density
        self.encoding = stack_encodings([f.encoding for f in fields])
        self.mlp = StackedMLP([f.mlp for f in fields])

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (K, n, 3) in [0, 1]^3. Returns: density, shape (K, n)."""
        return density_activation(self.mlp(self.encoding(x))[..., 0], self.density_kind, self.average_init_density)

    def copy_run_into(self, run: int, field: DensityField) -> None:
        self.encoding.copy_run_into(run, field.encoding)
        self.mlp.copy_run_into(run, field.mlp)


class BatchModel(nn.Module):
    """K NeRFs of one engine (proposal sampler) rendering their own rays in one pass.

    Args:
        models: K `NerfModel`s with the same config and background (their parameters are copied).

    Attributes:
        runs: K.
        field: the `StackedField`.
        networks: the proposal networks (`StackedDensityField`), coarse to fine.
        anneal: buffer, the proposal weights' exponent (shared: the runs step in lockstep).
    """

    def __init__(self, models: list[NerfModel]):
        super().__init__()
        config = models[0].config
        reason = batch_support(config)
        if reason is not None:
            raise ValueError(reason)
        if any(m.config != config for m in models):
            raise ValueError("a trial batch trains runs of one engine configuration")
        sampler: ProposalSampler = models[0].sampler
        self.config, self.runs = config, len(models)
        self.field = StackedField([m.field for m in models])
        self.networks = nn.ModuleList(
            [StackedDensityField([m.sampler.networks[i] for m in models]) for i in range(len(sampler.networks))]
        )
        self.samples, self.num_samples = sampler.samples, sampler.num_samples
        self.schedule = ProposalSchedule(config.sampler.proposal.update_every, config.sampler.proposal.warmup_steps)
        self.register_buffer("background", models[0].background.clone())
        self.register_buffer("anneal", torch.tensor(1.0))
        self.update_networks = True

    def param_groups(self) -> dict[str, list[nn.Parameter]]:
        """Trainable parameters by optimiser group, as `NerfModel.param_groups`."""
        return {"field": list(self.field.parameters()), "proposal": list(self.networks.parameters())}

    def before_step(self, step: int) -> None:
        """Anneal the proposal weights and decide whether this step updates the proposal networks."""
        self.anneal.fill_(
            proposal_anneal(step, self.config.sampler.proposal.anneal_steps, self.config.sampler.proposal.anneal_slope)
        )
        self.update_networks = self.schedule.updates(step)

    def forward(
        self,
        origins: Tensor,
        directions: Tensor,
        background: Tensor | None = None,
        generator: RunGenerators | None = None,
    ) -> RenderOutput:
        """Render each run's rays with that run's NeRF.

        Args:
            origins, directions: Tensors with shape (K, n_rays, 3), world space, unit directions.
            background: Tensor with shape (3,) or (K * n_rays, 3); None for the configured one.
            generator: each run's source of sample jitter in training mode.

        Returns:
            RenderOutput over the K * n_rays rays, run-major (run k's rays are rows
            k * n_rays to (k + 1) * n_rays - 1); extras hold the proposal histograms.
        """
        runs, n_rays, _ = origins.shape
        config = self.config
        o, d = origins.reshape(-1, 3), directions.reshape(-1, 3)
        t_min, t_max = ray_box_span(o, d, config.scene.box_half_size, config.scene.near, config.scene.far)

        def weights_of(level: int, edges: Tensor) -> Tensor:
            mids = 0.5 * (edges[:, 1:] + edges[:, :-1])
            sigma = self.networks[level](self._unit_points(o, d, mids, runs)).reshape(mids.shape)
            return render_weights(sigma, edges[:, 1:] - edges[:, :-1])[0]

        edges, extras = place_samples_of(self, weights_of, t_min, t_max, generator)
        t_starts, t_ends = edges[:, :-1], edges[:, 1:]
        weights, rgbs = self._shade(o, d, t_starts, t_ends, runs)
        if background is None and config.renderer.background_mode == "last_sample":
            far = self._unit_points(o, d, t_ends[:, -1:], runs)
            _, geometry = self.field.density(far)
            background = self.field.color(geometry[:, :, None], d.reshape(runs, n_rays, 3)).reshape(-1, 3)
        elif background is None and config.renderer.background_mode == "last_composited":
            background = rgbs[:, -1]
        background = (self.background if background is None else background).to(weights)
        rgb, accumulation, depth = composite(weights, rgbs, t_starts, t_ends, background)
        return RenderOutput(rgb, accumulation, depth, weights, t_starts, t_ends, extras)

    def _unit_points(self, o: Tensor, d: Tensor, t: Tensor, runs: int) -> Tensor:
        """Points at distances t (K * n_rays, m) along the rays, in the unit cube: (K, n_rays * m, 3)."""
        points = o[:, None, :] + d[:, None, :] * t[..., None]
        return unit_cube(points.reshape(runs, -1, 3), self.config.scene.box_half_size)

    def _shade(self, o: Tensor, d: Tensor, t_starts: Tensor, t_ends: Tensor, runs: int) -> tuple[Tensor, Tensor]:
        """Weights (K * n_rays, n) and colours (K * n_rays, n, 3) of the final samples.

        Every sample is evaluated (fixed shapes); what a run alone skips is masked to what it
        computes there: density 0 on empty intervals, colour 0 where the transmittance is at most
        `config.sampler.transmittance_eps`."""
        n = t_starts.shape[1]
        density, geometry = self.field.density(self._unit_points(o, d, 0.5 * (t_starts + t_ends), runs))
        live = t_ends > t_starts
        sigma = torch.where(live, density.reshape(live.shape), 0.0)
        weights, transmittance = render_weights(sigma, t_ends - t_starts)
        colours = self.field.color(geometry.reshape(runs, -1, n, self.field.geo_feat_dim), d.reshape(runs, -1, 3))
        visible = live & (transmittance.detach() > self.config.sampler.transmittance_eps)
        rgbs = torch.where(visible[..., None], colours.reshape(-1, n, 3), 0.0)
        return weights, rgbs

    def run_losses(self, output: RenderOutput, target: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        """Each run's training loss, and its parts named as `NerfModel.losses` ("rgb",
        "distortion", "interlevel"), weighted alike.

        Args:
            output: a training pass's `forward` output.
            target: Tensor with shape (K * n_rays, 3), the rays' colours.

        Returns:
            loss: Tensor with shape (K,): run k's mean squared error plus its distortion and
                interlevel losses (summed per ray, then averaged: the engine version's rounding).
            named: name -> Tensor with shape (K,), each part alone.
        """
        config, runs = self.config, self.runs
        mse = (output.rgb.float() - target).square().reshape(runs, -1).mean(dim=-1)
        edges = torch.cat([output.t_starts, output.t_ends[:, -1:]], dim=-1)
        distortion = config.sampler.proposal.distortion_loss_mult * distortion_per_ray(edges, output.weights)
        named = {"rgb": mse, "distortion": distortion.reshape(runs, -1).mean(dim=-1)}
        per_ray = distortion
        extras = output.extras or {}
        if "proposal_edges" in extras:
            interlevel = config.sampler.proposal.interlevel_loss_mult * interlevel_loss_per_ray(
                edges, output.weights, extras["proposal_edges"], extras["proposal_weights"]
            )
            named["interlevel"] = interlevel.reshape(runs, -1).mean(dim=-1)
            per_ray = per_ray + interlevel
        return mse + per_ray.reshape(runs, -1).mean(dim=-1), named

    def copy_run_into(self, run: int, model: NerfModel) -> None:
        """Write run `run`'s parameters and sampler state into `model` (a `NerfModel` of the same
        config), which then renders as that run would alone."""
        with torch.no_grad():
            self.field.copy_run_into(run, model.field)
            for stacked, network in zip(self.networks, model.sampler.networks):
                stacked.copy_run_into(run, network)
            model.sampler.anneal.fill_(float(self.anneal))
            model.sampler.update_networks = self.update_networks


# The most runs an automatic batch holds, until a GPU measures a batch's peak memory: the
# per-run estimate below is computed, not measured.
MAX_AUTO_BATCH = 8
# What one run's selection and evaluation may take besides the batch's training: they run one run
# at a time. Measured at paper scale on an H100: 14.4 GiB for a whole trial, 21-24 GiB for the
# candidate scoring of entropy and FisherRF (BENCHMARKS.md, "GPU: the paper preset on an H100").
SELECTION_RESERVE_BYTES = 24 * 2**30


def estimated_run_bytes(config: NerfConfig, fused: bool) -> int:
    """A rough upper estimate of one run's memory in a trial batch, in bytes: its parameters
    with their gradients and Adam's two moments, and the activations a training step keeps for
    its backward pass (without `fused` hash kernels also the PyTorch path's rows, weights and
    gathered features of every point's 8 vertices per level). An estimate for choosing a batch's
    size; the GPU benchmark measures the peak (`benchmarks/bench_gpu.py`)."""
    field, proposal = config.field, config.sampler.proposal
    if field.encoding == "hash":
        grid = field.hash
        encoding_params = grid.levels * 2**grid.log2_table_size * grid.features_per_level
        encoding_width = grid.levels * grid.features_per_level
        corner_floats = 0 if fused else grid.levels * 8 * (2 + grid.features_per_level)
    else:
        planes = field.planes
        encoding_params = sum(3 * planes.features * r * r for r in planes.resolutions)
        encoding_width, corner_floats = planes.features * len(planes.resolutions), 0
    levels = len(proposal.samples)
    proposal_params = levels * proposal.hash_levels * 2**proposal.log2_table_size * 2
    rays = config.optimiser.batch_size
    field_samples, proposal_samples = rays * config.sampler.num_samples, rays * sum(proposal.samples)
    per_field_sample = (
        encoding_width
        + 2 * field.hidden_dim
        + 2 * (field.sh_levels**2 + field.geo_feat_dim)
        + 2 * field.color_hidden_dim * field.color_layers
        + 24  # positions, densities, weights, colours, masks and their gradients
        + corner_floats
    )
    per_proposal_sample = (
        proposal.hash_levels * 2 + 2 * proposal.hidden_dim + 12 + (0 if fused else proposal.hash_levels * 32)
    )
    distortion = 3 * rays * config.sampler.num_samples**2
    floats = 4 * (encoding_params + proposal_params) + field_samples * per_field_sample
    floats += proposal_samples * per_proposal_sample + distortion
    return 4 * floats


def auto_batch_size(config: NerfConfig, device, runs: int) -> tuple[int, str]:
    """How many runs of engine `config` a trial batch on the GPU `device` holds: what 80% of its
    free memory holds, less `SELECTION_RESERVE_BYTES` (scaled down for a small engine), at twice
    `estimated_run_bytes` a run (the allocator's slack); at most `runs` and `MAX_AUTO_BATCH`. (On a
    CPU a batch gains little whatever its size: BENCHMARKS.md, "Trial batches"; its size is asked for.)

    Returns:
        the size, and a line saying how it was chosen.
    """
    from nerfaug.device import describe_device, resolve_device
    from nerfaug.nerf.encoding import triton_available

    device = resolve_device(device)
    per_run = 2 * estimated_run_bytes(config, fused=triton_available())
    reserve = min(SELECTION_RESERVE_BYTES, 10 * per_run)
    free, _ = torch.cuda.mem_get_info(device)
    size = max(1, min(runs, MAX_AUTO_BATCH, int(0.8 * free - reserve) // per_run))
    text = (
        f"trial batches of {size} runs (about {per_run / 2**30:.1f} GiB a run by estimate, "
        f"{reserve / 2**30:.0f} GiB kept for one run's selection, {free / 2**30:.0f} GiB free on "
        f"{describe_device(device)})"
    )
    return size, text
