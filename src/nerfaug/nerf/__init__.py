"""The NeRF engine: encodings and fields, samplers, volume rendering, and the trainer."""

from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel
from nerfaug.nerf.registry import ENCODINGS, FIELDS, SAMPLERS, build_encoding, build_field, build_sampler
from nerfaug.nerf.sampler import Sampler
from nerfaug.nerf.trainer import Trainer, TrainingDiverged
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights

__all__ = [
    "ENCODINGS",
    "FIELDS",
    "SAMPLERS",
    "NerfConfig",
    "NerfModel",
    "RenderOutput",
    "Sampler",
    "Trainer",
    "TrainingDiverged",
    "build_encoding",
    "build_field",
    "build_sampler",
    "composite",
    "render_weights",
]
