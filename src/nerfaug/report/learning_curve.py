"""The report's learning curves: for runs that added their views in rounds, test PSNR against the
views in the model, per method, median and IQR over trials (a figure per results folder, one panel
per scene), and a table per scene with each method's area under the curve, the summary of a run's
curve a comparison can use.

Read from each run's result.json ("before_rounds" and "rounds", written by runs of more than one
round), or from a study table's row ("curve"); a results folder without such runs gets no section.
The study page draws the same figure and tables per engine from its table alone.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from nerfaug.plotting import legend_below, new_figure, save_figure
from nerfaug.report.collect import Results, Run
from nerfaug.report.document import Block, Figure, Heading, Paragraph, Table, number, slug
from nerfaug.statistics import summarise

PSNR_DECIMALS = 2


def run_curve(run: Run) -> list[tuple[int, float]] | None:
    """A run's learning curve: (views in the model, test PSNR in dB) before its first round and
    after each round, views increasing; None for a run of one round or a record without the points."""
    result = run.result
    if "curve" in result:  # a study table's row (`report.study_table`), already checked
        return [(int(views), float(psnr)) for views, psnr in result["curve"]]
    rounds = result.get("rounds")
    start = result.get("before_rounds")
    if not isinstance(rounds, list) or len(rounds) < 2 or not isinstance(start, dict):
        return None
    points = []
    for point in [start, *rounds]:
        metrics = point.get("metrics") if isinstance(point, dict) else None
        psnr = metrics.get("psnr") if isinstance(metrics, dict) else None
        views = point.get("views") if isinstance(point, dict) else None
        if not isinstance(psnr, (int, float)) or not isinstance(views, int):
            return None
        points.append((views, float(psnr)))
    return points


def curve_area(points: list[tuple[int, float]]) -> float:
    """The area under a learning curve, dB x views, by the trapezoidal rule over its view counts.

    Example:
        >>> curve_area([(4, 20.0), (5, 22.0), (6, 22.0)])
        43.0
    """
    views = np.array([v for v, _ in points], dtype=float)
    psnr = np.array([p for _, p in points], dtype=float)
    return float(np.sum((views[1:] - views[:-1]) * (psnr[1:] + psnr[:-1]) / 2))


def curve_mean(points) -> float:
    """The area under a learning curve divided by the span of its views, dB: the curve's mean
    height, the summary of a run's curve the study of rounds compares (its secondary outcome).

    Example:
        >>> curve_mean([(4, 20.0), (5, 22.0), (6, 22.0)])
        21.5
    """
    return curve_area(points) / (points[-1][0] - points[0][0])


def method_curves(results: Results, scene: str) -> dict[str, list[list[tuple[int, float]]]]:
    """Per method, the learning curves of its runs on `scene` (runs of one round left out)."""
    found = {}
    for method in results.methods:
        curves = [c for r in results.runs_of(scene, method) if (c := run_curve(r)) is not None]
        if curves:
            found[method] = curves
    return found


def _by_views(curves: list[list[tuple[int, float]]]) -> dict[int, list[float]]:
    """PSNR values at each view count, over the curves."""
    grouped: dict[int, list[float]] = {}
    for curve in curves:
        for views, psnr in curve:
            grouped.setdefault(views, []).append(psnr)
    return dict(sorted(grouped.items()))


def plot_learning_curves(results: Results, path: Path) -> Path | None:
    """Test PSNR against views in the model: per method the median over trials at each view
    count, its IQR shaded, one panel per scene. None (nothing written) without runs in rounds."""
    from nerfaug.report.figures import method_colours  # matplotlib's palette, only when drawing

    panels = [(scene, curves) for scene in results.scenes if (curves := method_curves(results, scene))]
    if not panels:
        return None
    colours = method_colours(results.methods)
    figure = new_figure(5.2 * len(panels), 4.0)
    axes = np.atleast_1d(figure.subplots(1, len(panels)))
    for ax, (scene, curves) in zip(axes, panels):
        for method, runs in curves.items():
            grouped = _by_views(runs)
            views = np.array(list(grouped))
            q1, median, q3 = np.array([np.percentile(v, [25, 50, 75]) for v in grouped.values()]).T
            # The last point is another measurement (after the last training step, on every test
            # view; the others a round's 100-odd steps after it, on a few): joined by a dashed
            # segment and drawn as a diamond, so its rise is not read as the last view's worth.
            style = {"color": colours[method], "markersize": 3.5, "linewidth": 1.5}
            ax.plot(views[:-1], median[:-1], marker="o", label=f"{method} ({len(runs)} runs)", **style)
            ax.plot(views[-2:], median[-2:], linestyle="--", **style)
            ax.plot(views[-1:], median[-1:], marker="D", **style)
            ax.fill_between(views, q1, q3, color=colours[method], alpha=0.15, linewidth=0)
        ax.set_xlabel("views in the model (diamond: after the last step, on every test view)", fontsize=8.5)
        ax.set_ylabel("test PSNR (dB)")
        ax.set_title(scene, fontsize=10)
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.grid(alpha=0.3)
    legend_below(figure, axes)
    figure.suptitle("Learning curves: test PSNR after each round, median over trials, IQR shaded", fontsize=11)
    return save_figure(figure, path)


def _table(results: Results, scene: str) -> Table | None:
    curves = method_curves(results, scene)
    if not curves:
        return None
    counts = sorted({views for runs in curves.values() for curve in runs for views, _ in curve})
    rows = []
    for method, runs in curves.items():
        area = summarise([curve_area(c) for c in runs])
        mean = summarise([curve_mean(c) for c in runs])
        grouped = _by_views(runs)
        cells = [
            method,
            str(len(runs)),
            f"{number(area['median'], 1)} [{number(area['q1'], 1)}, {number(area['q3'], 1)}]",
            f"{number(mean['median'], 2)} [{number(mean['q1'], 2)}, {number(mean['q3'], 2)}]",
        ]
        cells += [number(float(np.median(grouped[v])), PSNR_DECIMALS) if v in grouped else "" for v in counts]
        rows.append(cells)
    return Table(
        ["method", "runs", "area, dB x views (median [q1, q3])", "area / span of views, dB (median [q1, q3])"]
        + [f"PSNR at {v} views" for v in counts],
        rows,
        [
            "Area under each run's curve of test PSNR against views in the model (trapezoidal), median and quartiles "
            "over its runs; the same divided by the span of views (the curve's mean height, the study of rounds' "
            "secondary outcome); then the median PSNR at each view count. Points before the last are measured on a few "
            "test views spread over all of them (each round's record says how many), the last on every test view."
        ],
    )


def learning_curve_section(
    results: Results, figure: Path | None, title: str = "Learning curves (views added in rounds)"
) -> list[Block]:
    """The learning curves' heading (`title`), figure and one table per scene; empty without runs
    in rounds."""
    tables = [(scene, table) for scene in results.scenes if (table := _table(results, scene)) is not None]
    if not tables:
        return []
    blocks: list[Block] = [
        Heading(title),
        Paragraph(
            "Each method chose its views in rounds, each round with the model trained on the views so far; "
            "after each round the runs were scored on test views. A curve starts at the initial views, before "
            "the first round, where every method's runs of a seed are the same model."
        ),
    ]
    if figure is not None:
        caption = (
            "Test PSNR against views in the model, before the first round and after each, median over trials, "
            "IQR shaded; the last point (a diamond, joined by a dashed line) is after training to the last step, "
            "on every test view, the others a round's steps after the round, on a few test views"
        )
        blocks.append(Figure(figure, caption))
    for scene, table in tables:
        blocks += [Heading(f"{scene}: area under the learning curve", level=3), table]
    return blocks


def study_curve_figures(results: dict[str, Results], folder: Path) -> dict[str, Path]:
    """A study's learning-curve figures, one per engine with runs in rounds (`results`: engine ->
    its runs, as `report.study.Study.results`): engine -> FOLDER/learning_curves_<engine>.png."""
    found = {}
    for engine, runs in results.items():
        if (path := plot_learning_curves(runs, Path(folder) / f"learning_curves_{slug(engine)}.png")) is not None:
            found[engine] = path
    return found


def study_curve_blocks(results: dict[str, Results], figures: dict[str, Path]) -> list[Block]:
    """The study page's learning curves: per engine with runs in rounds, its figure and per-scene
    tables (each run's curve from the table's rows); empty for a study of one round."""
    blocks: list[Block] = []
    for engine, runs in results.items():
        blocks += learning_curve_section(runs, figures.get(engine), f"Learning curves, engine {engine}")
    return blocks


__all__ = [
    "curve_area",
    "curve_mean",
    "learning_curve_section",
    "method_curves",
    "plot_learning_curves",
    "run_curve",
    "study_curve_blocks",
    "study_curve_figures",
]
