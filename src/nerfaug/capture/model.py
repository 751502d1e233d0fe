"""`SessionModel`: what the steps of a session that use its NeRF need of it (proposing, rendering,
uncertainty images, held-out scores): the model, where it runs, the cameras it trains on, and the
session's world frame, camera and background. The session builds one; the steps never see the
session itself."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from nerfaug.cameras import Cameras
from nerfaug.data.world_frame import Hemisphere
from nerfaug.selection.candidates import with_poses

if TYPE_CHECKING:
    from nerfaug.nerf.model import NerfModel


@dataclass(frozen=True)
class SessionModel:
    """A session's trained NeRF, seen from the world frame.

    Attributes:
        model: the `NerfModel`.
        device: where it runs.
        train_cameras: the engine-frame cameras it trains on, at the training resolution.
        step: its training step.
        hemisphere: the session's hemisphere (world frame <-> engine frame).
        template: one world-frame camera with the session's intrinsics at the identity pose, full
            resolution.
        background: RGB in [0, 1] behind transparent pixels, as trained.
        seed: the session's seed.
        pool: a sparse start's candidate pool (a transforms JSON of world-frame poses), or None.
    """

    model: NerfModel
    device: torch.device | str
    train_cameras: Cameras
    step: int
    hemisphere: Hemisphere
    template: Cameras
    background: tuple[float, float, float]
    seed: int
    pool: Path | None = None

    def background_tensor(self) -> Tensor:
        """`background` as a Tensor with shape (3,) on the model's device."""
        return torch.tensor(self.background, dtype=torch.float32, device=self.device)

    def engine_cameras(self, poses: Tensor, width: int | None = None) -> Cameras:
        """Cameras with the session's intrinsics at world-frame `poses` (n, 4, 4), moved into the
        engine frame on the model's device, at the training resolution (or `width` pixels across)."""
        train = self.train_cameras
        camera = self.template.resized(train.width, train.height)
        if width is not None:
            camera = camera.resized(int(width), max(1, round(int(width) * train.height / train.width)))
        engine = self.hemisphere.to_engine(torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4))
        return with_poses(camera, engine).to(self.device)

    def render(self, poses: Tensor, width: int | None = None) -> Tensor:
        """What the NeRF sees from world-frame `poses` (n, 4, 4): images (n, H, W, 3) in [0, 1],
        at the training resolution (or `width` pixels across)."""
        cameras = self.engine_cameras(poses, width)
        background = self.background_tensor()
        return torch.stack([self.model.render_image(cameras, i, background)["rgb"].cpu() for i in range(len(cameras))])
