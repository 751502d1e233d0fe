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
from pathlib import Path

import numpy as np

from nerfaug.metrics import HIGHER_IS_BETTER, METRIC_LABELS, METRICS
from nerfaug.plotting import new_figure, save_figure
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


def plot_paired_differences(
    cells: Iterable[tuple[Results, str, str]],
    methods: list[str],
    reference: str,
    path: Path,
    metric: str = "psnr",
) -> Path | None:
    """One column per method: each pair's difference to the reference (one dot per trial,
    coloured by cell), the median over all pairs as a bar, and zero as a dashed line.

    Args:
        cells: (an engine's results, scene, label) per cell.
        methods: in display order; the reference is left out.
        reference: the method subtracted (uniform).
        path: where the PNG goes.
        metric: the metric compared.

    Returns:
        `path`, or None when no method has a pair.
    """
    from matplotlib import colormaps

    cells = list(cells)
    compared = [m for m in methods if m != reference]
    differences = {
        (m, label): np.subtract(*paired_values(results, scene, m, reference, metric)[:2])
        for m in compared
        for results, scene, label in cells
    }
    if not any(d.size for d in differences.values()):
        return None
    palette = colormaps["tab10"].colors
    figure = new_figure(max(6.0, 1.0 * len(compared)), 4.2)
    ax = figure.subplots()
    jitter = np.random.default_rng(0)
    for i, method in enumerate(compared):
        pooled = []
        for j, (_, _, label) in enumerate(cells):
            d = differences[(method, label)]
            pooled += d.tolist()
            ax.scatter(
                i + (j - (len(cells) - 1) / 2) * 0.08 + jitter.uniform(-0.02, 0.02, d.size),
                d,
                s=16,
                color=palette[j % len(palette)],
                edgecolor="black",
                linewidth=0.3,
                label=label if i == 0 else None,
                zorder=3,
            )
        if pooled:
            ax.plot([i - 0.35, i + 0.35], [np.median(pooled)] * 2, color="black", linewidth=2)
    ax.axhline(0.0, color="0.4", linestyle="--", linewidth=1)
    ax.set_xticks(range(len(compared)), compared, rotation=20, ha="right")
    unit = " (dB)" if metric == "psnr" else ""
    better = "higher" if HIGHER_IS_BETTER[metric] else "lower"
    ax.set_ylabel(f"{METRIC_LABELS[metric]} - {reference}, same trial{unit}")
    ax.set_title(f"Paired differences to {reference} ({better} is better; bar: median over all pairs)", fontsize=10)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, title="cell", title_fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_figure(figure, path)


__all__ = ["paired_values", "plot_paired_differences", "pooled_comparisons"]
