"""`NerfConfig`: every setting of the engine, nested by component, with the presets.

A `NerfConfig` composes one config per part of the engine, as nerfstudio's model configs compose
their field, sampler and renderer configs:

    NerfConfig
      scene       SceneConfig       the box the scene lives in and the ray's near/far
      field       FieldConfig       the radiance field: its encoding, MLPs
        encoding    HashGridConfig | PlanesConfig       (by name: "hash", field.hash.*; "kplanes", field.planes.*)
      sampler     SamplerConfig     where along a ray the field is evaluated
        kind        OccupancyConfig | ProposalConfig    (by name: "occupancy", sampler.occupancy.*; "proposal", ...)
      optimiser   OptimiserConfig   rays per step, learning rates, Adam
      renderer    RendererConfig    what rays that pass through the scene see

A component chosen among alternatives is an object of the chosen type, holding its own settings and
no other's (`nerf.names`); readers dispatch on its type. By name, the choice and its settings are
what they were: `field.encoding` "hash" and `field.hash.levels`.

Every setting also has one flat name, the one results are fingerprinted by and a variant's name
uses (`hash_levels` is `field.hash.levels`; the table is `FLAT_NAMES`): fingerprints and session
files written before the nesting hold these names, and still read.

Units: distances in world units (NeRF-synthetic: cameras about 4 units from the origin, the
object inside a box of half-size 1.5), learning rates per Adam step.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, ClassVar, Literal

from nerfaug.nerf import names
from nerfaug.nerf.bounds import Count, Counts, Fraction, Log2Size, NonNegative, Positive, Share, SHLevels, Steps
from nerfaug.registry import Presets, lookup, unknown
from nerfaug.schema import RequestError, validated

# What rays that pass through the scene see (`RendererConfig.background_mode`); the last two need
# no background colour from the caller.
BACKGROUND_MODES = ("fixed", "last_sample", "last_composited")


# Each setting's bounds are its type (`nerfaug.nerf.bounds`), checked by pydantic wherever settings
# change; every float is finite.


def _flat(name: str) -> dict:
    """Field metadata: this setting's flat name, where it is not the group's prefix + its name."""
    return {"flat": name}


@dataclass(frozen=True)
class SceneConfig:
    """The scene's bounds."""

    near: NonNegative = 2.0
    """samples lie in [near, far] along each ray (Blender: 2 and 6)."""
    far: Positive = 6.0
    """the far end of every ray."""
    box_half_size: Positive = 1.5
    """the scene is the axis-aligned box [-h, h]^3; density is 0 outside."""

    def __post_init__(self) -> None:
        if not 0 <= self.near < self.far:
            raise ValueError(f"need 0 <= near < far, got near={self.near}, far={self.far}")


@dataclass(frozen=True)
class HashGridConfig:
    """A multiresolution hash grid (nerfacto's encoding): the field's encoding "hash"."""

    NAME: ClassVar[str] = "hash"  # `FieldConfig.encoding` by name
    GROUP: ClassVar[str] = "hash"  # its settings' group by name: field.hash.levels
    FLAT_PREFIX: ClassVar[str] = "hash_"
    levels: Count = 16
    """grid levels."""
    features_per_level: Count = 2
    """features per level."""
    log2_table_size: Log2Size = 19
    """log2 of the hash table's entries per level."""
    base_resolution: Count = 16
    """the coarsest grid resolution."""
    max_resolution: Count = 2048
    """the finest grid resolution."""


@dataclass(frozen=True)
class PlanesConfig:
    """A factorised multi-scale tri-plane grid (K-planes; much faster on a CPU): the field's
    encoding "kplanes"."""

    NAME: ClassVar[str] = "kplanes"
    GROUP: ClassVar[str] = "planes"
    FLAT_PREFIX: ClassVar[str] = "plane_"
    resolutions: Counts = (64, 256)
    """one tri-plane per resolution."""
    features: Count = 8
    """channels of each plane."""


@dataclass(frozen=True)
class FieldConfig:
    """The radiance field: a position encoding, a density MLP and a colour MLP."""

    encoding: HashGridConfig | PlanesConfig = PlanesConfig()
    """the position encoding: "hash" (a multiresolution hash grid, as nerfacto; its settings
    field.hash.*) or "kplanes" (field.planes.*)."""
    hidden_dim: Count = 64
    """density MLP width."""
    geo_feat_dim: Count = 15
    """size of the feature the density MLP passes on to the colour MLP."""
    color_hidden_dim: Count = 64
    """colour MLP width."""
    color_layers: Count = 2
    """colour MLP hidden layers."""
    sh_levels: SHLevels = 4
    """spherical-harmonics levels of the direction encoding (4 -> 16 terms)."""
    density_activation: Literal["trunc_exp", "softplus"] = "trunc_exp"
    """"trunc_exp" (nerfacto) or "softplus"."""
    average_init_density: Positive = 0.01
    """the density of a freshly initialised field, on average."""


@dataclass(frozen=True)
class OccupancyConfig:
    """An occupancy grid whose empty cells the stratified samples skip: the sampler "occupancy"."""

    NAME: ClassVar[str] = "occupancy"  # `SamplerConfig.kind` by name
    GROUP: ClassVar[str] = "occupancy"  # its settings' group by name: sampler.occupancy.resolution
    FLAT_PREFIX: ClassVar[str] = "occupancy_"
    resolution: Count = 64
    """grid cells per axis."""
    update_every: Count = 16
    """training steps between updates of the grid."""
    warmup_steps: Steps = 256
    """steps during which every cell counts as occupied."""
    ema_decay: Fraction = 0.95
    """EMA decay of the cells' opacities."""
    threshold: NonNegative = 0.01
    """opacity below which a cell is empty."""
    update_fraction: Share = 0.25
    """fraction of all cells probed at random per update (besides the occupied ones)."""


@dataclass(frozen=True)
class ProposalConfig:
    """nerfacto's proposal density networks, and the losses that train them: the sampler "proposal".

    The update schedule: the proposal networks get gradients (from the interlevel loss) only on
    update steps; on the others they run without a graph. Steps 0-9 all update; after that a step
    updates once more than `clip(update_every * step / warmup_steps, 1, update_every)` steps have
    passed since the last update (so every 2nd step early on, every 6th after warm-up, as
    nerfstudio's ProposalNetworkSampler). `update_every = 0` updates every step.
    """

    NAME: ClassVar[str] = "proposal"
    GROUP: ClassVar[str] = "proposal"
    FLAT_PREFIX: ClassVar[str] = "proposal_"
    samples: Counts = (256, 96)
    """samples per proposal level (one entry per proposal network)."""
    hash_levels: Count = 5
    """hash levels of each proposal network."""
    max_resolutions: Counts = (128, 256)
    """finest hash resolution of each proposal network."""
    log2_table_size: Log2Size = 17
    """log2 of the proposal networks' hash table size."""
    hidden_dim: Count = 16
    """proposal MLP width."""
    anneal_steps: Count = 1000
    """steps over which the proposal weights' annealing runs."""
    anneal_slope: Positive = 10.0
    """slope of the annealing."""
    interlevel_loss_mult: NonNegative = field(default=1.0, metadata=_flat("interlevel_loss_mult"))
    """weight of the interlevel loss."""
    distortion_loss_mult: NonNegative = field(default=0.002, metadata=_flat("distortion_loss_mult"))
    """weight of the distortion loss."""
    update_every: Steps = 0
    """nerfacto's proposal-update schedule: at most this many steps between updates (0: every step)."""
    warmup_steps: Count = 5000
    """steps over which the update interval grows to `update_every`."""

    def __post_init__(self) -> None:
        if len(self.samples) != len(self.max_resolutions):
            raise ValueError(
                f"proposal_samples {self.samples} and proposal_max_resolutions "
                f"{self.max_resolutions} must have one entry per proposal network"
            )


@dataclass(frozen=True)
class SamplerConfig:
    """Where along a ray the field is evaluated."""

    # By name the sampler's part's settings follow `transmittance_eps` ("parts_last"), as they did
    # when every engine held both parts' settings: variant names list their changes in this order.
    kind: OccupancyConfig | ProposalConfig = field(
        default=OccupancyConfig(), metadata=_flat("sampler") | {"parts_last": True}
    )
    """"occupancy" (stratified samples, empty cells of an occupancy grid skipped; its settings
    sampler.occupancy.*) or "proposal" (nerfacto's proposal networks, sampler.proposal.*)."""
    num_samples: Count = 48
    """colour samples per ray."""
    transmittance_eps: Fraction = 1e-4
    """colour is not evaluated where the transmittance is below this."""


@dataclass(frozen=True)
class OptimiserConfig:
    """What each step trains on, and Adam's settings."""

    batch_size: Count = 4096
    """rays per step, drawn uniformly from all pixels of all training views."""
    field_lr: Positive = 1e-2
    """initial learning rate of the NeRF field (paper: 0.002 for chair/materials)."""
    lr: Positive = 1e-2
    """initial learning rate of every other parameter group (the proposal networks)."""
    lr_final: Positive = 1e-4
    """each group decays exponentially to this at step `lr_decay_steps`."""
    lr_decay_steps: Count = 200_000
    """the step at which the learning rates reach `lr_final`."""
    adam_eps: Positive = 1e-15
    """Adam's epsilon."""


@dataclass(frozen=True)
class RendererConfig:
    """What a ray that passes through the scene sees, and how renders are chunked."""

    background_mode: Literal["fixed", "last_sample", "last_composited"] = "fixed"
    """"fixed" (the trainer's background colour), "last_sample" (the field's colour at the ray's
    exit from the box, nerfacto's default) or "last_composited" (the colour of the ray's last
    composited sample, nerfacto's definition to the letter). "last_sample" lets a faint young
    field explain white pixels without pushing its colours to black, but with few views it also
    explains them view by view: measured on a 100x100 lego-like scene with 12 views, a reduced
    paper preset after 400 steps had PSNR 26.4 dB on the training views and 13.8 dB on test views
    with "last_sample", 20.7 / 19.8 dB with "fixed"."""
    random_background: bool = False
    """composite training pixels that have an alpha channel over a random colour each step
    (nerfacto's trick against floaters on transparent data)."""
    render_chunk: Count = 16384
    """rays per chunk when rendering without gradients."""

    def __post_init__(self) -> None:
        if self.background_mode not in BACKGROUND_MODES:
            choices = ", ".join(BACKGROUND_MODES)
            raise ValueError(f"background_mode must be one of {choices}, got {self.background_mode!r}")


@dataclass(frozen=True)
class NerfConfig:
    """Every setting of one NeRF (a nerfacto-style field trained with Adam), by component.

    `NerfConfig.preset(name)` gives a named engine; `flat()` and `with_settings(...)` read and
    change settings by their flat names (`FLAT_NAMES`).
    """

    scene: SceneConfig = SceneConfig()
    """the scene's bounds."""
    field: FieldConfig = FieldConfig()
    """the radiance field."""
    sampler: SamplerConfig = SamplerConfig()
    """the ray sampler."""
    optimiser: OptimiserConfig = OptimiserConfig()
    """rays per step and the optimiser."""
    renderer: RendererConfig = RendererConfig()
    """the background and render chunks."""

    # `field.encoding` and `sampler.kind` are parts whose types' `NAME`s are names in
    # `nerf.registry`, which imports this module: an encoding or sampler is built from there.

    @classmethod
    def preset(cls, name: str, **settings) -> NerfConfig:
        """A named engine, optionally with some settings (flat names) changed.

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
          for "darker") and never recovered. On real captures its opaque start can end empty
          (BENCHMARKS.md, "Empty NeRFs on a real capture").
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

        A variant of a preset that changes some settings is named `BASE+FLAT_NAME=VALUE[+...]`,
        e.g. "nerfacto-cpu+background_mode=last_sample" (`parse_variant`); its settings are the
        preset's with those changed, so it is fingerprinted like any preset.
        """
        base, changes = parse_variant(name)
        return lookup(PRESETS, PRESETS.kind, base).with_settings(**{**changes, **settings})

    def flat(self) -> dict[str, Any]:
        """Every setting this engine has by its flat name (`FLAT_NAMES`): its chosen parts', not
        the others' (a fingerprint fills those in: `experiment.fingerprints.engine_settings`)."""
        return {flat: names.get(self, path) for flat, path in FLAT_NAMES.items() if not names.unused(self, path)}

    def with_settings(self, **settings) -> NerfConfig:
        """A copy with the settings given by flat name changed, e.g. `with_settings(hash_levels=8)`.

        Raises:
            ValueError: an unknown name (with the closest known ones), a value a component refuses,
                or a setting of a part the engine does not use (a RequestError naming it).
        """
        for name in settings:
            if name not in FLAT_NAMES:
                raise ValueError(unknown("engine setting", name, sorted(FLAT_NAMES)))
        return self.changed({FLAT_NAMES[name]: value for name, value in settings.items()})

    def changed(self, changes: dict[tuple[str, ...], Any]) -> NerfConfig:
        """A copy with the settings at the nested names `changes` changed ({("field", "hash",
        "levels"): 8}), checked once. A changed chooser (("field", "encoding"): "hash") takes its
        part at that part's defaults, with the settings `changes` gives it.

        Raises:
            ValueError: an unknown name or part, a value out of its bounds (a RequestError naming
                it by its path), or a setting of a part the result does not use: a change the
                engine never reads would name a new engine that trains as the old one.
        """
        data = self.to_dict()
        for path, value in changes.items():
            group = data
            for step in path[:-1]:
                group = group.setdefault(step, {})
                if not isinstance(group, dict):
                    raise RequestError(".".join(path), value, f"{step} is a setting, not a group of settings")
            group[path[-1]] = value
        config = NerfConfig.from_dict(data)
        for path, value in changes.items():
            if why := names.unused(config, path):
                raise RequestError(".".join(path), value, why)
        return config

    def to_dict(self) -> dict:
        """The settings nested by name, as records hold them: a choice as its part's name and that
        part's settings ({"field": {"encoding": "hash", "hash": {...}, ...}}); tuples stay tuples."""
        return names.to_names(self)

    @classmethod
    def from_dict(cls, data: dict) -> NerfConfig:
        """The inverse of `to_dict`; also reads the flat form (`flat()`) that files written before
        the settings were nested hold, and records that hold every part's settings (those of the
        parts not chosen are skipped). Lists, e.g. from JSON, become tuples.

        Raises:
            ValueError: a setting no engine has, or a value out of its bounds.
        """
        if set(data) <= set(FLAT_NAMES) and data:
            nested: dict = {}
            for name, value in data.items():
                *groups, leaf = FLAT_NAMES[name]
                group = nested
                for step in groups:
                    group = group.setdefault(step, {})
                group[leaf] = value
            data = nested
        return _checked(names.build(cls, data, "engine"))


def _checked(node: Any, where: tuple[str, ...] = ()) -> Any:
    """`node` (a `NerfConfig` or one of its groups), once each setting has its type and bounds;
    else a RequestError (a ValueError) naming the first refused one by its name:
    "field.hidden_dim 0: must be >= 1". Each group is checked by pydantic with its own settings
    (a part's under its group's name, "field.hash")."""
    own = {f.name: getattr(node, f.name) for f in fields(node) if not is_dataclass(getattr(node, f.name))}
    validated(type(node), own, ".".join(where))  # a check only: `node` keeps its values as given
    for f in fields(node):
        value = getattr(node, f.name)
        if is_dataclass(value):
            _checked(value, (*where, value.GROUP if names.choice(type(node), f.name) else f.name))
    return node


FLAT_NAMES: dict[str, tuple[str, ...]] = names.leaves(NerfConfig)
"""Each setting's flat name -> its nested name in `NerfConfig`, e.g. "hash_levels" -> ("field",
"hash", "levels"), every part's (an engine has its chosen parts' only). The flat names are those of
fingerprints, variants and files written before nesting."""


PRESETS: Presets[NerfConfig] = Presets(
    "engine preset",
    {
        "paper": NerfConfig(
            field=FieldConfig(encoding=HashGridConfig()),
            # nerfacto's proposal-update schedule (`proposal_update_every=5`, `proposal_warmup=5000`).
            sampler=SamplerConfig(kind=ProposalConfig(update_every=5, warmup_steps=5000)),
            optimiser=OptimiserConfig(batch_size=4096),
            renderer=RendererConfig(background_mode="fixed"),
        ),
        "cpu": NerfConfig(
            field=FieldConfig(
                encoding=PlanesConfig(resolutions=(64, 128), features=8),
                color_layers=1,
                average_init_density=1.0,
            ),
            sampler=SamplerConfig(kind=OccupancyConfig(warmup_steps=64), num_samples=64),
            optimiser=OptimiserConfig(batch_size=1024, lr_final=1e-3, lr_decay_steps=5000),
        ),
        "nerfacto-cpu": NerfConfig(
            field=FieldConfig(
                encoding=HashGridConfig(levels=6, log2_table_size=14, max_resolution=256),
                hidden_dim=32,
                color_hidden_dim=32,
                density_activation="trunc_exp",
                average_init_density=0.01,
            ),
            sampler=SamplerConfig(
                kind=ProposalConfig(samples=(32, 16), hash_levels=3, max_resolutions=(64, 128), log2_table_size=12),
                num_samples=16,
            ),
            optimiser=OptimiserConfig(batch_size=512),
            renderer=RendererConfig(background_mode="fixed"),
        ),
        "test": NerfConfig(
            field=FieldConfig(
                encoding=PlanesConfig(resolutions=(16, 32), features=4),
                hidden_dim=16,
                geo_feat_dim=7,
                color_hidden_dim=16,
                color_layers=1,
            ),
            sampler=SamplerConfig(
                kind=OccupancyConfig(resolution=16, update_every=4, warmup_steps=8),
                num_samples=16,
            ),
            optimiser=OptimiserConfig(batch_size=128),
            renderer=RendererConfig(render_chunk=4096),
        ),
    },
)
"""The engine presets by name (`NerfConfig.preset` describes each)."""

# A named variant is a preset with some settings changed. Each is pinned by digest like the
# presets (tests/nerf/test_presets.py); the study compares a variant with its base cell by cell.
# Changed by `replace`, not `with_settings`, whose check builds the settings' validator at import
# (a quarter of a command's `--help`); each preset is checked by reading it back
# (tests/nerf/test_config.py).
_NERFACTO = PRESETS["nerfacto-cpu"]
PRESETS["nerfacto-cpu-last-sample"] = dataclasses.replace(
    _NERFACTO, renderer=dataclasses.replace(_NERFACTO.renderer, background_mode="last_sample")
)

VARIANT_SEPARATOR = "+"


HASH_CPU_ENGINE_VERSION = "hash-cpu-1"
"""The arithmetic of a run on the CPU whose hash grids (the field's, the proposal networks') run
`nerfaug.nerf.hash_cpu`'s fused C loop: its sums in another order than the PyTorch path's, so its
runs are never mixed with the reference engine's in one cell of a study. The reference engine
(every run recorded before it; a run alone or in a batch of any size, `nerfaug.nerf.trainer`)
records no version."""


CPU_FUSED_ENGINE_VERSION = "cpu-fused-3"
"""The arithmetic of a run on the CPU with the hash loop (`HASH_CPU_ENGINE_VERSION`), the
proposal sampler's per-ray C loops (`nerfaug.nerf.sampler_cpu`: weights, resampling, interlevel
and distortion losses) and every MLP of the field and the proposal networks in one C pass with
fused multiply-adds (`nerfaug.nerf.mlp_cpu`), opt-in by NERFAUG_CPU_KERNELS=fused; its runs are
never mixed with either earlier version's. (`cpu-fused-2`, the same without the MLP loop, was
measured in benchmarks only and no study ran on it.)"""


def uses_hash_grid(config: NerfConfig) -> bool:
    """Whether engine `config` has a hash grid (its field's encoding, or proposal networks)."""
    return isinstance(config.field.encoding, HashGridConfig) or isinstance(config.sampler.kind, ProposalConfig)


def _setting(base: NerfConfig, name: str, text: str, where: str):
    """`text` as a value of the setting `name` (a flat name), typed like the base preset's value
    (a setting of a part the preset does not use: like that part's default)."""
    if name not in FLAT_NAMES:
        raise ValueError(f"{where}: {unknown('setting', name, sorted(FLAT_NAMES))}")
    current = preset_value(base, FLAT_NAMES[name])
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
        try:  # the components' own checks (e.g. background_mode's values), and what the engine reads
            preset.with_settings(**changes)
        except ValueError as error:
            raise ValueError(f"engine {name!r}: {error}") from None
    return base, changes


def preset_value(config: NerfConfig, path: tuple[str, ...]) -> Any:
    """The setting at `path` of `config`; of a part `config` does not use, that part's default:
    what every engine held there when each held every part's settings (`NerfConfig.changed` takes a
    newly chosen part at its defaults), so a variant that chooses a part and sets one of its
    settings to its default names the engine the part's choice alone names."""
    return names.part_default(NerfConfig, path) if names.unused(config, path) else names.get(config, path)


def _variant_text(value: Any) -> str:
    """A setting's value as a variant name writes it (`_setting` reads it back)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return ",".join(_variant_text(v) for v in value)
    return str(value).replace("e+", "e")  # 1e+30 as 1e30: "+" separates a variant's changes


EnginePreset = PRESETS.name_type()
"""The preset names as a type, for a CLI (tyro) to offer and check."""
