"""What a study runs, as the options of `nerfaug study`: `StudySpec` (its fields, their help and the
command line that plans the study again); `nerfaug.experiment.study` plans and runs it.

Light (no torch): `nerfaug study --help` reads it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug.device_choice import Device
from nerfaug.experiment.config import STUDY_PRESETS, Names
from nerfaug.experiment.layout import StudyFolder
from nerfaug.nerf.bounds import Count, NonNegativeInt, Steps
from nerfaug.schema import SCHEMA, Settings

StudyPreset = STUDY_PRESETS.name_type()
DEFAULT_PRESET = "study"

PROCEDURAL_SCENES = ("lego", "chair", "materials")
"""The study's default scenes: the procedural stand-ins of the paper's three (the cow, a real
mesh, and real captures are given by name or folder, as the real-scene study does)."""


# How `nerfaug study --help` shows the options whose default (None) is decided when the study is planned.
Engines = Annotated[
    Names | None,
    tyro.conf.arg(
        metavar="ENGINE [ENGINE ...]",
        help_behavior_hint="(default: every preset but the test one, and the paper's only on a GPU; the reason "
        "is printed)",
    ),
]
Scenes = Annotated[
    Names | None,
    tyro.conf.arg(metavar="SCENE [SCENE ...]", help_behavior_hint=f"(default: {' '.join(PROCEDURAL_SCENES)})"),
]
Methods = Annotated[
    Names | None,
    tyro.conf.arg(metavar="METHOD [METHOD ...]", help_behavior_hint='(default: the registry\'s "study" family)'),
]
Trials = Annotated[
    Count | None,
    tyro.conf.arg(
        metavar="INT",
        help_behavior_hint="(default: 10, or more when Bonferroni over the comparisons with uniform needs more "
        "for p < 0.05 to be reachable)",
    ),
]
PresetCount = Annotated[Count | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: the preset's)")]
PresetSteps = Annotated[Steps | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: the preset's)")]
Table = Annotated[
    Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint=f"(default: {StudyFolder(Path('OUT')).table})")
]


@dataclass(frozen=True)
class StudySpec(Settings):
    """What a study runs: the options of `nerfaug study` that decide its runs (None: decided when
    it is planned, `make_plan`). Each is checked when the spec is made, by the bounds in its
    annotation (`nerfaug.schema.Settings`); the rules between them are the protocol's, checked when
    the plan makes its `ExperimentConfig`.

    Args:
        out: the study folder.
        engines: engine presets, or variants written PRESET+GROUP.SETTING=VALUE (e.g.
            nerfacto-cpu+optimiser.lr=0.005), the name the study gives the cell.
        scenes: built-in scene names or dataset folders.
        methods: selection methods (`nerfaug methods`).
        trials: trials per (scene, method, engine).
        resolution: image size of the built-in scenes (and the width dataset folders are shrunk to).
        layouts: initial layouts: trial k starts from layout k mod LAYOUTS, the half the initial
            views come from turned by 1/LAYOUTS of the way round each time.
        steps: training steps per run (the preset's unless given).
        n_initial: initial training views (the preset's unless given).
        n_new: views each round adds (the preset's unless given).
        add_at_step: the training step of the first round (the preset's unless given).
        rounds: rounds of selection, each chosen with the model trained on the views so far (1:
            the paper's protocol, one round).
        round_every: training steps between two rounds; unused with one round.
        round_growth: fixed (round_every steps between rounds) or per-view (round_every steps per
            view in the model: training between rounds grows with the views, as FisherRF's
            schedule); unused with one round.
        device: where the runs train, select and evaluate.
        preset: the study's protocol, which --steps and --selection.* change: study (the paper's
            at 100x100) or tiny (a smoke test: seconds per run, after the built-in scenes are rendered).
        table: the per-run table to record runs in and summarise; runs it records with their
            current fingerprint are not run again.
        batch: runs trained together as one batch (each computed as it would be alone); 1: each
            run alone; 0: auto (1 on a CPU, as many as memory holds on a GPU).
    """

    __pydantic_config__ = SCHEMA

    out: Path = Path("results/study")
    engines: Engines = None
    scenes: Scenes = None
    methods: Methods = None
    trials: Trials = None
    resolution: Count = 100
    layouts: Count = 1
    steps: Count = STUDY_PRESETS[DEFAULT_PRESET].steps
    n_initial: PresetCount = None
    n_new: PresetCount = None
    add_at_step: PresetSteps = None
    rounds: Count = 1
    round_every: Count = STUDY_PRESETS[DEFAULT_PRESET].round_every
    round_growth: Literal["fixed", "per-view"] = "fixed"
    device: Device = "auto"
    preset: StudyPreset = DEFAULT_PRESET
    table: Table = None
    batch: NonNegativeInt = 0

    def schedule_changes(self) -> dict[str, int]:
        """The schedule's settings given over the preset's (n_initial, n_new, add_at_step)."""
        return {k: v for k in ("n_initial", "n_new", "add_at_step") if (v := getattr(self, k)) is not None}

    def command(self) -> list[str]:
        """The command line that plans this study again (--steps only where it is not the preset's)."""
        command = ["nerfaug", "study", "--out", str(self.out)]
        if self.table is not None:
            command += ["--table", str(self.table)]
        for flag, values in (("--engines", self.engines), ("--scenes", self.scenes), ("--methods", self.methods)):
            if values:
                command += [flag, *map(str, values)]
        for flag, value in (
            ("--trials", self.trials),
            ("--resolution", self.resolution),
            ("--steps", None if self.steps == STUDY_PRESETS[self.preset].steps else self.steps),
            ("--device", self.device),
            ("--preset", self.preset),
            ("--layouts", self.layouts if self.layouts != 1 else None),
            ("--batch", self.batch if self.batch != 0 else None),
            ("--n-initial", self.n_initial),
            ("--n-new", self.n_new),
            ("--add-at-step", self.add_at_step),
            ("--rounds", self.rounds if self.rounds != 1 else None),
            ("--round-every", self.round_every if self.rounds != 1 else None),
            ("--round-growth", self.round_growth if self.rounds != 1 and self.round_growth != "fixed" else None),
        ):
            if value is not None:
                command += [flag, str(value)]
        return command
