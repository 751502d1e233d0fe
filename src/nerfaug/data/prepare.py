"""Prepare a downloaded dataset for experiments: a copy at a chosen image width, masks merged into
the images' alpha, with a record of where it came from (`prepared.json`: the source's digest).

A dataset with splits (NeRF-synthetic) is written in the Blender format, split by split; a
captured set (one listing: LLFF, IDR/DTU, nerfstudio) as one nerfstudio `transforms.json`, in
its own world frame (the experiments move captured sets into the engine frame when they load
them). Images are shrunk by area averaging, by any factor, so every scene of a study can share
one width; the intrinsics are scaled to match.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import torch

from nerfaug.data.blender import write_blender_split
from nerfaug.data.errors import DatasetError
from nerfaug.data.formats import FORMATS, find_split, has_split
from nerfaug.data.nerfstudio import write_nerfstudio
from nerfaug.data.views import Views
from nerfaug.jsonio import atomic_write_json, read_json
from nerfaug.owned import is_empty, mark, marked, overlaps, remove_owned
from nerfaug.progress import progress_bar

PREPARED = "prepared.json"
MARKER_KIND = "prepared-dataset"
SPLITS = ("train", "val", "test", "initial")
LICENCE_NAMES = ("LICENSE", "LICENSE.md", "LICENSE.txt", "LICENCE", "README.md", "README.txt")
# What a preparation writes into its folder (`nerfaug.owned.foreign_files`): an interrupted one is
# removed and started again only when the folder holds nothing else.
HOLDS = (
    PREPARED,
    "transforms.json",
    "transforms_*.json",
    "images/*.png",
    *(f"{split}/*.png" for split in SPLITS),
    *(f"SOURCE-{name}" for name in LICENCE_NAMES),
)


def source_digest(source: Path) -> str:
    """sha256 of every file under `source` (relative path and bytes, in sorted order): the
    identity of a downloaded dataset, recorded with what is prepared and studied from it."""
    digest = hashlib.sha256()
    for path in sorted(p for p in Path(source).rglob("*") if p.is_file()):
        digest.update(path.relative_to(source).as_posix().encode() + b"\0")
        with path.open("rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def shrink(image: torch.Tensor, alpha: torch.Tensor | None, width: int, height: int):
    """An (h, w, 3) image composited over a background and its (h, w) alpha, area-averaged to
    (height, width). Compositing is linear, so averaging the composite equals compositing the
    averaged premultiplied colour and alpha."""
    area = torch.nn.functional.interpolate(image.permute(2, 0, 1)[None], size=(height, width), mode="area")
    small = area[0].permute(1, 2, 0).contiguous()
    if alpha is None:
        return small, None
    return small, torch.nn.functional.interpolate(alpha[None, None], size=(height, width), mode="area")[0, 0]


def shrunk_views(views: Views, width: int, label: str) -> Views:
    """Every view of the lazy `views` at `width` px (height to keep the aspect), one image in memory at a time."""
    cameras = views.cameras
    height = max(1, round(cameras.height * width / cameras.width))
    images, alphas = [], []
    with progress_bar() as bar:
        task = bar.add_task(label, total=len(views), every=10)
        for i in range(len(views)):
            image, alpha = views.loader(i) if views.loader is not None else (views.images[i], None)
            small, small_alpha = shrink(image, alpha, width, height)
            images.append(small)
            alphas.append(small_alpha)
            bar.advance(task)
    stacked = None if any(a is None for a in alphas) else torch.stack(alphas)
    return Views(cameras.resized(width, height), torch.stack(images), list(views.names), stacked)


def prepare_dataset(source: Path, out: Path, width: int) -> Path:
    """Write `source` (a dataset folder in any registered format) into `out` at `width` px.

    Returns `out`. A second call with the same source and width does nothing.

    Raises:
        DatasetError: the source is missing or malformed (naming file, field and value).
        ValueError: `width` is not between 1 and the source's width, `out` holds other files, or
            lies inside the source (which is only read) or holds it.
        FolderRefused: `out` is an interrupted preparation holding a file nerfaug did not write.
    """
    source, out = Path(source), Path(out)
    if overlaps(out, source):
        raise ValueError(
            f"--out {out}: lies inside or holds the source {source}, which is only read; choose a folder outside it"
        )
    train = find_split(source, "train")
    full = train.load(lazy=True)
    if not 1 <= width <= full.cameras.width:
        raise ValueError(
            f"--width {width}: must be between 1 and the width of {source}'s images ({full.cameras.width} px)"
        )
    digest = source_digest(source)
    record = {"source": str(source.resolve()), "source_digest": digest, "format": train.format.name, "width": width}
    if marked(out, MARKER_KIND) and (out / PREPARED).is_file():
        previous = read_json(out / PREPARED)
        if {k: previous.get(k) for k in record} == record:
            return out
        raise ValueError(f"{out}: prepared from another source or at another width; choose another --out")
    if marked(out, MARKER_KIND) and not (out / PREPARED).is_file():  # an interrupted preparation: start again
        remove_owned(out, MARKER_KIND, "move your files out of it, or choose another --out", HOLDS)
    if not is_empty(out):
        raise ValueError(f"{out}: exists and holds files nerfaug did not write; choose an empty or new folder")
    mark(out, MARKER_KIND)
    captured = not has_split(source, "test")
    splits = ["train"] if captured else [s for s in SPLITS if has_split(source, s)]
    counts = {}
    for split in splits:
        views = shrunk_views(find_split(source, split).load(lazy=True), width, f"{source.name} {split}")
        counts[split] = len(views)
        if captured:
            write_nerfstudio(out, views)
        elif FORMATS["blender"].fits(views.cameras):
            write_blender_split(out, split, views)
        else:
            raise DatasetError(
                find_split(source, split).listing, "cameras differ in intrinsics; split datasets must share one camera"
            )
    for name in LICENCE_NAMES:  # the licence travels with the data
        if (source / name).is_file():
            shutil.copyfile(source / name, out / f"SOURCE-{name}")
    atomic_write_json(out / PREPARED, record | {"splits": counts, "captured": captured})
    return out
