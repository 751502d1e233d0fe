"""What a sweep runs: scenes x methods x trials under one protocol, with the paper's presets.

Light: `nerfaug run --help` and `nerfaug study --help` read it, so torch (`nerfaug.device`) is
imported only where the device is resolved.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import tyro
from annotated_types import MinLen
from pydantic import PlainValidator, model_validator

from nerfaug.device_choice import Device
from nerfaug.experiment.fingerprints import defaults_of, engine_name, engine_record, surviving
from nerfaug.experiment.schedule import check_schedule
from nerfaug.nerf.bounds import Count, NonNegativeInt, Positive, Seed, Steps
from nerfaug.nerf.config import (
    CPU_FUSED_ENGINE_VERSION,
    HASH_CPU_ENGINE_VERSION,
    NerfConfig,
    ProposalConfig,
    uses_hash_grid,
)
from nerfaug.nerf.engine import ENGINE_OPTION, Engine, RefusedEngine
from nerfaug.registry import Presets
from nerfaug.schema import SCHEMA, RequestError, Settings, unchecked
from nerfaug.selection.config import SelectionConfig

# Method families (Tables I and II, the main comparison, the study) live with the methods.
from nerfaug.selection.families import (  # noqa: F401 (re-exported)
    AUTHORS_VARIANTS,
    BATCH_AWARE,
    FAMILIES,
    MAIN_COMPARISON,
    STUDY_METHODS,
    TABLE_I,
    TABLE_II,
)

# The paper lowers the field's learning rate for these scenes "for model stability when adding data".
LOW_FIELD_LR_SCENES = {"chair": 0.002, "materials": 0.002}


# The fields no run's fingerprint holds: which runs a sweep makes, and what a run saves beside its
# numbers. Every other field is fingerprinted, a field added later only when it differs from its
# neutral value (`nerfaug.experiment.fingerprints`).
# `batch`: a run computes the same numbers in a batch of any size as alone (`nerfaug.nerf.trainer`).
NOT_FINGERPRINTED = frozenset(
    {"scenes", "methods", "trials", "save_renders", "view_uncertainty", "hemisphere_map", "batch"}
)
# Fingerprinted in another form: the device by its kind, the selection options and the engine by
# each of their settings.
_FINGERPRINTED_AS = frozenset({"device", "selection"})

# `fingerprinted`'s default: the engine version of this machine's runs.
_THIS_MACHINE = object()

# Names given one or more times: a sweep needs at least one scene and one method.
Names = Annotated[tuple[str, ...], MinLen(1)]


@dataclass
class ExperimentConfig(Settings):
    """The protocol of the paper's Sec. IV, made configurable.

    Per (scene, method, trial): train on the fixed initial views (the same for every trial of a
    scene), at `add_at_step` ask the method for `n_new` views among the candidates, add the
    oracle's images of them (with `rounds` > 1: again every `round_every` steps, each round chosen
    with the model trained on the views so far), train to `steps`, evaluate on the test split. Trials differ only by
    seed (initialisation, ray sampling, and the selector's randomness).

    Its fields are the options of `nerfaug run` (tyro reads each field's docstring as its help,
    one line each), which start from a preset (`PROTOCOL_PRESETS`). Each is checked when the
    config is made (`nerfaug.schema.Settings`): its bounds in its annotation, the rules between
    fields in `_rules`; a refusal is one line naming the option ("--n-initial 0: must be >= 1").
    What needs the disk or a registry that loads torch (the scenes, the methods' names, the
    engine's parts) is checked before a sweep starts (`nerfaug.experiment.sweep.check_config`).
    """

    __pydantic_config__ = SCHEMA

    scenes: Annotated[Names, tyro.conf.arg(metavar="SCENE [SCENE ...]")] = ("lego",)
    """built-in scene names (rendered with Blender) or dataset folders (Blender format, or captured
    sets: nerfstudio, LLFF, IDR/DTU)."""
    methods: Annotated[Names, tyro.conf.arg(metavar="METHOD [METHOD ...]")] = MAIN_COMPARISON
    """selection methods (see `nerfaug methods`); the first is compared with the others."""
    trials: Count = 3
    """trials per (scene, method); trial k uses seed + k."""
    seed: Seed = 0
    """base seed."""
    engine: Annotated[Engine, PlainValidator(Engine.read), ENGINE_OPTION] = Engine.of("cpu")
    """the NeRF engine preset (the names `nerfaug train --engine` takes); any of its settings is an option
    too (`nerfaug engines` lists them)."""
    resolution: Count = 100
    """image size of built-in scenes (or the width user data is downscaled to)."""
    steps: Count = 2000
    """training steps per run."""
    add_at_step: Steps = 200
    """the training step at which each method adds its views."""
    n_new: Count = 6
    """views each method adds."""
    n_initial: Count = 6
    """initial training views, all on one half of the hemisphere."""
    # The field's active-learning protocol (FisherRF's: few initial views, one added a round,
    # training between rounds) is e.g. --n-initial 4 --n-new 1 --rounds 8 (`experiment.schedule`).
    rounds: Count = 1
    """rounds of selection, each adding n_new views chosen with the model trained so far (1: the paper's protocol)."""
    round_every: Count = 100
    """training steps between two rounds (the first at add_at_step); unused with one round."""
    round_growth: Literal["fixed", "per-view"] = "fixed"
    """fixed: round_every steps between rounds; per-view: round_every steps per view in the model
    (training between rounds grows with the views, as FisherRF's schedule); unused with one round."""
    pool: Count = 300
    """candidate views of a built-in scene, uniform over the hemisphere."""
    # The paper evaluates all 200 test views. A captured set without a test split keeps n_test of
    # its views, at most a quarter, spread over all directions, apart for testing.
    n_test: Count = 50
    """test views evaluated, spread evenly over the test split (all of it when it holds no more)."""
    # One layout: a rendered scene's `initial` split as rendered. Each further layout turns the
    # half the initial views lie on by a `layouts`-th of the way round.
    layouts: Count = 1
    """initial layouts: trial k starts from layout k mod LAYOUTS, each turned 1/LAYOUTS of the way round."""
    render_samples: Count = 16
    """Cycles samples per pixel of built-in scenes."""
    field_lr: Annotated[dict[str, Positive], tyro.conf.Suppress] = field(
        default_factory=lambda: dict(LOW_FIELD_LR_SCENES)
    )
    """Field learning rate by scene name, over the engine preset's `field_lr` (the paper: 0.002 for
    chair and materials); `engine_config` applies it."""
    # One thread per run, with one run per core, measured faster and far steadier than two threads
    # per run on a 2-core machine: torch's second thread stalls whenever anything else wants a core.
    threads_per_run: Count = 1
    """torch threads in each run (fixed, so that local and Ray runs compute identically)."""
    save_renders: NonNegativeInt = 3
    """test renders saved per run (for the report's figures)."""
    # Off in the study, whose page does not show them: they cost several seconds of a run (FisherRF
    # per pixel).
    view_uncertainty: bool = True
    """save the first test view's uncertainty images (the report's figure and AUSE; no metric needs them)."""
    # Off in the GPU study, whose calls bring back only the runs' records: matplotlib's figure cost
    # about 2 s a run on the CPU (BENCHMARKS.md, "Cheaper trials"); the report draws its own maps.
    hemisphere_map: bool = True
    """draw the run's selection scores over the hemisphere (uncertainty.png in its folder)."""
    # Only the kind (cpu / cuda) is fingerprinted: the two give different numbers (other kernels and
    # reduction orders), so a results folder never mixes them.
    device: Device = "auto"
    """where runs train, select and evaluate."""

    # A batch trains K runs in lockstep in one process (`nerfaug.nerf.trainer.Trainer`), each
    # computed as it would be alone: its size changes no number, only how runs share a process.
    batch: NonNegativeInt = 0
    """runs trained together as one batch; 1: each run alone; 0: auto (1 on a CPU, as many as memory holds on a GPU)."""

    selection: SelectionConfig = field(default_factory=SelectionConfig)
    """options of the selection methods (every one fingerprinted); a method's own settings apply over them."""
    # Fingerprinted when set (set apart from the default, off): compiled kernels round differently.
    compile: Annotated[str | None, tyro.conf.arg(metavar="BACKEND", help_behavior_hint="(default: off)")] = None
    """a torch.compile backend for the engine's networks ("inductor", on a GPU); off: plain PyTorch."""

    def __post_init__(self) -> None:
        # An engine given by name, or read from an earlier record: read, and checked, once. One the
        # command line named wrongly is refused when the settings are checked, after the parser.
        if not isinstance(self.engine, RefusedEngine):
            try:
                self.engine = Engine.read(self.engine)
            except RequestError:
                raise  # it names the setting
            except ValueError as error:
                raise ValueError(f"--engine {self.engine!r}: {error}") from None
        super().__post_init__()

    def check(self) -> None:
        if isinstance(self.engine, RefusedEngine):
            raise ValueError(f"--engine {self.engine.given!r}: {self.engine.why}")
        super().check()

    def to_record(self) -> dict:
        """Every option as plain data, as config.json and sweep.json record them; the engine as
        `Engine.record` writes it (its preset's name, or its settings nested by component)."""
        return dataclasses.asdict(self) | {"engine": self.engine.record()}

    @model_validator(mode="after")
    def _rules(self) -> ExperimentConfig:
        """The rules between settings (each setting's own bounds are in its annotation)."""
        if len(set(self.methods)) != len(self.methods):
            raise ValueError(f"--methods {self.methods!r}: a method is listed twice")
        check_schedule(self)  # the steps, the rounds and the pool they draw on
        return self

    def fingerprinted(self, engine_version: str | None | object = _THIS_MACHINE) -> dict:
        """The settings that change a run's numbers; results made under others are not mixed.

        Flat, so a refusal names the setting: the protocol's settings by name (every field but
        `NOT_FINGERPRINTED`; the device by its kind; the engine's arithmetic as "engine_version"), every
        `SelectionConfig` field as "selection.<field>", and the engine preset's `NerfConfig` as
        "engine.<flat name>" ("engine" keeps the preset's name; per-scene overrides are
        "field_lr"). A setting added since fingerprint version 1 is left out at its neutral value,
        and one another setting leaves unused is taken at it (with one round, the spacing of
        rounds; `nerfaug.experiment.fingerprints`), so adding one moves no recorded fingerprint. Values
        are as JSON stores them (tuples become lists), so a setting read back from sweep.json
        compares equal to the same setting in code. `engine_version`: the arithmetic hashed, this
        machine's (`engine_version()`) unless given (a recorded run's, to re-derive its fingerprint
        on any machine: `experiment.study.rederived_fingerprints`).
        """
        from nerfaug.device import device_kind  # torch: here, so that `nerfaug run --help` loads none

        own = [f.name for f in dataclasses.fields(self) if f.name not in NOT_FINGERPRINTED | _FINGERPRINTED_AS]
        record = {name: getattr(self, name) for name in own} | {"device": device_kind(self.device)}
        record["engine"] = engine_name(self.engine)
        record["engine_version"] = self.engine_version() if engine_version is _THIS_MACHINE else engine_version
        record.update({f"selection.{k}": v for k, v in self.selection.to_dict().items()})
        defaults = defaults_of(type(self)) | {"engine_version": None}
        defaults |= {f"selection.{k}": v for k, v in defaults_of(type(self.selection)).items()}
        return surviving(record, defaults) | engine_record(self.engine)

    def engine_version(self) -> str | None:
        """The arithmetic this config's runs train with, recorded with each run and fingerprinted: on
        the CPU, where its hash grids run the fused C loop (`HASH_CPU_ENGINE_VERSION`: where a C
        compiler built it and `NERFAUG_HASH_KERNEL` is not "torch",
        `nerfaug.nerf.encoding.HashEncoding.default_kernel`), that version; else None, the reference
        engine every run before it ran. With NERFAUG_CPU_KERNELS=fused (`nerfaug.nerf.sampler_cpu`)
        an engine with proposal networks also runs their per-ray C loops: `CPU_FUSED_ENGINE_VERSION`.
        A run in a batch of any size is computed as it would be alone
        (`nerfaug.nerf.trainer.Trainer`), so the batch's size is no part of it."""
        from nerfaug.device import device_kind  # torch: here, so that `nerfaug run --help` loads none

        if device_kind(self.device) != "cpu" or not uses_hash_grid(self.engine.config):
            return None
        from nerfaug.nerf.encoding import HashEncoding  # torch, likewise

        if not HashEncoding.cpu_loop_selected():
            return None
        from nerfaug.nerf import sampler_cpu

        if sampler_cpu.selected() and isinstance(self.engine.config.sampler.kind, ProposalConfig):
            return CPU_FUSED_ENGINE_VERSION
        return HASH_CPU_ENGINE_VERSION

    def replace(self, **changes) -> ExperimentConfig:
        return dataclasses.replace(self, **changes)

    def engine_config(self, scene: str) -> NerfConfig:
        """The `NerfConfig` a run on `scene` (a built-in name or a dataset folder) trains with: the
        engine preset's, with the field learning rate `field_lr` gives the scene's name, if any.
        The one place a run's field learning rate is decided."""
        name = Path(scene).name
        if name not in self.field_lr:
            return self.engine.config
        config = self.engine.config
        optimiser = dataclasses.replace(config.optimiser, field_lr=self.field_lr[name])
        return dataclasses.replace(config, optimiser=optimiser)


# Made unchecked, so that `--help` builds no validator: each preset is checked when it is chosen
# (`Presets.choose` makes a copy), and tests/experiment/test_settings.py checks every one.
PROTOCOL_PRESETS: Presets[ExperimentConfig] = Presets(
    "preset",
    unchecked(
        lambda: {
            "quick": ExperimentConfig(trials=5, steps=800, pool=100, n_test=20),
            "paper": ExperimentConfig(
                scenes=("lego", "chair", "materials"),
                trials=10,
                engine="paper",
                resolution=800,
                steps=10_000,
                pool=500,
                n_test=200,
                render_samples=64,
            ),
            "ablation": ExperimentConfig(
                methods=tuple(dict.fromkeys(TABLE_I + TABLE_II + ("distance-nbv",) + AUTHORS_VARIANTS)),
                trials=5,
            ),
            "tiny": ExperimentConfig(
                methods=("ours", "uniform"),
                trials=2,
                engine="test",
                resolution=24,
                steps=60,
                add_at_step=20,
                n_new=2,
                n_initial=3,
                pool=12,
                n_test=3,
                render_samples=4,
                save_renders=1,
            ),
        }
    ),
)
"""The protocols of `nerfaug run --preset`:

quick: the default (`make demo`); the built-in lego at 100x100 with the CPU engine, the four
    methods of the main comparison, five trials each (the fewest with which Mann-Whitney with a
    Bonferroni factor of 3 can reach p < 0.05), 800 steps (views added at 200, as in the paper),
    100 candidates and 20 test views: about 14 minutes on an idle two-core machine, rendering
    included (BENCHMARKS.md, "The demo's time estimate against its time").
paper: lego/chair/materials at 800x800 (or the data's resolution), 10k steps, 10 trials, the
    paper's learning rates and its main comparison.
ablation: the paper's Tables I and II (terms; NBV vs sampling) on lego.
tiny: seconds-long smoke run for tests.
"""

PresetName = PROTOCOL_PRESETS.name_type()
"""The protocol presets' names as a type, for a CLI (tyro) to offer and check."""

STUDY_PRESETS: Presets[ExperimentConfig] = Presets(
    "study preset",
    unchecked(
        lambda: {
            # The paper's protocol at 100x100 (the defaults). No uncertainty images: the study's page
            # does not show them, and they cost seconds per run.
            "study": ExperimentConfig(view_uncertainty=False),
            "tiny": PROTOCOL_PRESETS.choose("tiny", view_uncertainty=False),
            # The GPU study (docs/study-plan.md, 2026-11-27): the paper engine at the paper's scale
            # (400 px, 10k steps, 200 test views); the page shows no uncertainty images.
            "gpu": ExperimentConfig(
                engine="paper",
                resolution=400,
                steps=10_000,
                n_test=200,
                render_samples=32,
                view_uncertainty=False,
                hemisphere_map=False,
            ),
        }
    ),
)
"""The protocols a study runs every engine under (`nerfaug study --preset`): "study" is the
paper's protocol at 100x100 (6 initial views, 6 added at step 200, 2000 steps, a pool of 300, 50
test views); "gpu" the same at the paper's scale for its engine (400 px, 10k steps, 200 test
views); "tiny" is the tests' smoke preset (its runs take seconds; built-in scenes are
rendered first, which takes minutes)."""

# Concurrent runs a sweep may start (`--workers`): beyond any machine's cores, and the C int a process pool takes.
MAX_WORKERS = 1024


def check_workers(workers) -> int:
    """`workers` (concurrent runs); ValueError naming --workers unless an integer in 1..`MAX_WORKERS`."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"--workers {workers!r}: must be an integer from 1 to {MAX_WORKERS}")
    return workers
