"""The NeRF engine: encodings and fields, samplers, volume rendering, and the trainer."""

from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel
from nerfaug.nerf.trainer import Trainer, TrainingDiverged
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights

__all__ = ["NerfConfig", "NerfModel", "RenderOutput", "Trainer", "TrainingDiverged", "composite", "render_weights"]
