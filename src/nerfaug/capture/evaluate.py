"""How good a session's NeRF is on held-out views: PSNR, SSIM and LPIPS of its renders against a
dataset split (what `nerfaug eval` reports, as nerfstudio's `ns-eval` does for its models)."""

from __future__ import annotations

from pathlib import Path

import torch

from nerfaug.cameras import Cameras
from nerfaug.data import Views, load_dataset
from nerfaug.evaluation import EvaluationResult, evaluate_views


def load_held_out(session, data: str | Path, split: str = "test", max_views: int | None = None) -> Views:
    """`split` of the dataset folder `data`, world frame, at the session's training resolution
    (its `downscale`) and composited over its background (images loaded on access); its first
    `max_views` views when given."""
    views = load_dataset(
        Path(data), split, lazy=True, downscale=session.state.downscale, background=tuple(session.state.background)
    )
    if max_views is None or max_views >= len(views):
        return views
    # The first views keep their indices, so the lazy loader serves them unchanged.
    return Views(views.cameras[list(range(max_views))], None, views.names[:max_views], loader=views.loader)


def engine_cameras(session, cameras: Cameras) -> Cameras:
    """World-frame `cameras` moved into the engine frame the session's NeRF is trained in."""
    return session.hemisphere.cameras_to_engine(cameras)


def evaluate_session(session, views: Views, lpips="auto", progress: bool = False) -> EvaluationResult:
    """Render each of `views` with the session's NeRF and score it against its image.

    Args:
        session: a `CaptureSession` opened with its model.
        views: world-frame views with images (`load_held_out`); their intrinsics and size are
            the renders' (give them at the training resolution to score what was trained).
        lpips: as `nerfaug.evaluation.evaluate_views` ("auto": when its weights are installed).
        progress: show a progress bar.

    Returns:
        `EvaluationResult`: per view and mean PSNR (dB), SSIM and LPIPS (None when unavailable).
    """
    session.require_model()
    device = session.trainer.device
    cameras = engine_cameras(session, views.cameras).to(device)
    background = torch.tensor(session.state.background, dtype=torch.float32, device=device)

    def render(_, index: int):
        return session.trainer.model.render_image(cameras, index, background)

    return evaluate_views(render, views, lpips=lpips, progress=progress)
