"""The study's runs: the study family of selection methods x the engine presets x the scenes,
each as one resumable sweep per engine into `OUT/<engine>/`, and its plan recorded in study.json.
The `nerfaug study` command (`nerfaug.cli.study`) runs them, then records every finished run in the
per-run table and writes the combined summary from it (`nerfaug.report.study`). The study
folder's layout: `experiment.layout.StudyFolder`.

Re-running the same command skips completed runs (each engine's sweep resumes on its own), and
runs recorded in the table with the fingerprint they would have now (a study committed beside
its page resumes without its run folders).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
import time
import traceback
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from nerfaug import runfiles
from nerfaug.data.prepare import PREPARED
from nerfaug.device import resolve_device
from nerfaug.experiment.config import STUDY_PRESETS, ExperimentConfig, check_workers
from nerfaug.experiment.fingerprints import engine_settings
from nerfaug.experiment.layout import StudyFolder
from nerfaug.experiment.protocol import prepare_scene, render_builtin, run_trials, scene_folder
from nerfaug.experiment.runfolder import write_error
from nerfaug.experiment.store import RunKey, check_sweep, fingerprint, read_result, run_fingerprint
from nerfaug.experiment.study_spec import PROCEDURAL_SCENES, StudySpec
from nerfaug.experiment.sweep import check_config, run_sweep, scene_name, sweep_record
from nerfaug.jsonio import read_json
from nerfaug.nerf.config import PRESETS
from nerfaug.nerf.engine import Engine, is_flat_variant
from nerfaug.nerf.registry import check_names
from nerfaug.schema import RequestError, validated
from nerfaug.selection import METHODS
from nerfaug.selection.families import FAMILIES
from nerfaug.statistics import min_attainable_paired_p

DEFAULT_TRIALS = 10
"""Trials per (scene, engine, method): with 10 seed-paired trials a two-sided Wilcoxon signed-rank
test, Bonferroni over the 7 methods compared with uniform, reaches p < 0.05 when 9 of 10 pairs
agree in sign (not only under complete separation)."""
SMOKE_ENGINES = ("test",)
"""Engine presets made for the test suite: never part of a default study."""
GPU_ENGINES = ("paper",)
"""Engine presets left out of a default study on a CPU: the paper's nerfacto-sized engine is about
100x slower there than the cpu preset (BENCHMARKS.md), so one study would take weeks."""
BY_NAME_ONLY_ENGINES = {
    "nerfacto-cpu-last-sample": "rendered empty in 94 of 400 real-scene runs, so it cannot tell methods apart "
    "(docs/results-real.md); run it by name with --engines nerfacto-cpu-last-sample",
}
"""Engine presets a default study leaves out, with why: still runnable by name."""


def study_methods() -> tuple[str, ...]:
    """The study's methods: the registry's "study" family (ours, its authors' variant, the
    batch-aware variants and the baselines)."""
    return tuple(FAMILIES["study"])


def engine_presets() -> tuple[str, ...]:
    """Every engine preset that exists (`nerfaug.nerf.config.PRESETS`), in its order."""
    return tuple(PRESETS)


def default_engines(device: str) -> tuple[list[str], dict[str, str]]:
    """The engines a study runs by default on `device` ("cpu" or "cuda"), and those it leaves out
    with the reason."""
    chosen, left_out = [], {}
    for name in engine_presets():
        if name in SMOKE_ENGINES:
            left_out[name] = "a smoke-test preset for the test suite, not a NeRF to compare methods on"
        elif name in BY_NAME_ONLY_ENGINES:
            left_out[name] = BY_NAME_ONLY_ENGINES[name]
        elif name in GPU_ENGINES and device != "cuda":
            left_out[name] = (
                "needs a GPU: on a CPU it is about 100x slower than the cpu preset; run it on a GPU "
                f"with --engines {name} --device cuda"
            )
        else:
            chosen.append(name)
    return chosen, left_out


def min_trials(n_comparisons: int, alpha: float = 0.05, start: int = DEFAULT_TRIALS) -> int:
    """The smallest n >= `start` (trials per method, paired by seed) at which a two-sided Wilcoxon
    signed-rank test on the pairs, Bonferroni x `n_comparisons`, can reach p < alpha."""
    n = start
    while min_attainable_paired_p(n) * max(1, n_comparisons) >= alpha:
        n += 1
    return n


def machine() -> dict:
    """What the study ran on, for its summary."""
    return {
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "host": platform.node(),
    }


@dataclass
class StudyPlan:
    """What a study runs. `scenes` are names as results show them; `datasets` their folders."""

    out: Path
    config: ExperimentConfig
    engines: list[str]
    left_out: dict[str, str] = field(default_factory=dict)
    scenes: list[str] = field(default_factory=list)
    datasets: dict[str, str] = field(default_factory=dict)
    command: list[str] = field(default_factory=list)
    # What `check_config` found of each scene (a dataset's pool, test views, image size), by name:
    # what the time estimate reads.
    checked: dict[str, dict] = field(default_factory=dict)

    def engine_config(self, engine: str) -> ExperimentConfig:
        return self.config.replace(engine=engine, scenes=tuple(self.datasets[s] for s in self.scenes))

    def record(self) -> dict:
        return {
            "engines": self.engines,
            "engine_settings": {e: engine_settings(Engine.read(e)) for e in self.engines},
            "left_out": self.left_out,
            "scenes": self.scenes,
            "datasets": self.datasets,
            "methods": list(self.config.methods),
            "trials": self.config.trials,
            "config": self.config.to_record(),
            "command": self.command,
            "machine": machine(),
            "written": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        }


def prepare_datasets(
    out: Path, scenes: tuple[str, ...], config: ExperimentConfig, progress: bool = True
) -> dict[str, str]:
    """scene name -> dataset folder (absolute). A built-in scene is rendered once (cached by its
    manifest) into OUT/datasets/<res>px/<scene>/, a folder named by the scene so that results and
    per-scene settings (the field learning rate) know it by its name; a dataset folder is used
    as it is, named by its folder."""
    found = {}
    for scene in scenes:
        folder = scene_folder(scene)
        if folder is None:
            folder = render_builtin(scene, StudyFolder(Path(out)).dataset(config.resolution, scene), config, progress)
        name = Path(folder).name
        if name in found:
            raise ValueError(f"two scenes are named {name!r} ({found[name]} and {folder}); rename a dataset folder")
        found[name] = str(Path(folder).resolve())
    return found


def write_plan(plan: StudyPlan) -> None:
    """OUT/study.json: the plan grown by the earlier sittings'; a study.json linked out of OUT is
    refused (`PathRefused`, one line) before anything is read or written through it."""
    plan.out.mkdir(parents=True, exist_ok=True)
    name = StudyFolder(plan.out).record.name
    runfiles.write_json(plan.out, name, merged_record(runfiles.path_in(plan.out, name), plan.record()))


def merged_record(path: Path, record: dict) -> dict:
    """`record` grown by the study.json at `path`, if any (`merge_records`)."""
    try:
        previous = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return record
    return merge_records(previous, record) if isinstance(previous, dict) else record


def merge_records(previous: dict, record: dict) -> dict:
    """`record` grown by an earlier sitting's: a study may run in sittings, one engine or scene at
    a time (`--engines nerfacto-cpu --scenes lego`), and its summary covers every engine and scene
    run so far. The methods and trials are the latest command's; the commands of every sitting
    are kept."""
    merged = dict(record)
    merged["engine_settings"] = {**previous.get("engine_settings", {}), **record.get("engine_settings", {})}
    merged["design"] = record.get("design") or previous.get("design")
    merged["engines"] = list(dict.fromkeys([*previous.get("engines", []), *record["engines"]]))
    merged["scenes"] = list(dict.fromkeys([*previous.get("scenes", []), *record["scenes"]]))
    merged["datasets"] = {**previous.get("datasets", {}), **record["datasets"]}
    left_out = {**previous.get("left_out", {}), **record["left_out"]}
    merged["left_out"] = {e: why for e, why in left_out.items() if e not in merged["engines"]}
    commands = [c for c in previous.get("commands", [previous.get("command")]) if c]
    merged["commands"] = [*commands, record["command"]] if record["command"] not in commands else commands
    return merged


def prepared_source(folder: Path) -> dict | None:
    """What a dataset folder prepared by `nerfaug scene prepare` was made from: the downloaded
    folder's digest, its format and the width (None for other folders, built-in scenes among them)."""
    path = Path(folder) / PREPARED
    if not path.is_file():
        return None
    prepared = read_json(path)
    return {k: prepared.get(k) for k in ("source_digest", "format", "width")}


REAL_STUDY_SCENES = ("mic", "maryRose", "dtu_scan24", "cow", "moldGoldCape")
"""The real-scene study's planned scenes (docs/study-plan.md; the last is held back for
replication; `nerfaug.report.study_hypotheses` judges its hypotheses on the same names)."""
REAL_STUDY_HELD_BACK = ("moldGoldCape",)
"""The real-scene study's replication scene: judged per cell, kept out of the means across scenes."""
GPU_STUDY_ENGINES = ("paper",)
GPU_STUDY_SCENES = ("mic", "lego", "maryRose", "dtu_scan24", "moldGoldCape")
"""The GPU study's planned scenes (docs/study-plan.md, 2026-11-27), on the paper engine at 400 px:
mic, the procedural lego stand-in and two real captures, the last held back for replication."""
GPU_STUDY_HELD_BACK = ("moldGoldCape",)
GPU_STUDY_FIRST = ("uniform", "ours")
"""The GPU study's deciding comparison (docs/study-plan.md, amended 2026-11-28): on each scene,
ours and uniform over every trial run before the scene's other methods."""


def gpu_study_order(scenes, methods, trials: int, first=GPU_STUDY_FIRST) -> list[RunKey]:
    """The GPU study's runs in the order its slots run them: scene by scene (in `scenes`' order);
    within a scene the methods of `first` trial by trial (seed pairs complete as early as they
    can), then the scene's other methods trial by trial. `scenes` are names as results show them."""
    leading = [m for m in methods if m in first]
    rest = [m for m in methods if m not in first]
    return [
        RunKey(scene, method, trial)
        for scene in scenes
        for group in (leading, rest)
        for trial in range(trials)
        for method in group
    ]


class EngineSweep:
    """One engine's sweep of a study, opened for runs handed out a unit at a time by a caller that
    decides their number and order itself (a GPU slot's scheduler, `benchmarks/gpu_study.py`):
    study.json and sweep.json written and the datasets checked as `run_study` does; every unit
    runs as one batch (`run_trials`), each run computed as it would be alone."""

    def __init__(self, plan: StudyPlan, engine: str, table: dict | None = None):
        self.config = plan.engine_config(engine)
        write_plan(plan)
        self.root = StudyFolder(plan.out).engine(engine).root
        self.record = sweep_record(self.config, plan.command, check_config(self.config))
        check_sweep(self.root, self.record)
        self.datasets = {
            scene_name(s): prepare_scene(self.root, s, self.config, progress=False) for s in self.config.scenes
        }
        self.recorded = table_keys(table, engine)

    def pending(self, key: RunKey) -> bool:
        """Whether run `key` is still to run: no valid result here, none recorded in the table."""
        expected = run_fingerprint(self.record["fingerprint"], self.record["methods"][key.method])
        return read_result(key.folder(self.root), expected) is None and self.recorded.get(key) != expected

    def run(self, keys: list[RunKey]) -> dict[RunKey, dict | str]:
        """`keys` (runs of one engine configuration) as one batch. Per key, its result, or
        the one-line reason it failed (kept in its folder's error.json, as a sweep keeps it)."""
        try:
            outcomes = run_trials(keys, self.datasets, self.config, self.root)
        except Exception as error:  # noqa: BLE001 (the batch as a whole failed: each of its runs did)
            outcomes = dict.fromkeys(keys, error)
        done = {}
        for key, outcome in outcomes.items():
            if isinstance(outcome, BaseException):
                text = "".join(traceback.format_exception_only(type(outcome), outcome)).strip()
                if key.folder(self.root).exists():
                    write_error(key.folder(self.root), text, "".join(traceback.format_exception(outcome)))
                outcome = text
            done[key] = outcome
        return done


def run_study(
    plan: StudyPlan,
    workers: int = 1,
    force: bool = False,
    progress: bool = True,
    table: dict | None = None,
    budget_s: float | None = None,
) -> dict[str, dict]:
    """Run every engine's sweep (resuming; runs recorded in `table` with their current fingerprint
    are not run again), writing OUT/study.json first; with `budget_s`, start no run that would end
    past it (`run_sweep`). Returns engine -> {"failed": {run: reason}, "results": n valid results,
    "unstarted": n runs left, None for an engine not begun}."""
    began = time.monotonic()
    check_workers(workers)  # before anything is written
    study = StudyFolder(plan.out)
    write_plan(plan)
    outcomes = {}
    for index, engine in enumerate(plan.engines):
        left = None if budget_s is None else max(budget_s - (time.monotonic() - began), 1e-6)
        if left is not None and left <= 1e-6 and index > 0:  # the first engine's first unit always starts
            outcomes[engine] = {"failed": {}, "results": 0, "unstarted": None}
            continue
        if progress:
            print(f"study: engine {engine} -> {study.engine(engine).root}", file=sys.stderr)
        outcome = run_sweep(
            plan.engine_config(engine),
            study.engine(engine).root,
            workers=workers,
            force=force,
            progress=progress,
            command=plan.command,
            recorded=table_keys(table, engine),
            budget_s=left,
        )
        outcomes[engine] = {"failed": outcome.failed, "results": len(outcome.results), "unstarted": outcome.unstarted}
    return outcomes


def table_keys(table: dict | None, engine: str) -> dict[RunKey, str]:
    """The runs of `engine` a study's table records, by key, with their run fingerprints."""
    return {
        RunKey(r["scene"], r["method"], r["trial"]): r["fingerprint"]
        for r in (table or {}).get("runs", [])
        if r["engine"] == engine
    }


def rederived_fingerprints(plan: dict, runs: Iterable[tuple[str, str | None, str]]) -> dict[tuple, str | None]:
    """The fingerprint each of `runs` ((engine, engine version or None for the reference engine,
    method)) of the study whose plan record (study.json's, as its table keeps it) is `plan` has now:
    the settings the plan records (`plan["config"]`) for that engine, hashed by this code with the
    engine version the run records (not this machine's), and the method's definition today; None
    for a method this code no longer has. A recorded run whose fingerprint is not this one was made
    with other settings than those it records (or before a change of how they hash).

    Raises:
        RequestError: naming the field of `plan["config"]` that this code refuses.
    """
    settings = plan.get("config")
    if not isinstance(settings, dict):
        raise RequestError("plan.config", settings, "missing or not an object")
    sweeps: dict[tuple[str, str | None], str] = {}
    found: dict[tuple, str | None] = {}
    for engine, version, method in runs:
        if (engine, version) not in sweeps:
            config = validated(ExperimentConfig, {**settings, "engine": engine}, "plan.config")
            sweeps[engine, version] = fingerprint(config.fingerprinted(engine_version=version))
        spec = METHODS.get(method)
        found[engine, version, method] = (
            None if spec is None else run_fingerprint(sweeps[engine, version], spec.definition())
        )
    return found


def with_design(record: dict, out: Path) -> dict:
    """`record` (a study.json) with what its summary needs beyond the sittings run: "design", the
    cells a full study runs on its device (the default engines x the built-in scenes), so cells not
    run yet are named; and "engine_settings" of each engine run, from its sweep.json's fingerprint
    (the settings its runs were made with)."""
    device = record.get("config", {}).get("device", "cpu")
    engines, _ = default_engines("cuda" if device == "cuda" else "cpu")
    ran = list(record.get("scenes", []))
    # The procedural or the real-scene study: its planned scenes (those not run yet are named); a
    # study of other scenes (a user's own) plans just the scenes it ran.
    ran_engines = set(record.get("engines", []))
    gpu_study = bool(ran_engines) and ran_engines <= set(GPU_STUDY_ENGINES) and set(ran) <= set(GPU_STUDY_SCENES)
    if gpu_study:
        planned, engines = GPU_STUDY_SCENES, list(GPU_STUDY_ENGINES)
    elif set(ran) <= set(PROCEDURAL_SCENES):
        planned = PROCEDURAL_SCENES
    else:
        planned = REAL_STUDY_SCENES if set(ran) <= set(REAL_STUDY_SCENES) else ()
    design = {"engines": engines, "scenes": list(dict.fromkeys([*planned, *ran]))}
    if planned == REAL_STUDY_SCENES:
        design["held_back"] = list(REAL_STUDY_HELD_BACK)
    elif planned == GPU_STUDY_SCENES:
        design["held_back"] = list(GPU_STUDY_HELD_BACK)
    # A design recorded by an earlier sitting stands; one recorded before held-back scenes were
    # part of it gains them (the plan named its held-back scene before any run).
    record = {**record, "design": {**design, **(record.get("design") or {})}}
    settings = dict(record.get("engine_settings", {}))
    for engine in record.get("engines", []):
        try:
            results = StudyFolder(out).engine(engine)
            fingerprinted = json.loads(runfiles.read_text(results.root, results.sweep.name))["fingerprinted"]
        except (OSError, ValueError, KeyError, TypeError):  # PathRefused too: the sweep then refuses it
            continue
        found = {k.removeprefix("engine."): v for k, v in fingerprinted.items() if k.startswith("engine.")}
        settings[engine] = found or settings.get(engine, {})
    return {**record, "engine_settings": settings}


def make_plan(spec: StudySpec, command: list[str], progress: bool = True) -> StudyPlan:
    """The plan of the study `spec`, with the datasets prepared; `command` plans it again."""
    device_type = _device_type(spec.device)
    chosen, left_out = _engines(spec.engines, device_type)
    methods = tuple(spec.methods) if spec.methods else study_methods()
    comparisons = max(1, sum(m != "uniform" for m in methods))
    config = STUDY_PRESETS.choose(
        spec.preset,
        methods=methods,
        trials=min_trials(comparisons) if spec.trials is None else spec.trials,
        resolution=spec.resolution,
        device=device_type,
        layouts=spec.layouts,
        steps=spec.steps,
        batch=spec.batch,
        rounds=spec.rounds,
        round_every=spec.round_every,
        round_growth=spec.round_growth,
        **spec.schedule_changes(),
    )
    scenes = tuple(spec.scenes) if spec.scenes else PROCEDURAL_SCENES
    # Every setting checked before any dataset is rendered (a bad --trials costs nothing).
    checked: dict[str, dict] = {}
    for engine in chosen:
        checked = check_config(config.replace(scenes=scenes, engine=engine))
    datasets = prepare_datasets(spec.out, scenes, config, progress=progress)
    return StudyPlan(Path(spec.out), config, chosen, left_out, list(datasets), datasets, command, checked)


def _device_type(device: str) -> str:
    try:
        return resolve_device(device).type
    except ValueError as error:
        raise SystemExit(f"--device: {error}") from None


def _engines(engines, device_type: str) -> tuple[list[str], dict[str, str]]:
    """The engines a study runs (`engines`, or by default those for `device_type`), and those left out with why."""
    if engines is None:
        return default_engines(device_type)
    return cell_names(engines), {}


def cell_names(engines) -> list[str]:
    """The cells `--engines` names, each by `Engine.cell_name` (the settings' nested names, values
    as the engine holds them), once each.

    Raises:
        SystemExit: one line naming an engine that is refused, or given by an earlier record's flat
            names (with the cell name it means).
    """
    cells = []
    for engine in engines:
        try:
            read = Engine.read(engine)
            check_names(read.config)
        except ValueError as error:
            raise SystemExit(f"--engines: {error}") from None
        if is_flat_variant(engine):  # an earlier record's form: read from tables, not taken as a new cell
            raise SystemExit(f"--engines {engine}: give each setting by its nested name: {read.cell_name()}")
        cells.append(read.cell_name())
    return list(dict.fromkeys(cells))


__all__ = [
    "DEFAULT_TRIALS",
    "EngineSweep",
    "GPU_STUDY_FIRST",
    "GPU_STUDY_ENGINES",
    "GPU_STUDY_HELD_BACK",
    "GPU_STUDY_SCENES",
    "PROCEDURAL_SCENES",
    "REAL_STUDY_SCENES",
    "StudySpec",
    "prepared_source",
    "StudyPlan",
    "default_engines",
    "engine_presets",
    "gpu_study_order",
    "make_plan",
    "merge_records",
    "merged_record",
    "min_trials",
    "prepare_datasets",
    "rederived_fingerprints",
    "run_study",
    "study_methods",
    "table_keys",
]
