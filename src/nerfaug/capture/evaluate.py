"""How good a session's NeRF is on held-out views: PSNR, SSIM and LPIPS of its renders against a
dataset split (what `nerfaug eval` reports, as nerfstudio's `ns-eval` does for its models)."""

from __future__ import annotations

import json
from pathlib import Path

import nerfaug
from nerfaug import owned
from nerfaug.capture.model import SessionModel
from nerfaug.data.formats import load_dataset
from nerfaug.data.views import Views, spread_over_frames
from nerfaug.errors import FolderRefused
from nerfaug.evaluation import EvaluationResult, evaluate_views
from nerfaug.jsonio import atomic_write_json
from nerfaug.selection.candidates import matching_poses

# The key marking a JSON `write_evaluation` wrote (and may overwrite).
EVAL_KIND = "session-eval"


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
        `EvaluationResult`: per view and mean PSNR (dB), SSIM and LPIPS (None when unavailable),
        and per view `trained_on`: whether the session trains on that pose (then the view scores
        how well it was fitted, not how well the NeRF generalises; `trained_on_count`).
    """
    cameras = model.hemisphere.cameras_to_engine(views.cameras).to(model.device)
    background = model.background_tensor()

    def render(_, index: int):
        return model.model.render_image(cameras, index, background)

    result = evaluate_views(render, views, lpips=lpips, progress=progress)
    # Compared in the engine frame, as proposals compare poses, so the tolerance ignores the data's units.
    seen = matching_poses(cameras.camera_to_world.cpu(), model.train_cameras.camera_to_world.cpu())
    for row in result.per_view:
        row["trained_on"] = bool(seen[row["index"]])
    return result


def trained_on_count(result: EvaluationResult) -> int:
    """How many of an `evaluate_model` result's views the session trains on."""
    return sum(bool(row.get("trained_on")) for row in result.per_view)


def check_evaluation_out(out: Path, data: Path) -> None:
    """Refuse to write an evaluation (`write_evaluation`) inside the dataset `data` it scores, or
    over a file that is not an evaluation nerfaug wrote.

    Raises:
        FolderRefused: naming the file and what to do.
    """
    if owned.overlaps(out, data):
        raise FolderRefused(f"{out}: lies inside the dataset {data}; nothing is written into an input folder")
    if out.exists():
        try:
            ours = json.loads(out.read_text()).get("nerfaug", {}).get("kind") == EVAL_KIND
        except (OSError, ValueError, AttributeError):
            ours = False
        if not ours:
            raise FolderRefused(
                f"{out}: exists and is not an evaluation nerfaug wrote, so it is not overwritten; choose another --out"
            )


def write_evaluation(out: Path, result: EvaluationResult, run: Path, step: int, data: Path, split: str) -> None:
    """`result`, the session in `run` at `step` scored on `split` of `data`, as the JSON `out`,
    marked as an evaluation nerfaug wrote (which `check_evaluation_out` lets be overwritten)."""
    kind = {"kind": EVAL_KIND, "version": nerfaug.__version__}
    record = {"nerfaug": kind, "session": str(run), "step": step, "data": str(data), "split": split}
    atomic_write_json(out, {**record, **result.to_dict()})
