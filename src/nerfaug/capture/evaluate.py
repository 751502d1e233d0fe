"""How good a session's NeRF is on held-out views: PSNR, SSIM and LPIPS of its renders against a
dataset split (what `nerfaug eval` reports, as nerfstudio's `ns-eval` does for its models)."""

from __future__ import annotations

from pathlib import Path

from nerfaug.capture.model import SessionModel
from nerfaug.data.formats import load_dataset
from nerfaug.data.views import Views, spread_over_frames
from nerfaug.evaluation import EvaluationResult, evaluate_views


def load_held_out(
    data: str | Path, split: str = "test", downscale: int = 1, background=(1.0, 1.0, 1.0), max_views: int | None = None
) -> Views:
    """`split` of the dataset folder `data`, world frame, shrunk by `downscale` (a session's
    training resolution) and composited over `background` (images loaded on access); when
    `max_views` is given, that many of its views spread evenly over the split's frames (a test
    split is often an orbit, and its first frames would all look at one side of the object)."""
    views = load_dataset(Path(data), split, lazy=True, downscale=downscale, background=tuple(background))
    if max_views is None or max_views >= len(views):
        return views
    kept = spread_over_frames(max_views, len(views))
    source = views.loader
    return Views(views.cameras[kept], None, [views.names[i] for i in kept], loader=lambda i: source(kept[i]))


def evaluate_model(model: SessionModel, views: Views, lpips="auto", progress: bool = False) -> EvaluationResult:
    """Render each of `views` with the session's NeRF and score it against its image.

    Args:
        model: the session's NeRF.
        views: world-frame views with images (`load_held_out`); their intrinsics and size are
            the renders' (give them at the training resolution to score what was trained).
        lpips: as `nerfaug.evaluation.evaluate_views` ("auto": when its weights are installed).
        progress: show a progress bar.

    Returns:
        `EvaluationResult`: per view and mean PSNR (dB), SSIM and LPIPS (None when unavailable).
    """
    cameras = model.hemisphere.cameras_to_engine(views.cameras).to(model.device)
    background = model.background_tensor()

    def render(_, index: int):
        return model.model.render_image(cameras, index, background)

    return evaluate_views(render, views, lpips=lpips, progress=progress)
