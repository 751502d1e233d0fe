"""What a session asks of the dataset it grows, beyond its format (`nerfaug.data.formats`): which
split a new session trains on (and which of its views, for a sparse start), its frames as the
trainer sees them, the names new frames may take, and views that repeat a pose."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import torch

from nerfaug.cameras import Cameras
from nerfaug.capture.requests import START_LAYOUTS, RequestError, SparseStart
from nerfaug.data.errors import DatasetError
from nerfaug.data.formats import has_split
from nerfaug.data.frames import read_image
from nerfaug.data.interface import DatasetSplit
from nerfaug.data.views import Views
from nerfaug.data.world_frame import Hemisphere
from nerfaug.layouts import held_out_count, split_views

# A new frame's image name (file stem): no separators, no leading dot.
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")

# A dataset nerfaug rendered (`nerfaug scene render`) records its settings here; its initial
# split holds the views taken as already captured, its train split the pool.
RENDER_MANIFEST = "scene.json"

# The key of a sparse start's record (`SessionState.start`) naming the views kept apart for testing;
# a session started before views were kept apart has none.
HELD_OUT_KEY = "held_out"


def default_split(root: Path) -> tuple[str, str]:
    """The split a new session trains on when none is given, and why (for the user).

    A dataset nerfaug rendered has a candidate pool of hundreds of views as its train split and
    the views taken as already captured as its initial split: the initial split is the default.
    Any other dataset trains on its train split (or its single nerfstudio transforms file).

    Returns:
        (split, reason): e.g. ("initial", "a dataset nerfaug rendered: ...").
    """
    root = Path(root)
    if (root / RENDER_MANIFEST).is_file() and has_split(root, "initial"):
        return "initial", (
            f"the initial views of a dataset nerfaug rendered ({root / RENDER_MANIFEST}); its train split is "
            "the pool of candidate views, use --split train to train on all of them"
        )
    return "train", "the dataset's train split (--split chooses another)"


def duplicate_frames(cameras: Cameras, names: Sequence[str], tolerance: float = 1e-5) -> list[tuple[str, str]]:
    """Pairs of frames (by name) whose camera poses coincide: the same view twice.

    Args:
        cameras: n cameras; their `camera_to_world` (n, 4, 4) are compared.
        names: n frame names.
        tolerance: largest difference between matrix entries still taken as the same pose.
    """
    poses = cameras.camera_to_world.reshape(len(names), -1).double()
    close = (poses[:, None] - poses[None]).abs().amax(-1) <= tolerance
    return [(names[i], names[j]) for i, j in close.triu(1).nonzero().tolist()]


def engine_views(dataset: DatasetSplit, start: int, downscale: int, background, hemisphere: Hemisphere) -> Views:
    """Frames `start:` of `dataset` as the trainer sees them: shrunk by `downscale`, composited
    over `background` (RGB in [0, 1]), cameras in the engine frame of `hemisphere`.

    Raises:
        DatasetError: an image is missing, unreadable, or not the size of the dataset's camera.
    """
    frames = dataset.frames()[start:]
    files = dataset.frame_files(frames, start)
    background = torch.tensor(tuple(background), dtype=torch.float32)
    loaded = [
        read_image(f, background, downscale, dataset.listing, f"frames[{start + i}].file_path")
        for i, f in enumerate(files)
    ]
    full = dataset.load(lazy=True).cameras
    cameras = full[list(range(start, len(full)))]
    height, width = full.height // downscale, full.width // downscale
    for i, (image, _) in enumerate(loaded):
        if image.shape[:2] != (height, width):
            raise DatasetError(
                dataset.listing,
                f"image size differs from the dataset's {full.width}x{full.height}",
                field=f"frames[{start + i}].file_path",
                value=str(files[i]),
            )
    if (width, height) != (cameras.width, cameras.height):
        cameras = cameras.resized(width, height)
    cameras = hemisphere.cameras_to_engine(cameras)
    alphas = None
    if all(a is not None for _, a in loaded):
        alphas = torch.stack([a for _, a in loaded])
    return Views(cameras, torch.stack([im for im, _ in loaded]), [str(f["file_path"]) for f in frames], alphas)


def sparse_start(source: DatasetSplit, views: Views, hemisphere: Hemisphere, start: SparseStart):
    """(`source` narrowed to a sparse start's initial views, their cameras, the candidate pool:
    a transforms dict of the other views' world-frame poses and names, the start's record).

    A set with a test split of its own is scored on it. Any other (a captured set's one listing,
    a Blender folder with a train split only) keeps a spread quarter of its views (at most
    `HELD_OUT_MOST`) apart first, as the experiments keep it (`split_views`): neither initial nor
    a candidate, named in the record's "held_out" (`HELD_OUT_KEY`) for `nerfaug eval` to score."""
    held_out = not has_split(source.root, "test")
    world = views.cameras.camera_to_world
    count = held_out_count(len(views)) if held_out else 0
    try:
        split = split_views(hemisphere.to_engine(world), count, start.initial, start.layout, START_LAYOUTS)
    except ValueError as error:
        kept = f", {count} of them held out for testing" if count else ""
        of = f"of {len(views)} views of {source.listing}{kept}"
        raise RequestError("initial", start.initial, f"{error} ({of})") from None
    if not split.pool:
        raise RequestError("initial", start.initial, f"must leave candidates: the dataset has {len(views)} views")
    frames = [{"file_path": views.names[i], "transform_matrix": world[i].double().tolist()} for i in split.pool]
    record = {
        "initial": start.initial,
        "layout": start.layout,
        "of": len(views),
        "names": [views.names[i] for i in split.initial],
    }
    if held_out:  # [] when the set is too small to keep any apart
        record[HELD_OUT_KEY] = [views.names[i] for i in split.held_out]
    chosen = split.initial
    return replace(source, only=tuple(chosen)), views.cameras[chosen], {"frames": frames}, record
