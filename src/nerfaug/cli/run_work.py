"""The work of the experiment's commands (`nerfaug.cli.run`): the sweep of `nerfaug run` and its
report, `nerfaug report`, `nerfaug methods`, and the paper's tables for the report. It loads torch
(the sweep, the device) and matplotlib (the report's figures), so `nerfaug.cli.run` imports it only
when a command runs.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from nerfaug.cli.run_size import RunKind, per_cell, scene_sizes, size_line
from nerfaug.device import resolve_device
from nerfaug.errors import Interrupted
from nerfaug.experiment import sweep
from nerfaug.experiment.config import PROTOCOL_PRESETS, ExperimentConfig
from nerfaug.experiment.store import finished_runs
from nerfaug.report import PaperTables, ReportError, write_report
from nerfaug.scenes.builtin import BUILTIN_SCENES
from nerfaug.selection import METHODS, TABLE_I_ROWS, TABLE_II_ROWS, get_method


def run(
    protocol: ExperimentConfig,
    out: Path,
    data: Path | None,
    backend: str,
    workers: int | None,
    address: str | None,
    force: bool,
    report: bool,
) -> None:
    """`nerfaug run`: the sweep of `protocol` (`--data` as its one scene) into `out`, then its report."""
    config = run_config(protocol, data)
    workers = workers if workers is not None else sweep.default_workers(config)
    checked = sweep.check_config(config)  # a refusal comes before the plan it would contradict
    print(run_size_line(config, out, workers, checked), flush=True)
    try:
        outcome = sweep.run_sweep(
            config,
            out,
            backend=backend,
            workers=workers,
            address=address,
            force=force,
            command=["nerfaug", *sys.argv[1:]],
            checked=checked,
        )
    except KeyboardInterrupt as stop:
        raise Interrupted(
            f"{out}: {Interrupted.why(stop)}; its {len(finished_runs(out))} finished run(s) are kept; "
            "re-run the same command to resume",
            stop,
        ) from None
    if report:
        paths = write_report(out, paper_tables())
        print("report: " + ", ".join(str(p) for p in paths))
    if outcome.failed:
        print(f"{len(outcome.failed)} run(s) failed; re-run the same command to retry them:", file=sys.stderr)
        for key, why in outcome.failed.items():
            print(f"  {key}: {why}", file=sys.stderr)
        raise SystemExit(1)


def run_config(protocol: ExperimentConfig, data: Path | None) -> ExperimentConfig:
    """The protocol the runs use: `data` (`--data`) as the one scene, and the device decided here,
    once, so every run (and the fingerprint) sees the same one."""
    config = protocol
    if data is not None:  # a path, never taken for a built-in scene of the same name
        config = config.replace(scenes=(str(data) if data.is_absolute() else os.path.join(".", data),))
    try:
        return config.replace(device=resolve_device(config.device).type)
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None


def run_size_line(config: ExperimentConfig, out: Path, workers: int, checked: dict | None = None) -> str:
    """How many runs `config` makes, how big, and about how long on this device (`nerfaug.cli.run_size`);
    `checked`: what `sweep.check_config` found of its scenes (a dataset's pool, test views, size)."""
    runs, finished = runs_to_do(config, Path(out), checked=checked)
    shape = " x ".join(
        (
            per_cell(len(config.scenes), "scene"),
            per_cell(len(config.methods), "method"),
            per_cell(config.trials, "trial"),
        )
    )
    builtin = sum(scene in BUILTIN_SCENES for scene in config.scenes)
    views = config.pool + config.n_test + config.n_initial
    return size_line("nerfaug run", runs, finished, shape, config, workers, render=(builtin, views))


def runs_to_do(
    config: ExperimentConfig, root: Path, recorded=None, checked: dict | None = None
) -> tuple[dict[RunKind, int], int]:
    """The runs of `config` a resume into `root` would make, as `nerfaug.cli.run_size` costs them
    (their `RunKind`: engine, the method's scoring estimator, this machine's engine version, the
    scene's size where `checked`, `sweep.check_config`'s record, knows it -> runs), and how many it
    skips as finished (in `root`, or `recorded` elsewhere: `sweep.finished_in_plan`)."""
    sizes = scene_sizes(checked or {})
    version = config.engine_version()
    runs: dict[RunKind, int] = {}
    finished = 0
    for scene in config.scenes:
        one, size = config.replace(scenes=(scene,)), sizes.get(sweep.scene_name(scene))
        for method in config.methods:
            done = sweep.finished_in_plan(one.replace(methods=(method,)), root, recorded)
            kind = RunKind(str(config.engine), get_method(method).estimator, version, size)
            runs[kind] = runs.get(kind, 0) + config.trials - done
            finished += done
    return runs, finished


def paper_tables() -> PaperTables:
    """The rows of the paper's ablation tables as the method registry defines them, and its
    protocol's image side (the paper preset's): what a report compares with the paper."""
    return PaperTables(TABLE_I_ROWS, TABLE_II_ROWS, PROTOCOL_PRESETS["paper"].resolution)


def report(results: Path) -> None:
    """`nerfaug report`: report.md and report.html of the results folder `results`."""
    try:
        paths = write_report(results, paper_tables())
    except ReportError as error:
        raise SystemExit(str(error)) from None
    for path in paths:
        print(path)


def methods() -> None:
    """`nerfaug methods`: every view-selection method, what it does and the settings it fixes."""
    width = max(len(name) for name in METHODS)
    for name, spec in METHODS.items():
        settings = ", ".join(f"{k}={v}" for k, v in spec.settings.items())
        print(f"{name:<{width}}  {spec.description}" + (f" [settings: {settings}]" if settings else ""))
