"""The registry of on-disk dataset formats (`FORMATS`), and what picks one: `detect_format`,
`find_split`, `load_dataset`.

A format is one `Format` object with every operation on a folder in it (`nerfaug.data.interface`).
Adding a format is one module defining it plus one entry in `FORMATS` (or, for a format defined
outside the package, `with register_format(MyFormat()):`). No format's module imports this one,
so the formats never import back the code that picks them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

from nerfaug.containment import inside
from nerfaug.data.blender import BlenderFormat
from nerfaug.data.errors import DatasetError
from nerfaug.data.idr import IdrFormat
from nerfaug.data.interface import DatasetSplit, Format
from nerfaug.data.llff import LlffFormat
from nerfaug.data.nerfstudio import NerfstudioFormat
from nerfaug.data.views import Views
from nerfaug.registry import lookup

FORMATS: dict[str, Format] = {
    # Blender first: a folder holding both kinds of listing is read by its split files. It is also
    # the plainest: a session keeps a dataset in it whenever it describes the cameras exactly.
    "blender": BlenderFormat(),
    "nerfstudio": NerfstudioFormat(),
    # Captured sets: IDR before LLFF, since DTU copies often carry a poses_bounds.npy beside
    # cameras_sphere.npz, whose cameras are the calibrated ones.
    "idr": IdrFormat(),
    "llff": LlffFormat(),
}
"""Dataset formats by name, in the order they are detected."""

EXCHANGE_FORMAT = "nerfstudio"
"""The format other tools open most widely: what an export writes unless told otherwise."""


@contextlib.contextmanager
def register_format(fmt: Format) -> Iterator[Format]:
    """Register `fmt` (after the built-in formats) while the block runs.

    Example:
        >>> with register_format(MyFormat()):  # doctest: +SKIP
        ...     views = load_dataset("data/mine")
    """
    if fmt.name in FORMATS:
        raise ValueError(f"a dataset format named {fmt.name!r} is registered already")
    FORMATS[fmt.name] = fmt
    try:
        yield fmt
    finally:
        FORMATS.pop(fmt.name, None)


def get_format(name: str) -> Format:
    """The format `name`, or a ValueError naming it and the known ones."""
    return lookup(FORMATS, "dataset format", name)


def detect_format(root: str | Path, split: str = "train") -> Format | None:
    """The first format in `FORMATS` that holds `split` under `root`."""
    root = Path(root)
    return next((f for f in FORMATS.values() if f.detect(root, split)), None)


def has_split(root: str | Path, split: str) -> bool:
    """Whether `root` holds `split` as a split of its own (not a listing every split reads)."""
    root = Path(root)
    return any(f.has_splits and f.detect(root, split) for f in FORMATS.values())


def _missing(root: Path, split: str) -> DatasetError:
    if not root.is_dir():
        return DatasetError(root, "dataset folder does not exist")
    expected = " nor ".join(f"{f.listing(root, split).relative_to(root)} ({f.name} format)" for f in FORMATS.values())
    return DatasetError(root, f"no {expected}")


def find_split(root: str | Path, split: str = "train") -> DatasetSplit:
    """`split` of the dataset folder `root`, in the format that holds it.

    Raises:
        DatasetError: the folder does not exist, holds no known format, or its listing is a link
            to a file outside it (what is copied from a dataset is read from the dataset itself).
    """
    root = Path(root)
    found = detect_format(root, split)
    if found is None:
        raise _missing(root, split)
    inside(root, found.listing(root, split), "this listing")
    return DatasetSplit(root, found, split)


def require_split(root: str | Path, split: str, purpose: str) -> DatasetSplit:
    """`split` of the dataset folder `root` as a split of its own, for `purpose` (e.g. "a test
    split is needed for evaluation").

    Raises:
        DatasetError: `root` holds no known format, or its format holds no such split: naming the
            file that would list it, or saying that the format keeps one listing for every split.
    """
    root = Path(root)
    if has_split(root, split):
        return find_split(root, split)
    fmt = find_split(root, "train").format
    if not fmt.has_splits:
        raise DatasetError(
            fmt.listing(root, split),
            f"{purpose}: the {fmt.name} format keeps one listing for every split; add the {split} views as "
            + " or ".join(f"{f.listing(root, split).name} ({f.name} format)" for f in FORMATS.values() if f.has_splits),
        )
    raise DatasetError(fmt.listing(root, split), f"{purpose}: file not found")


def load_dataset(root: str | Path, split: str = "train", **kwargs) -> Views:
    """Load a split from a folder in any registered format (Blender: `transforms_{split}.json`;
    nerfstudio: `transforms.json`), whichever `root` holds. `kwargs` go to the reader
    (background, downscale, lazy).

    Raises:
        DatasetError: the folder does not exist, holds no known format, or its files are bad
            (`PathRefused` for one that leads outside `root`).
    """
    return find_split(root, split).load(**kwargs)


def plainest_format(source: DatasetSplit, cameras) -> Format:
    """The format a copy of `source` is kept in: the first of `FORMATS` when it describes
    `cameras` exactly and the source records no lens distortion; else the source's own, or, when
    that keeps masks apart from the images, `EXCHANGE_FORMAT` (whose images carry the masks as
    their alpha: what a session reads its views with)."""
    plainest = next(iter(FORMATS.values()))
    header, frames = source.read()
    if plainest.fits(cameras) and not source.format.lens_distortion(header, frames):
        return plainest
    if source.format.has_masks(Path(source.root)):
        return FORMATS[EXCHANGE_FORMAT]
    return source.format
