"""`Views`: a set of images with their cameras; the unit that datasets, the trainer and the oracle
exchange."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from nerfaug.cameras import Cameras


@dataclass
class Views:
    """Images (composited over the background) and the cameras that took them.

    Attributes:
        cameras: `n` cameras sharing one image size.
        images: Tensor with shape (n, height, width, 3), float32 in [0, 1]; or None while lazy.
        names: one name per view (the `file_path` of the Blender format).
        alphas: Tensor with shape (n, height, width) in [0, 1] when the source had an alpha channel.
        loader: for lazy views, loads image `i` as (image (h, w, 3), alpha (h, w) or None).
    """

    cameras: Cameras
    images: Tensor | None
    names: list[str]
    alphas: Tensor | None = None
    loader: Callable[[int], tuple[Tensor, Tensor | None]] | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.cameras)

    def image(self, index: int) -> Tensor:
        """Image `index` with shape (height, width, 3), loading it if the views are lazy."""
        if self.images is not None:
            return self.images[index]
        assert self.loader is not None
        return self.loader(index)[0]

    def materialised(self) -> Views:
        """The same views with every image in memory."""
        if self.images is not None:
            return self
        assert self.loader is not None
        loaded = [self.loader(i) for i in range(len(self))]
        alphas = None
        if all(a is not None for _, a in loaded):
            alphas = torch.stack([a for _, a in loaded])
        return Views(self.cameras, torch.stack([im for im, _ in loaded]), list(self.names), alphas)

    def subset(self, indices) -> Views:
        """The views at `indices` (a list of ints), in that order (lazy views stay lazy)."""
        indices = [int(i) for i in indices]
        if self.images is None and self.loader is not None:
            loader = self.loader
            names = [self.names[i] for i in indices]
            return Views(self.cameras[indices], None, names, loader=lambda k: loader(indices[k]))
        full = self.materialised()
        return Views(
            full.cameras[indices],
            full.images[indices],
            [full.names[i] for i in indices],
            None if full.alphas is None else full.alphas[indices],
        )

    @staticmethod
    def cat(parts: list[Views]) -> Views:
        parts = [p.materialised() for p in parts]
        alphas = None
        if all(p.alphas is not None for p in parts):
            alphas = torch.cat([p.alphas for p in parts])
        return Views(
            Cameras.cat([p.cameras for p in parts]),
            torch.cat([p.images for p in parts]),
            [n for p in parts for n in p.names],
            alphas,
        )


def spread_over_frames(count: int, total: int) -> list[int]:
    """`count` frame indices spread evenly over `total` frames (all of them when count >= total).

    Example:
        >>> spread_over_frames(4, 200)
        [0, 66, 133, 199]
    """
    if count >= total:
        return list(range(total))
    return [int(i) for i in np.round(np.linspace(0, total - 1, count)).astype(int)]
