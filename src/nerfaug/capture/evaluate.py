"""How good a session's NeRF is on held-out views: PSNR, SSIM and LPIPS of its renders against a
dataset split, or the views a sparse start kept apart (what `nerfaug eval` reports, as
nerfstudio's `ns-eval` does for its models)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import nerfaug
from nerfaug import owned
from nerfaug.capture.dataset import HELD_OUT_KEY
from nerfaug.capture.model import SessionModel
from nerfaug.data.formats import has_split, load_dataset
from nerfaug.data.views import Views, spread_over_frames
from nerfaug.errors import FolderRefused
from nerfaug.evaluation import EvaluationResult, evaluate_views
from nerfaug.jsonio import atomic_write_json
from nerfaug.layouts import HELD_OUT_SHARE
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
    return narrowed(views, None, max_views)


def narrowed(views: Views, names: list[str] | None, max_views: int | None) -> Views:
    """Those of `views` named in `names` (all when None), in their order; of those, `max_views`
    spread evenly over them (all when None or no fewer). Lazy views stay lazy."""
    if names is not None:
        wanted = set(names)
        views = views.subset([i for i, name in enumerate(views.names) if name in wanted])
    if max_views is None or max_views >= len(views):
        return views
    return views.subset(spread_over_frames(max_views, len(views)))


@dataclass(frozen=True)
class TestViews:
    """Which views of a split a session is scored on (`choose_test_views`)."""

    names: list[str] | None
    """the frames to score, by name; None: every frame of the split."""
    says: str
    """which views they are, for the user: "split 'test' of DATA", "the 33 views ... kept apart"."""
    note: str | None = None
    """one line when the views may include ones the session trains on, saying why."""


def choose_test_views(start: dict | None, started_from: str, data: Path, split: str, listed: list[str]) -> TestViews:
    """The views of `split` of `data` (its frames' names `listed`) a session is scored on.

    A test split of its own (NeRF-synthetic's) is scored whole. A set without one (a captured
    set's one listing, every split of which is all of it; a Blender folder of a train split only)
    scores the views a sparse start kept apart (`start["held_out"]`: neither trained on nor
    candidates) when `data` lists them all. Otherwise every frame is scored, with a note where the
    listing is the captured set's one listing, saying why: the session trains on the whole set, was
    started before views were kept apart, or `data` is another folder.

    Args:
        start: the session's sparse start record (`SessionState.start`), None when it has none.
        started_from: the split the session was started from (`SessionState.source.split`).
        data: the dataset folder scored.
        split: the split asked for.
        listed: the names of that split's frames, in order.
    """
    kept = None if start is None else start.get(HELD_OUT_KEY)
    own = has_split(data, split)
    if own and split != started_from:
        return TestViews(None, f"split '{split}' of {data}")
    if kept and set(kept) <= set(listed):
        return TestViews(kept, f"the {len(kept)} views of {data} kept apart for testing when the session started")
    if own:  # the split trained from, of a set with splits: the trained-on views are counted
        return TestViews(None, f"split '{split}' of {data}")
    every = f"all {len(listed)} views of {data} (one listing: every split of it is all of it)"
    if start is None:
        note = "the session trains on a whole set, so no view of it is held out; score it on views kept out of it"
    elif kept is None:
        note = (
            "the session was started before a sparse start kept views apart for testing, so none is held out; "
            "a session started again with --initial keeps a spread quarter apart"
        )
    elif not kept:
        few = f"its {start['of']} views are too few (one in {HELD_OUT_SHARE} is kept)"
        note = f"the session's start kept no view apart for testing: {few}"
    else:
        missing = next(name for name in kept if name not in set(listed))
        note = f"{data} does not list the views the session's start kept apart for testing (e.g. {missing})"
    return TestViews(None, every, note)


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


def write_evaluation(
    out: Path, result: EvaluationResult, run: Path, step: int, data: Path, split: str, views: str
) -> None:
    """`result`, the session in `run` at `step` scored on `split` of `data` (which of its `views`:
    `TestViews.says`; every view's name is in `per_view`), as the JSON `out`, marked as an
    evaluation nerfaug wrote (which `check_evaluation_out` lets be overwritten)."""
    kind = {"kind": EVAL_KIND, "version": nerfaug.__version__}
    record = {"nerfaug": kind, "session": str(run), "step": step, "data": str(data), "split": split, "views": views}
    atomic_write_json(out, {**record, **result.to_dict()})
