"""Collecting a results folder: the sweep record, every run folder (aggregated or not, with the
reason) and the planned runs that never ran.

Only runs whose result.json is valid for the sweep's fingerprint (`store.read_result`) are
aggregated; every other run folder is listed with the reason, never silently counted. Run folders
are read through the run-folder contract (`nerfaug.experiment.runfolder`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from nerfaug import runfiles
from nerfaug.experiment.layout import TRIAL_NAME, ResultsFolder
from nerfaug.experiment.runfolder import FILES, read_error, read_progress
from nerfaug.experiment.store import RESULT_KEYS, read_result, run_fingerprint


class ReportError(RuntimeError):
    """The folder is not a results folder the report can read."""


@dataclass(frozen=True)
class Run:
    """One aggregated run: its valid result.json and its folder (for selection, renders, history)."""

    scene: str
    method: str
    trial: int
    folder: Path
    result: dict

    def metric(self, name: str) -> float | None:
        value = self.result["metrics"].get(name)
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    def seconds(self, phase: str) -> float | None:
        timing = self.result["timing"]
        value = timing.get(phase) if isinstance(timing, dict) else None
        return float(value) if isinstance(value, (int, float)) else None


@dataclass(frozen=True)
class NotAggregated:
    folder: Path
    reason: str


@dataclass
class Results:
    """What a results folder holds, split into aggregated runs and the rest."""

    root: Path
    sweep: dict
    runs: list[Run]
    not_aggregated: list[NotAggregated]
    missing: list[str]
    scenes: list[str] = field(default_factory=list)
    methods: list[str] = field(default_factory=list)

    @property
    def config(self) -> dict:
        return self.sweep.get("config", {})

    @property
    def ours(self) -> str | None:
        """The method compared with the others: the first of the config's methods."""
        configured = self.config.get("methods") or self.methods
        return configured[0] if configured else None

    @property
    def baselines(self) -> list[str]:
        present = {run.method for run in self.runs}
        return [m for m in self.methods if m != self.ours and m in present]

    def runs_of(self, scene: str | None = None, method: str | None = None) -> list[Run]:
        chosen = [
            r for r in self.runs if (scene is None or r.scene == scene) and (method is None or r.method == method)
        ]
        return sorted(chosen, key=lambda r: (r.scene, r.method, r.trial))

    def values(self, scene: str, method: str, metric: str) -> list[float]:
        return [v for r in self.runs_of(scene, method) if (v := r.metric(metric)) is not None]


def read_sweep(root: Path) -> dict:
    path = ResultsFolder(root).sweep
    if not runfiles.exists(root, path.name):
        raise ReportError(f"{path} not found: {root} is not a results folder written by `nerfaug run`")
    try:
        sweep = json.loads(runfiles.read_text(root, path.name))  # PathRefused for a link leading out
    except json.JSONDecodeError as error:
        raise ReportError(f"{path}: invalid JSON ({error.msg} at line {error.lineno})") from None
    if not isinstance(sweep, dict) or "fingerprint" not in sweep:
        raise ReportError(f"{path}: no fingerprint; not a sweep record")
    return sweep


def why_not_valid(folder: Path, fingerprint: str) -> str:
    """A human reason why `read_result(folder, fingerprint)` refused the run (for the report only;
    the decision itself is `read_result`'s)."""
    path = runfiles.path_in(folder, FILES.result)
    if not path.exists() and (error := read_error(folder)) is not None:
        return f"failed: {error}"
    if not path.exists():
        step = read_progress(folder)
        last = "" if step is None else f", last progress at step {step}"
        return f"no result.json (interrupted, failed or still running{last})"
    try:
        result = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        return f"result.json unreadable or truncated ({getattr(error, 'msg', error)})"
    if not isinstance(result, dict):
        return "result.json is not a JSON object"
    missing = [key for key in RESULT_KEYS if key not in result]
    if missing:
        return f"result.json lacks {', '.join(missing)}"
    if result["fingerprint"] != fingerprint:
        return (
            f"made with another configuration or method definition (fingerprint {result['fingerprint']}, "
            f"expected {fingerprint})"
        )
    return "result.json has no numeric PSNR"


def _read_run(folder: Path, sweep: dict) -> Run | NotAggregated:
    scene, method, name = folder.parts[-3:]
    match = TRIAL_NAME.fullmatch(name)
    if match is None:
        return NotAggregated(folder, "folder name is not trial_<k>")
    if method not in sweep.get("methods", {}):
        return NotAggregated(folder, f"method {method!r} is not in sweep.json (its definition is unknown)")
    fingerprint = run_fingerprint(sweep["fingerprint"], sweep["methods"][method])
    result = read_result(folder, fingerprint)
    if result is None:
        return NotAggregated(folder, why_not_valid(folder, fingerprint))
    trial = int(match.group(1))
    claimed = (str(result["scene"]), str(result["method"]), result["trial"])
    if claimed != (scene, method, trial):
        where = f"{claimed[0]}/{claimed[1]}/trial {claimed[2]}"
        return NotAggregated(folder, f"result.json is for {where}, not this folder")
    return Run(scene, method, trial, folder, result)


def _ordered(configured: list[str], found: set[str]) -> list[str]:
    """The config's order first (the first method is ours), then anything else found, sorted."""
    return [x for x in configured if x in found] + sorted(found - set(configured))


def collect_results(results_dir: Path) -> Results:
    """Read a results folder: the sweep record, every run folder (valid or not) and the planned
    runs that have no folder at all."""
    root = Path(results_dir)
    sweep = read_sweep(root)
    runs, skipped = [], []
    for folder in ResultsFolder(root).run_folders():
        item = _read_run(folder, sweep)
        (runs if isinstance(item, Run) else skipped).append(item)
    config = sweep.get("config", {})
    # Results name a user dataset by its folder's name (sweep.scene_name).
    planned_scenes = [Path(s).name for s in config.get("scenes", [])]
    planned_methods = list(config.get("methods", []))
    existing = set(ResultsFolder(root).run_folders())
    missing = [
        f"{scene}/{method}/trial {trial}"
        for scene in planned_scenes
        for method in planned_methods
        for trial in range(int(config.get("trials", 0)))
        if ResultsFolder(root).run(scene, method, trial) not in existing
    ]
    scenes = _ordered(planned_scenes, {r.scene for r in runs} | {f.folder.parts[-3] for f in skipped})
    methods = _ordered(planned_methods, {r.method for r in runs})
    return Results(root, sweep, runs, skipped, missing, scenes, methods)


__all__ = ["NotAggregated", "ReportError", "Results", "Run", "collect_results", "read_sweep", "why_not_valid"]
