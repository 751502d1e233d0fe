"""The one way figures are made and saved: matplotlib's object-oriented API (no pyplot, so no
global state and no GUI backend; safe in any process) and an atomic PNG write.

FIGURE_DPI is 110 for every figure. The report embeds its PNGs in one HTML page whose width is
capped at 1200 px; at 110 dpi its widest figure (four hemisphere maps, 14 in) is already about
1550 px wide, so a higher dpi (maps.py used 130) only adds bytes, about (130/110)^2 = 1.4x, to every
page and run folder, while 6-pt labels stay about 9 px tall and legible.
"""

from __future__ import annotations

import io
from pathlib import Path

from nerfaug.jsonio import atomic_write_bytes

FIGURE_DPI = 110


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


__all__ = ["FIGURE_DPI", "figure_png", "new_figure", "save_figure"]
