"""Rendering scenes with Blender in a child process, and writing them as NeRF-synthetic datasets.

The parent (this module) never imports bpy: it writes a job file, runs
`python -m nerfaug.scenes.worker JOB.json` once per batch of poses (so bpy's start-up is paid
once per batch, not per view), turns the child's per-frame lines into a progress bar and reads
the RGBA PNGs back. Poses are 4x4 camera-to-world matrices in the OpenGL convention, which is
also Blender's camera convention (looks down -z, +y up), so a pose is the camera's matrix_world.
Renders are deterministic: the same arguments give the same pixels (Cycles' seed is fixed, and
the pixels do not depend on the thread count).
"""

from __future__ import annotations

import collections
import contextlib
import fcntl
import hashlib
import importlib.metadata
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
from rich.console import Console
from torch import Tensor

import nerfaug
from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split
from nerfaug.data.frames import read_image
from nerfaug.hemisphere import (
    BLENDER_CAMERA_ANGLE_X,
    BLENDER_RADIUS,
    fibonacci_angles,
    half_hemisphere_poses,
    pose_from_angles,
    sample_uniform_poses,
)
from nerfaug.jsonio import atomic_write_json, read_json
from nerfaug.owned import foreign_files
from nerfaug.progress import progress_bar
from nerfaug.registry import did_you_mean
from nerfaug.scenes import builtin, worker
from nerfaug.scenes.builtin import BUILTIN_SCENES

# Bump when the layout or meaning of a rendered dataset changes; older caches then re-render.
DATASET_FORMAT = 1
DATASET_SPLITS = ("train", "initial", "test", "val")
# What one render may ask for (checked before anything is rendered): views per split, and below
# the image size, Cycles' samples and its seed (a C int).
MAX_VIEWS = 100_000
MAX_SAMPLES = 16_777_216
RENDER_BOUNDS = {"resolution": (1, 16_384), "samples": (1, MAX_SAMPLES), "seed": (0, 2**31 - 1)}
# What a rendered dataset folder holds (`nerfaug.owned.foreign_files`): one holding anything else is not replaced.
RENDERED_HOLDS = ("scene.json", "transforms_*.json", *(f"{split}/*.png" for split in DATASET_SPLITS))
_SCENE_CODE = (Path(__file__).with_name("builders.py"), Path(__file__).with_name("worker.py"))


class BlenderNotAvailable(ImportError):
    """bpy (Blender as a Python module) is not installed in this environment."""


class RenderError(RuntimeError):
    """The Blender child process failed; the message carries the end of its output."""


def require_bpy() -> None:
    """Raise BlenderNotAvailable, saying how to install bpy, unless it can be imported."""
    if importlib.util.find_spec("bpy") is None:
        raise BlenderNotAvailable(
            "rendering scenes needs Blender's Python module bpy: pip install 'nerfaug[blender]' "
            f"(bpy needs Python 3.11; this is Python {sys.version_info.major}.{sys.version_info.minor})"
        )


def scene_spec(scene: str | Path) -> dict:
    """The worker's description of a scene: `{"builtin": name}` for one of BUILTIN_SCENES,
    `{"blend": absolute path}` for an existing .blend file."""
    if isinstance(scene, str) and scene in BUILTIN_SCENES:
        return {"builtin": scene}
    path = Path(scene).expanduser()
    if path.suffix == ".blend" and path.is_file():
        return {"blend": str(path.resolve())}
    raise ValueError(
        f"unknown scene {str(scene)!r}: {did_you_mean(scene, BUILTIN_SCENES)}expected one of "
        f"{', '.join(BUILTIN_SCENES)} or an existing .blend file"
    )


def render_poses(
    scene: str | Path,
    poses: Tensor,
    paths: list[Path],
    width: int,
    height: int,
    camera_angle_x: float = BLENDER_CAMERA_ANGLE_X,
    samples: int = 16,
    seed: int = 0,
    threads: int = 2,
    progress: bool = True,
    description: str = "rendering",
) -> None:
    """Render each pose to an RGBA PNG (straight alpha, 8-bit), in one Blender child process.

    Poses whose PNG already exists are skipped, so a killed batch resumes where it stopped
    (the worker only ever leaves complete PNGs under their final names).

    Args:
        scene: one of BUILTIN_SCENES or a path to a .blend file.
        poses: Tensor with shape (n, 4, 4), OpenGL camera-to-world.
        paths: n PNG paths to write.
        camera_angle_x: horizontal field of view, radians.
        samples, seed: Cycles samples per pixel and noise seed.
        threads: CPU threads for Cycles.

    Raises:
        BlenderNotAvailable: bpy is not installed.
        RenderError: the child process failed.
    """
    require_bpy()
    poses = torch.as_tensor(poses, dtype=torch.float64).reshape(-1, 4, 4)
    if len(paths) != len(poses):
        raise ValueError(f"got {len(poses)} poses but {len(paths)} output paths")
    frames = [
        {"pose": pose.tolist(), "path": str(Path(path).resolve())}
        for pose, path in zip(poses, paths)
        if not Path(path).is_file()
    ]
    if not frames:
        return
    for folder in {Path(frame["path"]).parent for frame in frames}:
        folder.mkdir(parents=True, exist_ok=True)
    job = {
        "scene": scene_spec(scene),
        "width": int(width),
        "height": int(height),
        "camera_angle_x": float(camera_angle_x),
        "samples": int(samples),
        "seed": int(seed),
        "threads": int(threads),
        "frames": frames,
    }
    with tempfile.TemporaryDirectory(prefix="nerfaug-render-") as folder:
        job_path = Path(folder) / "job.json"
        job_path.write_text(json.dumps(job))
        _run_worker(job_path, len(frames), progress, description)


def _run_worker(job_path: Path, n_frames: int, progress: bool, description: str) -> None:
    """Run the worker on `job_path`, advancing a progress bar on each finished frame."""
    env = dict(os.environ)
    # The child must import this same nerfaug, installed or not.
    package_root = str(Path(nerfaug.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH")) if p)
    command = [sys.executable, "-m", "nerfaug.scenes.worker", str(job_path)]
    log = collections.deque(maxlen=40)
    done = 0
    with (
        progress_bar(enabled=progress) as bar,
        subprocess.Popen(
            command,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            errors="replace",
            env=env,
        ) as child,
    ):
        task = bar.add_task(f"{description} (starting Blender)", total=n_frames)
        try:
            for line in child.stdout:
                if line.startswith(worker.READY):
                    bar.update(task, description=description)
                elif line.startswith(worker.FRAME):
                    done += 1
                    bar.update(task, completed=done)
                else:
                    log.append(line.rstrip())
            child.wait()
        finally:
            if child.poll() is None:  # the parent was interrupted: do not leave Blender running
                child.kill()
    if child.returncode != 0 or done != n_frames:
        tail = "\n".join(log)
        raise RenderError(
            f"Blender worker exited with code {child.returncode} after {done} of {n_frames} frames "
            f"(job {job_path}); last output:\n{tail}"
        )


def read_rgba(paths: list[Path]) -> Tensor:
    """Straight (not premultiplied) RGBA PNGs as a float32 Tensor with shape (n, H, W, 4) in [0, 1]."""
    return torch.from_numpy(np.stack([iio.imread(p) for p in paths]).astype(np.float32) / 255.0)


def render_views(
    scene: str | Path,
    poses: Tensor,
    width: int,
    height: int,
    camera_angle_x: float = BLENDER_CAMERA_ANGLE_X,
    samples: int = 16,
    seed: int = 0,
    background=(1.0, 1.0, 1.0),
    names: list[str] | None = None,
    threads: int = 2,
    progress: bool = True,
) -> Views:
    """Render poses and return them as Views composited over `background`, with alphas.

    Args:
        poses: Tensor with shape (n, 4, 4), OpenGL camera-to-world.
        background: RGB in [0, 1] behind transparent pixels.
        names: one name per view; default `r_0`, `r_1`, ...

    Returns:
        Views with images (n, height, width, 3) and alphas (n, height, width).
    """
    poses = torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4)
    if len(poses) == 0:
        raise ValueError("no poses to render")
    names = names if names is not None else [f"r_{i}" for i in range(len(poses))]
    if len(names) != len(poses):
        raise ValueError(f"got {len(poses)} poses but {len(names)} names")
    with tempfile.TemporaryDirectory(prefix="nerfaug-views-") as folder:
        paths = [Path(folder) / f"{i:05d}.png" for i in range(len(poses))]
        render_poses(scene, poses, paths, width, height, camera_angle_x, samples, seed, threads, progress)
        background = torch.as_tensor(background, dtype=torch.float32)
        loaded = [read_image(path, background, 1, path, "rendered image") for path in paths]
    cameras = Cameras.from_fov(poses, camera_angle_x, width, height)
    return Views(cameras, torch.stack([im for im, _ in loaded]), list(names), torch.stack([a for _, a in loaded]))


def dataset_poses(pool: int, test: int, initial: int, val: int, seed: int) -> dict[str, Tensor]:
    """Camera poses of each split of a scene dataset, each a Tensor with shape (n, 4, 4).

    train: the candidate pool, uniform on the hemisphere (seeded); initial: fixed views on one
    half; test: a Fibonacci spiral over the whole hemisphere; val: `val` of the test poses,
    evenly spread through that spiral.
    """
    generator = torch.Generator().manual_seed(seed)
    test_poses = pose_from_angles(*fibonacci_angles(test))
    return {
        "train": sample_uniform_poses(pool, generator),
        "initial": half_hemisphere_poses(initial),
        "test": test_poses,
        "val": test_poses[val_indices(test, val)],
    }


def val_indices(test: int, val: int) -> list[int]:
    """Indices of the `val` test views used as the validation split (evenly spaced)."""
    return np.linspace(0, test - 1, min(val, test)).round().astype(int).tolist()


def dataset_manifest(
    spec: dict,
    resolution: int,
    pool: int,
    test: int,
    initial: int,
    val: int,
    samples: int,
    seed: int,
) -> dict:
    """Everything that determines a rendered dataset's content; equal manifests, equal datasets.

    Holds a digest of the scene-building code and the bpy version (both change pixels) and,
    for a .blend file, a digest of its bytes (editing it must re-render); for a built-in scene
    built from files (the cow's mesh and texture), a digest of those files.
    """
    digest = hashlib.sha256()
    for path in _SCENE_CODE:
        digest.update(path.read_bytes())
    scene = dict(spec)
    if "blend" in spec:
        scene["sha256"] = hashlib.sha256(Path(spec["blend"]).read_bytes()).hexdigest()
    if spec.get("builtin") in builtin.BUILTIN_ASSETS:
        scene["assets_sha256"] = assets_digest(spec["builtin"])
    return {
        "format": DATASET_FORMAT,
        "scene": scene,
        "resolution": resolution,
        "pool": pool,
        "test": test,
        "initial": initial,
        "val": val,
        "samples": samples,
        "seed": seed,
        "camera_angle_x": BLENDER_CAMERA_ANGLE_X,
        "radius": BLENDER_RADIUS,
        "bpy": importlib.metadata.version("bpy"),
        "scene_code_sha256": digest.hexdigest(),
    }


def assets_digest(scene: str) -> str:
    """SHA-256 (hex) over the names and bytes of the files the built-in `scene` is built from
    (`builtin.BUILTIN_ASSETS`); "" for a procedural scene.

    Raises:
        FileNotFoundError: one of the files is missing (an install without its package data).
    """
    names = builtin.BUILTIN_ASSETS.get(scene, ())
    if not names:
        return ""
    digest = hashlib.sha256()
    for name in names:
        path = builtin.ASSETS / scene / name
        if not path.is_file():
            raise FileNotFoundError(f"the built-in scene {scene!r} needs {path}, which is missing: reinstall nerfaug")
        data = path.read_bytes()
        digest.update(f"{name}\0{len(data)}\0".encode())
        digest.update(data)
    return digest.hexdigest()


def is_complete(root: Path, manifest: dict) -> bool:
    """Whether `root` holds a finished dataset rendered with exactly `manifest`."""
    try:
        if read_json(root / "scene.json") != manifest:
            return False
        for split in DATASET_SPLITS:
            frames = read_json(root / f"transforms_{split}.json")["frames"]
            if not all((root / f"{frame['file_path']}.png").is_file() for frame in frames):
                return False
    except (ValueError, KeyError, TypeError):  # DatasetError is a ValueError: missing or bad JSON
        return False
    return True


def render_scene_dataset(
    scene: str | Path,
    out: Path,
    resolution: int = 200,
    pool: int = 300,
    test: int = 200,
    initial: int = 6,
    samples: int = 16,
    seed: int = 0,
    progress: bool = True,
    val: int = 8,
    threads: int = 2,
) -> Path:
    """Render a scene into a NeRF-synthetic dataset folder; cached by its arguments.

    Writes `transforms_{train,initial,test,val}.json` with RGBA PNGs (train = the candidate
    pool, uniform on the hemisphere; initial = the fixed views on one half; test = spread over
    the hemisphere; val = a few test views), all `resolution` x `resolution` with NeRF-synthetic's
    field of view and radius, and `scene.json` recording the arguments.

    If `out` already holds a dataset with the same manifest, nothing is rendered. Otherwise the
    frames are rendered into a hidden sibling folder `.{out.name}.partial` (a killed render
    resumes from it) and moved to `out` only when complete, so `out` never looks complete
    when it is not. A previous dataset in `out` is replaced.

    Args:
        scene: one of BUILTIN_SCENES or a path to a .blend file.
        out: dataset folder.
        resolution: image width and height in pixels.
        pool, test, initial, val: number of views per split (val views are copies of test views).
        samples, seed: Cycles samples per pixel; seed of both the pool poses and Cycles' noise.
        threads: CPU threads for Cycles (does not change the pixels).

    Returns:
        `out`.

    Raises:
        BlenderNotAvailable: bpy is not installed.
        FileExistsError: `out` is a non-empty folder that is not a rendered scene dataset, or
            one holding a file nerfaug did not write.
    """
    require_bpy()
    counts = {"resolution": resolution, "pool": pool, "test": test, "initial": initial, "val": val, "samples": samples}
    for name, value in {**counts, "seed": seed}.items():
        low, high = RENDER_BOUNDS.get(name, (1, MAX_VIEWS))
        if int(value) != value or not low <= value <= high:
            raise ValueError(f"{name} {value!r}: must be an integer from {low} to {high}")
    out = Path(out)
    manifest = dataset_manifest(scene_spec(scene), resolution, pool, test, initial, val, samples, seed)
    if is_complete(out, manifest):
        if progress:
            Console(stderr=True).print(f"{out}: already rendered with these arguments, nothing to do")
        return out
    if out.is_dir() and any(out.iterdir()) and not (out / "scene.json").exists():
        raise FileExistsError(f"{out} is not empty and holds no scene.json: refusing to replace it")
    foreign = foreign_files(out, RENDERED_HOLDS) if out.is_dir() else []
    if foreign:  # a rendered dataset with a user's file in it: replacing it would delete the file
        raise FileExistsError(
            f"{out}: holds {foreign[0]}, which nerfaug did not write, so the dataset is not replaced; "
            "move it elsewhere, or choose another --out"
        )
    # Two processes asked for the same folder (e.g. two sweeps, or a sweep and `nerfaug scene
    # render`) would share one staging folder: the second waits for the first, then finds the
    # dataset complete. The lock is on the parent folder, so nothing is left behind.
    out.parent.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(out.parent):
        if is_complete(out, manifest):
            return out
        return _render_dataset(scene, out, manifest, threads, progress)


@contextlib.contextmanager
def exclusive_lock(folder: Path):
    """Hold an exclusive advisory lock (`flock`) on the existing folder `folder`; waits while
    another process holds it."""
    handle = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX)
        yield
    finally:
        os.close(handle)  # releases the lock


def _render_dataset(scene, out: Path, manifest: dict, threads: int, progress: bool) -> Path:
    """The body of `render_scene_dataset`, run while holding its lock: the dataset `manifest`
    (`dataset_manifest`) describes, its counts, resolution and seed read from it."""
    resolution, samples, seed = manifest["resolution"], manifest["samples"], manifest["seed"]
    test, val = manifest["test"], manifest["val"]
    staging = out.with_name(f".{out.name}.partial")
    renders = staging / "renders"
    if not (staging / "manifest.json").is_file() or read_json(staging / "manifest.json") != manifest:
        shutil.rmtree(staging, ignore_errors=True)
        atomic_write_json(staging / "manifest.json", manifest)

    poses = dataset_poses(manifest["pool"], test, manifest["initial"], val, seed)
    # val repeats test views: render train, initial and test only, in one child process.
    rendered = ("train", "initial", "test")
    paths = {split: [renders / split / f"r_{i}.png" for i in range(len(poses[split]))] for split in rendered}
    render_poses(
        scene,
        torch.cat([poses[s] for s in rendered]),
        [p for s in rendered for p in paths[s]],
        resolution,
        resolution,
        BLENDER_CAMERA_ANGLE_X,
        samples,
        seed,
        threads,
        progress,
        description=f"rendering {Path(str(scene)).stem}",
    )
    paths["val"] = [paths["test"][i] for i in val_indices(test, val)]
    names = {split: [p.stem for p in paths[split]] for split in DATASET_SPLITS}
    for split in DATASET_SPLITS:
        write_blender_split(staging, split, _dataset_views(poses[split], paths[split], names[split]))
    shutil.rmtree(renders)
    (staging / "manifest.json").unlink()
    atomic_write_json(staging / "scene.json", manifest)
    _replace_folder(staging, out)
    return out


def _dataset_views(poses: Tensor, paths: list[Path], names: list[str]) -> Views:
    """Rendered PNGs as Views for `write_blender_split`.

    Like every Views, the images are composited over a background (white); the writer
    un-composites them beside their alphas, so the files hold Blender's RGBA up to 8-bit rounding.
    """
    rgba = read_rgba(paths)
    height, width = rgba.shape[1:3]
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, width, height)
    alpha = rgba[..., 3:]
    composited = rgba[..., :3] * alpha + (1.0 - alpha)
    return Views(cameras, composited.contiguous(), names, alpha[..., 0].contiguous())


def _replace_folder(source: Path, target: Path) -> None:
    """Move the finished folder `source` to `target`, replacing whatever was there."""
    if target.exists():
        trash = target.with_name(f".{target.name}.old-{os.getpid()}")
        target.rename(trash)
        source.rename(target)
        shutil.rmtree(trash)
    else:
        target.parent.mkdir(parents=True, exist_ok=True)
        source.rename(target)
