"""Which reader a dataset folder needs: the registry of on-disk formats, and `load_dataset`.

Adding a format is one reader module plus one `Format` entry in `FORMATS`. Nothing inside
`nerfaug.data` imports this module, so the readers never import back the code that picks them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from nerfaug.data.blender import load_blender_split
from nerfaug.data.errors import DatasetError
from nerfaug.data.nerfstudio import load_nerfstudio
from nerfaug.data.views import Views


@dataclass(frozen=True)
class Format:
    """A dataset format: the file that marks a folder as holding `split` in it, and its reader.

    Attributes:
        name: short name ("blender", "nerfstudio").
        marker: `marker(root, split)` is the file whose presence identifies the format.
        load: `load(root, split, **kwargs)` reads that split as `Views`.
    """

    name: str
    marker: Callable[[Path, str], Path]
    load: Callable[..., Views]


FORMATS: tuple[Format, ...] = (
    # Blender first: a folder holding both kinds of file is read by its split files.
    Format("blender", lambda root, split: root / f"transforms_{split}.json", load_blender_split),
    # nerfstudio's one transforms.json has no splits: every split reads all of its frames.
    Format(
        "nerfstudio",
        lambda root, split: root / "transforms.json",
        lambda root, split, **kwargs: load_nerfstudio(root, **kwargs),
    ),
)


def detect_format(root: str | Path, split: str = "train") -> Format | None:
    """The first format in `FORMATS` whose marker file exists for `split` under `root`."""
    root = Path(root)
    return next((f for f in FORMATS if f.marker(root, split).exists()), None)


def load_dataset(root: str | Path, split: str = "train", **kwargs) -> Views:
    """Load a split from a Blender (`transforms_{split}.json`) or nerfstudio (`transforms.json`)
    folder, whichever `root` holds. `kwargs` go to the reader (background, downscale, lazy).

    Raises:
        DatasetError: the folder does not exist, holds no known format, or its files are bad.
    """
    root = Path(root)
    found = detect_format(root, split)
    if found is not None:
        return found.load(root, split, **kwargs)
    if not root.is_dir():
        raise DatasetError(root, "dataset folder does not exist")
    raise DatasetError(root, f"no transforms_{split}.json (Blender format) nor transforms.json (nerfstudio format)")
