"""The work of `nerfaug study` (`nerfaug.cli.study`): the study's runs (`nerfaug.experiment.study`),
then its per-run table and its page (`nerfaug.report.study_table`, `nerfaug.report.study_page`),
joined here because the experiments run and record while the report reads what they recorded, and
neither imports the other. The methods' labels and definitions come from the method registry
(`nerfaug.selection`) and are recorded in the table, which the page is generated from. It loads
torch, so `nerfaug.cli.study` imports it only when the command runs.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from nerfaug import runfiles
from nerfaug.cli.option_names import engine_with
from nerfaug.cli.run_size import per_cell, size_line
from nerfaug.cli.run_work import runs_to_do
from nerfaug.device import device_kind
from nerfaug.experiment import study as study_runs
from nerfaug.experiment.layout import StudyFolder
from nerfaug.experiment.study import cell_names, default_engines, table_keys
from nerfaug.experiment.study_spec import StudySpec
from nerfaug.experiment.sweep import default_workers
from nerfaug.report import study_page, study_table
from nerfaug.report.collect import ReportError
from nerfaug.report.rounds_verdicts import OneShotArm
from nerfaug.report.study import collect_study
from nerfaug.report.study_hypotheses import plan_kind
from nerfaug.selection import METHODS
from nerfaug.selection.config import SelectionConfig


def study(
    spec: StudySpec,
    selection: SelectionConfig,
    workers: int | None,
    force: bool,
    summary_only: bool,
    results_doc: Path | None,
    budget_s: float | None,
    engine_settings: dict | None = None,
    hypotheses: str = "auto",
    one_shot_table: Path | None = None,
) -> None:
    """`nerfaug study`: the runs of `spec` with `selection` (none with `summary_only`), then the
    table and the page (and `results_doc`); `engine_settings` (flat name -> value) change every
    engine the study runs; `hypotheses` names the plan whose hypotheses the pages judge;
    `one_shot_table` the study of rounds' one-shot arm (Q2), read and checked before any run."""
    if spec.engines:  # each cell by its one name, checked before anything runs
        spec = replace(spec, engines=tuple(cell_names(spec.engines)))
    if engine_settings:
        spec = with_engine_settings(spec, engine_settings)
    arm = None
    if one_shot_table is not None:
        if hypotheses not in ("auto", "rounds") or (hypotheses == "auto" and not summary_only and spec.rounds == 1):
            given = f"--hypotheses {hypotheses}" if hypotheses != "auto" else "a study of one round (--rounds 1)"
            raise SystemExit(
                f"--one-shot-table {one_shot_table}: read for the study of rounds' Q2 only, not with {given}"
            )
        arm = one_shot_arm(one_shot_table)
    out = Path(spec.out)
    # The table's default place is in OUT, held to it (a link planted there is refused); --table
    # names a file of the user's choosing, anywhere.
    table_path = Path(spec.table) if spec.table is not None else runfiles.checked(out, StudyFolder(out).table.name)
    previous = read_study_table(table_path, "--table " if spec.table is not None else "")
    failed = {} if summary_only else run(spec, selection, previous, workers, force, budget_s, table_path)
    recorded = record_table(out, table_path, previous)
    print(f"study table: {table_path} ({len(recorded['runs'])} runs)")
    if arm is not None:
        check_rounds_table(recorded, table_path, hypotheses, arm)
    paths = study_page.write_study(out, recorded, hypotheses, arm)
    print("study summary: " + ", ".join(str(p) for p in paths))
    if results_doc is not None:
        print(f"results: {study_page.write_results_doc(recorded, table_path, results_doc, hypotheses, arm)}")
    if failed:
        print(f"{len(failed)} run(s) failed; re-run the same command to retry them:", file=sys.stderr)
        for key, why in failed.items():
            print(f"  {key}: {why}", file=sys.stderr)
        raise SystemExit(1)


def read_study_table(path: Path, option: str = "") -> dict | None:
    """The study's table at `path` (None where there is none yet), checked (`study_table.read_table`).

    Raises:
        SystemExit: a table that cannot be read (not JSON, not a study table, a row missing a
            field): one line naming `option` (how the user gave it, "" for OUT's own), the file
            and the field, before anything is run or written.
    """
    if not path.exists():
        return None
    try:
        return study_table.read_table(path)
    except ReportError as error:
        raise SystemExit(f"{option}{error}") from None


def one_shot_arm(path: Path) -> OneShotArm:
    """The table at `path` as the study of rounds' one-shot arm: read with the checks every table
    has (`study_table.read_table`), holding runs of one round only, and with the fingerprints its
    runs would have now, re-derived from the settings its plan records
    (`experiment.study.rederived_fingerprints`): a run whose recorded fingerprint differs counts
    for nothing.

    Raises:
        SystemExit: one line naming the file and the field refused.
    """
    try:
        table = study_table.read_table(path)
    except ReportError as error:
        raise SystemExit(f"--one-shot-table {error}") from None
    for index, run in enumerate(table["runs"]):
        if run.get("curve"):
            raise SystemExit(
                f"--one-shot-table {path}: runs[{index}].curve: a run in rounds (it has a learning curve); this "
                "table must hold the one-shot arm's runs of one round"
            )
    rows = study_table.table_rows(table)
    try:
        now = study_runs.rederived_fingerprints(table["plan"], {_version_key(r) for r in rows})
    except ValueError as error:  # RequestError: a setting of its plan this nerfaug refuses
        raise SystemExit(f"--one-shot-table {path}: {error}") from None
    current = frozenset(r.fingerprint for r in rows if now[_version_key(r)] == r.fingerprint)
    return OneShotArm(table, current, str(path))


def _version_key(row: study_table.RunRow) -> tuple[str, str | None, str]:
    """(engine, engine version or None for the reference engine, method): what sets a run's fingerprint."""
    return (row.engine, row.engine_version or None, row.method)


def check_rounds_table(table: dict, path: Path, hypotheses: str, arm: OneShotArm) -> None:
    """Refuse (one line) a one-shot arm given for a table that is not the study of rounds'."""
    study = collect_study(table)
    kind = plan_kind(study, hypotheses)
    if kind != "rounds":
        raise SystemExit(
            f"--one-shot-table {arm.source}: read for the study of rounds' Q2 only; the table {path} is judged "
            f"by the {kind} plan (plan.config.rounds: {study.plan.get('config', {}).get('rounds', 1)})"
        )


def with_engine_settings(spec: StudySpec, settings: dict) -> StudySpec:
    """`spec` whose engines (--engines, or the default ones for its device) each have `settings`
    changed, checked once here; a study names each engine's cell and folder by the settings'
    nested names (`Engine.cell_name`: "nerfacto-cpu+optimiser.lr=0.005")."""
    engines = spec.engines or default_engines(device_kind(spec.device))[0]
    return replace(spec, engines=tuple(engine_with(engine, settings).cell_name() for engine in engines))


def method_records() -> dict[str, dict]:
    """name -> its label, description and definition, for every method of the registry (what the
    study's table records of the methods it ran)."""
    return {
        name: {"label": spec.label, "description": spec.description, "definition": spec.definition()}
        for name, spec in METHODS.items()
    }


def run(
    spec: StudySpec,
    selection: SelectionConfig,
    previous: dict | None,
    workers: int | None,
    force: bool,
    budget_s: float | None,
    table_path: Path | None = None,
) -> dict[str, str]:
    """Plan the study and run its sweeps (runs `previous`, the table, records are not run
    again); the runs that failed, "engine: run" -> why. Refused in one line before any run
    (SystemExit) where a scene's runs would start from or be scored on other views than the
    table at `table_path` records for it."""
    plan = study_runs.make_plan(spec, spec.command() + selection.flags())
    plan.config = plan.config.replace(selection=selection)
    if previous is not None:
        check_scenes_before_running(plan, previous, table_path)
    for engine, why in plan.left_out.items():
        print(f"study: engine {engine} left out: {why}", file=sys.stderr)
    workers = workers if workers is not None else default_workers(plan.config)
    print(study_size_line(plan, workers, previous), flush=True)
    outcomes = study_runs.run_study(plan, workers=workers, force=force, table=previous, budget_s=budget_s)
    return {f"{engine}: {key}": why for engine, o in outcomes.items() for key, why in o["failed"].items()}


def check_scenes_before_running(plan, previous: dict, table_path: Path | None) -> None:
    """Refuse a study whose scenes' datasets, as they are on disk now, would give runs other initial
    views (per layout), another initial half or other test views than the table records for the
    scene: runs of two versions of a dataset, which its table cannot hold (`record_table` refuses
    them after running too, for a dataset that changes while the study runs). Every dataset is
    on disk by now (`make_plan` prepares them); one that does not load is left to its runs to
    refuse. Reads cameras and names only, no image.

    Raises:
        SystemExit: one line naming the scene, the table and its field.
    """
    from nerfaug.experiment.protocol import load_scene_data

    config = plan.config
    expected = {}
    for name in plan.scenes:
        if name not in previous.get("scenes", {}):
            continue
        folder = Path(plan.datasets[name])  # prepared by `make_plan`: a user's folder, or a rendered built-in
        layouts, halves, test = {}, {}, None
        try:
            for layout in range(config.layouts):
                data = load_scene_data(folder, config, layout=layout, lazy=True)
                layouts[str(layout)] = study_table.rounded_poses(data.initial.cameras.camera_to_world)
                if "half" in data.record:
                    halves[str(layout)] = data.record["half"]
                test = data.names()["test"]
        except (OSError, ValueError):  # refused, in its own words, when its runs load it
            continue
        expected[name] = study_table.scene_record(
            {"layouts": layouts, "test_views": test} | ({"halves": halves} if halves else {})
        )
    try:
        study_table.check_against_table(expected, previous, table_path or Path("the table"))
    except study_table.RunsDisagree as error:
        raise SystemExit(
            f"{error}, before any run: runs from other views (another version of the dataset, or other --layouts, "
            "--n-initial or --n-test) belong to a study of their own (another --out, another --table)"
        ) from None


def study_size_line(plan, workers: int, table: dict | None = None) -> str:
    """How many runs the study makes, how big, and about how long on this device (`nerfaug.cli.run_size`);
    runs already finished are those of this plan in OUT or in `table` (the study's table)."""
    config = plan.config
    study = StudyFolder(Path(plan.out))
    runs: dict[tuple[str, str], int] = {}
    finished = 0
    for engine in plan.engines:
        root = study.engine(engine).root
        to_do, done = runs_to_do(plan.engine_config(engine), root, table_keys(table, engine), plan.checked)
        runs |= to_do
        finished += done
    shape = " x ".join(
        (
            per_cell(len(plan.engines), "engine"),
            per_cell(len(plan.scenes), "scene"),
            per_cell(len(config.methods), "method"),
            per_cell(config.trials, "trial"),
        )
    )
    return size_line("nerfaug study", runs, finished, shape, config, workers)


def record_table(out: Path, table_path: Path, previous: dict | None) -> dict:
    """The study's table: `previous` (the table at `table_path`, if any) updated with every valid
    run under OUT, written back; `previous` itself when OUT holds no study.

    Raises:
        SystemExit: neither OUT/study.json nor the table exists; or a run folder disagrees with
            the other runs of its scene, or the runs of a scene with what the previous table records
            for it (other initial or test views: the table holds one set per scene), refused before
            the table is written.
    """
    path = StudyFolder(Path(out)).record
    if not path.is_file():
        if previous is None:
            raise SystemExit(
                f"study: nothing to summarise: neither {path} nor the table {table_path} exists; run a "
                "study first, or pass --table FILE"
            )
        return previous
    record = study_runs.with_design(json.loads(runfiles.read_text(out, path.name)), Path(out))
    if previous is not None:
        record = study_runs.merge_records(previous["plan"], record)
    try:
        rows, scenes = study_table.rows_from_folders(Path(out), record["engines"])
        study_table.check_against_table(scenes, previous, table_path)
    except ReportError as error:
        # Runs of two versions of a dataset in one OUT (or a damaged sweep record): input this
        # table cannot hold, not a failure of the work (the runs are complete), so the one-line
        # refusal of bad input (exit 2), before anything is written.
        advice = (
            ": runs made from another version of the dataset belong to a study of their own (another --out, "
            "another --table)"
            if isinstance(error, study_table.RunsDisagree)
            else ""
        )
        raise SystemExit(f"{error}; the table {table_path} was not written, and the runs are kept{advice}") from None
    for scene, folder in record.get("datasets", {}).items():
        if scene in scenes and (source := study_runs.prepared_source(Path(folder))) is not None:
            scenes[scene]["source"] = source
    recorded = study_table.make_table(record, rows, scenes, previous, method_records())
    study_table.write_table(table_path, recorded)
    return recorded
