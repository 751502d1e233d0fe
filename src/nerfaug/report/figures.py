"""The report's figures, as PNGs under the results folder's `figures/`: box plots per scene
(the paper's Fig. 4), the methods' uncertainty over the hemisphere (Fig. 1, drawn by
`nerfaug.maps`), the test renders (Fig. 3), the training curves, and a test view's error and uncertainty images
(`view_uncertainty`). Every figure is written by
`nerfaug.plotting.save_figure` (atomic, one dpi)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nerfaug import runfiles
from nerfaug.experiment.layout import ResultsFolder
from nerfaug.experiment.runfolder import (
    FILES,
    read_history,
    read_selection,
    render_paths,
)
from nerfaug.maps import plot_method_maps
from nerfaug.metrics import HIGHER_IS_BETTER, METRIC_LABELS, METRICS
from nerfaug.plotting import legend_below, new_figure, save_figure
from nerfaug.report.collect import Results, Run
from nerfaug.report.document import slug
from nerfaug.report.view_uncertainty import plot_view_uncertainty


def method_colours(methods: list[str]) -> dict[str, tuple]:
    from matplotlib import colormaps

    palette = colormaps["tab10"].colors
    return {m: palette[i % len(palette)] for i, m in enumerate(methods)}


def plot_boxplots(results: Results, scene: str, path: Path, title: str | None = None) -> Path | None:
    """Fig. 4: one panel per metric, one box per method over trials, each trial as a dot; `title`
    defaults to the scene's."""
    methods = [m for m in results.methods if results.runs_of(scene, m)]
    if not methods:
        return None
    colours = method_colours(results.methods)
    data_by_metric = {metric: [results.values(scene, m, metric) for m in methods] for metric in METRICS}
    # A metric with no values keeps a narrow panel that says so, rather than vanishing.
    widths = [1.0 if any(data_by_metric[metric]) else 0.35 for metric in METRICS]
    figure = new_figure(max(8.0, 0.75 * len(methods) * sum(widths)), 3.8)
    axes = figure.subplots(1, len(METRICS), gridspec_kw={"width_ratios": widths})
    jitter = np.random.default_rng(0)
    for ax, metric in zip(axes, METRICS):
        data = data_by_metric[metric]
        arrow = "higher is better" if HIGHER_IS_BETTER[metric] else "lower is better"
        ax.set_title(f"{METRIC_LABELS[metric]} ({arrow})", fontsize=10)
        if not any(data):
            ax.text(
                0.5,
                0.5,
                f"{METRIC_LABELS[metric]}\nn/a\n(not computed\nin these runs)",
                ha="center",
                va="center",
                transform=ax.transAxes,
                color="0.4",
            )
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        positions = [i for i, d in enumerate(data) if d]
        boxes = ax.boxplot(
            [data[i] for i in positions],
            positions=positions,
            widths=0.6,
            patch_artist=True,
            showfliers=False,
            medianprops={"color": "black"},
        )
        for patch, i in zip(boxes["boxes"], positions):
            patch.set_facecolor((*colours[methods[i]][:3], 0.35))
        for i in positions:
            x = i + jitter.uniform(-0.12, 0.12, len(data[i]))
            ax.scatter(x, data[i], s=14, color=colours[methods[i]], edgecolor="black", linewidth=0.4, zorder=3)
        ax.set_xticks(range(len(methods)), methods, rotation=30, ha="right", fontsize=9)
        ax.set_xlim(-0.6, len(methods) - 0.4)
        ax.grid(axis="y", alpha=0.3)
    figure.suptitle(title or f"{scene}: test metrics over trials", fontsize=11)
    return save_figure(figure, path)


def _first_run_with(results: Results, scene: str, method: str, filename: str) -> Run | None:
    """The lowest trial that has `filename` (trial 0 unless it is missing)."""
    return next((r for r in results.runs_of(scene, method) if runfiles.exists(r.folder, filename)), None)


MAP_PANELS_PER_FIGURE = 4  # wider figures shrink each hemisphere below legibility in the HTML page


def _map_panels(results: Results, scene: str) -> tuple[list, list[str]]:
    """(method, trial, selection) for each method's lowest trial with a selection.json whose
    candidates are the scene's shared pool; and notes on methods left out."""
    panels, notes, pool = [], [], None
    for method in results.methods:
        run = _first_run_with(results, scene, method, FILES.selection)
        selection = read_selection(run.folder) if run else None
        if selection is None:
            continue
        candidates = selection.candidate_poses
        if pool is None:
            pool = candidates
        elif candidates.shape != pool.shape or not np.allclose(candidates, pool, atol=1e-5):
            notes.append(f"{method} left out: its candidate poses differ from {panels[0][0]}'s")
            continue
        panels.append((method, run.trial, selection))
    return panels, notes


def plot_uncertainty_maps(results: Results, scene: str, folder: Path) -> tuple[list[Path], list[str]]:
    """Fig. 1: per method, its first trial's scores over the hemisphere with the initial (triangles)
    and chosen (stars) views, drawn by `nerfaug.maps.plot_method_maps`, at most
    MAP_PANELS_PER_FIGURE methods per image. Returns the images and notes."""
    panels, notes = _map_panels(results, scene)
    paths = []
    for part, first in enumerate(range(0, len(panels), MAP_PANELS_PER_FIGURE)):
        chunk = panels[first : first + MAP_PANELS_PER_FIGURE]
        maps = {f"{m} (trial {t})": (s.scores, s.chosen_poses) for m, t, s in chunk}
        suffix = "" if len(panels) <= MAP_PANELS_PER_FIGURE else f"_{part + 1}"
        path = folder / f"fig1_uncertainty_{slug(scene)}{suffix}.png"
        plot_method_maps(
            maps,
            chunk[0][2].candidate_poses,
            chunk[0][2].train_poses,
            path,
            title=f"{scene}: uncertainty over the hemisphere, seen from above (bright = uncertain)",
            train_label="initial views",
        )
        paths.append(path)
    return paths, notes


def _read_png(path: Path) -> np.ndarray | None:
    import imageio.v3 as iio

    try:
        return iio.imread(path)[..., :3]
    except Exception:  # noqa: BLE001 -- imageio raises many types; an unreadable render is left out
        return None


def _render_rows(results: Results, scene: str) -> tuple[list[tuple[str, list]], int]:
    """(label, images) per row: the ground truth (from a render_vs_gt image), then each method's
    renders of its lowest trial; and the number of columns."""
    rows, ground_truth = [], None
    for method in results.methods:
        run = next((r for r in results.runs_of(scene, method) if render_paths(r.folder)), None)
        if run is None:
            continue
        images = [_read_png(p) for p in render_paths(run.folder)]
        rows.append((f"{method}\n(trial {run.trial})", images))
        if ground_truth is None:
            pairs = [_read_png(p) for p in render_paths(run.folder, "render_vs_gt")]
            # Render left, ground truth right: the right half is the ground truth.
            ground_truth = [p[:, p.shape[1] // 2 :] if p is not None else None for p in pairs]
    if ground_truth:
        rows.insert(0, ("ground truth", ground_truth))
    return rows, max((len(images) for _, images in rows), default=0)


def plot_render_grid(results: Results, scene: str, path: Path) -> Path | None:
    """Fig. 3: the saved test renders, one row per method (ground truth on top)."""
    rows, columns = _render_rows(results, scene)
    if not rows or columns == 0:
        return None
    figure = new_figure(2.0 * columns + 1.2, 2.0 * len(rows))
    axes = figure.subplots(len(rows), columns, squeeze=False)
    for r, (label, images) in enumerate(rows):
        for c in range(columns):
            ax = axes[r, c]
            ax.set_xticks([])
            ax.set_yticks([])
            for spine in ax.spines.values():
                spine.set_visible(False)
            if c < len(images) and images[c] is not None:
                ax.imshow(images[c])
            if c == 0:
                ax.set_ylabel(label, fontsize=9, rotation=0, ha="right", va="center")
            if r == 0:
                ax.set_title(f"test view {c}", fontsize=9)
    # No title: the report's caption names the scene, and a suptitle collides with the column titles.
    figure.subplots_adjust(wspace=0.03, hspace=0.05)
    return save_figure(figure, path)


HISTORY_KEYS = ("psnr", "train_psnr", "loss", "train_loss")
HISTORY_LABELS = {
    "psnr": "training-batch PSNR (dB)",
    "train_psnr": "training PSNR (dB)",
    "loss": "training loss",
    "train_loss": "training loss",
}


def history_series(history) -> tuple[str, np.ndarray, np.ndarray] | None:
    """(quantity, steps, values) from a history.json: a list of per-step records
    ({"step": .., "psnr": ..}) or a dict of equal-length lists ({"step": [..], "psnr": [..]}).
    PSNR is preferred; the loss is used when no PSNR was recorded."""
    if isinstance(history, dict):
        steps = history.get("step", history.get("steps"))
        if not isinstance(steps, list):
            return None
        columns = {
            k: v for k, v in history.items() if k in HISTORY_KEYS and isinstance(v, list) and len(v) == len(steps)
        }
        records = [{"step": step, **{k: v[i] for k, v in columns.items()}} for i, step in enumerate(steps)]
    elif isinstance(history, list):
        records = [h for h in history if isinstance(h, dict) and isinstance(h.get("step"), (int, float))]
    else:
        return None
    for key in HISTORY_KEYS:
        pairs = [(float(h["step"]), float(h[key])) for h in records if isinstance(h.get(key), (int, float))]
        pairs = [(s, v) for s, v in pairs if math.isfinite(v)]
        if len(pairs) >= 2:
            steps, values = np.array(pairs).T
            order = np.argsort(steps, kind="stable")
            return key, steps[order], values[order]
    return None


def loss_series(history) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each named loss of a history.json's per-step records ({"step", "losses": {name: value}}),
    as name -> (steps, values); empty for a history without named losses."""
    if not isinstance(history, list):
        return {}
    found: dict[str, list[tuple[float, float]]] = {}
    for record in history:
        losses = record.get("losses") if isinstance(record, dict) else None
        if not isinstance(losses, dict) or not isinstance(record.get("step"), (int, float)):
            continue
        for name, value in losses.items():
            if isinstance(value, (int, float)) and math.isfinite(value) and value > 0:
                found.setdefault(name, []).append((float(record["step"]), float(value)))
    return {name: tuple(np.array(pairs).T) for name, pairs in found.items() if len(pairs) >= 2}


CURVE_POINTS = 200  # per-step batch PSNR is noisy: average it over windows down to about this many points


def _smooth(steps: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Window means of consecutive records, about CURVE_POINTS of them."""
    window = max(1, len(steps) // CURVE_POINTS)
    usable = len(steps) // window * window
    return steps[:usable].reshape(-1, window).mean(1), values[:usable].reshape(-1, window).mean(1)


def _median_curve(series: list[tuple[np.ndarray, np.ndarray]]):
    """Median and quartiles over trials on the union of their steps (each trial interpolated
    only within the steps it recorded)."""
    grid = np.unique(np.concatenate([s for s, _ in series]))
    stacked = np.full((len(series), grid.size), np.nan)
    for row, (steps, values) in zip(stacked, series):
        inside = (grid >= steps[0]) & (grid <= steps[-1])
        row[inside] = np.interp(grid[inside], steps, values)
    q1, median, q3 = np.nanpercentile(stacked, [25, 50, 75], axis=0)
    return grid, median, q1, q3


def training_curves_figure(results: Results):
    """Training PSNR (or loss) against step: median over trials per method, IQR shaded, one panel
    per scene. The runs record the PSNR of each step's training batch (no held-out views): the axis
    says so, and the step where views were added is drawn, where the batch's PSNR dips as it meets
    them. A second row draws each named loss (`history.json`'s "losses": rgb, distortion,
    interlevel), median over the scene's runs, on a log scale. None when no run recorded a history."""
    panels, losses = [], {}
    for scene in results.scenes:
        curves, named = {}, {}
        for method in results.methods:
            histories = [read_history(r.folder) for r in results.runs_of(scene, method)]
            found = [f for f in map(history_series, histories) if f is not None]
            if found:
                key = found[0][0]
                curves[method] = (key, [_smooth(s, v) for k, s, v in found if k == key])
            for history in histories:
                for name, (steps, values) in loss_series(history).items():
                    named.setdefault(name, []).append(_smooth(steps, values))
        if curves:
            panels.append((scene, curves))
            losses[scene] = named
    if not panels:
        return None
    colours = method_colours(results.methods)
    rows = 2 if any(losses.values()) else 1
    figure = new_figure(5.2 * len(panels), 3.8 * rows)
    grid_axes = np.atleast_2d(figure.subplots(rows, len(panels))).reshape(rows, len(panels))
    axes = grid_axes[0]
    add_at = results.config.get("add_at_step")
    if rows == 2:
        for ax, (scene, _curves) in zip(grid_axes[1], panels):
            _draw_losses(ax, losses[scene], add_at)
    for ax, (scene, curves) in zip(axes, panels):
        for method, (_key, series) in curves.items():
            grid, median, q1, q3 = _median_curve(series)
            ax.plot(grid, median, color=colours[method], label=method, linewidth=1.4)
            ax.fill_between(grid, q1, q3, color=colours[method], alpha=0.15, linewidth=0)
        keys = {key for key, _ in curves.values()}
        ax.set_ylabel(" / ".join(HISTORY_LABELS[k] for k in sorted(keys)))
        if keys & {"loss", "train_loss"}:
            ax.set_yscale("log")
        if add_at is not None:
            ax.axvline(add_at, color="0.3", linestyle="--", linewidth=1)
            ax.text(
                add_at, 0.02, " views added", transform=ax.get_xaxis_transform(), fontsize=8, va="bottom", color="0.3"
            )
        ax.set_xlabel("step")
        ax.set_title(scene, fontsize=10)
        ax.grid(alpha=0.3)
    legend_below(figure, axes)
    shown = {key for _, curves in panels for key, _ in curves.values()}
    held_out = " (training batches, not held-out views)" if shown & {"psnr", "train_psnr"} else ""
    figure.suptitle(f"Training curves{held_out}: median over trials, IQR shaded", fontsize=11, y=1.03)
    return figure


LOSS_STYLES = {"rgb": "-", "distortion": "--", "interlevel": ":"}
LOSS_GREYS = ("0.1", "0.4", "0.6")


def _draw_losses(ax, named: dict[str, list], add_at) -> None:
    """Each named loss of one scene's runs (every method's: the losses are the engine's, not the
    selection's): median over runs, IQR shaded, on a log scale."""
    order = [n for n in LOSS_STYLES if n in named] + sorted(n for n in named if n not in LOSS_STYLES)
    for i, name in enumerate(order):
        series = named[name]
        grid, median, q1, q3 = _median_curve(series)
        # Greys, told apart by line style: a method's colour here would claim a curve that pools them all.
        colour = LOSS_GREYS[i % len(LOSS_GREYS)]
        ax.plot(grid, median, color=colour, linestyle=LOSS_STYLES.get(name, "-"), label=name, linewidth=1.4)
        ax.fill_between(grid, q1, q3, color=colour, alpha=0.15, linewidth=0)
    ax.set_yscale("log")
    ax.set_ylabel("each loss (weighted, as summed)")
    ax.set_xlabel("step")
    if add_at is not None:
        ax.axvline(add_at, color="0.3", linestyle="--", linewidth=1)
    ax.legend(fontsize=8, frameon=False, title="every method's runs pooled", title_fontsize=8)
    ax.grid(alpha=0.3)


def plot_training_curves(results: Results, path: Path) -> Path | None:
    """`training_curves_figure` written to `path`; None (nothing written) when it has nothing to draw."""
    figure = training_curves_figure(results)
    return None if figure is None else save_figure(figure, path)


@dataclass
class Figures:
    """The report's figures by scene (an absent key: nothing to draw)."""

    boxplots: dict[str, Path] = field(default_factory=dict)
    maps: dict[str, list[Path]] = field(default_factory=dict)
    map_notes: dict[str, list[str]] = field(default_factory=dict)
    renders: dict[str, Path] = field(default_factory=dict)
    curves: Path | None = None
    view_uncertainty: dict[str, Path] = field(default_factory=dict)

    def paths(self) -> list[Path]:
        found = [*self.boxplots.values(), *(p for ps in self.maps.values() for p in ps), *self.renders.values()]
        return found + ([self.curves] if self.curves else []) + list(self.view_uncertainty.values())


def figure_folder(root: Path) -> Path:
    """The results folder's `figures/` (as shown, unresolved: the report links its figures
    relative to `root`), refused (`PathRefused`) where it is a link leading out of `root`; a
    figure planted there as a link is replaced by the figure, the link's target left alone."""
    return runfiles.checked(root, ResultsFolder(Path(root)).figures.relative_to(root))


def make_figures(results: Results) -> Figures:
    folder = figure_folder(results.root)
    figures = Figures()
    for scene in results.scenes:
        name = slug(scene)
        if (path := plot_boxplots(results, scene, folder / f"fig4_boxplots_{name}.png")) is not None:
            figures.boxplots[scene] = path
        maps, notes = plot_uncertainty_maps(results, scene, folder)
        if maps:
            figures.maps[scene], figures.map_notes[scene] = maps, notes
        if (path := plot_render_grid(results, scene, folder / f"fig3_renders_{name}.png")) is not None:
            figures.renders[scene] = path
        if (path := plot_view_uncertainty(results, scene, folder / f"view_uncertainty_{name}.png")) is not None:
            figures.view_uncertainty[scene] = path
    figures.curves = plot_training_curves(results, folder / "training_curves.png")
    return figures


__all__ = [
    "Figures",
    "history_series",
    "figure_folder",
    "make_figures",
    "method_colours",
    "plot_boxplots",
    "plot_render_grid",
    "plot_training_curves",
    "plot_uncertainty_maps",
    "training_curves_figure",
]
