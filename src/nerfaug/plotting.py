"""The one way figures are made and saved: matplotlib's object-oriented API (no pyplot, so no
global state and no GUI backend; safe in any process) and an atomic PNG write.

FIGURE_DPI is 110 for every figure. The report embeds its PNGs in one HTML page whose width is
capped at 1200 px; at 110 dpi its widest figure (four hemisphere maps, 14 in) is already about
1550 px wide, so a higher dpi (maps.py used 130) only adds bytes, about (130/110)^2 = 1.4x, to every
page and run folder, while 6-pt labels stay about 9 px tall and legible.

Scores spanning many decades (FisherRF's) are drawn one way everywhere (`draw_log_image`): on a log
scale clipped to `LOG_DECADES`, at the size of the panels beside them, the scale named on the bar.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from nerfaug.jsonio import atomic_write_bytes

FIGURE_DPI = 110
# A log colour scale spans at most this many decades below its largest value. FisherRF's score is a
# sum of squared gradients: pixels whose rays cross empty space score 10^-15 or less of the
# brightest pixel, and a log scale down to them (15-24 decades measured) leaves every pixel that
# matters in the top fifth of the colour map. Four decades keep every pixel above 1/10^4 of the
# brightest distinct, and draw the rest in the lowest colour, where they are worth nothing.
LOG_DECADES = 4


def new_figure(width: float, height: float):
    """A matplotlib Figure of `width` x `height` inches, not registered with pyplot."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height))


def figure_png(figure, dpi: int = FIGURE_DPI) -> bytes:
    """`figure` rendered as PNG bytes (tight bounding box), e.g. to answer an HTTP request."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    return buffer.getvalue()


def save_figure(figure, path: str | Path, dpi: int = FIGURE_DPI) -> Path:
    """Render `figure` as a PNG (tight bounding box) and write it atomically to `path`, creating
    its folder: a reader never sees a half-written image. Returns the path."""
    path = Path(path)
    atomic_write_bytes(path, figure_png(figure, dpi))
    return path


def legend_below(figure, axes) -> None:
    """One legend for all of `axes`' labelled artists (each label once), below the panels, so it
    never hides a curve."""
    legend = {label: handle for ax in axes for handle, label in zip(*ax.get_legend_handles_labels())}
    figure.legend(
        legend.values(),
        legend.keys(),
        loc="upper center",
        bbox_to_anchor=(0.5, 0.0),
        ncol=min(4, len(legend)),
        fontsize=8,
        frameon=False,
    )


def log_range(values, decades: int = LOG_DECADES) -> tuple[float, float] | None:
    """(low, high) of a log colour scale over the positive `values`: from their largest down to at
    most `decades` decades below it; None when no value is positive."""
    values = np.asarray(values, dtype=np.float64)
    positive = values[np.isfinite(values) & (values > 0)]
    if not positive.size:
        return None
    high = float(positive.max())
    return max(float(positive.min()), high / 10.0**decades), high


def upsample(image, height: int, width: int) -> np.ndarray:
    """`image` enlarged to (height, width) by bilinear interpolation between pixel centres, so a
    coarser image is drawn at the size of the panels beside it without showing its pixels as blocks.

    Args:
        image: array with shape (h, w), h <= height, w <= width.
        height, width: the size to draw it at.

    Returns:
        float64 array with shape (height, width).

    Example:
        >>> upsample(np.array([[0.0, 1.0]]), 1, 4)
        array([[0.  , 0.25, 0.75, 1.  ]])
    """
    image = np.asarray(image, dtype=np.float64)
    h, w = image.shape

    def taps(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        at = np.clip((np.arange(n_out) + 0.5) * n_in / n_out - 0.5, 0, n_in - 1)
        low = np.floor(at).astype(int)
        return low, np.minimum(low + 1, n_in - 1), at - low

    r0, r1, fr = taps(h, height)
    c0, c1, fc = taps(w, width)
    rows = image[r0] * (1 - fr)[:, None] + image[r1] * fr[:, None]
    return rows[:, c0] * (1 - fc) + rows[:, c1] * fc


def colour_bar(figure, image, ax, label: str):
    """The colour bar of an image panel, labelled with what its values are and their unit (small
    type: a panel's label is often two lines and must not reach the next panel)."""
    bar = figure.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    bar.set_label(label, fontsize=7)
    bar.ax.tick_params(labelsize=7)
    return bar


def draw_log_image(figure, ax, image, shape: tuple[int, int], value_range: tuple[float, float] | None, label: str):
    """Draw a score image of positive values (FisherRF's) on a log colour scale clipped to
    `value_range`, at `shape` pixels (interpolated in log space when it is coarser), with a colour
    bar labelled `label` and the scale: values at or below the low end, 0 included, take the lowest
    colour. Returns the AxesImage.

    Args:
        figure: the matplotlib Figure of `ax`.
        ax: the Axes to draw in.
        image: array with shape (h, w), >= 0.
        shape: (H, W) to draw it at, e.g. the render's beside it.
        value_range: (low, high) of the scale (`log_range`); None: a linear scale over the image.
        label: what the values are, with their unit.
    """
    from matplotlib import colormaps
    from matplotlib.colors import LogNorm

    image = np.asarray(image, dtype=np.float64)
    cmap = colormaps["inferno"]
    if value_range is None:
        shown = upsample(image, *shape) if image.shape != tuple(shape) else image
        drawn = ax.imshow(shown, cmap=cmap, interpolation="nearest")
        colour_bar(figure, drawn, ax, label)
        return drawn
    low, high = value_range
    logs = np.log10(np.clip(image, low, high))
    shown = 10.0 ** (upsample(logs, *shape) if image.shape != tuple(shape) else logs)
    drawn = ax.imshow(shown, cmap=cmap, norm=LogNorm(low, high, clip=True), interpolation="nearest")
    decades = np.log10(high / low)
    colour_bar(figure, drawn, ax, f"{label}\nlog scale, top {decades:.2g} decades")
    return drawn


__all__ = [
    "FIGURE_DPI",
    "LOG_DECADES",
    "colour_bar",
    "draw_log_image",
    "figure_png",
    "log_range",
    "new_figure",
    "save_figure",
    "upsample",
]
