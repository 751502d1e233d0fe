"""The live render: the session's NeRF seen from the viewer's camera, at a size the CPU affords.

The checkpoint is only read (`torch.load`, weights only), again whenever a save replaces it (the
session writes it atomically, so a read sees the old file or the new one). The viewer takes no
lock: the session's lock (`nerfaug.capture.lock`) is exclusive and held by a training for its whole
run, so a reader waiting on it would see nothing while it trains, and one holding it would make the
next `nerfaug train` wait. It renders on one thread at the process's lowered priority (`cli.view`),
and each frame's size follows its time budget (`width_for`), so a training beside it keeps the cores.
"""

from __future__ import annotations

import io
import math
import threading
import time
from pathlib import Path

import numpy as np
import torch

from nerfaug import runfiles
from nerfaug.cameras import Cameras
from nerfaug.capture.runfolder import CHECKPOINT_FILE
from nerfaug.data.world_frame import Hemisphere
from nerfaug.errors import PathRefused
from nerfaug.nerf.trainer import Trainer

MOVING_WIDTH, RESTING_WIDTH, SMALLEST_WIDTH = 64, 192, 24
MOVING_BUDGET_S, RESTING_BUDGET_S = 0.25, 2.0  # seconds a frame may take while moving / at rest
# OpenCV camera (viser: +z forward, +y down) to OpenGL (nerfaug: -z forward, +y up): flip y and z.
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])


def width_for(target: int, aspect: float, budget_s: float, seconds_per_pixel: float | None) -> int:
    """The width of a frame: `target` pixels across unless the last frames' pace
    (`seconds_per_pixel`) says it would take more than `budget_s`; never under `SMALLEST_WIDTH`.

    >>> width_for(192, 1.0, 2.0, None), width_for(192, 1.0, 2.0, 1e-4)
    (192, 141)
    """
    if seconds_per_pixel is None or seconds_per_pixel <= 0:
        return target
    affordable = math.sqrt(budget_s / seconds_per_pixel * aspect)
    return int(max(SMALLEST_WIDTH, min(target, affordable)))


class LiveModel:
    """The session's NeRF for rendering, loaded from `run_dir`'s checkpoint on the CPU; `refresh`
    loads it again once a save has replaced the file. Thread-safe: one frame renders at a time."""

    def __init__(self, run_dir: Path, hemisphere: Hemisphere, background) -> None:
        self.run_dir = Path(run_dir)
        self.hemisphere = hemisphere
        self.background = torch.tensor(background, dtype=torch.float32)
        self.model = None
        self.step: int | None = None
        self.loaded_key = None
        self.seconds_per_pixel: float | None = None
        self.lock = threading.Lock()

    def refresh(self) -> bool:
        """Load the checkpoint when it changed since the last load; whether a new model came.
        A checkpoint that cannot be read now (being replaced, damaged) keeps the model there is."""
        try:  # a checkpoint linked out of the run folder is never read (`runfiles`)
            stat = runfiles.path_in(self.run_dir, CHECKPOINT_FILE).stat()
        except (OSError, PathRefused):
            return False
        key = (stat.st_mtime_ns, stat.st_size)
        if key == self.loaded_key:
            return False
        try:
            data = io.BytesIO(runfiles.read_bytes(self.run_dir, CHECKPOINT_FILE))
            trainer = Trainer.load_checkpoint(data, device="cpu", progress=False)
        except Exception:  # noqa: BLE001 -- torch.load and the state dicts raise many types; tried again later
            return False
        trainer.model.eval()
        with self.lock:
            self.model, self.step, self.loaded_key = trainer.model, trainer.step, key
        return True

    def set_hemisphere(self, hemisphere: Hemisphere) -> None:
        self.hemisphere = hemisphere

    def render(self, camera_to_world: np.ndarray, fov_y: float, aspect: float, width: int) -> np.ndarray | None:
        """The NeRF from an OpenCV camera-to-world pose (4, 4) in the world frame (viser's camera),
        vertical field of view `fov_y` (radians), `aspect` (width / height), `width` pixels across:
        uint8 (H, W, 3); None before a model is loaded."""
        if self.model is None:
            return None
        height = max(1, round(width / aspect))
        focal = 0.5 * height / math.tan(0.5 * fov_y)
        pose = torch.as_tensor(camera_to_world @ OPENCV_TO_OPENGL, dtype=torch.float64)
        engine = self.hemisphere.to_engine(pose)
        cameras = Cameras(engine, focal, focal, width / 2.0, height / 2.0, width, height)
        with self.lock:
            start = time.perf_counter()
            with torch.inference_mode():
                rgb = self.model.render_image(cameras, 0, self.background)["rgb"]
            elapsed = time.perf_counter() - start
        self.seconds_per_pixel = elapsed / (width * height)
        return (rgb.clamp(0, 1) * 255).round().to(torch.uint8).numpy()
