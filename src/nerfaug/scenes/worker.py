"""The render child process: set up one scene in bpy, then render a batch of camera poses.

Run as `python -m nerfaug.scenes.worker JOB.json`. bpy runs here, in its own process, because
bpy and torch in one process is fragile; the parent (`nerfaug.scenes.render`) never imports bpy.

The job file holds:
    scene: {"builtin": name} or {"blend": path}
    width, height: image size in pixels
    camera_angle_x: horizontal field of view, radians
    samples, seed, threads: Cycles settings
    frames: list of {"pose": 4x4 camera-to-world (OpenGL == Blender camera), "path": PNG to write}

On stdout it prints `nerfaug-worker-ready <seconds>` (READY) once the scene is set up, then
`nerfaug-worker-frame <index>` (FRAME) after each PNG is complete; every other line is bpy's own
output. If the parent dies, the next of these prints fails on the closed pipe and the worker
stops with it.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

READY = "nerfaug-worker-ready"
FRAME = "nerfaug-worker-frame"


def render_frame(scene, camera, pose: list[list[float]], path: Path) -> None:
    """Render one pose to an RGBA PNG at `path`, written under a temporary name and then
    renamed, so a killed render never leaves a truncated image that looks finished."""
    import bpy
    from mathutils import Matrix

    camera.matrix_world = Matrix(pose)
    partial = path.with_name(f".{path.name}.partial")
    scene.render.filepath = str(partial)
    bpy.ops.render.render(write_still=True)
    os.replace(partial, path)


def run(job: dict) -> None:
    """Set up the scene described by `job` (see the module docstring) and render its frames."""
    started = time.perf_counter()
    from nerfaug.scenes import builders  # imports bpy (optional): here, and timed as start-up

    scene = builders.load_scene(job["scene"])
    builders.configure_render(scene, job["width"], job["height"], job["samples"], job["seed"], job["threads"])
    camera = builders.prepare_camera(scene, job["camera_angle_x"])
    print(f"{READY} {time.perf_counter() - started:.3f}", flush=True)
    for index, frame in enumerate(job["frames"]):
        render_frame(scene, camera, frame["pose"], Path(frame["path"]))
        print(f"{FRAME} {index}", flush=True)


if __name__ == "__main__":
    run(json.loads(Path(sys.argv[1]).read_text()))
