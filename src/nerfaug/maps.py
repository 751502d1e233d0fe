"""Maps of candidate scores over the hemisphere seen from above, like the paper's Fig. 1.

The upper hemisphere is drawn as a disk with the pole at the centre and the horizon at the rim,
azimuth measured counter-clockwise from +x (right). The default projection is Lambert's
equal-area one (radius = sin(polar / 2) / sin(pi / 4)), so candidates drawn uniformly in area
look evenly spread; "equidistant" makes the radius proportional to the polar angle instead.
Scores at the scattered candidates are interpolated linearly (Delaunay triangles) onto a grid,
with the nearest candidate's value outside their convex hull; bright means uncertain (high
score). Rings mark 30 and 60 degrees of elevation (labelled "elev."), spokes the azimuth.
Training views are drawn as triangles, chosen views as stars. Figures are written
atomically at the project's one dpi (`nerfaug.plotting.save_figure`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.tri import LinearTriInterpolator, Triangulation
from scipy.spatial import cKDTree

from nerfaug.hemisphere import angles_from_pose
from nerfaug.plotting import save_figure
from nerfaug.registry import check_name

PROJECTIONS = ("equal-area", "equidistant")
_GRID = 200
_CMAP = "inferno"
# The disk's colour where nothing is scored: no candidate near (a region the candidates leave out,
# such as the view from straight above when they come from a capture's own views), or a method
# with no score at all.
_UNSCORED = "0.85"
NO_CANDIDATE = "grey: no candidate here, nothing scored"
NO_SCORE = "grey: one score for every candidate, none to compare"


def _disk_radius(polar, projection: str):
    """Distance from the disk's centre of a polar angle (radians); 1 at the horizon."""
    if projection == "equal-area":
        return np.sin(np.asarray(polar) / 2) / math.sin(math.pi / 4)
    return np.asarray(polar) / (math.pi / 2)


def _as_poses(poses) -> torch.Tensor:
    poses = poses if torch.is_tensor(poses) else torch.as_tensor(np.asarray(poses))
    return poses.detach().cpu().reshape(-1, 4, 4).double()


def hemisphere_xy(camera_to_world, projection: str = "equal-area", centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Disk coordinates of camera positions (unit disk = the upper hemisphere).

    Args:
        camera_to_world: array or Tensor with shape (n, 4, 4).
        projection: "equal-area" or "equidistant".
        centre: the hemisphere's centre, world space.

    Returns:
        Array with shape (n, 2); views below the horizon land outside the unit disk.
    """
    check_name("projection", projection, PROJECTIONS)
    poses = _as_poses(camera_to_world)
    if poses.shape[0] == 0:
        return np.zeros((0, 2))
    azimuth, polar, _ = angles_from_pose(poses, centre)
    azimuth, polar = azimuth.double().numpy(), polar.double().numpy()
    radius = _disk_radius(polar, projection)
    return np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth)], axis=-1)


# A grid point farther than this many typical candidate spacings (the median distance between
# neighbours) from every candidate has no score to show (a captured set's candidates may cover a
# wedge only): it is left blank, not extrapolated. Uniform candidates leave no hole that wide:
# none was masked inside the disk for 30, 50 or 500 of them over 20 seeds each.
_FAR_SPACINGS = 6.0


def _interpolate(xy: np.ndarray, values: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ma.MaskedArray:
    """Scattered values onto the grid: linear inside the points' triangulation, nearest outside,
    masked where no candidate is near (`_FAR_SPACINGS`). Returns a masked array shaped as `gx`."""
    if xy.shape[0] == 0 or np.ptp(values) == 0:
        return np.ma.masked_array(np.full_like(gx, values.mean() if values.size else 0.0))
    distance, nearest = cKDTree(xy).query(np.stack([gx.ravel(), gy.ravel()], axis=-1))
    grid = values[nearest].reshape(gx.shape)
    unique = np.unique(xy, axis=0)
    if len(unique) < 3:  # a point or two: nothing to triangulate, no spacing to judge holes by
        return np.ma.masked_array(grid)
    spacing = float(np.median(cKDTree(unique).query(unique, k=2)[0][:, 1]))
    far = (distance > _FAR_SPACINGS * spacing).reshape(gx.shape)
    try:
        # matplotlib's triangulation rather than scipy's griddata: the same linear interpolation,
        # without griddata's seconds-long first call on a busy multi-threaded machine.
        linear = LinearTriInterpolator(Triangulation(xy[:, 0], xy[:, 1]), values)(gx, gy)
        grid = np.where(np.ma.getmaskarray(linear), grid, linear.filled(0.0))
    except (ValueError, RuntimeError):  # all points on a line: no triangles
        pass
    return np.ma.masked_array(grid, mask=far)


def _draw(
    ax: Axes,
    candidate_c2w,
    scores,
    train_c2w,
    chosen_c2w,
    projection,
    centre,
    vmin=None,
    vmax=None,
    train_label="",
    unscored: str | None = None,
):
    """One map on `ax`; the image drawn (None when `unscored`: the method gave every candidate
    one score, so the disk stays grey and the legend says why, in those words)."""
    xy = hemisphere_xy(candidate_c2w, projection, centre)
    values = np.asarray(torch.as_tensor(scores).detach().cpu().double().reshape(-1))
    if values.shape[0] != xy.shape[0]:
        raise ValueError(f"{xy.shape[0]} candidate poses but {values.shape[0]} scores")
    axis = np.linspace(-1.0, 1.0, _GRID)
    gx, gy = np.meshgrid(axis, axis)
    grid = _interpolate(xy, values, gx, gy)
    inside = gx**2 + gy**2 <= 1.0
    grid = np.ma.masked_where(~inside, grid)
    ax.add_patch(Circle((0.0, 0.0), 1.0, color=_UNSCORED, zorder=0))  # shows where no candidate lies
    if unscored is not None or (np.ma.getmaskarray(grid) & inside).any():
        # The grey is named in the legend (a patch of no size stands for it there).
        ax.add_patch(Circle((0.0, 0.0), 0.0, color=_UNSCORED, label=unscored or NO_CANDIDATE))
    image = None
    if unscored is None:
        image = ax.imshow(
            grid,
            origin="lower",
            extent=(-1, 1, -1, 1),
            cmap=_CMAP,
            interpolation="bilinear",
            vmin=vmin,
            vmax=vmax,
        )
    ax.scatter(xy[:, 0], xy[:, 1], s=1.5, c="white" if unscored is None else "0.5", alpha=0.25, linewidths=0)

    theta = np.linspace(0, 2 * math.pi, 200)
    for polar_deg in (30, 60, 90):
        r = _disk_radius(np.radians(polar_deg), projection)
        ax.plot(r * np.cos(theta), r * np.sin(theta), color="0.6", lw=0.6 if polar_deg < 90 else 1.0)
        if polar_deg < 90:  # rings labelled by elevation, as every output; the rim (0 degrees) is the horizon
            ax.text(
                r * math.cos(math.radians(112)),
                r * math.sin(math.radians(112)),
                f"{90 - polar_deg}° elev.",
                color="0.8",
                fontsize=6,
                ha="center",
                va="bottom",
            )
    for az_deg in range(0, 360, 90):
        a = math.radians(az_deg)
        ax.plot([0, math.cos(a)], [0, math.sin(a)], color="0.6", lw=0.4)
        name = f"{az_deg}° az." if az_deg == 90 else f"{az_deg}°"  # the rim's labels: azimuth, named once
        ax.text(1.09 * math.cos(a), 1.09 * math.sin(a), name, ha="center", va="center", fontsize=7)

    train = hemisphere_xy(train_c2w, projection, centre)
    ax.scatter(
        train[:, 0],
        train[:, 1],
        marker="^",
        s=70,
        c="#29b6f6",
        edgecolors="black",
        linewidths=0.8,
        label=train_label,
        zorder=3,
    )
    if chosen_c2w is not None:
        chosen = hemisphere_xy(chosen_c2w, projection, centre)
        ax.scatter(
            chosen[:, 0],
            chosen[:, 1],
            marker="*",
            s=160,
            c="#00e676",
            edgecolors="black",
            linewidths=0.8,
            label="chosen views",
            zorder=4,
        )
    # Captured sets (LLFF, DTU) may hold views below the horizon: beyond the rim, kept in frame.
    drawn = [xy, train] + ([chosen] if chosen_c2w is not None else [])
    reach = max([float(np.linalg.norm(points, axis=-1).max()) for points in drawn if len(points)], default=0.0)
    limit = max(1.18, reach + 0.1)
    if reach > 1.0 + 1e-6:
        # In axes units: side-by-side panels later share the widest panel's limits, and the note
        # must stay at the bottom of each.
        ax.text(
            0.5,
            0.0,
            "beyond the rim: below the horizon",
            ha="center",
            va="bottom",
            fontsize=6,
            color="0.3",
            transform=ax.transAxes,
        )
    ax.set_xlim(-limit, limit)
    ax.set_ylim(-limit, limit)
    ax.set_aspect("equal")
    ax.axis("off")
    return image


def hemisphere_map_figure(
    candidate_c2w,
    scores,
    train_c2w,
    chosen_c2w=None,
    title: str | None = None,
    label: str = "score",
    projection: str = "equal-area",
    centre=(0.0, 0.0, 0.0),
    train_label: str = "training views",
) -> Figure:
    """The scores over the hemisphere seen from above, as a matplotlib Figure (arguments as
    `plot_hemisphere_map`'s)."""
    # A bare Figure renders with Agg and touches no pyplot state (no global backend, no leaks).
    fig = Figure(figsize=(5.6, 4.6))
    ax = fig.subplots()
    image = _draw(ax, candidate_c2w, scores, train_c2w, chosen_c2w, projection, centre, train_label=train_label)
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.02).set_label(label, fontsize=8)
    ax.legend(loc="lower left", bbox_to_anchor=(-0.05, -0.08), fontsize=7, frameon=False)
    if title:
        ax.set_title(title)
    return fig


def plot_hemisphere_map(
    candidate_c2w,
    scores,
    train_c2w,
    chosen_c2w=None,
    path: str | Path | None = None,
    title: str | None = None,
    label: str = "score",
    projection: str = "equal-area",
    centre=(0.0, 0.0, 0.0),
    train_label: str = "training views",
) -> Path:
    """Draw the scores over the hemisphere seen from above and save it as a PNG.

    Args:
        candidate_c2w: Tensor or array with shape (n_candidates, 4, 4), where the scores live.
        scores: Tensor or array with shape (n_candidates,); bright = high.
        train_c2w: Tensor or array with shape (n_training, 4, 4), drawn as triangles.
        chosen_c2w: Tensor or array with shape (n_chosen, 4, 4), drawn as stars; None for none.
        path: PNG file to write (folders are created); required.
        title: title above the map.
        label: the colourbar's label: what the scores are, with their unit (a method's
            `MethodSpec.score_label`).
        projection: "equal-area" (default) or "equidistant".
        centre: the hemisphere's centre, world space.
        train_label: the legend's name for the triangles (an experiment's "initial views").

    Returns:
        The path written.
    """
    if path is None:
        raise ValueError("plot_hemisphere_map needs the path of the PNG to write")
    figure = hemisphere_map_figure(
        candidate_c2w, scores, train_c2w, chosen_c2w, title, label, projection, centre, train_label
    )
    return save_figure(figure, path)


def plot_method_maps(
    maps: dict,
    candidate_c2w,
    train_c2w,
    path: str | Path,
    title: str | None = None,
    projection: str = "equal-area",
    centre=(0.0, 0.0, 0.0),
    train_label: str = "training views",
) -> Path:
    """`method_maps_figure(maps, candidate_c2w, train_c2w, ...)` saved as a PNG at `path`; returns the path."""
    return save_figure(method_maps_figure(maps, candidate_c2w, train_c2w, title, projection, centre, train_label), path)


def method_maps_figure(
    maps: dict,
    candidate_c2w,
    train_c2w,
    title: str | None = None,
    projection: str = "equal-area",
    centre=(0.0, 0.0, 0.0),
    train_label: str = "training views",
) -> Figure:
    """One hemisphere map per method, side by side, and save them as a PNG.

    Each panel's scores are min-max normalised for display (methods score on different scales),
    so colours compare where a method is uncertain, not how much. A method that gives every
    candidate one score (uniform) has no colours: its disk stays grey, and the legend says why;
    grey within a scored disk is where no candidate lies.

    Args:
        maps: method name -> (scores (n_candidates,), chosen_c2w (n_chosen, 4, 4) or None).
        candidate_c2w: Tensor or array with shape (n_candidates, 4, 4), shared by all methods.
        train_c2w: Tensor or array with shape (n_training, 4, 4).
        title: a title over all panels.
        projection, centre, train_label: as in `plot_hemisphere_map`.

    Returns:
        The Figure (a bare matplotlib Figure, no pyplot state).
    """
    if not maps:
        raise ValueError("no methods to draw")
    n = len(maps)
    fig = Figure(figsize=(3.3 * n + 0.9, 3.8))
    axes = fig.subplots(1, n, squeeze=False)
    image = None
    for ax, (name, (scores, chosen)) in zip(axes[0], maps.items()):
        values = torch.as_tensor(np.asarray(scores) if not torch.is_tensor(scores) else scores).double()
        span = values.max() - values.min()
        shown = (values - values.min()) / span if span > 0 else torch.full_like(values, 0.5)
        # One score for every candidate (uniform's): no colour on a scale of scores it does not have.
        drawn = _draw(
            ax,
            candidate_c2w,
            shown,
            train_c2w,
            chosen,
            projection,
            centre,
            vmin=0.0,
            vmax=1.0,
            train_label=train_label,
            unscored=None if span > 0 else NO_SCORE,
        )
        image = drawn if drawn is not None else image
        ax.set_title(name, fontsize=10)
    limit = max(ax.get_xlim()[1] for ax in axes[0])  # one scale, so the panels' disks match
    for ax in axes[0]:
        ax.set_xlim(-limit, limit)
        ax.set_ylim(-limit, limit)
    legend = {label: handle for ax in axes[0] for handle, label in zip(*ax.get_legend_handles_labels())}
    fig.legend(legend.values(), legend.keys(), loc="lower center", ncol=2, fontsize=8, frameon=False)
    if image is not None:
        fig.colorbar(
            image,
            ax=list(axes[0]),
            fraction=0.02,
            pad=0.01,
            label="each method's own score,\nmin-max scaled per panel (no unit)",
        )
    if title:
        fig.suptitle(title)
    return fig
