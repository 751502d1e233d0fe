"""A run's memory, estimated from its engine's settings before anything is built, and the refusal of
an engine that cannot fit this machine: one line naming the setting that makes it too large
(`--engine.field.hidden-dim 1000000000: ...`), where otherwise the allocator would fail half-way
through creating a session.

The estimate counts what grows with the settings: the parameters (with their gradients and Adam's
two moments), the activations one training step keeps for its backward pass, and one render
chunk's; not the dataset's images, which do not depend on the engine. (`nerf.batch_size`'s
`estimated_run_bytes` sizes batches on a GPU the same way; it leaves out the MLPs' weights,
which are small at any sensible width.) Light: no torch.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from nerfaug.nerf.config import PRESETS, HashGridConfig, ProposalConfig
from nerfaug.nerf.engine import Engine
from nerfaug.schema import RequestError

FLOAT = 4  # bytes of a float32
# A parameter's float, its gradient and Adam's two moments.
PER_PARAMETER = 4 * FLOAT
# The cgroup (v2) file that may hold this process's memory limit, below the machine's.
CGROUP_LIMIT = Path("/sys/fs/cgroup/memory.max")


def _mlp(inputs: int, hidden: int, outputs: int, layers: int) -> int:
    """Weights and biases of `nerf.field.mlp(inputs, hidden, outputs, layers)`."""
    return inputs * hidden + hidden + (layers - 1) * (hidden * hidden + hidden) + hidden * outputs + outputs


def parameters(config: Any) -> int:
    """The engine `config`'s (a `NerfConfig`) parameter count, an upper bound (a hash level that
    is dense at its resolution holds fewer entries than the table)."""
    field, sampler = config.field, config.sampler
    if isinstance(grid := field.encoding, HashGridConfig):
        encoding, width = (
            grid.levels * 2**grid.log2_table_size * grid.features_per_level,
            grid.levels * grid.features_per_level,
        )
    else:
        planes = field.encoding
        encoding = sum(3 * planes.features * r * r for r in planes.resolutions)
        width = planes.features * len(planes.resolutions)
    count = encoding + _mlp(width, field.hidden_dim, 1 + field.geo_feat_dim, 1)
    count += _mlp(field.sh_levels**2 + field.geo_feat_dim, field.color_hidden_dim, 3, field.color_layers)
    if isinstance(proposal := sampler.kind, ProposalConfig):
        each = proposal.hash_levels * 2**proposal.log2_table_size * 2 + _mlp(
            proposal.hash_levels * 2, proposal.hidden_dim, 1, 1
        )
        count += len(proposal.samples) * each
    return count


def _per_sample(config: Any) -> int:
    """Floats one colour sample keeps for the backward pass: its encoding (with the interpolated
    corners), the MLPs' activations, and the compositing's."""
    field = config.field
    if isinstance(grid := field.encoding, HashGridConfig):
        encoding = grid.levels * grid.features_per_level + grid.levels * 8 * (2 + grid.features_per_level)
    else:
        planes = field.encoding
        encoding = len(planes.resolutions) * planes.features * (1 + 3 * 4)  # 3 planes, 4 corners each
    return (
        encoding
        + 2 * field.hidden_dim
        + 2 * (field.sh_levels**2 + field.geo_feat_dim)
        + 2 * field.color_hidden_dim * field.color_layers
        + 24  # positions, densities, weights, colours, masks and their gradients
    )


def estimated_bytes(config: Any) -> int:
    """A rough upper estimate of the memory one run of engine `config` (a `NerfConfig`) takes to
    train, in bytes: parameters with gradients and Adam's moments, plus the larger of one
    training step's activations and one render chunk's."""
    sampler, rays = config.sampler, config.optimiser.batch_size
    samples = sampler.num_samples
    step = rays * samples * _per_sample(config) + 3 * rays * samples**2  # the distortion loss's pairs
    if isinstance(proposal := sampler.kind, ProposalConfig):
        per = proposal.hash_levels * (2 + 32) + 2 * proposal.hidden_dim + 12
        step += rays * sum(proposal.samples) * per
    else:
        step += 2 * sampler.kind.resolution**3  # the grid and its opacities
    render = config.renderer.render_chunk * samples * _per_sample(config) // 4  # no gradients: a few layers' at a time
    return PER_PARAMETER * parameters(config) + FLOAT * max(step, render)


def machine_memory() -> int:
    """This machine's memory in bytes, or the memory limit of this process's cgroup where lower."""
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    try:
        limit = CGROUP_LIMIT.read_text().strip()
    except OSError:
        return total
    return min(total, int(limit)) if limit.isdigit() else total


def gib(count: int) -> str:
    """Bytes in GiB as a person reads them: 1.5 GiB, 480 GiB, 3.2e+04 GiB."""
    value = count / 2**30
    return f"{value:.1f} GiB" if value < 100 else f"{value:.0f} GiB" if value < 1e5 else f"{value:.1e} GiB"


def check_fits(config: Any, changes: dict[tuple[str, ...], Any], base: Any, limit: int | None = None) -> None:
    """Refuse the engine `config` when `estimated_bytes` exceeds `limit` (this machine's memory
    unless given), as a RequestError naming the setting whose change made it largest.

    Args:
        config: the engine (a `NerfConfig`).
        changes: the settings the engine changes from its preset, path -> value.
        base: the preset (a `NerfConfig`); the engine with one change left out shows how much of
            the estimate that change is to blame for.
    """
    limit = machine_memory() if limit is None else limit
    need = estimated_bytes(config)
    if need <= limit:
        return
    blame, path, value = need, (), None
    for where, given in changes.items():
        try:
            restored = estimated_bytes(base.changed({p: v for p, v in changes.items() if p != where}))
        except (ValueError, ZeroDivisionError):  # e.g. a part's setting without the choice of the part
            continue
        if restored < blame:
            blame, path, value = restored, where, given
    problem = (
        f"one run of this engine needs about {gib(need)} of memory by estimate, more than this machine's {gib(limit)}"
    )
    raise RequestError(".".join(path), value, problem)


def check_engine_fits(engine: Engine, limit: int | None = None) -> Engine:
    """`engine`, once one run of it fits this machine's memory (`check_fits`); a refusal that no
    single setting is to blame for names the engine: "engine 'paper': one run of this engine
    needs ...".

    Raises:
        RequestError: naming the setting (its path) and its value; ValueError: naming the engine.
    """
    try:
        check_fits(engine.config, engine.changes(), PRESETS[engine.preset], limit)
    except RequestError as error:
        if error.argument:
            raise
        raise ValueError(f"engine {engine.preset!r}: {error.problem}") from None
    return engine
