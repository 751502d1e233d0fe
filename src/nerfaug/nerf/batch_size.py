"""How many runs a batch on a GPU holds: each run's memory estimated from its engine's settings,
against the device's free memory (`nerfaug.nerf.trainer.Trainer` trains the batch)."""

from __future__ import annotations

import torch

from nerfaug.nerf.config import HashGridConfig, NerfConfig, ProposalConfig

# The most runs an automatic batch holds, until a GPU measures a batch's peak memory: the
# per-run estimate below is computed, not measured.
MAX_AUTO_BATCH = 8
# What one run's selection and evaluation may take besides the batch's training: they run one run
# at a time. Measured at paper scale on an H100: 14.4 GiB for a whole trial, 21-24 GiB for the
# candidate scoring of entropy and FisherRF (BENCHMARKS.md, "GPU: the paper preset on an H100").
SELECTION_RESERVE_BYTES = 24 * 2**30


def estimated_run_bytes(config: NerfConfig, fused: bool) -> int:
    """A rough upper estimate of one run's memory in a batch, in bytes: its parameters
    with their gradients and Adam's two moments, and the activations a training step keeps for
    its backward pass (without `fused` hash kernels also the PyTorch path's rows, weights and
    gathered features of every point's 8 vertices per level). An estimate for choosing a batch's
    size; the GPU benchmark measures the peak (`benchmarks/bench_gpu.py`)."""
    field = config.field
    if isinstance(grid := field.encoding, HashGridConfig):
        encoding_params = grid.levels * 2**grid.log2_table_size * grid.features_per_level
        encoding_width = grid.levels * grid.features_per_level
        corner_floats = 0 if fused else grid.levels * 8 * (2 + grid.features_per_level)
    else:
        planes = field.encoding
        encoding_params = sum(3 * planes.features * r * r for r in planes.resolutions)
        encoding_width, corner_floats = planes.features * len(planes.resolutions), 0
    # An engine without proposal networks (an occupancy grid) counts none.
    proposal = config.sampler.kind if isinstance(config.sampler.kind, ProposalConfig) else None
    levels = len(proposal.samples) if proposal else 0
    proposal_params = levels * proposal.hash_levels * 2**proposal.log2_table_size * 2 if proposal else 0
    rays = config.optimiser.batch_size
    field_samples = rays * config.sampler.num_samples
    proposal_samples = rays * sum(proposal.samples) if proposal else 0
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
        if proposal
        else 0
    )
    distortion = 3 * rays * config.sampler.num_samples**2
    floats = 4 * (encoding_params + proposal_params) + field_samples * per_field_sample
    floats += proposal_samples * per_proposal_sample + distortion
    return 4 * floats


def auto_batch_size(config: NerfConfig, device, runs: int) -> tuple[int, str]:
    """How many runs of engine `config` a batch on the GPU `device` holds: what 80% of its
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
        f"batches of {size} runs (about {per_run / 2**30:.1f} GiB a run by estimate, "
        f"{reserve / 2**30:.0f} GiB kept for one run's selection, {free / 2**30:.0f} GiB free on "
        f"{describe_device(device)})"
    )
    return size, text
