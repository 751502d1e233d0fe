"""The NeRF engine: encodings and fields, samplers, volume rendering, and the trainer.

The names below are imported on first use, so that `nerfaug.nerf.config` (the engine presets,
which the `nerfaug train` command's options name) stays free of torch: `nerfaug train --help`
answers without loading it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from nerfaug.registry import lazy_exports

_HOMES = {
    "NerfConfig": "nerfaug.nerf.config",
    "NerfModel": "nerfaug.nerf.model",
    "ENCODINGS": "nerfaug.nerf.registry",
    "FIELDS": "nerfaug.nerf.registry",
    "SAMPLERS": "nerfaug.nerf.registry",
    "build_encoding": "nerfaug.nerf.registry",
    "build_field": "nerfaug.nerf.registry",
    "build_sampler": "nerfaug.nerf.registry",
    "Sampler": "nerfaug.nerf.sampler",
    "Trainer": "nerfaug.nerf.trainer",
    "TrainingDiverged": "nerfaug.nerf.trainer",
    "RenderOutput": "nerfaug.nerf.volrend",
    "composite": "nerfaug.nerf.volrend",
    "render_weights": "nerfaug.nerf.volrend",
}

if TYPE_CHECKING:
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.model import NerfModel
    from nerfaug.nerf.registry import ENCODINGS, FIELDS, SAMPLERS, build_encoding, build_field, build_sampler
    from nerfaug.nerf.sampler import Sampler
    from nerfaug.nerf.trainer import Trainer, TrainingDiverged
    from nerfaug.nerf.volrend import RenderOutput, composite, render_weights


__getattr__, __dir__ = lazy_exports(__name__, _HOMES, globals())


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
