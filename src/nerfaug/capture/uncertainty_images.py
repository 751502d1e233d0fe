"""Uncertainty images of any view of a session: for world-frame poses, what the NeRF renders, its
depth, the per-ray entropy and FisherRF's per-pixel score (`nerfaug.uncertainty.images`), as one
PNG figure with colour bars and as arrays (.npy files, or one .npz).

Figures of several views compare by eye when they share their colour scales (`colour_scales` of
the batch); the arrays are never rescaled or masked.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from nerfaug.capture.model import SessionModel
from nerfaug.capture.requests import FISHER_WIDTH, check_image_widths
from nerfaug.jsonio import atomic_write_bytes
from nerfaug.metrics import PIXEL_LABELS
from nerfaug.plotting import colour_bar, draw_log_image, figure_png, log_range, new_figure, save_figure
from nerfaug.progress import progress_bar
from nerfaug.selection import SelectionConfig
from nerfaug.selection.estimators import fisher_train_diagonal
from nerfaug.uncertainty.images import fisher_pixel_scores, view_images

ARRAYS = ("rgb", "depth", "opacity", "entropy", "fisher")
# A ray less opaque than this shows mostly the background: its expected depth is an average over a
# few faint samples anywhere along the ray (noise), so the depth panel draws it as background.
BACKGROUND_OPACITY = 0.5
BACKGROUND_GREY = (0.82, 0.82, 0.82, 1.0)


@dataclass
class ViewMaps:
    """One view's images.

    Attributes:
        pose: (4, 4) world-frame camera-to-world.
        rgb: (H, W, 3) float32 in [0, 1], the NeRF's render.
        depth: (H, W) float32, expected termination distance in world units.
        opacity: (H, W) float32 in [0, 1], each ray's accumulated opacity (0: only background).
        entropy: (H, W) float32, ray entropy in bits.
        fisher: (h, w) float32, FisherRF's per-pixel score (rendered `fisher_width` across), or None.
        step: the training step of the model.
        azimuth, elevation: the pose about the session's hemisphere, degrees.
    """

    pose: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    opacity: np.ndarray
    entropy: np.ndarray
    fisher: np.ndarray | None
    step: int
    azimuth: float
    elevation: float


def training_fisher(model: SessionModel, generator: torch.Generator | None = None) -> Tensor:
    """H_train of the session's NeRF as its FisherRF proposals take it (`fisher_train_diagonal`
    with the `SelectionConfig` defaults).

    Returns:
        Tensor with shape (P,).
    """

    generator = generator if generator is not None else torch.Generator().manual_seed(model.seed)
    train = model.train_cameras.to(model.device)
    return fisher_train_diagonal(model.model, train, SelectionConfig(), generator)


def view_maps(
    model: SessionModel,
    poses,
    width: int | None = None,
    fisher: bool = True,
    fisher_width: int = FISHER_WIDTH,
    progress: bool = False,
    names: Sequence[str] | None = None,
) -> list[ViewMaps]:
    """The images of world-frame `poses` seen by the session's NeRF.

    Args:
        model: the session's NeRF.
        poses: Tensor with shape (n, 4, 4) (or (4, 4)), world-frame camera-to-world.
        width: pixels across of the render, depth and entropy; None: the training resolution.
        fisher: also compute FisherRF's per-pixel score (3 backward passes per pixel).
        fisher_width: pixels across of the FisherRF image.
        progress: show a line (or a live bar) per view and kind of image.
        names: the views' names, for the progress display.

    Returns:
        One `ViewMaps` per pose.

    Raises:
        RequestError: a width out of its range (`check_image_widths`).
    """
    width, fisher_width = check_image_widths(width, fisher_width)
    world = torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4)
    names = list(names) if names is not None else [f"view {i}" for i in range(len(world))]
    cameras = model.engine_cameras(world, width)
    background = model.background_tensor()
    fisher_cameras = model.engine_cameras(world, fisher_width) if fisher else None
    azimuth, polar, _ = model.hemisphere.angles(world)
    maps = []
    # Units of work: FisherRF's training diagonal, then per view its render and its FisherRF image.
    kinds = 2 if fisher else 1
    with progress_bar(enabled=progress, fields="{kind}") as bar:
        task = bar.add_task("uncertainty images", total=kinds * len(world) + int(fisher), every=1, kind="")
        h_train = None
        if fisher:
            bar.update(task, kind="FisherRF of the training views")
            h_train = training_fisher(model)
            bar.advance(task)
        for i in range(len(world)):
            bar.update(task, kind=f"{names[i]}: render, depth, entropy")
            images = view_images(model.model, cameras, i, background)
            bar.advance(task)
            scores = None
            if fisher:
                bar.update(task, kind=f"{names[i]}: FisherRF")
                scores = fisher_pixel_scores(model.model, fisher_cameras, h_train, i, background=background).numpy()
                bar.advance(task)
            maps.append(
                ViewMaps(
                    pose=world[i].double().numpy(),
                    rgb=images["rgb"].clamp(0, 1).numpy().astype(np.float32),
                    depth=(images["depth"] * model.hemisphere.scale).numpy().astype(np.float32),
                    opacity=images["accumulation"].clamp(0, 1).numpy().astype(np.float32),
                    entropy=images["entropy"].numpy().astype(np.float32),
                    fisher=None if scores is None else scores.astype(np.float32),
                    step=model.step,
                    azimuth=math.degrees(float(azimuth[i])),
                    elevation=90.0 - math.degrees(float(polar[i])),
                )
            )
    return maps


@dataclass(frozen=True)
class ColourScales:
    """The values the colours of the depth, entropy and FisherRF panels span.

    Attributes:
        depth: (near, far) in world units over the foreground pixels; None when there are none.
        entropy: the entropy at the top of its scale, bits (the bottom is 0).
        fisher: (low, high) of FisherRF's log scale, at most `nerfaug.plotting.LOG_DECADES`
            decades (`log_range`); None when no pixel scores above 0.
    """

    depth: tuple[float, float] | None
    entropy: float
    fisher: tuple[float, float] | None


def colour_scales(views: Sequence[ViewMaps]) -> ColourScales:
    """One set of colour scales spanning every view in `views`: figures drawn with it compare by
    eye (the same colour is the same value in each)."""
    foreground = [v.depth[v.opacity >= BACKGROUND_OPACITY] for v in views]
    foreground = np.concatenate([d[np.isfinite(d)] for d in foreground]) if views else np.zeros(0)
    depth = (float(foreground.min()), float(foreground.max())) if foreground.size else None
    entropy = max([float(np.nanmax(v.entropy)) for v in views if v.entropy.size] + [0.0])
    fisher = [v.fisher.reshape(-1) for v in views if v.fisher is not None]
    fisher = log_range(np.concatenate(fisher)) if fisher else None
    return ColourScales(depth, entropy if entropy > 0 else 1.0, fisher)


def figure(maps: ViewMaps, title: str = "", scales: ColourScales | None = None):
    """The render, depth, entropy and (when computed) FisherRF panels of one view, side by side,
    each measured panel with its colour bar naming the quantity and its unit. FisherRF, computed
    on fewer pixels, is drawn at the render's size (interpolated on its log scale).

    Args:
        maps: the view's images.
        title: shown before the view's step and angles.
        scales: the panels' colour scales (`colour_scales` of a batch, to compare its figures);
            None: this view's own.
    """
    from matplotlib import colormaps

    scales = scales if scales is not None else colour_scales([maps])
    panels = 4 if maps.fisher is not None else 3
    fig = new_figure(3.4 * panels, 3.2)
    fig.set_layout_engine("constrained")  # room for each panel's colour bar and its label
    axes = fig.subplots(1, panels)
    axes[0].imshow(maps.rgb, interpolation="nearest")
    axes[0].set_title("render", fontsize=9)
    # Background pixels (mostly transparent rays) are left out of the depth's colours, in grey.
    depth = np.ma.masked_where(maps.opacity < BACKGROUND_OPACITY, maps.depth)
    near, far = scales.depth if scales.depth is not None else (None, None)
    colours = colormaps["viridis_r"].with_extremes(bad=BACKGROUND_GREY)
    image = axes[1].imshow(depth, cmap=colours, interpolation="nearest", vmin=near, vmax=far)
    axes[1].set_title("depth (grey: background)", fontsize=9)
    colour_bar(fig, image, axes[1], PIXEL_LABELS["depth"])
    image = axes[2].imshow(maps.entropy, cmap="magma", interpolation="nearest", vmin=0, vmax=scales.entropy)
    axes[2].set_title("ray entropy", fontsize=9)
    colour_bar(fig, image, axes[2], PIXEL_LABELS["entropy"])
    if maps.fisher is not None:
        h, w = maps.fisher.shape
        draw_log_image(fig, axes[3], maps.fisher, maps.rgb.shape[:2], scales.fisher, PIXEL_LABELS["fisher"])
        axes[3].set_title(f"FisherRF (computed at {w}x{h} px)", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    heading = f"step {maps.step}, azimuth {maps.azimuth:.1f} deg, elevation {maps.elevation:.1f} deg"
    fig.suptitle(f"{title}: {heading}" if title else heading, fontsize=9)
    return fig


def figure_bytes(maps: ViewMaps, title: str = "", scales: ColourScales | None = None) -> bytes:
    """`figure` as PNG bytes."""

    return figure_png(figure(maps, title, scales))


def arrays(maps: ViewMaps) -> dict[str, np.ndarray]:
    """The view's arrays by name (`ARRAYS`, without fisher when not computed) and its pose."""
    named = {name: getattr(maps, name) for name in ARRAYS if getattr(maps, name) is not None}
    return {**named, "pose": maps.pose}


def npz_bytes(maps: ViewMaps) -> bytes:
    """The view's arrays as one .npz file's bytes (`numpy.load` reads it)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays(maps))
    return buffer.getvalue()


def write_maps(maps: ViewMaps, folder: Path, name: str, scales: ColourScales | None = None) -> list[Path]:
    """Write `name.png` (the figure, with `scales` or its own) and `name_<array>.npy` into
    `folder`; returns the files."""

    written = [save_figure(figure(maps, name, scales), Path(folder) / f"{name}.png")]
    for key, value in arrays(maps).items():
        buffer = io.BytesIO()
        np.save(buffer, value)
        path = Path(folder) / f"{name}_{key}.npy"
        atomic_write_bytes(path, buffer.getvalue())
        written.append(path)
    return written
