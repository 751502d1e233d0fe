"""A simulated capture: proposed poses rendered by Blender with a session's camera, one PNG per
frame named after its `file_path` stem, ready to be added to the session (`nerfaug add RUN
--images OUT --poses POSES`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field

from nerfaug import runfiles
from nerfaug.capture.folder import camera_of
from nerfaug.capture.proposal import read_poses
from nerfaug.capture.requests import Seed, check_threads, validated
from nerfaug.capture.runfolder import SESSION_FILE
from nerfaug.capture.state import SessionState
from nerfaug.data.blender import blender_fits
from nerfaug.errors import DatasetError
from nerfaug.scenes.render import MAX_SAMPLES, render_poses

# Cycles samples per pixel of a simulated capture.
CyclesSamples = Annotated[int, Field(ge=1, le=MAX_SAMPLES)]


def render_proposals(
    run: Path, poses: Path, scene: str | Path, out: Path, samples: int = 16, seed: int = 0, threads: int = 2
) -> list[Path]:
    """Render the poses of the JSON `poses` (as `nerfaug propose` writes it) of the session in
    `run` with its camera's intrinsics and image size into `out`.

    Args:
        scene: a built-in scene (lego, chair, materials, cow) or a .blend file.
        samples, seed: Cycles samples per pixel (1..`MAX_SAMPLES`) and noise seed (>= 0).
        threads: CPU threads for Cycles (>= 1).

    Returns:
        The PNGs, one per pose, in the file's order.

    Raises:
        RequestError: `samples`, `seed` or `threads` out of range (checked before anything is read).
        DatasetError: the session's camera has non-square pixels or an off-centre principal point
            (Blender renders from one horizontal field of view: `blender_fits`).
    """
    validated(CyclesSamples, samples, "samples")
    validated(Seed, seed, "seed")
    check_threads(threads)
    k = SessionState.read(run).intrinsics
    if not blender_fits(camera_of(k)):  # Blender renders from one camera_angle_x
        raise DatasetError(
            runfiles.shown(run, SESSION_FILE),
            "Blender renders square pixels with the principal point at the image centre",
            "intrinsics",
            {"width": k.width, "height": k.height, "fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy},
        )
    matrices, names = read_poses(poses)
    paths = [out / f"{name}.png" for name in names]
    render_poses(scene, matrices, paths, k.width, k.height, k.camera_angle_x, samples, seed, threads)
    return paths
