"""The study of rounds' hypotheses (docs/study-plan.md, "Plan of 2026-11-28: the study of rounds",
Q1-Q4) judged from its table, with the GPU study's tests and words (`report.study_verdicts`):
"holds", "not supported" (with the smallest effect the test could have seen), "contradicted", or
"partial: n of m runs" while a planned cell is incomplete (a partial table decides nothing; its
numbers are shown as they stand). Q3 names its outcome: "coverage wins", "uncertainty wins" or,
when neither side is significantly better than both of the other, "not supported".

The primary outcome is the PSNR over every test view at the end; the area under the learning
curve divided by its span of views (`RunRow.auc`) is shown beside Q1, deciding nothing.
Q2 compares each rounds run with the one-shot run of the same method, seed, layout and engine
version in the study's own one-shot arm (docs/study-plan.md, its amendment of 2026-11-28). A table
keeps one run per engine, scene, method and trial, so that arm is a study, and a table, of its
own: the caller gives its runs and the fingerprints they would have now (`OneShotArm`; `nerfaug
study --one-shot-table` re-derives them from that table's plan), and a row whose fingerprint is not
among them was made with other settings and is no arm of the comparison. Without it Q2 is not
judged.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import PurePath

from nerfaug.report.document import Block, Heading, Paragraph, Table
from nerfaug.report.study import REFERENCE, Cell, Study
from nerfaug.report.study_table import RunRow, table_rows
from nerfaug.report.study_verdicts import (
    ALPHA,
    GPU_METHODS,
    all_hold,
    dead_per_cell,
    dead_runs,
    detectable,
    held_back_row,
    judged,
    mean_interval,
    min_detectable_effect,
    regime_test,
    says,
    sensitivity,
    touches,
    verdict_row,
)
from nerfaug.statistics import seed_level_comparison

# The plan's design (experiment.study carries the scenes; tests check they agree).
ROUNDS_SCENES = ("mic", "maryRose", "dtu_scan24", "cow")
ROUNDS_HELD_BACK = "moldGoldCape"
ROUNDS_METHODS = GPU_METHODS  # uniform, ours, ours-batch-sharp, fisherrf, entropy-sampling, furthest
ROUNDS_TRIALS = 10
Q1_K = 5  # Bonferroni over the five methods compared with uniform
Q2_METHODS = ("uniform", "ours")
Q2_ONE_SHOT_RUNS = len(ROUNDS_SCENES) * len(Q2_METHODS) * ROUNDS_TRIALS  # the one-shot arm: 80 runs
Q3_PAIRS = (("furthest", "ours"), ("furthest", "fisherrf"))
HEADERS = ["", "hypothesis", "test", "verdict", "evidence", "smallest effect it could have seen", "dead runs"]


@dataclass(frozen=True)
class OneShotArm:
    """The one-shot arm of the study of rounds kept in a table of its own (Q2's other side).

    Attributes:
        table: that table, as `study_table.read_table` gives it (runs of one round).
        current: the fingerprints its runs would have now; a row with another counts for nothing.
        source: the table's path as the command was given it (the page's command names it so).
    """

    table: dict
    current: frozenset[str]
    source: str

    @property
    def name(self) -> str:
        """The table file's name: what the page's text calls it (never a path of this machine)."""
        return PurePath(self.source).name


def planned_runs(study: Study, engine: str, scenes: Iterable[str]) -> tuple[int, int]:
    """(runs in the table, runs planned) of the plan's methods and trials on `scenes`."""
    scenes = set(scenes)
    done = {
        (r["scene"], r["method"], r["trial"])
        for r in study.table["runs"]
        if r["engine"] == engine
        and r["scene"] in scenes
        and r["method"] in ROUNDS_METHODS
        and r["trial"] < ROUNDS_TRIALS
    }
    return len(done), len(scenes) * len(ROUNDS_METHODS) * ROUNDS_TRIALS


def _partial(study: Study, engine: str, scenes: Iterable[str]) -> str | None:
    n, m = planned_runs(study, engine, scenes)
    return None if n == m else f"partial: {n} of {m} runs"


def _cells(study: Study, engine: str) -> list[Cell]:
    return [c for c in study.cells if c.engine == engine and c.scene in ROUNDS_SCENES]


def family(study: Study, engine: str, drop: set | None = None) -> dict[str, dict]:
    """Q1's family: every planned method against uniform, per regime over the four scenes, x5."""
    cells = _cells(study, engine)
    return {m: regime_test(cells, m, REFERENCE, Q1_K, drop) for m in ROUNDS_METHODS if m != REFERENCE}


def auc_test(cells: list[Cell], method: str, k: int = Q1_K) -> dict | None:
    """The secondary outcome: the per-regime sign-flip test on the curves' mean heights (area /
    span of views) of method - uniform, x k; None without runs in rounds."""
    per_cell = {
        c.scene: c.methods[method].differences(c.methods[REFERENCE], "auc")
        for c in cells
        if method in c.methods and REFERENCE in c.methods
    }
    if not any(per_cell.values()):
        return None
    result = seed_level_comparison({s: d for s, d in per_cell.items() if d}, k, alpha=ALPHA)
    result["low"], result["high"] = mean_interval(result["seed_means"])
    return result


def q1(study: Study, engine: str) -> tuple[list[str], list[str]]:
    """Q1's row, and the methods its family finds better than uniform (for Q4)."""
    dead = dead_runs(study)
    tests, clean = family(study, engine), family(study, engine, dead)
    partial = _partial(study, engine, ROUNDS_SCENES)
    verdict = partial or judged(tests["ours"])
    evidence = [says(f"{m} - uniform", t) for m, t in tests.items()]
    secondary = auc_test(_cells(study, engine), "ours")
    if secondary is not None:
        evidence.append("secondary, deciding nothing: " + says("ours - uniform, curve area / span", secondary))
    row = verdict_row(
        "Q1",
        "ours beats uniform in rounds (the other four methods against uniform reported beside it)",
        "per-regime sign-flip on final PSNR, x5",
        verdict,
        evidence,
        detectable(tests["ours"]["seed_means"], Q1_K) if verdict == "not supported" else "",
        sensitivity(
            touches(dead, engine, ROUNDS_SCENES, ("ours", REFERENCE)),
            judged(clean["ours"]),
            [says("ours - uniform", clean["ours"])],
        ),
    )
    better = [] if partial else [m for m, t in tests.items() if t["significant"] and t["better"]]
    return row, better


def _dead_key(row: RunRow) -> tuple[str, str, str, int]:
    """A row as `dead_runs` names a run: (engine, scene, method, seed)."""
    return (row.engine, row.scene, row.method, row.seed)


def _by_pair(rows: list[RunRow]) -> dict[tuple[str, str, int, int, str], RunRow]:
    """Rows by what pairs them: (scene, method, seed, layout, engine version)."""
    return {(r.scene, r.method, r.seed, r.layout, r.engine_version): r for r in rows}


def q2_tests(study: Study, engine: str, one_shot: dict, current: set[str], drop: set | None = None) -> dict[str, dict]:
    """Per method of Q2: rounds - one-shot PSNR on the same scene, seed, layout and engine
    version, each seed's mean over the four scenes, exact sign-flip, x2. `study`: the runs in
    rounds; one-shot rows of `engine` in the table `one_shot` count only with a fingerprint in
    `current`; `drop`: dead runs (of either arm) whose pairs are left out."""
    mine = _by_pair([r for r in table_rows(study.table) if r.engine == engine])
    theirs = _by_pair([r for r in table_rows(one_shot) if r.engine == engine and r.fingerprint in current])
    tests = {}
    for method in Q2_METHODS:
        per_scene: dict[str, dict[int, float]] = {}
        for key, row in mine.items():
            scene, m, seed = key[:3]
            other = theirs.get(key)
            if m != method or scene not in ROUNDS_SCENES or other is None:
                continue
            if drop is not None and (_dead_key(row) in drop or _dead_key(other) in drop):
                continue
            per_scene.setdefault(scene, {})[seed] = row.psnr - other.psnr
        result = seed_level_comparison(per_scene, len(Q2_METHODS), alpha=ALPHA) if per_scene else None
        if result is not None:
            result["low"], result["high"] = mean_interval(result["seed_means"])
        tests[method] = result
    return tests


def _arm_partial(arm: list[RunRow]) -> str | None:
    """ "partial: n of 80 one-shot runs" while the one-shot arm's cells are incomplete."""
    done = {
        (r.scene, r.method, r.trial)
        for r in arm
        if r.scene in ROUNDS_SCENES and r.method in Q2_METHODS and r.trial < ROUNDS_TRIALS
    }
    return None if len(done) == Q2_ONE_SHOT_RUNS else f"partial: {len(done)} of {Q2_ONE_SHOT_RUNS} one-shot runs"


def q2(study: Study, engine: str, arm: OneShotArm | None) -> list[str]:
    """Q2's row. `study`: the runs in rounds; `arm`: the one-shot arm's table (None: not judged)."""
    claim = "rounds beat one-shot at equal budget, for uniform and for ours (same seed, layout and engine version)"
    test = "per-regime sign-flip on rounds - one-shot PSNR, x2"
    if arm is None:
        why = (
            "no one-shot table was given (nerfaug study --one-shot-table FILE: the table of the study's "
            "one-shot arm, uniform and ours in one round)"
        )
        return verdict_row("Q2", claim, test, "not judged", [why], "", "")
    one_shot, current = arm.table, set(arm.current)
    partial = _partial(study, engine, ROUNDS_SCENES)
    tests = q2_tests(study, engine, one_shot, current)
    runs = [r for r in table_rows(one_shot) if r.engine == engine and r.method in Q2_METHODS]
    stale = sum(r.fingerprint not in current for r in runs)
    missing = [m for m, t in tests.items() if t is None]
    verdict = (
        partial
        or (f"not judged: no current one-shot runs of {', '.join(missing)}" if missing else None)
        or _arm_partial([r for r in runs if r.fingerprint in current])
        or all_hold([judged(t) for t in tests.values()])
    )
    evidence = [says(f"{m}: rounds - one-shot", t) for m, t in tests.items() if t is not None]
    if stale:
        evidence.append(f"{stale} one-shot run(s) left out: their fingerprints no longer match their settings")
    floor = "; ".join(f"{m}: {detectable(t['seed_means'], 2)}" for m, t in tests.items() if t is not None)
    dead = dead_runs(study) | {_dead_key(r) for r in table_rows(one_shot) if r.empty}
    clean = {m: t for m, t in q2_tests(study, engine, one_shot, current, dead).items() if t is not None}
    n_dead = sum(e == engine and sc in ROUNDS_SCENES and m in Q2_METHODS for e, sc, m, _ in dead)
    return verdict_row(
        "Q2",
        claim,
        test,
        verdict,
        evidence,
        floor if verdict == "not supported" else "",
        sensitivity(n_dead, all_hold([judged(t) for t in clean.values()]), [says(m, t) for m, t in clean.items()]),
    )


def _q3_outcome(tests: dict[tuple[str, str], dict]) -> str:
    """ "coverage wins" if furthest is significantly better than both, "uncertainty wins" if both
    are significantly better than furthest, else "not supported"."""
    if all(t["significant"] and t["better"] for t in tests.values()):
        return "coverage wins"
    if all(t["significant"] and not t["better"] for t in tests.values()):
        return "uncertainty wins"
    return "not supported"


def q3(study: Study, engine: str) -> list[str]:
    dead = dead_runs(study)
    cells = _cells(study, engine)
    tests = {pair: regime_test(cells, *pair, len(Q3_PAIRS)) for pair in Q3_PAIRS}
    clean = {pair: regime_test(cells, *pair, len(Q3_PAIRS), dead) for pair in Q3_PAIRS}
    verdict = _partial(study, engine, ROUNDS_SCENES) or _q3_outcome(tests)
    floor = "; ".join(f"{a} - {b}: {detectable(t['seed_means'], len(Q3_PAIRS))}" for (a, b), t in tests.items())
    return verdict_row(
        "Q3",
        "coverage against uncertainty: furthest against ours and against fisherrf (two-sided; coverage wins only "
        "if furthest beats both, uncertainty wins only if both beat furthest)",
        "two per-regime sign-flip tests, x2",
        verdict,
        [says(f"{a} - {b}", t) for (a, b), t in tests.items()],
        floor if verdict == "not supported" else "",
        sensitivity(
            touches(dead, engine, ROUNDS_SCENES, {m for pair in Q3_PAIRS for m in pair}),
            _q3_outcome(clean),
            [says(f"{a} - {b}", t) for (a, b), t in clean.items()],
        ),
    )


def q4(study: Study, engine: str, better: list[str], q1_partial: str | None) -> list[str]:
    claim = f"every method Q1's family finds better than uniform also beats it on the held-back {ROUNDS_HELD_BACK}"
    test = "per-cell Wilcoxon signed-rank, p < 0.05, x the methods so found"
    if q1_partial:
        return verdict_row("Q4", claim, test, q1_partial, ["Q1's family is not judged yet"], "", "")
    if not better:
        return verdict_row("Q4", claim, test, "not applicable", ["no method was found better than uniform"], "", "")
    partial = _partial(study, engine, (ROUNDS_HELD_BACK,))
    return held_back_row("Q4", claim, test, study, engine, ROUNDS_HELD_BACK, better, partial, dead_runs(study))


def rounds_rows(study: Study, engine: str, arm: OneShotArm | None = None) -> list[list[str]]:
    """Q1-Q4 on `engine`: each with its test, verdict, evidence, the smallest effect it could have
    seen (beside "not supported") and its line without dead runs. Q2 pairs with `arm`, the one-shot
    arm's table and the fingerprints its runs would have now; without it Q2 is not judged."""
    q1_row, better = q1(study, engine)
    partial = _partial(study, engine, ROUNDS_SCENES)
    return [q1_row, q2(study, engine, arm), q3(study, engine), q4(study, engine, better, partial)]


def smallest_effect_note() -> str:
    """The smallest effect Q1's test sees with the planned seeds, in words."""
    mde = min_detectable_effect(ROUNDS_TRIALS, Q1_K)
    return f"{mde:.2f} per-seed SDs at x{Q1_K} with {ROUNDS_TRIALS} seeds" if math.isfinite(mde) else "none"


def rounds_blocks(study: Study, arm: OneShotArm | None = None) -> list[Block]:
    """The page's section: Q1-Q4 per engine of the table, with the dead runs per cell. `arm`: the
    one-shot arm's table (Q2), which the page names by its file name; without it Q2 is not judged."""
    where = (
        f"read from the table {arm.name}"
        if arm is not None
        else "kept in a table of its own, given with --one-shot-table: none was given, so Q2 is not judged"
    )
    blocks: list[Block] = [
        Heading("The planned hypotheses (the study of rounds)"),
        Paragraph(
            'Stated before the runs in docs/study-plan.md ("Plan of 2026-11-28: the study of rounds"), with its '
            f"tests: per regime, each seed's mean over {', '.join(ROUNDS_SCENES)} of the paired differences in final "
            "PSNR (every test view, after the last step), the exact sign-flip test, Bonferroni x5 (Q2, Q3: x2); Q4 "
            "per cell on the held-back scene. Q2 pairs each run in rounds with the run of the same method, seed, "
            "layout and engine version in the study's own one-shot arm (uniform and ours under the paper's "
            f"schedule, one round, {where}); one-shot runs of another engine version are not pooled "
            "with them. The area under the learning curve divided by its span of views is "
            "shown beside Q1 and decides nothing. Every verdict is computed from the table: a hypothesis is judged "
            "only when its cells are complete (partial: n of m runs, the numbers as they stand, deciding nothing). "
            '"Not supported" says the test did not find the effect, not that there is none: beside it, the '
            f"smallest effect the test could have seen (with the planned seeds, {smallest_effect_note()}). Dead "
            "runs stay in their cells; the last column gives the same tests without the pairs holding one."
        ),
    ]
    engines = list(study.engines)
    for engine in engines:
        rows = rounds_rows(study, engine, arm)
        if len(engines) > 1:
            rows = [[f"{r[0]} ({engine})", *r[1:]] for r in rows]
        scenes = (*ROUNDS_SCENES, ROUNDS_HELD_BACK)
        notes = [f"dead runs per cell, engine {engine}: {dead_per_cell(study, engine, scenes)}"]
        if arm is not None:
            dead = sorted((r.scene, r.method, r.seed) for r in table_rows(arm.table) if r.engine == engine and r.empty)
            notes.append(
                f"dead one-shot runs, engine {engine}: {len(dead)}"
                + (f" ({'; '.join(f'{sc} {m} seed {k}' for sc, m, k in dead)})" if dead else "")
            )
        blocks.append(Table(HEADERS, rows, notes))
    return blocks


__all__ = [
    "OneShotArm",
    "Q1_K",
    "ROUNDS_HELD_BACK",
    "ROUNDS_METHODS",
    "ROUNDS_SCENES",
    "ROUNDS_TRIALS",
    "auc_test",
    "family",
    "planned_runs",
    "q2_tests",
    "rounds_blocks",
    "rounds_rows",
]
