"""The experiment's commands: `nerfaug run` (the paper's experiment, scenes x methods x trials,
then its report), `nerfaug report` and `nerfaug methods`: their options and help. Their work, which
loads torch, is `nerfaug.cli.run_work`, imported when a command runs, so that `--help` answers at once.

`nerfaug run`'s options are the protocol's (`ExperimentConfig`'s fields) and start from a preset
(`PROTOCOL_PRESETS`): `nerfaug.cli` hands tyro the preset `--preset` names as the options'
default, so an option given changes the preset's value and one not given keeps it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import tyro

from nerfaug.cli.option_names import engine_with
from nerfaug.experiment.config import PROTOCOL_PRESETS, ExperimentConfig, PresetName
from nerfaug.registry import Presets

DEFAULT_PRESET = "quick"

Data = Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: the preset's scenes)")]
Workers = Annotated[
    int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: one run per core; one at a time on a GPU)")
]
Address = Annotated[str | None, tyro.conf.arg(metavar="ADDRESS", help_behavior_hint="(default: a local Ray instance)")]


@dataclass
class Run:
    """Run the paper's experiment (scenes x methods x trials), then write its report.

    Re-running the same command skips completed runs; killing it loses at most the runs in flight.
    The protocol's options start from the preset's values (`nerfaug run --preset paper --help`
    shows the paper's); those given change them.

    Any setting of the engine is an option too, over the engine's own value:
    --engine.GROUP.SETTING VALUE (e.g. --engine.field.hidden-dim 32); `nerfaug engines` lists them.

    Args:
        out: results folder.
        preset: the experiment's protocol, which the other options change: quick (lego at 100x100
            on the CPU, minutes), paper (Sec. IV: three scenes, 10 trials, 10k steps), ablation
            (Tables I and II), tiny (seconds; a smoke test).
        data: a dataset folder to run on: Blender format (its train split is the candidate pool,
            its test split the evaluation) or a captured set (nerfstudio, LLFF, IDR/DTU: split
            into test, initial and candidate views by direction); shorthand for --scenes DATA.
        backend: local (this machine) or ray (one task per run; --address joins a cluster).
        workers: concurrent runs (local backend) or Ray CPUs to start (local Ray).
        address: the Ray cluster to join.
        force: move the runs already in --out aside (into OUT/superseded/, nothing is deleted) and
            redo every run; needed when OUT's sweep.json is missing or its settings differ.
        report: write report.md / report.html at the end.
        engine_settings: the --engine.GROUP.SETTING given (nested by component; read apart from
            these options, `nerfaug.cli.engine_options`), changed over the engine's own: the runs'
            engine, recorded with them and fingerprinted.
    """

    PRESETS: ClassVar[Presets[ExperimentConfig]] = PROTOCOL_PRESETS

    out: Path = Path("results/quick")
    preset: PresetName = DEFAULT_PRESET
    data: Data = None
    protocol: Annotated[ExperimentConfig, tyro.conf.arg(name="")] = field(
        default_factory=lambda: PROTOCOL_PRESETS.choose(DEFAULT_PRESET)
    )
    backend: Literal["local", "ray"] = "local"
    workers: Workers = None
    address: Address = None
    force: bool = False
    report: bool = True
    engine_settings: tyro.conf.Suppress[dict] = field(default_factory=dict)

    @classmethod
    def from_preset(cls, name: str) -> Run:
        """The options before the command line changes them: the preset `name`'s protocol."""
        return cls(preset=name, protocol=PROTOCOL_PRESETS.choose(name))

    def __call__(self) -> None:
        from nerfaug.cli import run_work  # torch: here, so that `nerfaug run --help` loads none

        protocol = self.protocol
        if given := self.engine_settings:
            protocol = protocol.replace(engine=engine_with(protocol.engine, given))
        run_work.run(
            protocol,
            self.out,
            data=self.data,
            backend=self.backend,
            workers=self.workers,
            address=self.address,
            force=self.force,
            report=self.report,
        )


def report(results: tyro.conf.Positional[Path]) -> None:
    """Write report.md and a self-contained report.html for a results folder.

    Args:
        results: the folder `nerfaug run --out` wrote.
    """
    from nerfaug.cli import run_work  # torch, matplotlib: here, so that `--help` loads neither

    run_work.report(results)


def methods() -> None:
    """List the view-selection methods and what each does."""
    from nerfaug.cli import run_work  # torch (the methods' registry): here, so that `--help` loads none

    run_work.methods()
