"""Statistics over trials: medians and interquartile ranges, and Mann-Whitney U tests with a
Bonferroni correction, as the paper reports them (Sec. IV).

Quartiles use numpy's default linear interpolation (`np.percentile(..., method="linear")`, type 7
of Hyndman and Fan); IQR = Q3 - Q1. Relative changes are fractions (0.667 means +66.7 %).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from scipy import stats

from nerfaug.metrics import HIGHER_IS_BETTER

# Above these sizes the exact tests get slow; the normal approximation is good there anyway.
_EXACT_MAX_N = 50
_PERMUTATION_MAX_ARRANGEMENTS = 20_000


def _values(values: Iterable[float], what: str) -> np.ndarray:
    array = np.asarray(list(values), dtype=np.float64).reshape(-1)
    if array.size == 0:
        raise ValueError(f"{what}: no values")
    if np.isnan(array).any():
        raise ValueError(f"{what}: contains NaN")
    return array


def summarise(values: Iterable[float]) -> dict:
    """Median, quartiles (linear interpolation), IQR = q3 - q1, mean, min and max.

    Args:
        values: one number per trial (at least one, no NaN).

    Returns:
        dict with n (int) and median, q1, q3, iqr, mean, min, max (floats).

    Example:
        >>> summarise([1, 2, 3, 4])["iqr"]  # q1 = 1.75, q3 = 3.25
        1.5
    """
    x = _values(values, "summarise")
    q1, median, q3 = np.percentile(x, [25, 50, 75], method="linear")
    return {
        "n": int(x.size),
        "median": float(median),
        "q1": float(q1),
        "q3": float(q3),
        "iqr": float(q3 - q1),
        "mean": float(x.mean()),
        "min": float(x.min()),
        "max": float(x.max()),
    }


def _relative(new: float, reference: float) -> float:
    """(new - reference) / |reference|; nan when the reference is 0."""
    if reference == 0:
        return math.nan
    return (new - reference) / abs(reference)


def _test_method(x: np.ndarray, y: np.ndarray):
    """The Mann-Whitney method for these samples and its name.

    Without ties: the exact distribution of U (up to 50 values per sample). With ties scipy's
    "exact" ignores them, so: an exact permutation test while the arrangements are few enough to
    enumerate, else the normal approximation with tie and continuity corrections.
    """
    tied = np.unique(np.concatenate([x, y])).size < x.size + y.size
    if not tied and max(x.size, y.size) <= _EXACT_MAX_N:
        return "exact", "exact"
    # scipy's permutation test needs two values per sample; one trial (a smoke run) falls through.
    if tied and min(x.size, y.size) >= 2 and math.comb(x.size + y.size, x.size) <= _PERMUTATION_MAX_ARRANGEMENTS:
        return stats.PermutationMethod(n_resamples=np.inf), "permutation (exact, ties)"
    return "asymptotic", "asymptotic (tie and continuity corrected)"


def min_attainable_p(n1: int, n2: int) -> float:
    """The smallest two-sided Mann-Whitney p-value samples of these sizes can give (complete
    separation, no ties): 2 / C(n1 + n2, n1) for the exact test, capped at 1.

    Example:
        >>> round(min_attainable_p(2, 2), 3)
        0.333
    """
    if n1 < 1 or n2 < 1:
        return 1.0
    method = "exact" if max(n1, n2) <= _EXACT_MAX_N else "asymptotic"
    return float(stats.mannwhitneyu(np.arange(n1), np.arange(n1, n1 + n2), method=method).pvalue)


def min_attainable_paired_p(n_pairs: int) -> float:
    """The smallest two-sided p the exact Wilcoxon signed-rank test can give on `n_pairs` pairs:
    every difference of one sign, 2 / 2^n (capped at 1).

    Example:
        >>> min_attainable_paired_p(10)
        0.001953125
    """
    return min(1.0, 2.0 / 2.0 ** max(0, n_pairs))


def compare(
    ours: Iterable[float],
    baseline: Iterable[float],
    n_comparisons: int = 3,
    higher_is_better: bool = True,
    alpha: float = 0.05,
) -> dict:
    """Compare our trials with a baseline's: change of the median, change of the spread, and a
    two-sided Mann-Whitney U test with a Bonferroni correction.

    Args:
        ours, baseline: one value per trial (e.g. each trial's mean test PSNR).
        n_comparisons: the number of tests the correction accounts for (paper: 3, ours against
            each of three baselines).
        higher_is_better: direction of the metric (False for LPIPS); only used for `better`.
        alpha: significance level after the correction.

    Returns:
        dict with
        - n_ours, n_baseline, median_ours, median_baseline, iqr_ours, iqr_baseline;
        - median_change: (median_ours - median_baseline) / |median_baseline|, the paper's
          "+66.7 % median PSNR" is 0.667 (nan if the baseline median is 0);
        - iqr_reduction: (iqr_baseline - iqr_ours) / iqr_baseline, positive when ours is tighter
          (nan if the baseline IQR is 0);
        - better: our median is better than the baseline's in the metric's direction;
        - u_statistic: U of `ours`; prob_ours_greater: U / (n_ours n_baseline), the probability
          that a trial of ours exceeds one of the baseline (ties count half);
        - p_value (two-sided), test_method, p_bonferroni = min(1, p n_comparisons),
          significant = p_bonferroni < alpha;
        - min_attainable_p: the smallest p these sample sizes allow (`min_attainable_p`);
          too_small: even complete separation would not be significant after the correction;
          note: a sentence saying so when too_small, else "".
    """
    x, y = _values(ours, "ours"), _values(baseline, "baseline")
    if n_comparisons < 1:
        raise ValueError(f"n_comparisons must be at least 1, got {n_comparisons}")
    summary_x, summary_y = summarise(x), summarise(y)
    method, method_name = _test_method(x, y)
    test = stats.mannwhitneyu(x, y, alternative="two-sided", method=method)
    p = float(test.pvalue)
    p_bonferroni = min(1.0, p * n_comparisons)
    min_p = min_attainable_p(x.size, y.size)
    too_small = min(1.0, min_p * n_comparisons) >= alpha
    note = ""
    if too_small:
        note = (
            f"n={x.size} vs n={y.size}: the smallest two-sided p this test can give is {min_p:.3g} "
            f"({min(1.0, min_p * n_comparisons):.3g} after Bonferroni x{n_comparisons}), so it "
            f"cannot reach p < {alpha:g} whatever the data"
        )
    difference = summary_x["median"] - summary_y["median"]
    return {
        "n_ours": int(x.size),
        "n_baseline": int(y.size),
        "median_ours": summary_x["median"],
        "median_baseline": summary_y["median"],
        "median_change": _relative(summary_x["median"], summary_y["median"]),
        "iqr_ours": summary_x["iqr"],
        "iqr_baseline": summary_y["iqr"],
        "iqr_reduction": -_relative(summary_x["iqr"], summary_y["iqr"]),
        "better": bool(difference > 0 if higher_is_better else difference < 0),
        "u_statistic": float(test.statistic),
        "prob_ours_greater": float(test.statistic) / (x.size * y.size),
        "p_value": p,
        "test_method": method_name,
        "n_comparisons": int(n_comparisons),
        "p_bonferroni": p_bonferroni,
        "alpha": float(alpha),
        "significant": bool(p_bonferroni < alpha),
        "min_attainable_p": min_p,
        "too_small": bool(too_small),
        "note": note,
    }


_COMPARISON_KEYS = (
    "median_change",
    "iqr_reduction",
    "better",
    "p_value",
    "p_bonferroni",
    "significant",
    "too_small",
    "note",
)


def summary_table(
    results: Iterable[Mapping],
    metric: str,
    ours: str,
    baselines: Sequence[str],
    n_comparisons: int | None = None,
    higher_is_better: bool | None = None,
    alpha: float = 0.05,
) -> list[dict]:
    """One row per (scene, method): the metric's median and IQR over trials, and for each baseline
    how `ours` compares with it on that scene.

    Args:
        results: run records, e.g. {"scene": "lego", "method": "ours", "trial": 0, "psnr": 20.1,
            "ssim": 0.84, "lpips": 0.13}. Records whose metric is missing, None or NaN are counted
            in `n_missing` and left out of the statistics.
        metric: the key to summarise ("psnr", "ssim", "lpips", ...).
        ours: the method compared against the others.
        baselines: the methods `ours` is tested against, in display order; methods in `results`
            that are neither come after them with summaries only.
        n_comparisons: Bonferroni factor; default len(baselines).
        higher_is_better: default from the metric's name (psnr, ssim: True; lpips: False).
        alpha: significance level after the correction.

    Returns:
        Rows in order of scene (first appearance), then ours, the baselines, the other methods.
        Each row: scene, method, metric, role ("ours", "baseline" or "other"), n, n_missing,
        median, q1, q3, iqr, mean, min, max (None when n = 0), and the comparison of ours with
        this row's method (see `compare`): median_change, iqr_reduction, better, p_value,
        p_bonferroni, significant, too_small, note; None on the row of ours, of other methods,
        and where either side has no values.

    Raises:
        ValueError: two records share (scene, method, trial), or the metric's direction is unknown.
    """
    if higher_is_better is None:
        if metric.lower() not in HIGHER_IS_BETTER:
            raise ValueError(f"unknown direction for metric {metric!r}: pass higher_is_better")
        higher_is_better = HIGHER_IS_BETTER[metric.lower()]
    if n_comparisons is None:
        n_comparisons = max(1, len(baselines))

    groups: dict[tuple[str, str], list[float]] = {}
    missing: dict[tuple[str, str], int] = {}
    seen_trials = set()
    for record in results:
        key = (str(record["scene"]), str(record["method"]))
        if "trial" in record:
            trial = (*key, record["trial"])
            if trial in seen_trials:
                raise ValueError(f"two records for scene {key[0]!r}, method {key[1]!r}, trial {trial[2]!r}")
            seen_trials.add(trial)
        groups.setdefault(key, [])
        missing.setdefault(key, 0)
        value = record.get(metric)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            missing[key] += 1
        else:
            groups[key].append(float(value))

    scenes = list(dict.fromkeys(scene for scene, _ in groups))
    methods_seen = list(dict.fromkeys(method for _, method in groups))
    order = [ours, *baselines] + [m for m in methods_seen if m != ours and m not in baselines]

    rows = []
    for scene in scenes:
        ours_values = groups.get((scene, ours), [])
        for method in order:
            if (scene, method) not in groups:
                continue
            values = groups[(scene, method)]
            role = "ours" if method == ours else "baseline" if method in baselines else "other"
            row = {
                "scene": scene,
                "method": method,
                "metric": metric,
                "role": role,
                "n": len(values),
                "n_missing": missing[(scene, method)],
            }
            if values:
                row.update({k: v for k, v in summarise(values).items() if k != "n"})
            else:
                row.update(dict.fromkeys(("median", "q1", "q3", "iqr", "mean", "min", "max")))
            comparison = None
            if role == "baseline" and values and ours_values:
                comparison = compare(ours_values, values, n_comparisons, higher_is_better, alpha)
            for key in _COMPARISON_KEYS:
                row[key] = None if comparison is None else comparison[key]
            rows.append(row)
    return rows


def _median_difference(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.median(x, axis=axis) - np.median(y, axis=axis)


def bootstrap_median_difference(
    x: Iterable[float],
    y: Iterable[float],
    confidence: float = 0.95,
    n_resamples: int = 9999,
    seed: int = 0,
) -> dict:
    """median(x) - median(y) for two independent samples, with a percentile bootstrap confidence
    interval (`scipy.stats.bootstrap`, each sample resampled on its own, seeded).

    The percentile interval rather than BCa: with 5 trials the median's bootstrap distribution
    takes few distinct values, where BCa's acceleration estimate is unstable or undefined.

    Args:
        x, y: one value per trial (e.g. a method's and uniform's test PSNRs).
        confidence: the interval's coverage.
        n_resamples: bootstrap resamples.
        seed: seeds numpy's Generator, so the interval is reproducible.

    Returns:
        dict with difference, low, high (low and high nan when a sample has fewer than 2 values),
        confidence, n_resamples, method ("percentile").
    """
    x, y = _values(x, "x"), _values(y, "y")
    low = high = math.nan
    if x.size >= 2 and y.size >= 2:
        result = stats.bootstrap(
            (x, y),
            _median_difference,
            paired=False,
            vectorized=True,
            confidence_level=confidence,
            n_resamples=n_resamples,
            method="percentile",
            rng=np.random.default_rng(seed),
        )
        low, high = float(result.confidence_interval.low), float(result.confidence_interval.high)
    return {
        "difference": float(np.median(x) - np.median(y)),
        "low": low,
        "high": high,
        "confidence": float(confidence),
        "n_resamples": int(n_resamples),
        "method": "percentile",
    }


def paired_comparison(
    x: Iterable[float],
    y: Iterable[float],
    n_comparisons: int = 1,
    higher_is_better: bool = True,
    alpha: float = 0.05,
    confidence: float = 0.95,
    n_resamples: int = 9999,
    seed: int = 0,
) -> dict:
    """Compare two methods on paired trials: x[i] and y[i] share everything but the method (in the
    study: the same scene, engine and seed, hence the same initial views and the same NeRF up to
    the step where views are added), so d = x - y isolates the method.

    Two-sided Wilcoxon signed-rank test on d (`scipy.stats.wilcoxon`, zero differences dropped;
    exact for up to 50 pairs without ties, else scipy's "auto" rule), Bonferroni-corrected, and
    the median of d with a percentile bootstrap CI (pairs resampled together, seeded).

    Args:
        x, y: one value per pair, in the same order (at least one pair, no NaN).
        n_comparisons: Bonferroni factor.
        higher_is_better: direction of the metric; only used for `better`.
        alpha: significance level after the correction.
        confidence, n_resamples, seed: of the bootstrap CI.

    Returns:
        dict with n_pairs; wins, ties, losses (pairs where x is better, equal, worse, in the
        metric's direction); difference (median of d), low, high (its CI, nan for one pair);
        p_value (1.0 when every difference is zero), test_method, n_comparisons, p_bonferroni,
        significant (p_bonferroni < alpha), better (median of d favours x).

    Example:
        >>> paired_comparison([2.0, 3.0, 4.0], [1.0, 1.0, 1.0])["wins"]
        3
    """
    x, y = _values(x, "x"), _values(y, "y")
    if x.size != y.size:
        raise ValueError(f"paired samples differ in length: {x.size} and {y.size}")
    if n_comparisons < 1:
        raise ValueError(f"n_comparisons must be at least 1, got {n_comparisons}")
    d = x - y
    sign = 1.0 if higher_is_better else -1.0
    nonzero = d[d != 0]
    if nonzero.size == 0:
        p, method = 1.0, "no non-zero difference"
    else:
        method = "exact" if nonzero.size <= _EXACT_MAX_N and np.unique(np.abs(nonzero)).size == nonzero.size else "auto"
        p = float(stats.wilcoxon(nonzero, alternative="two-sided", method=method).pvalue)
    low = high = math.nan
    if d.size >= 2:
        interval = stats.bootstrap(
            (d,),
            np.median,
            vectorized=True,
            confidence_level=confidence,
            n_resamples=n_resamples,
            method="percentile",
            rng=np.random.default_rng(seed),
        ).confidence_interval
        low, high = float(interval.low), float(interval.high)
    difference = float(np.median(d))
    p_bonferroni = min(1.0, p * n_comparisons)
    return {
        "n_pairs": int(d.size),
        "wins": int((sign * d > 0).sum()),
        "ties": int((d == 0).sum()),
        "losses": int((sign * d < 0).sum()),
        "difference": difference,
        "low": low,
        "high": high,
        "confidence": float(confidence),
        "p_value": p,
        "test_method": f"Wilcoxon signed-rank ({method})",
        "n_comparisons": int(n_comparisons),
        "p_bonferroni": p_bonferroni,
        "alpha": float(alpha),
        "significant": bool(p_bonferroni < alpha),
        "better": bool(sign * difference > 0),
    }


def sign_flip_p(values: Iterable[float]) -> float:
    """Two-sided p of the sign-flip permutation test that the values are centred on zero: under
    the null each value's sign is a fair coin, so the statistic (the mean) is compared with its
    value under every one of the 2^n sign patterns (`scipy.stats.permutation_test`, one sample,
    permutation_type "samples", enumerated exactly up to 2^16 patterns, else 100k random ones).

    Args:
        values: one number per independent unit (in the study: per seed), at least one, no NaN.

    Example:
        >>> sign_flip_p([1.0, 2.0, 3.0])  # 2 of the 8 patterns reach |mean| = 2
        0.25
    """
    x = _values(values, "sign_flip_p")
    if not np.any(x) or x.size < 2:  # one value: both of its sign patterns reach |mean|, so p = 1
        return 1.0
    exact = x.size <= 16
    result = stats.permutation_test(
        (x,),
        lambda sample, axis: np.mean(sample, axis=axis),
        permutation_type="samples",
        vectorized=True,
        n_resamples=np.inf if exact else 100_000,
        alternative="two-sided",
        rng=np.random.default_rng(0),
    )
    return float(min(1.0, result.pvalue))


def seed_level_comparison(
    differences: Mapping[str, Mapping[int, float]],
    n_comparisons: int = 1,
    higher_is_better: bool = True,
    alpha: float = 0.05,
) -> dict:
    """Across cells, one value per seed: the paired differences of a method to a reference in
    several cells (scene, engine) that share their seeds, reduced to each seed's mean over the
    cells, then tested on those per-seed values. The cells' pairs are not independent units (trial
    k of every cell shares the seed, hence uniform's picks and the NeRF's initialisation), so
    pooling them would overstate the evidence; the seeds are the independent units.

    Args:
        differences: cell -> seed -> (method - reference) on that seed's trial. Only seeds
            present in every cell are used.
        n_comparisons: Bonferroni factor (methods compared with the reference).
        higher_is_better: direction of the metric; only used for `better` and wins.
        alpha: significance level after the correction.

    Returns:
        dict with n_seeds, n_cells, seeds; seed_means (per seed, in seed order); difference (the
        mean over seeds of the seed means), median (their median); wins, ties, losses (seeds whose
        mean favours the method, is zero, favours the reference); p_value (`sign_flip_p`, the
        decision), p_wilcoxon (two-sided signed-rank on the seed means, beside it), n_comparisons,
        p_bonferroni, significant, better. Empty differences give n_seeds 0 and p_value 1.

    Example:
        >>> r = seed_level_comparison({"a": {0: 1.0, 1: 2.0}, "b": {0: 3.0, 1: 0.0}})
        >>> r["seed_means"], r["difference"]
        ([2.0, 1.0], 1.5)
    """
    if n_comparisons < 1:
        raise ValueError(f"n_comparisons must be at least 1, got {n_comparisons}")
    cells = [dict(d) for d in differences.values() if d]
    seeds = sorted(set.intersection(*(set(d) for d in cells))) if cells else []
    sign = 1.0 if higher_is_better else -1.0
    if not seeds:
        return {
            "n_seeds": 0,
            "n_cells": len(cells),
            "seeds": [],
            "seed_means": [],
            "p_value": 1.0,
            "p_bonferroni": 1.0,
            "significant": False,
            "better": False,
            "n_comparisons": int(n_comparisons),
        }
    means = np.array([np.mean([d[seed] for d in cells]) for seed in seeds], dtype=np.float64)
    if np.isnan(means).any():
        raise ValueError("seed_level_comparison: contains NaN")
    p = sign_flip_p(means)
    nonzero = means[means != 0]
    p_wilcoxon = float(stats.wilcoxon(nonzero, alternative="two-sided").pvalue) if nonzero.size else 1.0
    p_bonferroni = min(1.0, p * n_comparisons)
    difference = float(means.mean())
    return {
        "n_seeds": len(seeds),
        "n_cells": len(cells),
        "seeds": seeds,
        "seed_means": [float(m) for m in means],
        "difference": difference,
        "median": float(np.median(means)),
        "wins": int((sign * means > 0).sum()),
        "ties": int((means == 0).sum()),
        "losses": int((sign * means < 0).sum()),
        "p_value": p,
        "p_wilcoxon": p_wilcoxon,
        "test_method": "sign-flip permutation test on the per-seed mean (exact)",
        "n_comparisons": int(n_comparisons),
        "p_bonferroni": p_bonferroni,
        "alpha": float(alpha),
        "significant": bool(p_bonferroni < alpha),
        "better": bool(sign * difference > 0),
    }


def _format_cell(value, spec: str | None) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return "nan"
        return format(float(value), spec or ".4g")
    if isinstance(value, (int, np.integer)) and spec:
        return format(int(value), spec)
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(
    rows: Sequence[Mapping | Sequence],
    columns: Sequence[str | int | tuple],
) -> str:
    """A GitHub-flavoured Markdown table.

    Args:
        rows: dicts (e.g. from `summary_table`), or sequences addressed by column index.
        columns: each a key (or index), a (key, header) pair, or (key, header, format spec), e.g.
            ("median_change", "vs ours", "+.1%"). Floats default to ".4g"; None is "-",
            booleans "yes"/"no".

    Returns:
        The table as a string ending in a newline.

    Example:
        >>> rows = [{"method": "ours", "median": 20.07}]
        >>> print(markdown_table(rows, ["method", ("median", "PSNR", ".2f")]), end="")
        | method | PSNR |
        |---|---|
        | ours | 20.07 |
    """
    specs = []
    for column in columns:
        if not isinstance(column, tuple):
            column = (column,)
        key, header, spec = (*column, None, None)[:3]
        specs.append((key, str(header if header is not None else key), spec))
    lines = [
        "| " + " | ".join(header for _, header, _ in specs) + " |",
        "|" + "---|" * len(specs),
    ]
    for row in rows:
        if isinstance(row, Mapping):
            cells = [row.get(key) for key, _, _ in specs]
        else:
            cells = [row[key] if key < len(row) else None for key, _, _ in specs]
        formatted = [_format_cell(cell, spec) for cell, (_, _, spec) in zip(cells, specs)]
        lines.append("| " + " | ".join(formatted) + " |")
    return "\n".join(lines) + "\n"


__all__ = [
    "HIGHER_IS_BETTER",
    "bootstrap_median_difference",
    "compare",
    "markdown_table",
    "min_attainable_p",
    "min_attainable_paired_p",
    "seed_level_comparison",
    "sign_flip_p",
    "paired_comparison",
    "summarise",
    "summary_table",
]
