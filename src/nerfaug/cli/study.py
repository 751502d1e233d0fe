"""The `nerfaug study` command: its options (`Study`: what the study runs, `StudySpec`, and how)
and help. Its work, which loads torch (the study's runs, then its per-run table and its page), is
`nerfaug.cli.study_work`, imported when the command runs, so that `--help` answers at once.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import tyro

from nerfaug.experiment.config import STUDY_PRESETS, ExperimentConfig
from nerfaug.experiment.study_spec import DEFAULT_PRESET, StudySpec
from nerfaug.registry import Presets
from nerfaug.selection.config import SelectionConfig

Workers = Annotated[
    int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: one run per core; one on a GPU)")
]
ResultsDoc = Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: none)")]
OneShotTable = Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: none)")]
BudgetSeconds = Annotated[float | None, tyro.conf.arg(metavar="SECONDS", help_behavior_hint="(default: no limit)")]


@dataclass(frozen=True)
class Study(StudySpec):
    """The study: which selection method wins where. Runs the study family of methods x engine
    presets x scenes as one resumable sweep per engine into OUT/<engine>/, records every finished
    run in a per-run table, and writes the summary OUT/study.md from that table alone: which method
    to use per engine, per (scene, engine) every method's paired difference to uniform (same seed)
    with a bootstrap 95% CI and a Wilcoxon signed-rank test, per engine a test with one value per
    seed, PSNR/SSIM/LPIPS, and the coverage of the chosen views.

    Any setting of the engine is an option too, over the engine's own value:
    --engine.GROUP.SETTING VALUE (e.g. --engine.field.hidden-dim 32); `nerfaug engines` lists them.

    Args:
        workers: concurrent runs.
        force: discard existing runs and redo them.
        summary_only: run nothing; rewrite the summary from the table (updated from OUT's run
            folders where OUT holds a study).
        results_doc: also write this Markdown page (e.g. docs/results.md), figures beside it.
        hypotheses: whose planned hypotheses the summary judges (docs/study-plan.md): the
            procedural study's (H1-H4), the real-scene study's (R1-R4), the GPU study's (G1-G4),
            the study of rounds' (Q1-Q4), none, or auto (rounds when the runs added views in
            rounds, else chosen from the table's engines and scenes).
        one_shot_table: the one-shot arm's table, for the study of rounds' Q2: the table of a
            study of one round (uniform and ours under the paper's schedule) run apart, whose runs
            the runs in rounds are paired with; read, never written. A run of it counts only with
            the fingerprint the settings its plan records give it now.
        budget_s: start no run that would end more than this many seconds from now (by the
            longest run or batch so far); the same command goes on with the rest.
        selection: options of the selection methods (every one is part of the runs' fingerprint;
            left at the preset's, they change nothing); a method's own settings (e.g.
            ours-authors') apply over them.
        engine_settings: the --engine.GROUP.SETTING given (nested by component; read apart from
            these options), over those of every engine the study runs.
    """

    PRESETS: ClassVar[Presets[ExperimentConfig]] = STUDY_PRESETS

    workers: Workers = None
    force: bool = False
    summary_only: bool = False
    results_doc: ResultsDoc = None
    hypotheses: Literal["auto", "procedural", "real", "gpu", "rounds", "none"] = "auto"
    one_shot_table: OneShotTable = None
    budget_s: BudgetSeconds = None
    selection: SelectionConfig = field(default_factory=lambda: STUDY_PRESETS.choose(DEFAULT_PRESET).selection)
    engine_settings: tyro.conf.Suppress[dict] = field(default_factory=dict)

    @classmethod
    def from_preset(cls, name: str) -> Study:
        """The options before the command line changes them: the preset `name`'s steps and
        selection settings (the protocol's other settings are the preset's, not options)."""
        protocol = STUDY_PRESETS.choose(name)
        return cls(preset=name, steps=protocol.steps, selection=protocol.selection)

    def __call__(self) -> None:
        from nerfaug.cli import study_work  # torch: here, so that `nerfaug study --help` loads none

        study_work.study(
            self,
            self.selection,
            workers=self.workers,
            force=self.force,
            summary_only=self.summary_only,
            results_doc=self.results_doc,
            hypotheses=self.hypotheses,
            one_shot_table=self.one_shot_table,
            budget_s=self.budget_s,
            engine_settings=self.engine_settings,
        )
