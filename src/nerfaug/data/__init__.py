"""Datasets: images with their cameras, read from and written to NeRF-synthetic (Blender) and
nerfstudio/instant-ngp `transforms.json` folders, through one registry of formats (`FORMATS`).

Inside the package imports go one way: errors <- views <- frames <- interface (the `Format`) <-
{blender, nerfstudio, llff, idr} <- formats (the registry).
The names below are imported on first use, so that `nerfaug.data.errors` (and `nerfaug.jsonio`,
which raises its `DatasetError`) stay free of torch and imageio.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from nerfaug.registry import lazy_exports

_HOMES = {
    "DatasetError": "nerfaug.data.errors",
    "Views": "nerfaug.data.views",
    "load_blender": "nerfaug.data.blender",
    "load_blender_split": "nerfaug.data.blender",
    "write_blender_split": "nerfaug.data.blender",
    "load_nerfstudio": "nerfaug.data.nerfstudio",
    "write_nerfstudio": "nerfaug.data.nerfstudio",
    "Format": "nerfaug.data.interface",
    "DatasetSplit": "nerfaug.data.interface",
    "NewFrame": "nerfaug.data.interface",
    "EXCHANGE_FORMAT": "nerfaug.data.formats",
    "FORMATS": "nerfaug.data.formats",
    "detect_format": "nerfaug.data.formats",
    "find_split": "nerfaug.data.formats",
    "get_format": "nerfaug.data.formats",
    "has_split": "nerfaug.data.formats",
    "load_dataset": "nerfaug.data.formats",
    "register_format": "nerfaug.data.formats",
    "require_split": "nerfaug.data.formats",
}

if TYPE_CHECKING:
    from nerfaug.data.blender import (
        load_blender,
        load_blender_split,
        write_blender_split,
    )
    from nerfaug.data.errors import DatasetError
    from nerfaug.data.formats import (
        EXCHANGE_FORMAT,
        FORMATS,
        detect_format,
        find_split,
        get_format,
        has_split,
        load_dataset,
        register_format,
        require_split,
    )
    from nerfaug.data.interface import DatasetSplit, Format, NewFrame
    from nerfaug.data.nerfstudio import load_nerfstudio, write_nerfstudio
    from nerfaug.data.views import Views


__getattr__, __dir__ = lazy_exports(__name__, _HOMES, globals())


__all__ = [
    "EXCHANGE_FORMAT",
    "FORMATS",
    "DatasetError",
    "DatasetSplit",
    "Format",
    "NewFrame",
    "Views",
    "detect_format",
    "find_split",
    "get_format",
    "has_split",
    "load_blender",
    "load_blender_split",
    "load_dataset",
    "register_format",
    "require_split",
    "load_nerfstudio",
    "write_blender_split",
    "write_nerfstudio",
]
