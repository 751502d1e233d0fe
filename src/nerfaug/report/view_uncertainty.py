"""The report's uncertainty of a test view: per method, the render of the first test view, its
squared error and the uncertainty images (ray entropy, FisherRF per pixel) side by side (a figure
per scene), and how well each uncertainty ranks the error, as AUSE (a table per scene).

Read from each run's `FILES.view_uncertainty` arrays; runs made before those were written are
counted and left out, and a results folder with none of them gets no such section.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfaug.experiment.runfolder import read_view_uncertainty
from nerfaug.metrics import PIXEL_LABELS
from nerfaug.plotting import colour_bar, draw_log_image, log_range, new_figure, save_figure
from nerfaug.report.collect import Results, Run
from nerfaug.report.document import Block, Figure, Heading, Paragraph, Table, number
from nerfaug.statistics import summarise
from nerfaug.uncertainty.sparsification import ause, mean_pool

KINDS = {"entropy": "ray entropy", "fisher": "FisherRF"}
AUSE_DECIMALS = 3


def run_ause(arrays: dict[str, np.ndarray]) -> dict[str, float | None]:
    """AUSE of each uncertainty image of a run's view against its per-pixel squared error.

    The FisherRF image is smaller than the view: the error is mean-pooled to its size first
    (`mean_pool`), so each FisherRF pixel is compared with the error over its footprint.

    Args:
        arrays: `read_view_uncertainty`'s arrays: error (H, W), entropy (H, W), fisher (h, w) or absent.

    Returns:
        {"entropy": float, "fisher": float or None when the run has no FisherRF image}.
    """
    error = arrays["error"]
    fisher = arrays.get("fisher")
    return {
        "entropy": ause(arrays["entropy"], error),
        "fisher": None if fisher is None else ause(fisher, mean_pool(error, *fisher.shape)),
    }


def _views(results: Results, scene: str, method: str) -> list[tuple[Run, dict]]:
    found = [(run, read_view_uncertainty(run.folder)) for run in results.runs_of(scene, method)]
    return [(run, arrays) for run, arrays in found if arrays is not None]


def method_ause(views: list[tuple[Run, dict]]) -> dict[str, dict | None]:
    """Each kind's AUSE over a method's runs (`run_ause` of each): {"entropy": summary, "fisher":
    summary or None} with `summarise`'s median and IQR (and "n", the runs with that image). The
    table and the figure's titles both show this value."""
    scores = [run_ause(arrays) for _, arrays in views]
    summaries: dict[str, dict | None] = {}
    for kind in KINDS:
        values = [s[kind] for s in scores if s[kind] is not None]
        summaries[kind] = {**summarise(values), "n": len(values)} if values else None
    return summaries


def ause_text(summary: dict | None) -> str:
    """A method's AUSE as its panels' titles say it: the median over its runs, and how many."""
    if summary is None:
        return "AUSE n/a"
    runs = "1 run" if summary["n"] == 1 else f"median of {summary['n']} runs"
    return f"AUSE {number(summary['median'], AUSE_DECIMALS)} ({runs})"


def view_uncertainty_figure(results: Results, scene: str):
    """One row per method (its lowest trial with the arrays): the render, the squared error, the
    ray entropy and the FisherRF score per pixel, each with its colour bar and unit; the error and
    entropy on one scale for every row, FisherRF on a log scale per row clipped to its top decades
    (`log_range`; its range differs by orders of magnitude between models), drawn at the render's
    size. The entropy and FisherRF panels name the method's AUSE as the table gives it
    (`method_ause`: the median over its runs). None when no run of the scene saved the arrays."""
    rows = [(m, views) for m in results.methods if (views := _views(results, scene, m))]
    if not rows:
        return None
    error_top = max(float(np.percentile(views[0][1]["error"], 99)) for _, views in rows) or 1.0
    entropy_top = max(float(views[0][1]["entropy"].max()) for _, views in rows) or 1.0
    figure = new_figure(14.0, 3.0 * len(rows))
    figure.set_layout_engine("constrained")  # room for each panel's colour bar and its label
    axes = figure.subplots(len(rows), 4, squeeze=False)
    for r, (method, views) in enumerate(rows):
        run, arrays = views[0]
        scores = method_ause(views)
        ax = axes[r]
        ax[0].imshow(np.clip(arrays["render"], 0, 1), interpolation="nearest")
        ax[0].set_ylabel(f"{method}\n(trial {run.trial})", fontsize=9)
        image = ax[1].imshow(arrays["error"], cmap="viridis", vmin=0, vmax=error_top, interpolation="nearest")
        colour_bar(figure, image, ax[1], PIXEL_LABELS["error"])
        image = ax[2].imshow(arrays["entropy"], cmap="magma", vmin=0, vmax=entropy_top, interpolation="nearest")
        colour_bar(figure, image, ax[2], PIXEL_LABELS["entropy"])
        ax[2].set_title(f"ray entropy\n{ause_text(scores['entropy'])}", fontsize=8)
        fisher = arrays.get("fisher")
        if fisher is None:
            ax[3].text(0.5, 0.5, "FisherRF\nnot saved", ha="center", va="center", transform=ax[3].transAxes)
        else:
            draw_log_image(figure, ax[3], fisher, arrays["error"].shape, log_range(fisher), PIXEL_LABELS["fisher"])
            h, w = fisher.shape
            ax[3].set_title(f"FisherRF (computed at {w}x{h} px)\n{ause_text(scores['fisher'])}", fontsize=8)
        ax[0].set_title("render", fontsize=8)
        ax[1].set_title("squared error", fontsize=8)
        for a in ax:
            a.set_xticks([])
            a.set_yticks([])
    return figure


def plot_view_uncertainty(results: Results, scene: str, path: Path) -> Path | None:
    """`view_uncertainty_figure` written to `path`; None (nothing written) when it has nothing to draw."""
    figure = view_uncertainty_figure(results, scene)
    return None if figure is None else save_figure(figure, path)


def _cell(summary: dict | None) -> str:
    if summary is None:
        return "n/a"
    return f"{number(summary['median'], AUSE_DECIMALS)} ({number(summary['iqr'], AUSE_DECIMALS)})"


def ause_table(results: Results, scene: str) -> Table | None:
    """Per method: the runs with the arrays, and the median (IQR) over them of each AUSE."""
    rows, older = [], 0
    for method in results.methods:
        runs = results.runs_of(scene, method)
        views = _views(results, scene, method)
        older += len(runs) - len(views)
        if not views:
            continue
        summaries = method_ause(views)
        cells = [_cell(summaries[k]) for k in KINDS]
        rows.append([method, f"{len(views)} of {len(runs)}", *cells])
    if not rows:
        return None
    notes = [
        "AUSE: the area between the sparsification curve (mean squared error of the pixels left as the most "
        "uncertain are removed) and the oracle's (the largest errors removed first), both divided by their "
        "largest value; 0 is a perfect ranking, lower is better. One test view per run (the first); FisherRF's "
        "image has fewer pixels than the view, so it is compared with the error mean-pooled to its size. "
        "The figure's titles show these medians."
    ]
    if older:
        notes.append(f"{older} run(s) without the arrays (made before runs saved them) are left out.")
    headers = ["method", "runs", *(f"AUSE {label}, median (IQR)" for label in KINDS.values())]
    return Table(headers, rows, notes)


def view_uncertainty_section(results: Results, figures: dict[str, Path]) -> list[Block]:
    """The section: per scene its figure (`figures[scene]`, when drawn) and its AUSE table; no
    section at all when no run saved the arrays."""
    blocks: list[Block] = []
    for scene in results.scenes:
        table = ause_table(results, scene)
        if table is None:
            continue
        blocks.append(Heading(scene, 3))
        if scene in figures:
            caption = (
                f"{scene}: the first test view per method (its lowest trial) after training: render, squared "
                "error, ray entropy and FisherRF's expected information gain per pixel (log scale over its top "
                "decades, its own per row, drawn at the render's size); the error (capped at the rows' 99th "
                "percentile) and the entropy on one scale for every row; each AUSE in a title is the method's "
                "median over its runs, as in the table"
            )
            blocks.append(Figure(figures[scene], caption))
        blocks.append(table)
    if not blocks:
        return []
    intro = Paragraph(
        "Where each model is uncertain on a test view, and whether that is where it is wrong: bright "
        "uncertainty should lie on large errors."
    )
    return [Heading("Uncertainty of a test view"), intro] + blocks


__all__ = [
    "ause_table",
    "ause_text",
    "method_ause",
    "plot_view_uncertainty",
    "run_ause",
    "view_uncertainty_figure",
    "view_uncertainty_section",
]
