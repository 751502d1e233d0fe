"""The experiment's commands: `nerfaug run` (the paper's experiment, scenes x methods x trials,
then its report), `nerfaug report` and `nerfaug methods`.

`nerfaug run`'s options are the protocol's (`ExperimentConfig`'s fields) and start from a preset
(`PROTOCOL_PRESETS`): `nerfaug.cli` hands tyro the preset `--preset` names as the options'
default, so an option given changes the preset's value and one not given keeps it. Importing this
module reads the presets and the selection methods' registry: `nerfaug.cli` imports it only when
one of its commands runs.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import tyro

from nerfaug.cli.run_size import per_cell, size_line
from nerfaug.device import resolve_device
from nerfaug.errors import Interrupted
from nerfaug.experiment import sweep
from nerfaug.experiment.config import PROTOCOL_PRESETS, ExperimentConfig, PresetName
from nerfaug.experiment.store import finished_runs
from nerfaug.registry import Presets
from nerfaug.report import PaperTables, ReportError, write_report
from nerfaug.scenes.builtin import BUILTIN_SCENES
from nerfaug.selection import METHODS, TABLE_I_ROWS, TABLE_II_ROWS

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

    @classmethod
    def from_preset(cls, name: str) -> Run:
        """The options before the command line changes them: the preset `name`'s protocol."""
        return cls(preset=name, protocol=PROTOCOL_PRESETS.choose(name))

    def __call__(self) -> None:
        config = self.config()
        workers = self.workers if self.workers is not None else sweep.default_workers(config)
        checked = sweep.check_config(config)  # a refusal comes before the plan it would contradict
        print(run_size_line(config, self.out, workers), flush=True)
        try:
            outcome = sweep.run_sweep(
                config,
                self.out,
                backend=self.backend,
                workers=workers,
                address=self.address,
                force=self.force,
                command=["nerfaug", *sys.argv[1:]],
                checked=checked,
            )
        except KeyboardInterrupt:
            raise Interrupted(
                f"{self.out}: interrupted; its {len(finished_runs(self.out))} finished run(s) are kept; re-run the "
                "same command to resume"
            ) from None
        if self.report:
            paths = write_report(self.out, paper_tables())
            print("report: " + ", ".join(str(p) for p in paths))
        if outcome.failed:
            print(f"{len(outcome.failed)} run(s) failed; re-run the same command to retry them:", file=sys.stderr)
            for key, why in outcome.failed.items():
                print(f"  {key}: {why}", file=sys.stderr)
            raise SystemExit(1)

    def config(self) -> ExperimentConfig:
        """The protocol the runs use: `--data` as the one scene, and the device decided here, once,
        so every run (and the fingerprint) sees the same one."""
        config = self.protocol
        if self.data is not None:  # a path, never taken for a built-in scene of the same name
            data = self.data
            config = config.replace(scenes=(str(data) if data.is_absolute() else os.path.join(".", data),))
        try:
            return config.replace(device=resolve_device(config.device).type)
        except ValueError as error:
            raise SystemExit(f"--device: {error}") from None


def run_size_line(config: ExperimentConfig, out: Path, workers: int) -> str:
    """How many runs `config` makes, how big, and about how long on this device (`nerfaug.cli.run_size`)."""
    total = len(config.scenes) * len(config.methods) * config.trials
    finished = sweep.finished_in_plan(config, Path(out))
    shape = " x ".join(
        (
            per_cell(len(config.scenes), "scene"),
            per_cell(len(config.methods), "method"),
            per_cell(config.trials, "trial"),
        )
    )
    builtin = sum(scene in BUILTIN_SCENES for scene in config.scenes)
    views = config.pool + config.n_test + config.n_initial
    return size_line(
        "nerfaug run",
        {config.engine: total - finished},
        finished,
        shape,
        config.resolution,
        config.steps,
        config.n_test,
        config.device,
        workers,
        render=(builtin, views),
    )


def paper_tables() -> PaperTables:
    """The rows of the paper's ablation tables as the method registry defines them, and its
    protocol's image side (the paper preset's): what a report compares with the paper."""
    return PaperTables(TABLE_I_ROWS, TABLE_II_ROWS, PROTOCOL_PRESETS["paper"].resolution)


def report(results: tyro.conf.Positional[Path]) -> None:
    """Write report.md and a self-contained report.html for a results folder.

    Args:
        results: the folder `nerfaug run --out` wrote.
    """
    try:
        paths = write_report(results, paper_tables())
    except ReportError as error:
        raise SystemExit(str(error)) from None
    for path in paths:
        print(path)


def methods() -> None:
    """List the view-selection methods and what each does."""
    width = max(len(name) for name in METHODS)
    for name, spec in METHODS.items():
        settings = ", ".join(f"{k}={v}" for k, v in spec.settings.items())
        print(f"{name:<{width}}  {spec.description}" + (f" [settings: {settings}]" if settings else ""))
