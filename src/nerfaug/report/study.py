"""The study's analysis, from its per-run table (`nerfaug.report.study_table`) alone.

Trial k of every method in a (scene, engine) cell shares the seed, the initial views and the NeRF
up to the step where views are added, so methods are compared with uniform on pairs of trials:
- per cell (the primary test): the paired differences over seeds, a two-sided Wilcoxon signed-rank
  test, Bonferroni over the methods compared with uniform in the cell, and the median difference
  with a percentile bootstrap CI (pairs resampled together);
- per regime (an engine, across its scenes; secondary): one value per seed, the mean of the
  paired differences over the cells, tested with the exact sign-flip permutation test
  (`statistics.seed_level_comparison`): cells share their seeds, so their pairs are not
  independent units.
Coverage of the chosen views (share on the unseen half, spread) comes from the poses in the table.
The page is written by `nerfaug.report.study_page`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nerfaug.coverage import view_coverage
from nerfaug.metrics import HIGHER_IS_BETTER, METRICS
from nerfaug.report.collect import Results
from nerfaug.report.study_table import (
    RunRow,
    engine_results,
    halves_by_layout,
    homogeneous,
    initial_poses_by_layout,
    table_rows,
)
from nerfaug.statistics import paired_comparison, seed_level_comparison, summarise

REFERENCE = "uniform"
OURS = "ours"
ALPHA = 0.05
BOOTSTRAP_SEED = 0


@dataclass
class MethodResult:
    """One method in one (scene, engine) cell.

    Attributes:
        values: metric -> one value per trial with that metric (trial order).
        trials: the trials (in order) behind `values["psnr"]`.
        seeds: seed of each of those trials.
        vs_reference: metric -> `statistics.paired_comparison` with uniform on the trials both
            have; absent for uniform itself and where no pair exists.
        coverage: per trial, {"trial", "unseen_share", "spread_deg"} of the chosen views.
    """

    method: str
    values: dict[str, list[float]]
    trials: list[int]
    seeds: list[int]
    vs_reference: dict[str, dict] = field(default_factory=dict)
    coverage: list[dict] = field(default_factory=list)
    rows: list[RunRow] = field(default_factory=list)

    def median(self, metric: str) -> float | None:
        return summarise(self.values[metric])["median"] if self.values.get(metric) else None

    def coverage_median(self, key: str) -> float | None:
        found = [c[key] for c in self.coverage if c[key] is not None and np.isfinite(c[key])]
        return float(np.median(found)) if found else None

    def differences(self, reference: MethodResult, metric: str = "psnr") -> dict[int, float]:
        """seed -> this method's value minus the reference's on the trial of that seed."""
        mine = {r.seed: r.metric(metric) for r in self.rows if r.metric(metric) is not None}
        theirs = {r.seed: r.metric(metric) for r in reference.rows if r.metric(metric) is not None}
        return {seed: mine[seed] - theirs[seed] for seed in sorted(set(mine) & set(theirs))}


@dataclass
class Cell:
    """One (scene, engine): its methods' results, the winner and what is missing."""

    scene: str
    engine: str
    methods: dict[str, MethodResult]
    n_comparisons: int
    planned: int
    missing: list[str]
    lpips_notes: list[str]

    @property
    def winner(self) -> str | None:
        medians = [(r.median("psnr"), m) for m, r in self.methods.items() if r.median("psnr") is not None]
        return max(medians, key=lambda x: x[0])[1] if medians else None

    @property
    def complete(self) -> bool:
        return not self.missing

    def significant(self, better: bool, metric: str = "psnr") -> list[str]:
        """Methods significantly better (or worse) than uniform in this cell."""
        return [
            m
            for m, r in self.methods.items()
            if (e := r.vs_reference.get(metric)) and e["significant"] and e["better"] == better
        ]


@dataclass
class Study:
    """The study's cells and regimes, read from its table."""

    table: dict
    cells: list[Cell]
    not_run: dict[str, str]
    results: dict[str, Results]
    regimes: dict[str, dict[str, dict]] = field(default_factory=dict)
    """engine -> method -> `seed_level_comparison` of its PSNR differences to uniform."""
    missing_cells: list[str] = field(default_factory=list)
    """"scene, engine" of the study's design (the plan's "design") an engine run has no runs of."""
    held_back: tuple[str, ...] = ()
    """Scenes the design holds back for replication: judged per cell, outside the regimes."""

    @property
    def plan(self) -> dict:
        return self.table["plan"]

    @property
    def methods(self) -> list[str]:
        """Every method with results in some cell, in the plan's order."""
        found = list(dict.fromkeys(m for c in self.cells for m in c.methods))
        planned = [m for m in self.plan.get("methods", []) if m in found]
        return planned + [m for m in found if m not in planned]

    @property
    def engines(self) -> list[str]:
        return list(dict.fromkeys(c.engine for c in self.cells))


def coverage_of(rows: list[RunRow], initial: dict[int, list], halves: dict[int, dict] | None = None) -> list[dict]:
    """Where each run's chosen views lie, relative to the initial views (and half, where recorded)
    of its own layout."""
    layouts = {layout: homogeneous(poses) for layout, poses in initial.items()}
    halves = halves or {}
    return [{"trial": r.trial, **view_coverage(r.poses(), layouts[r.layout], half=halves.get(r.layout))} for r in rows]


def paired_with(mine: list[RunRow], theirs: list[RunRow], metric: str) -> tuple[list[float], list[float]]:
    """The two methods' values of `metric` on the seeds both have, matched by seed (seed order)."""
    a = {r.seed: r.metric(metric) for r in mine if r.metric(metric) is not None}
    b = {r.seed: r.metric(metric) for r in theirs if r.metric(metric) is not None}
    seeds = sorted(set(a) & set(b))
    return [a[s] for s in seeds], [b[s] for s in seeds]


def make_cell(
    rows: list[RunRow],
    scene: str,
    engine: str,
    methods: list[str],
    trials: int,
    initial: dict[int, list],
    halves: dict[int, dict] | None = None,
) -> Cell:
    """The (scene, engine) cell of `rows` (the table's rows of that cell); `methods` and `trials`
    are the plan's, `initial` the scene's initial views per layout (3x4 lists), `halves` the
    azimuth window each layout's initial views came from, where recorded."""
    by_method: dict[str, MethodResult] = {}
    for method in list(dict.fromkeys([*methods, *(r.method for r in rows)])):
        mine = sorted((r for r in rows if r.method == method), key=lambda r: r.trial)
        if not mine:
            continue
        values = {metric: [v for r in mine if (v := r.metric(metric)) is not None] for metric in METRICS}
        by_method[method] = MethodResult(
            method,
            values,
            [r.trial for r in mine],
            [r.seed for r in mine],
            coverage=coverage_of(mine, initial, halves),
            rows=mine,
        )
    compared = [m for m in by_method if m != REFERENCE]
    # Bonferroni over every method the plan compares with uniform, run yet or not: the correction
    # does not shrink while a cell is incomplete.
    k = max(1, len([m for m in dict.fromkeys([*methods, *compared]) if m != REFERENCE]))
    reference = by_method.get(REFERENCE)
    for method in compared if reference is not None else []:
        for metric in METRICS:
            x, y = paired_with(by_method[method].rows, reference.rows, metric)
            if x:
                by_method[method].vs_reference[metric] = paired_comparison(
                    x, y, k, HIGHER_IS_BETTER[metric], alpha=ALPHA, seed=BOOTSTRAP_SEED
                )
    missing = [
        f"{m}: {len(by_method[m].trials) if m in by_method else 0} of {trials} trials"
        for m in methods
        if (len(by_method[m].trials) if m in by_method else 0) < trials
    ]
    lpips = sorted({r.lpips_status or "unknown reason" for r in rows if r.lpips is None})
    return Cell(scene, engine, by_method, k, trials, missing, lpips)


def regime_comparisons(cells: list[Cell], metric: str = "psnr") -> dict[str, dict]:
    """method -> `seed_level_comparison` of its differences to uniform over `cells` (one
    engine's), Bonferroni over the methods the cells compare (as each cell's test)."""
    methods = list(dict.fromkeys(m for c in cells for m in c.methods if m != REFERENCE))
    k = max([c.n_comparisons for c in cells], default=1)
    found = {}
    for method in methods:
        differences = {
            c.scene: c.methods[method].differences(c.methods[REFERENCE], metric)
            for c in cells
            if method in c.methods and REFERENCE in c.methods
        }
        if any(differences.values()):
            found[method] = seed_level_comparison(differences, k, HIGHER_IS_BETTER[metric], alpha=ALPHA)
    return found


def collect_study(table: dict) -> Study:
    """The study's cells (every planned engine x scene with results) and regimes, from its table."""
    plan = table["plan"]
    rows = table_rows(table)
    ran = list(dict.fromkeys(r.engine for r in rows))
    engines = [e for e in plan.get("engines", []) if e in ran] + [e for e in ran if e not in plan.get("engines", [])]
    not_run = dict(plan.get("left_out", {}))
    design = plan.get("design") or {}
    planned = list(dict.fromkeys([*design.get("engines", []), *plan.get("engines", [])]))
    not_run.update({e: "not run yet (no runs in the table)" for e in planned if e not in ran})
    scenes = list(dict.fromkeys([*plan.get("scenes", []), *(r.scene for r in rows)]))
    methods, trials = list(plan.get("methods", [])), int(plan.get("trials", 0))
    held_back = tuple(design.get("held_back", []))
    cells, regimes = [], {}
    for engine in engines:
        mine = [
            make_cell(
                [r for r in rows if r.engine == engine and r.scene == scene],
                scene,
                engine,
                methods,
                trials,
                initial_poses_by_layout(table["scenes"][scene]),
                halves_by_layout(table["scenes"][scene]),
            )
            for scene in scenes
            if any(r.engine == engine and r.scene == scene for r in rows)
        ]
        cells += mine
        # Over complete cells only: the seeds must be common to every cell, so one cell part-way
        # through would cut every scene down to its few seeds. A held-back scene replicates what
        # the others found; it is not part of their mean.
        pooled = [c for c in mine if c.scene not in held_back]
        regimes[engine] = regime_comparisons([c for c in pooled if c.complete] or pooled)
    results = {engine: engine_results(table, engine) for engine in engines}
    design_scenes = list(dict.fromkeys([*design.get("scenes", []), *scenes]))
    missing_cells = [
        f"{scene}, {engine}"
        for engine in engines
        for scene in design_scenes
        if not any(c.engine == engine and c.scene == scene for c in cells)
    ]
    return Study(table, cells, not_run, results, regimes, missing_cells, held_back)


__all__ = ["Cell", "MethodResult", "Study", "collect_study", "make_cell", "regime_comparisons"]
