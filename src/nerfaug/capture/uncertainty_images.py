"""Uncertainty images of any view of a session: for world-frame poses, what the NeRF renders, its
depth, the per-ray entropy and FisherRF's per-pixel score (`nerfaug.uncertainty.images`), as one
PNG figure with colour bars and as arrays (.npy files, or one .npz)."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from nerfaug.capture.model import SessionModel
from nerfaug.uncertainty.images import fisher_pixel_scores, view_images

ARRAYS = ("rgb", "depth", "entropy", "fisher")


@dataclass
class ViewMaps:
    """One view's images.

    Attributes:
        pose: (4, 4) world-frame camera-to-world.
        rgb: (H, W, 3) float32 in [0, 1], the NeRF's render.
        depth: (H, W) float32, expected termination distance in world units.
        entropy: (H, W) float32, ray entropy in bits.
        fisher: (h, w) float32, FisherRF's per-pixel score (rendered `fisher_width` across), or None.
        step: the training step of the model.
        azimuth, elevation: the pose about the session's hemisphere, degrees.
    """

    pose: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
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
    from nerfaug.selection import SelectionConfig
    from nerfaug.selection.estimators import fisher_train_diagonal

    generator = generator if generator is not None else torch.Generator().manual_seed(model.seed)
    train = model.train_cameras.to(model.device)
    return fisher_train_diagonal(model.model, train, SelectionConfig(), generator)


def view_maps(
    model: SessionModel, poses, width: int | None = None, fisher: bool = True, fisher_width: int = 16
) -> list[ViewMaps]:
    """The images of world-frame `poses` seen by the session's NeRF.

    Args:
        model: the session's NeRF.
        poses: Tensor with shape (n, 4, 4) (or (4, 4)), world-frame camera-to-world.
        width: pixels across of the render, depth and entropy; None: the training resolution.
        fisher: also compute FisherRF's per-pixel score (3 backward passes per pixel).
        fisher_width: pixels across of the FisherRF image.

    Returns:
        One `ViewMaps` per pose.
    """
    if width is not None and int(width) < 1:
        raise ValueError(f"width {width}: must be >= 1 pixel")
    if int(fisher_width) < 1:
        raise ValueError(f"fisher_width {fisher_width}: must be >= 1 pixel")
    world = torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4)
    cameras = model.engine_cameras(world, width)
    background = model.background_tensor()
    h_train = training_fisher(model) if fisher else None
    fisher_cameras = model.engine_cameras(world, fisher_width) if fisher else None
    azimuth, polar, _ = model.hemisphere.angles(world)
    maps = []
    for i in range(len(world)):
        images = view_images(model.model, cameras, i, background)
        scores = None
        if fisher:
            scores = fisher_pixel_scores(model.model, fisher_cameras, h_train, i, background=background).numpy()
        maps.append(
            ViewMaps(
                pose=world[i].double().numpy(),
                rgb=images["rgb"].clamp(0, 1).numpy().astype(np.float32),
                depth=(images["depth"] * model.hemisphere.scale).numpy().astype(np.float32),
                entropy=images["entropy"].numpy().astype(np.float32),
                fisher=None if scores is None else scores.astype(np.float32),
                step=model.step,
                azimuth=math.degrees(float(azimuth[i])),
                elevation=90.0 - math.degrees(float(polar[i])),
            )
        )
    return maps


def figure(maps: ViewMaps, title: str = ""):
    """The render, depth, entropy and (when computed) FisherRF panels of one view, side by side,
    each measured panel with its colour bar."""
    from matplotlib import colormaps
    from matplotlib.colors import LogNorm

    from nerfaug.plotting import new_figure

    panels = 4 if maps.fisher is not None else 3
    fig = new_figure(3.3 * panels, 3.2)
    axes = fig.subplots(1, panels)
    axes[0].imshow(maps.rgb, interpolation="nearest")
    axes[0].set_title("render")
    image = axes[1].imshow(maps.depth, cmap="viridis_r", interpolation="nearest")
    axes[1].set_title("depth (world units)")
    fig.colorbar(image, ax=axes[1], fraction=0.046, pad=0.04)
    image = axes[2].imshow(maps.entropy, cmap="magma", interpolation="nearest", vmin=0)
    axes[2].set_title("ray entropy (bits)")
    fig.colorbar(image, ax=axes[2], fraction=0.046, pad=0.04)
    if maps.fisher is not None:
        positive = maps.fisher[maps.fisher > 0]
        norm = None
        if positive.size and positive.max() > positive.min():
            norm = LogNorm(vmin=float(positive.min()), vmax=float(positive.max()))
        shown = np.where(maps.fisher > 0, maps.fisher, np.nan) if norm is not None else maps.fisher
        # Pixels with no gain (rays that touch no parameter) are drawn in the scale's lowest colour.
        colours = colormaps["inferno"].with_extremes(bad=colormaps["inferno"](0.0))
        image = axes[3].imshow(shown, cmap=colours, norm=norm, interpolation="nearest")
        axes[3].set_title("FisherRF score per pixel" + (" (log)" if norm is not None else ""))
        fig.colorbar(image, ax=axes[3], fraction=0.046, pad=0.04)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    heading = f"step {maps.step}, azimuth {maps.azimuth:.1f} deg, elevation {maps.elevation:.1f} deg"
    fig.suptitle(f"{title}: {heading}" if title else heading, fontsize=9)
    return fig


def figure_bytes(maps: ViewMaps, title: str = "") -> bytes:
    """`figure` as PNG bytes."""
    from nerfaug.plotting import figure_png

    return figure_png(figure(maps, title))


def arrays(maps: ViewMaps) -> dict[str, np.ndarray]:
    """The view's arrays by name (`ARRAYS`, without fisher when not computed) and its pose."""
    named = {name: getattr(maps, name) for name in ARRAYS if getattr(maps, name) is not None}
    return {**named, "pose": maps.pose}


def npz_bytes(maps: ViewMaps) -> bytes:
    """The view's arrays as one .npz file's bytes (`numpy.load` reads it)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays(maps))
    return buffer.getvalue()


def write_maps(maps: ViewMaps, folder: Path, name: str) -> list[Path]:
    """Write `name.png` (the figure) and `name_<array>.npy` into `folder`; returns the files."""
    from nerfaug.jsonio import atomic_write_bytes
    from nerfaug.plotting import save_figure

    written = [save_figure(figure(maps, name), Path(folder) / f"{name}.png")]
    for key, value in arrays(maps).items():
        buffer = io.BytesIO()
        np.save(buffer, value)
        path = Path(folder) / f"{name}_{key}.npy"
        atomic_write_bytes(path, buffer.getvalue())
        written.append(path)
    return written
