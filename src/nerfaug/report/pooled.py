"""A study's secondary analysis: each method against a reference over all (scene, engine) cells at
once, on paired trials.

In a study, trial k of every method in a cell uses the same seed, so it starts from the same
initial views and trains the same NeRF up to the step where views are added; the only difference
within a pair is the selection. Pooling the pairs of every cell gives a test of "does this method
beat the reference on average over the scenes and engines run" with far more power than the
per-cell Mann-Whitney test at 5 trials (whose smallest p after Bonferroni x6 is 0.048). It answers a
different question from the per-cell test and is reported beside it, not in its place.
"""

from __future__ import annotations

from collections.abc import Iterable

from nerfaug.metrics import HIGHER_IS_BETTER, METRICS
from nerfaug.report.collect import Results
from nerfaug.statistics import paired_comparison


def paired_values(
    results: Results, scene: str, method: str, reference: str, metric: str
) -> tuple[list[float], list[float], list[int]]:
    """`method`'s and `reference`'s values of `metric` on the trials both have, matched by trial.

    Returns:
        (method's values, reference's values, trials), in trial order.
    """
    found = {r.trial: v for r in results.runs_of(scene, method) if (v := r.metric(metric)) is not None}
    reference_found = {r.trial: v for r in results.runs_of(scene, reference) if (v := r.metric(metric)) is not None}
    trials = sorted(set(found) & set(reference_found))
    return [found[t] for t in trials], [reference_found[t] for t in trials], trials


def pooled_comparisons(
    cells: Iterable[tuple[Results, str]],
    methods: list[str],
    reference: str,
    alpha: float = 0.05,
    seed: int = 0,
) -> dict[str, dict[str, dict]]:
    """Every method (but the reference) against the reference, pairs pooled over `cells`.

    Args:
        cells: (an engine's results, scene) per cell.
        methods: the methods to compare, in display order; the Bonferroni factor is the number
            of them other than the reference.
        reference: the method compared against (uniform).
        alpha, seed: significance level after the correction; seed of the bootstrap CI.

    Returns:
        method -> metric -> `statistics.paired_comparison` of its pooled pairs, with "cells" (the
        number of cells that gave at least one pair) added; a method or metric without pairs is
        left out.
    """
    cells = list(cells)
    compared = [m for m in methods if m != reference]
    found: dict[str, dict[str, dict]] = {}
    for method in compared:
        for metric in METRICS:
            xs, ys, n_cells = [], [], 0
            for results, scene in cells:
                x, y, _ = paired_values(results, scene, method, reference, metric)
                xs += x
                ys += y
                n_cells += bool(x)
            if xs:
                entry = paired_comparison(
                    xs, ys, max(1, len(compared)), HIGHER_IS_BETTER[metric], alpha=alpha, seed=seed
                )
                found.setdefault(method, {})[metric] = {**entry, "cells": n_cells}
    return found


__all__ = ["paired_values", "pooled_comparisons"]
