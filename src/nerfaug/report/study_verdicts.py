"""What a planned test can and cannot say, and the GPU study's hypotheses (docs/study-plan.md, "Plan
of 2026-11-27: the GPU study", G1-G4) judged from its table.

Every verdict is one of "holds", "not supported", "contradicted" or "partial: n of m runs" (a
hypothesis is judged only on complete cells: a partial table decides nothing, and its numbers are
shown as they stand). Beside a "not supported" stands the smallest effect the test could have seen
(`detectable`): a test on few seeds with a Bonferroni factor cannot see a small effect, so its
silence is not evidence of none. Runs whose NeRF rendered background only ("dead", the health
check's `empty`) stay in their cells for the planned analysis, as the plan says; a sensitivity
line gives the same test without the pairs that hold one.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from scipy import optimize, stats

from nerfaug.report.document import p_value
from nerfaug.report.study import REFERENCE, Cell, Study
from nerfaug.statistics import paired_comparison, seed_level_comparison

ALPHA = 0.05
POWER = 0.8
CONFIDENCE = 0.95
BOOTSTRAP_SEED = 0

# The GPU study's design as its plan wrote it (benchmarks/gpu_study.py and nerfaug.experiment.study
# carry the same names; tests/report/test_study_verdicts.py checks they agree).
GPU_ENGINES = ("paper",)
GPU_SCENES = ("mic", "lego", "maryRose", "dtu_scan24")
GPU_HELD_BACK = "moldGoldCape"
GPU_METHODS = ("uniform", "ours", "ours-batch-sharp", "fisherrf", "entropy-sampling", "furthest")
GPU_TRIALS = 10
REGIME_K = 5  # the per-regime test: Bonferroni over the five methods compared with uniform
G2_BASELINES = ("entropy-sampling", "fisherrf")


# ----------------------------------------------------------------------------- statistics


def min_detectable_effect(n: int, n_comparisons: int = 1, alpha: float = ALPHA, power: float = POWER) -> float:
    """The smallest true mean of n independent values, in units of their standard deviation, that
    a two-sided test at alpha / n_comparisons detects with probability `power`: the one-sample
    t-test's power (noncentral t, normal values), which the exact sign-flip and signed-rank tests
    approach (at 10 values the sign-flip test needs about 5 % more). inf when no outcome of an
    exact sign-flip or signed-rank test on n values can be significant (2 / 2^n x k >= alpha).

    Example:
        >>> round(min_detectable_effect(10, 5), 2)
        1.33
    """
    level = alpha / n_comparisons
    if n < 2 or min(1.0, 2.0 ** (1 - n)) >= level:
        return math.inf
    df, critical = n - 1, stats.t.ppf(1 - level / 2, n - 1)

    def shortfall(effect: float) -> float:
        shift = effect * math.sqrt(n)
        # The lower tail (a significant result of the wrong sign) is below 1e-6 wherever power
        # is near 0.8; it is left out, as scipy's noncentral t returns nan there for large shifts.
        return float(stats.nct.sf(critical, df, shift)) - power

    return float(optimize.brentq(shortfall, 1e-6, 50.0, xtol=1e-10))


def mean_interval(values: Iterable[float], confidence: float = CONFIDENCE, seed: int = BOOTSTRAP_SEED) -> tuple:
    """(low, high): a percentile bootstrap interval of the mean (9999 resamples, seeded); nan for
    fewer than two values."""
    x = np.asarray(list(values), dtype=np.float64)
    if x.size < 2 or np.ptp(x) == 0:
        return (float(x.mean()), float(x.mean())) if x.size >= 2 else (math.nan, math.nan)
    ci = stats.bootstrap(
        (x,),
        np.mean,
        vectorized=True,
        confidence_level=confidence,
        n_resamples=9999,
        method="percentile",
        rng=np.random.default_rng(seed),
    ).confidence_interval
    return float(ci.low), float(ci.high)


def detectable(values: Iterable[float], n_comparisons: int, what: str = "seed pairs") -> str:
    """The smallest effect a test on `values` (one per seed) with this Bonferroni factor could have
    seen, in words: n, the factor, the smallest attainable p after it, and the effect it detects 4
    times in 5, in per-seed SDs and in dB at the values' observed spread."""
    x = np.asarray(list(values), dtype=np.float64)
    n = int(x.size)
    floor = min(1.0, 2.0 ** (1 - n) * n_comparisons) if n else 1.0
    mde = min_detectable_effect(n, n_comparisons)
    head = f"{n} {what}, x{n_comparisons}: smallest attainable p x {n_comparisons} = {p_value(floor)}"
    if math.isinf(mde):
        return f"{head}; no outcome could be significant"
    sd = float(np.std(x, ddof=1))
    return f"{head}; detectable (80 % power): {mde:.2f} per-seed SDs = {mde * sd:.2f} dB at the observed SD {sd:.2f} dB"


def floor_text(entry: dict) -> str:
    """What "not shown better" can and cannot say: the smallest mean gain the test could see."""
    n, k = entry["n_seeds"], entry["n_comparisons"]
    mde = min_detectable_effect(n, k)
    if math.isinf(mde):
        return f"With {n} seeds and p x {k}, no outcome could have been significant."
    sd = float(np.std(entry["seed_means"], ddof=1))
    return (
        f"That is not a finding that they are equal: with {n} seeds and p x {k} the test finds a mean gain 4 times "
        f"in 5 only from {mde:.2f} per-seed SDs ({mde * sd:.2f} dB at the SD of the closest method's seeds, "
        f"{sd:.2f} dB)."
    )


def verdict_line(study: Study) -> str:
    """The page's verdict in one line, per engine: the methods the across-scene test finds better
    (or worse) than uniform, else that none is shown better, with the largest mean gain."""
    parts = []
    for engine in study.engines:
        regime = study.regimes.get(engine, {})
        if not regime:
            parts.append(f"engine {engine}: no paired results yet")
            continue
        better = sorted((e["difference"], m) for m, e in regime.items() if e["significant"] and e["better"])
        worse = [m for m, e in regime.items() if e["significant"] and not e["better"]]
        best, entry = max(regime.items(), key=lambda kv: kv[1]["difference"])
        if better:
            top = regime[better[-1][1]]
            said = (
                f"{better[-1][1]} beats uniform ({top['difference']:+.2f} dB mean, p x {top['n_comparisons']} = "
                f"{p_value(top['p_bonferroni'])})"
            )
        else:
            said = (
                f"no method is shown better than uniform (largest mean gain {best} {entry['difference']:+.2f} dB, "
                f"p x {entry['n_comparisons']} = {p_value(entry['p_bonferroni'])})"
            )
        if worse:
            said += f"; worse than uniform: {', '.join(worse)}"
        cells = [c for c in study.cells if c.engine == engine and c.scene not in study.held_back]
        if not all(c.complete for c in cells) or any(m.endswith(f", {engine}") for m in study.missing_cells):
            said += " (provisional: cells incomplete)"
        parts.append(f"engine {engine}: {said}")
    return "**Verdict, per engine across its scenes:** " + ("; ".join(parts) or "no runs yet") + "."


# ----------------------------------------------------------------------------- dead runs


def dead_runs(study: Study) -> set[tuple[str, str, str, int]]:
    """(engine, scene, method, seed) of every run flagged as rendering background only."""
    return {(r["engine"], r["scene"], r["method"], r["seed"]) for r in study.table["runs"] if r.get("empty")}


def dead_per_cell(study: Study, engine: str, scenes: Iterable[str]) -> str:
    """Per scene of `engine`, the dead runs' count and which (method, seed), in words."""
    dead = dead_runs(study)
    parts = []
    for scene in scenes:
        found = sorted((m, s) for e, sc, m, s in dead if e == engine and sc == scene)
        parts.append(f"{scene} {len(found)}" + (f" ({', '.join(f'{m} seed {s}' for m, s in found)})" if found else ""))
    return "; ".join(parts)


def _differences(cell: Cell, method: str, reference: str, drop: set | None = None) -> dict[int, float]:
    if method not in cell.methods or reference not in cell.methods:
        return {}
    found = cell.methods[method].differences(cell.methods[reference])
    if drop is None:
        return found
    return {
        s: d
        for s, d in found.items()
        if (cell.engine, cell.scene, method, s) not in drop and (cell.engine, cell.scene, reference, s) not in drop
    }


def regime_test(cells: list[Cell], method: str, reference: str, k: int, drop: set | None = None) -> dict:
    """The per-regime test: each seed's mean over `cells` of (method - reference), then the exact
    sign-flip test, x k; with `drop` (dead runs), the pairs holding one are left out and a seed's
    mean is over the scenes left to it. Adds "low"/"high" (bootstrap CI of the mean)."""
    per_cell = {c.scene: _differences(c, method, reference, drop) for c in cells}
    if drop is None:
        result = seed_level_comparison(per_cell, k, alpha=ALPHA)
    else:
        seeds = sorted({s for d in per_cell.values() for s in d})
        means = {s: float(np.mean([d[s] for d in per_cell.values() if s in d])) for s in seeds}
        result = seed_level_comparison({"mean": means}, k, alpha=ALPHA)
    result["low"], result["high"] = mean_interval(result["seed_means"]) if result["n_seeds"] else (math.nan,) * 2
    return result


def cell_test(cell: Cell | None, method: str, k: int, drop: set | None = None) -> dict | None:
    """The per-cell test (two-sided Wilcoxon signed-rank, x k, median with bootstrap CI) of
    method - uniform, without the pairs holding a dead run when `drop` is given."""
    if cell is None:
        return None
    d = _differences(cell, method, REFERENCE, drop)
    if not d:
        return None
    result = paired_comparison(list(d.values()), [0.0] * len(d), k, alpha=ALPHA, seed=BOOTSTRAP_SEED)
    result["values"] = list(d.values())
    return result


def judged(entry: dict | None) -> str:
    """A planned directional claim's verdict from its test on complete cells."""
    if entry is None or not entry.get("n_seeds", entry.get("n_pairs", 0)):
        return "not supported"
    if entry["significant"]:
        return "holds" if entry["better"] else "contradicted"
    return "not supported"


def says(name: str, entry: dict | None, test: str = "sign-flip") -> str:
    """ "ours - uniform: +0.41 dB [−0.10, 0.93], 7/10 seeds better, sign-flip p x 5 = 0.410"."""
    if entry is None or not entry.get("n_seeds", entry.get("n_pairs", 0)):
        return f"{name}: no pairs"
    n = entry.get("n_seeds", entry.get("n_pairs"))
    low, high = entry["low"], entry["high"]
    ci = "" if math.isnan(low) else f" [{low:+.2f}, {high:+.2f}]"
    statistic = "mean" if test == "sign-flip" else "median"
    return (
        f"{name}: {statistic} {entry['difference']:+.2f} dB{ci}, {entry['wins']}/{n} seeds better, "
        f"{test} p x {entry['n_comparisons']} = {p_value(entry['p_bonferroni'])}"
    )


# ----------------------------------------------------------------------------- the GPU study


def gpu_runs(study: Study, engine: str, scenes: Iterable[str]) -> tuple[int, int]:
    """(runs in the table, runs planned) of the plan's methods and trials on `scenes`."""
    scenes = set(scenes)
    done = {
        (r["scene"], r["method"], r["trial"])
        for r in study.table["runs"]
        if r["engine"] == engine and r["scene"] in scenes and r["method"] in GPU_METHODS and r["trial"] < GPU_TRIALS
    }
    return len(done), len(scenes) * len(GPU_METHODS) * GPU_TRIALS


def _gpu_cells(study: Study, engine: str) -> list[Cell]:
    return [c for c in study.cells if c.engine == engine and c.scene in GPU_SCENES]


def verdict_row(
    name: str, claim: str, test: str, verdict: str, evidence: list[str], floor: str, dead: str
) -> list[str]:
    """One row of a plan's verdict table: the hypothesis, its claim and test, the verdict, the
    evidence, the smallest effect it could have seen and the line without dead runs."""
    return [name, claim, test, f"**{verdict}**", "; ".join(evidence), floor, dead]


def _partial(study: Study, engine: str, scenes) -> str | None:
    n, m = gpu_runs(study, engine, scenes)
    return None if n == m else f"partial: {n} of {m} runs"


def all_hold(verdicts: list[str]) -> str:
    """A claim made of several tests: contradicted if one is, holds if every one does."""
    if "contradicted" in verdicts:
        return "contradicted"
    return "holds" if verdicts and set(verdicts) == {"holds"} else "not supported"


def touches(dead: set, engine: str, scenes: Iterable[str], methods: Iterable[str]) -> int:
    """How many dead runs of `engine` lie in the pairs of `methods` on `scenes`."""
    scenes, methods = set(scenes), set(methods)
    return sum(e == engine and sc in scenes and m in methods for e, sc, m, _ in dead)


def sensitivity(n_dead: int, verdict: str, lines: list[str]) -> str:
    """The line without dead runs: the same tests without the pairs that hold one."""
    if not n_dead:
        return "no dead run in these pairs"
    return f"without the {n_dead} dead run(s)' pairs: {verdict}; " + "; ".join(lines)


def g_family(study: Study, engine: str, drop: set | None = None) -> dict[str, dict]:
    """Every method of the plan against uniform by the per-regime test on the four scenes, x5."""
    cells = _gpu_cells(study, engine)
    return {m: regime_test(cells, m, REFERENCE, REGIME_K, drop) for m in GPU_METHODS if m != REFERENCE}


def gpu_rows(study: Study, engine: str) -> list[list[str]]:
    """G1-G4 on `engine`, each with its test, verdict, evidence, the smallest effect it could have
    seen (beside "not supported") and its line without dead runs."""
    dead = dead_runs(study)
    partial = _partial(study, engine, GPU_SCENES)
    cells = _gpu_cells(study, engine)
    family, cleaned = g_family(study, engine), g_family(study, engine, dead)

    def dead_in(*methods: str) -> int:
        return touches(dead, engine, GPU_SCENES, methods)

    g1, g1_clean = family["ours"], cleaned["ours"]
    verdict = partial or judged(g1)
    g1_row = verdict_row(
        "G1",
        "ours beats uniform in PSNR on the paper engine (the paper's claim at its scale)",
        "per-regime sign-flip, x5",
        verdict,
        [says("ours - uniform", g1)],
        detectable(g1["seed_means"], REGIME_K) if verdict == "not supported" else "",
        sensitivity(dead_in("ours", REFERENCE), judged(g1_clean), [says("ours - uniform", g1_clean)]),
    )

    g2 = {b: regime_test(cells, "ours", b, len(G2_BASELINES)) for b in G2_BASELINES}
    g2_clean = {b: regime_test(cells, "ours", b, len(G2_BASELINES), dead) for b in G2_BASELINES}
    verdict = partial or all_hold([judged(t) for t in g2.values()])
    floor = "; ".join(f"ours - {b}: {detectable(t['seed_means'], len(G2_BASELINES))}" for b, t in g2.items())
    g2_row = verdict_row(
        "G2",
        "ours beats both baselines it was compared with, entropy-sampling and fisherrf",
        "two per-regime sign-flip tests, x2",
        verdict,
        [says(f"ours - {b}", t) for b, t in g2.items()],
        floor if verdict == "not supported" else "",
        sensitivity(
            dead_in("ours", *G2_BASELINES),
            all_hold([judged(t) for t in g2_clean.values()]),
            [says(f"ours - {b}", t) for b, t in g2_clean.items()],
        ),
    )

    better = [m for m, t in family.items() if t["significant"] and t["better"]]
    verdict = partial or ("contradicted" if better else "holds")
    floor = ""
    if verdict == "holds":
        spreads = [float(np.std(t["seed_means"], ddof=1)) for t in family.values() if t["n_seeds"] > 1]
        mde = min_detectable_effect(g1["n_seeds"], REGIME_K)
        floor = (
            "holds only as the plan defines it (no method shown better); not evidence that none is: "
            + detectable(g1["seed_means"], REGIME_K)
            + (
                f"; over the five methods {mde * min(spreads):.2f}-{mde * max(spreads):.2f} dB"
                if spreads and math.isfinite(mde)
                else ""
            )
        )
    clean_better = [m for m, t in cleaned.items() if t["significant"] and t["better"]]
    g3_row = verdict_row(
        "G3",
        "no method beats uniform (the real-scene finding at the paper's scale)",
        "per-regime sign-flip, x5, each of the five methods",
        verdict,
        [says(f"{m} - uniform", t) for m, t in family.items()],
        floor,
        sensitivity(
            dead_in(*GPU_METHODS),
            "contradicted" if clean_better else "holds",
            [says(f"{m} - uniform", t) for m, t in cleaned.items()],
        ),
    )
    return [g1_row, g2_row, g3_row, _g4(study, engine, partial, better, dead)]


def _g4(study: Study, engine: str, partial: str | None, better: list[str], dead: set) -> list[str]:
    claim = f"every method G1's family finds better than uniform also beats it on the held-back {GPU_HELD_BACK}"
    test = "per-cell Wilcoxon signed-rank, x the methods so found"
    if partial:
        return verdict_row("G4", claim, test, partial, ["G1's family is not judged yet"], "", "")
    if not better:
        return verdict_row("G4", claim, test, "not applicable", ["no method was found better than uniform"], "", "")
    held_partial = _partial(study, engine, (GPU_HELD_BACK,))
    return held_back_row("G4", claim, test, study, engine, GPU_HELD_BACK, better, held_partial, dead)


def gpu_engines(study: Study) -> list[str]:
    """The engines the G hypotheses are judged on: every engine the table holds (the GPU study runs
    one, `paper`; its CPU smoke test another, judged the same way)."""
    return list(study.engines)


__all__ = [
    "floor_text",
    "verdict_line",
    "GPU_ENGINES",
    "GPU_HELD_BACK",
    "GPU_METHODS",
    "GPU_SCENES",
    "dead_per_cell",
    "dead_runs",
    "detectable",
    "gpu_rows",
    "mean_interval",
    "min_detectable_effect",
    "regime_test",
]


def held_back_row(
    name: str, claim: str, test: str, study: Study, engine: str, scene: str, better: list[str], partial, dead: set
) -> list[str]:
    """The replication row of a plan (G4, Q4): each method its family found better than uniform
    against uniform in the held-back `scene`'s cell (Wilcoxon signed-rank, x the methods so found),
    holding only if every one holds; `partial` when that cell is incomplete; its sensitivity line
    without the `dead` runs."""
    cell = next((c for c in study.cells if c.engine == engine and c.scene == scene), None)
    tests = {m: cell_test(cell, m, len(better)) for m in better}
    clean = {m: cell_test(cell, m, len(better), dead) for m in better}
    verdict = partial or all_hold([judged(t) for t in tests.values()])
    floor = "; ".join(f"{m}: {detectable(t['values'], len(better))}" for m, t in tests.items() if t)
    return verdict_row(
        name,
        claim,
        test,
        verdict,
        [f"{scene}, " + says(f"{m} - uniform", t, "Wilcoxon") for m, t in tests.items()],
        floor if verdict == "not supported" else "",
        sensitivity(
            touches(dead, engine, (scene,), (*better, REFERENCE)),
            all_hold([judged(t) for t in clean.values()]),
            [says(f"{m} - uniform", t, "Wilcoxon") for m, t in clean.items()],
        ),
    )
