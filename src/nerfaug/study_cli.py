"""The `nerfaug study` command: the study's runs (`nerfaug.experiment.study`), then its per-run
table and its page (`nerfaug.report.study_table`, `nerfaug.report.study_page`), joined here
because the experiments run and record while the report reads what they recorded, and neither
imports the other. The methods' labels and definitions come from the method registry
(`nerfaug.selection`) and are recorded in the table, which the page is generated from.
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Literal

import tyro

from nerfaug.cli_options import COMMAND_LINE, given_fields
from nerfaug.experiment import study as study_runs
from nerfaug.experiment.study import StudyPreset
from nerfaug.selection.config import SelectionConfig


def method_records() -> dict[str, dict]:
    """name -> its label, description and definition, for every method of the registry (what the
    study's table records of the methods it ran)."""
    from nerfaug.selection import METHODS

    return {
        name: {"label": spec.label, "description": spec.description, "definition": spec.definition()}
        for name, spec in METHODS.items()
    }


# The defaults `--selection.*` options start from (read-only use: never mutated).
DEFAULT_SELECTION = SelectionConfig()


def study(
    out: Path = Path("results/study"),
    engines: Annotated[
        tuple[str, ...] | None,
        tyro.conf.arg(
            metavar="ENGINE [ENGINE ...]",
            help_behavior_hint="(default: every preset but the test one, and the paper's only on a GPU; the reason "
            "is printed)",
        ),
    ] = None,
    scenes: Annotated[
        tuple[str, ...] | None,
        tyro.conf.arg(
            metavar="SCENE [SCENE ...]", help_behavior_hint=f"(default: {' '.join(study_runs.PROCEDURAL_SCENES)})"
        ),
    ] = None,
    methods: Annotated[
        tuple[str, ...] | None,
        tyro.conf.arg(metavar="METHOD [METHOD ...]", help_behavior_hint='(default: the registry\'s "study" family)'),
    ] = None,
    trials: Annotated[
        int | None,
        tyro.conf.arg(
            metavar="INT",
            help_behavior_hint="(default: 10, or more when Bonferroni over the comparisons with uniform needs more "
            "for p < 0.05 to be reachable)",
        ),
    ] = None,
    resolution: int = 100,
    layouts: int = 1,
    steps: Annotated[
        int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: the preset's: study: 2000; tiny: 60)")
    ] = None,
    workers: Annotated[
        int | None, tyro.conf.arg(metavar="INT", help_behavior_hint="(default: one run per core; one on a GPU)")
    ] = None,
    force: bool = False,
    device: Literal["auto", "cpu", "cuda"] = "auto",
    preset: StudyPreset = "study",
    summary_only: bool = False,
    table: Annotated[
        Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: OUT/study-table.json)")
    ] = None,
    results_doc: Annotated[Path | None, tyro.conf.arg(metavar="PATH", help_behavior_hint="(default: none)")] = None,
    selection: SelectionConfig = DEFAULT_SELECTION,
) -> None:
    """The study: which selection method wins where. Runs the study family of methods x engine
    presets x scenes as one resumable sweep per engine into OUT/<engine>/, records every finished
    run in a per-run table, and writes the summary OUT/study.md from that table alone: which method
    to use per engine, per (scene, engine) every method's paired difference to uniform (same seed)
    with a bootstrap 95% CI and a Wilcoxon signed-rank test, per engine a test with one value per
    seed, PSNR/SSIM/LPIPS, and the coverage of the chosen views.

    Args:
        out: the study folder.
        engines: engine presets, or variants written BASE+FIELD=VALUE.
        scenes: built-in scene names or dataset folders.
        methods: selection methods (`nerfaug methods`).
        trials: trials per (scene, method, engine).
        resolution: image size of the built-in scenes (and the width dataset folders are shrunk to).
        layouts: initial layouts: trial k starts from layout k mod LAYOUTS, the half the initial
            views come from turned by 1/LAYOUTS of the way round each time.
        steps: training steps per run.
        workers: concurrent runs.
        force: discard existing runs and redo them.
        device: auto (cuda when there is a GPU), cpu or cuda.
        preset: the study's protocol: study (the paper's at 100x100) or tiny (a smoke test: seconds
            per run, after the built-in scenes are rendered).
        summary_only: run nothing; rewrite the summary from the table (updated from OUT's run
            folders where OUT holds a study).
        table: the per-run table to record runs in and summarise; runs it records with their
            current fingerprint are not run again.
        results_doc: also write this Markdown page (e.g. docs/results.md), figures beside it.
        selection: options of the selection methods (every one is part of the runs' fingerprint;
            left at their defaults, they change nothing); a method's own settings (e.g.
            ours-authors') apply over them.
    """
    from nerfaug.report.study_page import write_results_doc, write_study
    from nerfaug.report.study_table import read_table

    out = Path(out)
    table_path = Path(table) if table is not None else out / study_runs.TABLE_FILE
    previous = read_table(table_path) if table_path.exists() else None
    failed = {}
    if not summary_only:
        command = study_runs.study_command(
            out, engines, scenes, methods, trials, resolution, steps, device, preset, table, layouts
        )
        command += selection.flags()
        plan = study_runs.make_plan(
            out, engines, scenes, methods, trials, resolution, steps, device, preset, command, layouts=layouts
        )
        given = given_fields(selection, "selection", COMMAND_LINE.get())
        plan.config = plan.config.replace(selection=replace(plan.config.selection, **given))
        for engine, why in plan.left_out.items():
            print(f"study: engine {engine} left out: {why}", file=sys.stderr)
        if workers is None:
            workers = (
                1 if plan.config.device == "cuda" else max(1, (os.cpu_count() or 1) // plan.config.threads_per_run)
            )
        print(study_size_line(plan, workers), flush=True)
        outcomes = study_runs.run_study(plan, workers=workers, force=force, table=previous)
        failed = {f"{engine}: {key}": why for engine, o in outcomes.items() for key, why in o["failed"].items()}
    recorded = record_table(out, table_path, previous)
    print(f"study table: {table_path} ({len(recorded['runs'])} runs)")
    paths = write_study(out, recorded)
    print("study summary: " + ", ".join(str(p) for p in paths))
    if results_doc is not None:
        print(f"results: {write_results_doc(recorded, table_path, results_doc)}")
    if failed:
        print(f"{len(failed)} run(s) failed; re-run the same command to retry them:", file=sys.stderr)
        for key, why in failed.items():
            print(f"  {key}: {why}", file=sys.stderr)
        raise SystemExit(1)


def study_size_line(plan, workers: int) -> str:
    """How many runs the study makes, how big, and about how long on this device (`nerfaug.run_size`)."""
    from nerfaug.experiment.store import finished_runs
    from nerfaug.run_size import per_cell, size_line

    config = plan.config
    each = len(plan.scenes) * len(config.methods) * config.trials
    done = {engine: min(len(finished_runs(Path(plan.out) / engine)), each) for engine in plan.engines}
    shape = " x ".join(
        (
            per_cell(len(plan.engines), "engine"),
            per_cell(len(plan.scenes), "scene"),
            per_cell(len(config.methods), "method"),
            per_cell(config.trials, "trial"),
        )
    )
    runs = {engine: each - done[engine] for engine in plan.engines}
    return size_line(
        "nerfaug study",
        runs,
        sum(done.values()),
        shape,
        config.resolution,
        config.steps,
        config.n_test,
        config.device,
        workers,
    )


def record_table(out: Path, table_path: Path, previous: dict | None) -> dict:
    """The study's table: `previous` (the table at `table_path`, if any) updated with every valid
    run under OUT, written back; `previous` itself when OUT holds no study.

    Raises:
        SystemExit: neither OUT/study.json nor the table exists.
    """
    from nerfaug.report.study_table import make_table, rows_from_folders, write_table

    path = Path(out) / study_runs.STUDY_FILE
    if not path.is_file():
        if previous is None:
            raise SystemExit(
                f"study: nothing to summarise: neither {path} nor the table {table_path} exists; run a "
                "study first, or pass --table FILE"
            )
        return previous
    record = study_runs.with_design(json.loads(path.read_text()), Path(out))
    if previous is not None:
        record = study_runs.merge_records(previous["plan"], record)
    rows, scenes = rows_from_folders(Path(out), record["engines"])
    for scene, folder in record.get("datasets", {}).items():
        if scene in scenes and (source := study_runs.prepared_source(Path(folder))) is not None:
            scenes[scene]["source"] = source
    recorded = make_table(record, rows, scenes, previous, method_records())
    write_table(table_path, recorded)
    return recorded


__all__ = ["method_records", "record_table", "study", "study_size_line"]
