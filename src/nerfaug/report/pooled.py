"""The study's figure of paired differences: each method minus a reference on the trials that share
a seed in a (scene, engine) cell (the same initial views and the same NeRF up to the step where
views are added), one dot per pair, coloured by cell. The tests on those pairs are
`nerfaug.report.study`'s: per cell, and per regime with one value per seed.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from nerfaug.metrics import HIGHER_IS_BETTER, METRIC_LABELS
from nerfaug.plotting import new_figure, save_figure
from nerfaug.report.collect import Results


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


__all__ = ["paired_values", "plot_paired_differences"]
