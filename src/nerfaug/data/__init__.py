"""Datasets: images with their cameras, read from and written to NeRF-synthetic (Blender) and
nerfstudio/instant-ngp `transforms.json` folders."""

from nerfaug.data.blender import load_blender, load_blender_split, write_blender_split
from nerfaug.data.errors import DatasetError
from nerfaug.data.nerfstudio import load_nerfstudio, write_nerfstudio
from nerfaug.data.views import Views, load_dataset

__all__ = [
    "DatasetError", "Views", "load_blender", "load_blender_split", "load_dataset",
    "load_nerfstudio", "write_blender_split", "write_nerfstudio",
]
