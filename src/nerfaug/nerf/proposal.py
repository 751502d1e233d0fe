"""nerfacto's proposal sampler (mip-NeRF 360): small density networks whose weights place the
next level's samples, the histogram (interlevel) loss that makes proposal weights bound the final
ones, the distortion loss, the annealing of proposal weights early in training, and the schedule
of the steps that update them.

Histograms are (edges (n_rays, n + 1), weights (n_rays, n)) along the same rays.
"""

from __future__ import annotations

from typing import Protocol

import torch
from torch import Tensor, nn

from nerfaug.nerf import sampler_cpu
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.field import DensityField
from nerfaug.nerf.sampler import Sampler
from nerfaug.nerf.sampling import cdf_positions, sample_pdf, stratified_edges, unit_cube
from nerfaug.nerf.volrend import RenderOutput, render_weights

_EPS = 1e-7


def outer_measure(edges: Tensor, env_edges: Tensor, env_weights: Tensor) -> Tensor:
    """For each interval of `edges`, the total envelope weight over the envelope bins that
    overlap it (an upper bound on the mass any consistent histogram can put there).

    Args:
        edges: Tensor with shape (n_rays, n + 1).
        env_edges: Tensor with shape (n_rays, m + 1).
        env_weights: Tensor with shape (n_rays, m).

    Returns:
        Tensor with shape (n_rays, n).
    """
    cumulative = torch.cat([torch.zeros_like(env_weights[:, :1]), torch.cumsum(env_weights, dim=-1)], dim=-1)
    starts, ends = edges[:, :-1].contiguous(), edges[:, 1:].contiguous()
    m = env_weights.shape[-1]
    low = (torch.searchsorted(env_edges[:, :-1].contiguous(), starts, side="right") - 1).clamp(0, m - 1)
    high = torch.searchsorted(env_edges[:, 1:].contiguous(), ends, side="right").clamp(0, m - 1)
    return cumulative[:, 1:].gather(-1, high) - cumulative[:, :-1].gather(-1, low)


def interlevel_loss(
    edges: Tensor, weights: Tensor, proposal_edges: list[Tensor], proposal_weights: list[Tensor]
) -> Tensor:
    """mip-NeRF 360's proposal loss: penalise final weights not covered by each proposal's
    outer measure. Gradients reach only the proposal weights.

    Args:
        edges, weights: the final histogram, (n_rays, n + 1) and (n_rays, n).
        proposal_edges, proposal_weights: one histogram per proposal level.

    Returns:
        scalar Tensor, summed over levels, mean over rays and samples.
    """
    loss = weights.new_zeros(())
    for term in _interlevel_terms(edges, weights, proposal_edges, proposal_weights):
        loss = loss + term.mean()
    return loss


def _interlevel_terms(edges, weights, proposal_edges, proposal_weights):
    """Per proposal level, the interlevel penalty of every final sample: Tensors (n_rays, n)."""
    edges, weights = edges.detach(), weights.detach()
    for p_edges, p_weights in zip(proposal_edges, proposal_weights):
        if sampler_cpu.applies(edges, weights, p_edges, p_weights) and not p_edges.requires_grad:
            yield sampler_cpu.FusedInterlevel.apply(edges, weights, p_edges, p_weights, _EPS)
            continue
        bound = outer_measure(edges, p_edges, p_weights)
        yield (weights - bound).clamp(min=0) ** 2 / (weights + _EPS)


def distortion_loss(edges: Tensor, weights: Tensor) -> Tensor:
    """mip-NeRF 360's distortion loss, which pulls each ray's weight into one compact interval.

    L = sum_ij w_i w_j |m_i - m_j| + 1/3 sum_i w_i^2 (t_{i+1} - t_i), with t normalised to
    [0, 1] per ray so that the loss does not depend on the scene's scale.

    Args:
        edges: Tensor with shape (n_rays, n + 1).
        weights: Tensor with shape (n_rays, n).

    Returns:
        scalar Tensor, mean over rays.
    """
    return distortion_per_ray(edges, weights).mean()


def distortion_per_ray(edges: Tensor, weights: Tensor) -> Tensor:
    """`distortion_loss` of each ray: Tensor with shape (n_rays,) (shapes as there)."""
    if sampler_cpu.applies(edges, weights) and not edges.requires_grad:
        return sampler_cpu.FusedDistortion.apply(edges, weights, _EPS)
    span = (edges[:, -1:] - edges[:, :1]).clamp_min(_EPS)
    t = (edges - edges[:, :1]) / span
    mids = 0.5 * (t[:, 1:] + t[:, :-1])
    widths = t[:, 1:] - t[:, :-1]
    pairwise = (weights[:, :, None] * weights[:, None, :] * (mids[:, :, None] - mids[:, None, :]).abs()).sum((1, 2))
    return pairwise + (weights**2 * widths).sum(-1) / 3.0


def proposal_anneal(step: int, anneal_steps: int, slope: float) -> float:
    """Exponent applied to proposal weights before resampling: 0 (uniform) at step 0, rising to
    1 at `anneal_steps` along nerfacto's biased curve slope * f / ((slope - 1) f + 1)."""
    fraction = min(max(step / max(anneal_steps, 1), 0.0), 1.0)
    return slope * fraction / ((slope - 1.0) * fraction + 1.0)


def proposal_update_interval(step: int, update_every: int, warmup_steps: int) -> float:
    """nerfacto's update schedule: how many steps must pass before the proposal networks are
    updated again, rising linearly from 0 at step 0 to `update_every` at `warmup_steps`,
    clipped to [1, update_every]."""
    fraction = min(max(step / max(warmup_steps, 1), 0.0), 1.0)
    return min(max(update_every * fraction, 1.0), float(update_every))


def place_samples(
    weights_of, t_min, t_max, samples, num_samples: int, anneal, jitter: bool, generator, with_graph: bool
) -> tuple[Tensor, dict]:
    """The proposal sampler's cascade: stratified intervals for the first network, each
    network's weights (raised to `anneal`) placing the next level's intervals by inverse CDF, the
    last network's the `num_samples` final ones.

    Args:
        weights_of: `weights_of(level, edges)` -> that level's network's volume-rendering weights
            (n_rays, n) on intervals `edges` (n_rays, n + 1).
        t_min, t_max: Tensors with shape (n_rays,), where each ray is in the scene.
        samples: intervals per proposal level.
        anneal: the exponent of the proposal weights (a scalar Tensor or float).
        jitter, generator: stratified random positions, and their source.
        with_graph: whether the networks' evaluations keep a graph (steps that update them).

    Returns:
        The final edges (n_rays, num_samples + 1), and each level's histogram for the
        interlevel loss ("proposal_edges", "proposal_weights").
    """
    edges = stratified_edges(t_min, t_max, samples[0], jitter, generator)
    proposal_edges, proposal_weights = [], []
    targets = list(samples[1:]) + [num_samples]
    with torch.set_grad_enabled(with_graph):
        for level, n_next in enumerate(targets):
            weights = weights_of(level, edges)
            proposal_edges.append(edges)
            proposal_weights.append(weights)
            edges = _resample(edges, weights.detach() ** anneal, n_next, jitter, generator)
    return edges, {"proposal_edges": proposal_edges, "proposal_weights": proposal_weights}


def _resample(edges: Tensor, weights: Tensor, n_samples: int, jitter: bool, generator) -> Tensor:
    """`sample_pdf` (shapes as there), in one C pass a ray where `sampler_cpu` applies; the same
    random positions either way."""
    if not sampler_cpu.applies(edges, weights):
        return sample_pdf(edges, weights, n_samples, jitter, generator)
    u = cdf_positions(edges.shape[0], n_samples + 1, jitter, generator, edges.device)
    return sampler_cpu.sample_pdf(edges, weights, u, padding=0.01)


class ProposalState(Protocol):
    """What `place_samples_of` reads of a proposal sampler (`ProposalSampler`)."""

    samples: tuple[int, ...]
    num_samples: int
    anneal: Tensor
    training: bool
    update_networks: bool


def place_samples_of(
    sampler: ProposalState, weights_of, t_min: Tensor, t_max: Tensor, generator
) -> tuple[Tensor, dict]:
    """`place_samples` with `sampler`'s levels, annealing exponent and mode: jittered in training.

    Samples are placed without gradient, so outside training (e.g. a Fisher information pass in
    eval mode) and on steps that do not update them the networks need no graph.

    Args:
        sampler: the sampler whose cascade it is (its `samples`, `num_samples`, `anneal`,
            `training` and `update_networks`).
        weights_of, t_min, t_max, generator: as for `place_samples`.

    Returns:
        As `place_samples`: the final edges (n_rays, num_samples + 1) and the histograms.
    """
    return place_samples(
        weights_of,
        t_min,
        t_max,
        sampler.samples,
        sampler.num_samples,
        sampler.anneal,
        sampler.training,
        generator,
        with_graph=torch.is_grad_enabled() and sampler.training and sampler.update_networks,
    )


class ProposalSchedule:
    """Which training steps update the proposal networks (nerfstudio's ProposalNetworkSampler
    rule): every step below 10, then a step once more than `proposal_update_interval` steps have
    passed since the last update. A pure function of the step: a resumed run re-derives the
    counter by replaying the rule from step 0.
    """

    def __init__(self, update_every: int, warmup_steps: int):
        self.update_every, self.warmup_steps = update_every, warmup_steps
        self._step, self._since_update = -1, 0

    def _advance(self) -> bool:
        self._step += 1
        self._since_update += 1
        interval = proposal_update_interval(self._step, self.update_every, self.warmup_steps)
        updated = self._since_update > interval or self._step < 10
        if updated:
            self._since_update = 0
        return updated

    def updates(self, step: int) -> bool:
        """Whether training step `step` updates the proposal networks."""
        if self.update_every <= 0:
            return True
        if step <= self._step:  # asked again, or a step back (a reload): replay from the start
            self._step, self._since_update = -1, 0
        updated = True
        while self._step < step:
            updated = self._advance()
        return updated


class ProposalSampler(Sampler):
    """Stratified samples for the first proposal network; each network's weights (raised to the
    annealing exponent) place the next level's samples by inverse CDF, the last network's the
    `num_samples` final ones.

    Attributes:
        networks: the proposal `DensityField`s, coarse to fine.
        anneal: buffer, exponent of the proposal weights, annealed from 0 to 1 by `before_step`.
        update_networks: whether this training step's proposal evaluations build a graph
            (set by `before_step` from `schedule`).
    """

    def __init__(
        self,
        networks: list[DensityField],
        samples: tuple[int, ...],
        num_samples: int,
        half_size: float,
        schedule: ProposalSchedule,
        anneal_steps: int,
        anneal_slope: float,
        interlevel_loss_mult: float,
        distortion_loss_mult: float,
    ):
        super().__init__()
        self.networks = nn.ModuleList(networks)
        self.samples, self.num_samples, self.half_size = tuple(samples), num_samples, half_size
        self.schedule, self.anneal_steps, self.anneal_slope = schedule, anneal_steps, anneal_slope
        self.interlevel_loss_mult, self.distortion_loss_mult = interlevel_loss_mult, distortion_loss_mult
        self.register_buffer("anneal", torch.tensor(1.0))
        self.update_networks = True

    @classmethod
    def from_config(cls, config: NerfConfig) -> ProposalSampler:
        proposal = config.sampler.kind  # a `ProposalConfig`
        return cls(
            [DensityField(config, r) for r in proposal.max_resolutions],
            proposal.samples,
            config.sampler.num_samples,
            config.scene.box_half_size,
            ProposalSchedule(proposal.update_every, proposal.warmup_steps),
            proposal.anneal_steps,
            proposal.anneal_slope,
            proposal.interlevel_loss_mult,
            proposal.distortion_loss_mult,
        )

    @property
    def samples_per_ray(self) -> int:
        return max((*self.samples, self.num_samples))

    def sample(self, origins, directions, t_min, t_max, generator=None) -> tuple[Tensor, dict]:
        """See `Sampler.sample`; `extras` holds each network's histogram ("proposal_edges",
        "proposal_weights") for the interlevel loss."""
        return place_samples_of(
            self,
            lambda level, edges: self._weights(self.networks[level], origins, directions, edges),
            t_min,
            t_max,
            generator,
        )

    def _weights(self, network: DensityField, origins: Tensor, directions: Tensor, edges: Tensor) -> Tensor:
        """Volume-rendering weights of one network on intervals `edges` (n_rays, n + 1)."""
        mids = 0.5 * (edges[:, 1:] + edges[:, :-1])
        points = origins[:, None, :] + directions[:, None, :] * mids[..., None]
        sigma = network(unit_cube(points.reshape(-1, 3), self.half_size)).reshape(mids.shape)
        return self.render_weights(sigma, edges[:, 1:] - edges[:, :-1])[0]

    def fused_cpu(self, *tensors: Tensor) -> bool:
        """See `Sampler.fused_cpu`: where `sampler_cpu` applies to `tensors`."""
        return sampler_cpu.applies(*tensors)

    def render_weights(self, sigmas: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
        """See `Sampler.render_weights`: in one C pass a ray where `sampler_cpu` applies."""
        if sampler_cpu.applies(sigmas, deltas) and not deltas.requires_grad:
            return sampler_cpu.render_weights(sigmas, deltas)
        return render_weights(sigmas, deltas)

    def before_step(self, step, density_fn, generator=None) -> None:
        self.anneal.fill_(proposal_anneal(step, self.anneal_steps, self.anneal_slope))
        self.update_networks = self.schedule.updates(step)

    def auxiliary_losses(self, output: RenderOutput) -> dict[str, Tensor]:
        """{"distortion": the distortion loss of the final weights, "interlevel": the
        interlevel loss (when the pass kept the proposal histograms)}, weighted by the config's
        multipliers."""
        edges = torch.cat([output.t_starts, output.t_ends[:, -1:]], dim=-1)
        extras = output.extras or {}
        losses = {"distortion": self.distortion_loss_mult * distortion_loss(edges, output.weights)}
        if "proposal_edges" in extras:
            losses["interlevel"] = self.interlevel_loss_mult * interlevel_loss(
                edges, output.weights, extras["proposal_edges"], extras["proposal_weights"]
            )
        return losses
