"""`NerfConfig`: every hyperparameter of the field, the sampler and the optimiser, with presets.

Units: distances in world units (NeRF-synthetic: cameras about 4 units from the origin, the
object inside a box of half-size 1.5), learning rates per Adam step.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Literal

from nerfaug.registry import Presets, lookup, unknown

# What rays that pass through the scene see (`NerfConfig.background_mode`); the last two need no
# background colour from the caller.
BACKGROUND_MODES = ("fixed", "last_sample", "last_composited")


@dataclass(frozen=True)
class NerfConfig:
    """Hyperparameters of one NeRF (a nerfacto-style field trained with Adam).

    Scene bounds:
        near, far: samples lie in [near, far] along each ray (Blender: 2 and 6).
        box_half_size: the scene is the axis-aligned box [-h, h]^3; density is 0 outside.

    Field:
        encoding: a name in `nerfaug.nerf.registry.ENCODINGS`: "hash" (multiresolution hash
            grid, as nerfacto) or "kplanes" (factorised multi-scale tri-plane grid, much faster
            on a CPU).
        hash_*: levels, features per level, log2 of the table size per level, coarsest and
            finest grid resolution.
        plane_resolutions, plane_features: one tri-plane per resolution, `plane_features`
            channels each.
        hidden_dim, geo_feat_dim: density MLP width and the size of the feature it passes on
            to the colour MLP.
        color_hidden_dim, color_layers: colour MLP width and number of hidden layers.
        sh_levels: spherical-harmonics levels of the direction encoding (4 -> 16 terms).
        density_activation: "trunc_exp" (nerfacto) or "softplus".
        average_init_density: the density of a freshly initialised field, on average.

    Sampler:
        sampler: a name in `nerfaug.nerf.registry.SAMPLERS`: "occupancy" (stratified samples;
            empty cells of an occupancy grid are skipped) or "proposal" (nerfacto's proposal
            density networks).
        num_samples: colour samples per ray.
        occupancy_*: grid cells per axis, steps between updates, warm-up steps (all cells on),
            EMA decay of the cell opacities, opacity threshold below which a cell is empty,
            fraction of all cells probed at random per update (besides the occupied ones).
        transmittance_eps: colour is not evaluated where the transmittance is below this.
        proposal_*: samples per proposal level, hash levels and finest resolution of each
            proposal network, table size, MLP width, and the annealing of proposal weights.
        interlevel_loss_mult, distortion_loss_mult: loss weights (proposal sampler only).
        proposal_update_every, proposal_warmup_steps: nerfacto's proposal-update schedule. The
            proposal networks get gradients (from the interlevel loss) only on update steps;
            on the others they run without a graph. Steps 0-9 all update; after that a step
            updates once more than `clip(proposal_update_every * step / proposal_warmup_steps,
            1, proposal_update_every)` steps have passed since the last update (so every 2nd
            step early on, every 6th after warm-up, as nerfstudio's ProposalNetworkSampler).
            `proposal_update_every = 0` updates every step.

    Optimisation:
        batch_size: rays per step, drawn uniformly from all pixels of all training views.
        field_lr: initial learning rate of the NeRF field (paper: 0.002 for chair/materials).
        lr: initial learning rate of every other parameter group (the proposal networks).
        lr_final, lr_decay_steps: each group decays exponentially to `lr_final` at this step.
        adam_eps: Adam's epsilon.
        background_mode: what rays that pass through see when no background is passed:
            "fixed" (the trainer's background colour) or "last_sample" (the field's colour at
            the far end of the ray, nerfacto's default). "last_sample" lets a faint young field
            explain white pixels without pushing its colours to black, but with few views it
            also explains them view by view: measured on a 100x100 lego-like scene with 12
            views, a reduced paper preset after 400 steps had PSNR 26.4 dB on the training
            views and 13.8 dB on test views with "last_sample", 20.7 / 19.8 dB with "fixed".
            "last_composited" is nerfacto's definition to the letter: the colour of the ray's
            last composited sample (which is also composited with its own weight), where
            "last_sample" evaluates the field once more at the ray's exit from the box.
        random_background: composite training pixels that have an alpha channel over a random
            colour each step (nerfacto's trick against floaters on transparent data).
        render_chunk: rays per chunk when rendering without gradients.
    """

    near: float = 2.0
    far: float = 6.0
    box_half_size: float = 1.5

    encoding: str = "kplanes"
    hash_levels: int = 16
    hash_features_per_level: int = 2
    hash_log2_table_size: int = 19
    hash_base_resolution: int = 16
    hash_max_resolution: int = 2048
    plane_resolutions: tuple[int, ...] = (64, 256)
    plane_features: int = 8
    hidden_dim: int = 64
    geo_feat_dim: int = 15
    color_hidden_dim: int = 64
    color_layers: int = 2
    sh_levels: int = 4
    density_activation: Literal["trunc_exp", "softplus"] = "trunc_exp"
    average_init_density: float = 0.01

    sampler: str = "occupancy"
    num_samples: int = 48
    occupancy_resolution: int = 64
    occupancy_update_every: int = 16
    occupancy_warmup_steps: int = 256
    occupancy_ema_decay: float = 0.95
    occupancy_threshold: float = 0.01
    occupancy_update_fraction: float = 0.25
    transmittance_eps: float = 1e-4
    proposal_samples: tuple[int, ...] = (256, 96)
    proposal_hash_levels: int = 5
    proposal_max_resolutions: tuple[int, ...] = (128, 256)
    proposal_log2_table_size: int = 17
    proposal_hidden_dim: int = 16
    proposal_anneal_steps: int = 1000
    proposal_anneal_slope: float = 10.0
    interlevel_loss_mult: float = 1.0
    distortion_loss_mult: float = 0.002
    proposal_update_every: int = 0
    proposal_warmup_steps: int = 5000

    batch_size: int = 4096
    field_lr: float = 1e-2
    lr: float = 1e-2
    lr_final: float = 1e-4
    lr_decay_steps: int = 200_000
    adam_eps: float = 1e-15
    background_mode: Literal["fixed", "last_sample", "last_composited"] = "fixed"
    random_background: bool = False
    render_chunk: int = 16384

    def __post_init__(self) -> None:
        if not 0 <= self.near < self.far:
            raise ValueError(f"need 0 <= near < far, got near={self.near}, far={self.far}")
        if self.sampler == "proposal" and len(self.proposal_samples) != len(self.proposal_max_resolutions):
            raise ValueError(
                f"proposal_samples {self.proposal_samples} and proposal_max_resolutions "
                f"{self.proposal_max_resolutions} must have one entry per proposal network"
            )
        if self.background_mode not in BACKGROUND_MODES:
            choices = ", ".join(BACKGROUND_MODES)
            raise ValueError(f"background_mode must be one of {choices}, got {self.background_mode!r}")
        # `encoding` and `sampler` are names in `nerf.registry`, which imports this module: they
        # are checked there (`check_names`), where an engine is named and where parts are built.

    @classmethod
    def preset(cls, name: str, **overrides) -> NerfConfig:
        """A named configuration, optionally with some fields overridden.

        - "paper": nerfacto's defaults as the paper ran them (16-level hash grid, 2 features per
          level, 2^19 entries, proposal sampling 256/96/48, 4096 rays, lr 1e-2 -> 1e-4 over 200k
          steps, Adam eps 1e-15, average initial density 0.01). Meant for a GPU.
          The background is "fixed" white, not nerfacto's "last_sample": this engine has no
          scene contraction, and with nerfacto's grid and either definition of "last_sample"
          it fills 12-view scenes with view-dependent fog (measured on an H200 at 100 px,
          4 seeds: test PSNR 14.1-16.7 dB with "last_sample", 15.0-25.6 with "last_composited",
          19.6-20.2 with "fixed" in float32; BENCHMARKS.md, "GPU: the paper preset on an H200").
        - "cpu": a K-planes field with an occupancy grid, sized so that 2000 steps on 12 views of
          100x100 train in about 30-40 s on two CPU cores (measured ~15-20 ms per step). It
          starts as an opaque fog (average density 1, nerfstudio's default) and has a one-layer
          colour MLP: starting from density 0.01 with two colour layers, the colour MLP's
          sigmoid saturated at 0 within 20 steps (while the faint field asked every object pixel
          for "darker") and never recovered.
        - "nerfacto-cpu": nerfacto's structure (hash grid, two hash-grid proposal networks with
          the interlevel and distortion losses, trunc_exp density starting at 0.01, two-layer
          colour MLP, the paper preset's optimiser) shrunk for one CPU core: 6 hash levels of
          2^14 entries up to resolution 256, MLP width 32, proposal samples 32/16 (3 levels each),
          16 colour samples per ray, 512 rays per step. One 100x100 study trial (2000 steps, the
          "ours" selection, 50 test views) took 117 s of CPU time on one thread, 1.55x the cpu
          preset's, measured in one run (BENCHMARKS.md, "nerfacto-CPU preset"). Background "fixed":
          with 12 views of lego, after 2000 steps, "last_sample" fitted the training views better
          (29.5 vs 28.7 dB) and 16 held-out views of the training pool worse (22.6 vs 24.8 dB).
        - "nerfacto-cpu-last-sample": "nerfacto-cpu" with nerfacto's own "last_sample"
          background, the only change. NeRFs trained on 12 views fill the background with
          floaters there; on real scenes 94 of 400 study runs rendered empty, so the study leaves
          it out by default (`nerfaug.experiment.study.BY_NAME_ONLY_ENGINES`).
        - "test": tiny, for unit tests.

        A variant of a preset that changes some settings is named `BASE+FIELD=VALUE[+...]`, e.g.
        "nerfacto-cpu+background_mode=last_sample" (`parse_variant`); its settings are the
        preset's with those changed, so it is fingerprinted like any preset.
        """
        base, changes = parse_variant(name)
        return PRESETS.choose(base, **{**changes, **overrides})

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> NerfConfig:
        """The inverse of `to_dict` (lists, e.g. from JSON, become tuples)."""
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown NerfConfig fields: {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in data.items()})


PRESETS: Presets[NerfConfig] = Presets(
    "engine preset",
    {
        "paper": NerfConfig(
            encoding="hash",
            sampler="proposal",
            background_mode="fixed",
            batch_size=4096,
            # nerfacto's proposal-update schedule (`proposal_update_every=5`, `proposal_warmup=5000`).
            proposal_update_every=5,
            proposal_warmup_steps=5000,
        ),
        "cpu": NerfConfig(
            encoding="kplanes",
            plane_resolutions=(64, 128),
            plane_features=8,
            color_layers=1,
            average_init_density=1.0,
            sampler="occupancy",
            num_samples=64,
            occupancy_warmup_steps=64,
            batch_size=1024,
            lr_final=1e-3,
            lr_decay_steps=5000,
        ),
        "nerfacto-cpu": NerfConfig(
            encoding="hash",
            hash_levels=6,
            hash_log2_table_size=14,
            hash_max_resolution=256,
            hidden_dim=32,
            color_hidden_dim=32,
            density_activation="trunc_exp",
            average_init_density=0.01,
            sampler="proposal",
            num_samples=16,
            proposal_samples=(32, 16),
            proposal_hash_levels=3,
            proposal_max_resolutions=(64, 128),
            proposal_log2_table_size=12,
            batch_size=512,
            background_mode="fixed",
        ),
        "test": NerfConfig(
            encoding="kplanes",
            plane_resolutions=(16, 32),
            plane_features=4,
            hidden_dim=16,
            geo_feat_dim=7,
            color_hidden_dim=16,
            color_layers=1,
            sampler="occupancy",
            num_samples=16,
            occupancy_resolution=16,
            occupancy_update_every=4,
            occupancy_warmup_steps=8,
            batch_size=128,
            render_chunk=4096,
        ),
    },
)
"""The engine presets by name (`NerfConfig.preset` describes each)."""

# A named variant is a preset with some settings changed. Each is pinned by digest like the
# presets (tests/nerf/test_presets.py); the study compares a variant with its base cell by cell.
PRESETS["nerfacto-cpu-last-sample"] = replace(PRESETS["nerfacto-cpu"], background_mode="last_sample")

VARIANT_SEPARATOR = "+"


BATCH_ENGINE_VERSION = "batched-1"
"""The arithmetic of trial batches (`nerfaug.nerf.batch`), recorded with every run they train: a
run alone (`Trainer`, the reference engine) rounds otherwise, so results of the two are never
mixed in one cell of a study."""


def batch_support(config: NerfConfig) -> str | None:
    """Why engine `config` cannot train in trial batches (`nerfaug.nerf.batch`), or None when it can."""
    if config.sampler != "proposal":
        return f"trial batches need the proposal sampler; this engine uses {config.sampler!r}: run it with batch 1"
    return None


def _setting(base: NerfConfig, name: str, text: str, where: str):
    """`text` as a value of the field `name`, typed like the base preset's value."""
    known = {f.name for f in fields(NerfConfig)}
    if name not in known:
        raise ValueError(f"{where}: {unknown('setting', name, sorted(known))}")
    current = getattr(base, name)
    try:
        if isinstance(current, bool):
            if text.lower() not in ("true", "false"):
                raise ValueError("expected true or false")
            return text.lower() == "true"
        if isinstance(current, tuple):
            kind = type(current[0]) if current else float
            return tuple(kind(x) for x in text.split(",") if x)
        if isinstance(current, (int, float)):
            return type(current)(text)
        return text
    except ValueError as error:
        raise ValueError(f"{where}: {name}={text!r} is not a valid value ({error})") from None


def parse_variant(name: str) -> tuple[str, dict]:
    """The preset and the settings a variant name changes: "nerfacto-cpu+background_mode=last_sample"
    -> ("nerfacto-cpu", {"background_mode": "last_sample"}); a preset's own name -> (name, {}).

    Raises:
        ValueError: an unknown preset or setting, a value of the wrong type, or a malformed part.
    """
    base, *parts = name.split(VARIANT_SEPARATOR)
    preset = lookup(PRESETS, PRESETS.kind, base)
    changes = {}
    for part in parts:
        field_name, equals, text = part.partition("=")
        if not equals or not field_name:
            raise ValueError(f"engine {name!r}: {part!r} is not FIELD=VALUE")
        changes[field_name] = _setting(preset, field_name, text, f"engine {name!r}")
    if changes:
        replace(preset, **changes)  # NerfConfig's own checks (e.g. background_mode's values)
    return base, changes


EnginePreset = PRESETS.name_type()
"""The preset names as a type, for a CLI (tyro) to offer and check."""
