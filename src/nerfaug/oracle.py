"""Oracles: what returns the images of newly chosen camera poses.

`PoolOracle` looks them up in a pre-rendered candidate pool (the paper's protocol, where the
candidates are the dataset's train split); `BlenderOracle` renders them live with Blender, as a
robot or simulator would capture them. Both answer `capture(poses) -> Views`.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor

from nerfaug.data import Views, load_dataset
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X
from nerfaug.scenes.render import render_views, require_bpy, scene_spec


class PoseNotInPool(LookupError):
    """A requested pose matches no pose of the pool."""


class PoolOracle:
    """Images of poses from a fixed pool of rendered views.

    The images come back as the pool holds them: composited over the background the pool was
    loaded with (see `from_dataset`), with its alphas.

    Args:
        views: the pool.
        tolerance: largest absolute difference between matching entries of the 3x4 upper part
            of a requested pose and a pool pose (poses written to JSON as float32 round-trip
            within about 1e-6).
    """

    def __init__(self, views: Views, tolerance: float = 1e-3):
        self.views = views
        self.tolerance = tolerance

    @classmethod
    def from_dataset(
        cls, root: str | Path, split: str = "train", background=(1.0, 1.0, 1.0), tolerance: float = 1e-3
    ) -> PoolOracle:
        """The pool of one split of a dataset folder, composited over `background`."""
        return cls(load_dataset(root, split, background=background), tolerance)

    def match(self, poses: Tensor) -> Tensor:
        """The pool index of each pose.

        Args:
            poses: Tensor with shape (n, 4, 4), camera-to-world.

        Returns:
            Tensor with shape (n,), integer indices into the pool (the closest pool pose).

        Raises:
            PoseNotInPool: naming the first pose with no pool pose within `tolerance`.
        """
        poses = torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4)
        pool = self.views.cameras.camera_to_world
        difference = (poses[:, None, :3, :] - pool[None, :, :3, :]).abs().amax(dim=(-2, -1))
        distance, index = difference.min(dim=1)
        unmatched = torch.nonzero(distance > self.tolerance).flatten().tolist()
        if unmatched:
            i = unmatched[0]
            raise PoseNotInPool(
                f"pose {i} (camera at {[round(v, 4) for v in poses[i, :3, 3].tolist()]}) is not in the "
                f"pool of {len(pool)} views: the closest pool pose, {self.views.names[index[i]]!r}, "
                f"differs by {distance[i]:.3g} > tolerance {self.tolerance:g}"
                + (f" ({len(unmatched) - 1} more poses unmatched)" if len(unmatched) > 1 else "")
            )
        return index

    def capture(self, poses: Tensor, names: list[str] | None = None) -> Views:
        """The pool's views at `poses` (Tensor with shape (n, 4, 4)), in the same order.

        Cameras are the pool's own; `names` (n strings) rename the views, default the pool's names.
        """
        views = self.views.subset(self.match(poses).tolist())
        if names is not None:
            if len(names) != len(views):
                raise ValueError(f"got {len(views)} poses but {len(names)} names")
            views.names = list(names)
        return views


class BlenderOracle:
    """Images of any poses, rendered live with Blender (Cycles on the CPU, in a child process).

    Args:
        scene_or_blend: one of `nerfaug.scenes.BUILTIN_SCENES` or a path to a .blend file.
        width, height: image size in pixels.
        camera_angle_x: horizontal field of view, radians (NeRF-synthetic's by default).
        samples, seed: Cycles samples per pixel and noise seed; the same pose always gives the
            same image.
        background: RGB in [0, 1] behind transparent pixels.
        threads: CPU threads for Cycles.
        progress: show a progress bar while rendering.
    """

    def __init__(
        self,
        scene_or_blend: str | Path,
        width: int,
        height: int,
        camera_angle_x: float = BLENDER_CAMERA_ANGLE_X,
        samples: int = 16,
        seed: int = 0,
        background=(1.0, 1.0, 1.0),
        threads: int = 2,
        progress: bool = True,
    ):
        require_bpy()
        scene_spec(scene_or_blend)  # fail now, not at the first capture, on an unknown scene
        self.scene = scene_or_blend
        self.width, self.height = width, height
        self.camera_angle_x, self.samples, self.seed = camera_angle_x, samples, seed
        self.background, self.threads, self.progress = background, threads, progress
        self.captured = 0

    def capture(self, poses: Tensor, names: list[str] | None = None) -> Views:
        """Render `poses` (Tensor with shape (n, 4, 4), OpenGL camera-to-world) as Views with
        alphas. `names` default to `capture_{k}`, numbered across calls so they stay unique."""
        poses = torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4)
        if names is None:
            names = [f"capture_{self.captured + i}" for i in range(len(poses))]
        views = render_views(
            self.scene,
            poses,
            self.width,
            self.height,
            self.camera_angle_x,
            self.samples,
            self.seed,
            self.background,
            names,
            self.threads,
            self.progress,
        )
        self.captured += len(poses)
        return views
