"""Active capture: train a NeRF on the views you have, ask which views to capture next, add the
images you captured there (a robot, a phone, a simulator), and go on training.

A `CaptureSession` lives in a run folder:

    run/
      session.json          state: step, seed, engine, intrinsics, hemisphere, proposals, additions
      checkpoint.pt         the trainer (`Trainer.save_checkpoint`): model, optimiser, RNG, views
      dataset/              the dataset as it has grown, in the source's standard format:
                              Blender (`transforms_train.json` + `train/*.png`) or
                              nerfstudio (`transforms.json` + `images/*`)
      proposals/            proposal_000.json (poses + every candidate's score), proposal_000.png (map)

Frames of reference. Poses given to and returned by a session are in the dataset's world frame
(OpenGL camera-to-world, as in the Blender and nerfstudio formats). The NeRF is trained in an
*engine frame*: the hemisphere's centre at the origin, its `up` along +z, and its radius scaled to
`ENGINE_RADIUS` (NeRF-synthetic's 4.03), so that the engine's scene bounds (near 2, far 6, a box
of half-size 1.5) fit any object-centred capture, whatever its units. For NeRF-synthetic data
the two frames coincide (up to the estimate of the centre and radius).

The hemisphere is where candidate views live (the paper's Sec. III-C): the upper half, relative
to `up`, of the sphere of `radius` about `centre`. Both can be given or estimated from the
cameras (`estimate_hemisphere`).
"""

from __future__ import annotations

import datetime
import json
import math
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import imageio.v3 as iio
import numpy as np
import torch
from torch import Tensor

import nerfaug
from nerfaug.cameras import Cameras
from nerfaug.data import DatasetError, Views, load_dataset
from nerfaug.data.frames import (
    atomic_write_bytes, atomic_write_json, check_pose, read_image, read_json, resolve_image,
)
from nerfaug.hemisphere import BLENDER_RADIUS, angles_from_pose

SESSION_FORMAT = 1
SESSION_FILE = "session.json"
CHECKPOINT_FILE = "checkpoint.pt"
DATASET_DIR = "dataset"
PROPOSALS_DIR = "proposals"
ENGINE_RADIUS = BLENDER_RADIUS
# Image files a capture folder may hold; anything else in it is ignored.
CAPTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".bmp", ".webp")
# Formats every loader of both dataset formats reads; other captures are stored as PNG.
STORED_SUFFIXES = (".png", ".jpg", ".jpeg")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
# nerfstudio keys describing the camera, kept when a nerfstudio dataset is copied or exported.
_CAMERA_KEYS = ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "k4", "p1", "p2",
                "camera_angle_x")


class SessionError(RuntimeError):
    """A run folder is missing, incomplete or inconsistent; the message says which file and why."""


# ---- the hemisphere and the engine frame -------------------------------------------------------

def estimate_centre(camera_to_world: Tensor) -> Tensor:
    """The point closest, in least squares, to every camera's optical axis.

    Minimises sum_i || (I - d_i d_i^T) (x - o_i) ||^2 over x, for camera centres o_i and viewing
    directions d_i (each camera's -z axis): the point the cameras look at.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4), n >= 2, OpenGL convention.

    Returns:
        Tensor with shape (3,), float64, world space.

    Raises:
        ValueError: fewer than two cameras, or optical axes (nearly) parallel, so no single point
            is looked at.

    Example:
        >>> from nerfaug.hemisphere import sample_uniform_poses
        >>> estimate_centre(sample_uniform_poses(8, centre=(1.0, 2.0, 0.5)))  # doctest: +SKIP
        tensor([1.0000, 2.0000, 0.5000], dtype=torch.float64)
    """
    poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
    if poses.shape[0] < 2:
        raise ValueError(f"estimating the centre needs at least 2 cameras, got {poses.shape[0]}")
    origins = poses[:, :3, 3]
    directions = -poses[:, :3, 2]
    directions = directions / directions.norm(dim=-1, keepdim=True)
    projectors = torch.eye(3, dtype=torch.float64) - directions[:, :, None] * directions[:, None, :]
    a = projectors.sum(0)
    b = (projectors @ origins[:, :, None]).sum(0)[:, 0]
    eigenvalues = torch.linalg.eigvalsh(a)
    # An eigenvalue near 0 means a direction along which every axis runs: no unique closest point.
    if eigenvalues[0] < 1e-6 * poses.shape[0]:
        raise ValueError(
            "the cameras' optical axes are (nearly) parallel, so they do not look at one point; "
            "give the hemisphere's centre and radius explicitly"
        )
    return torch.linalg.solve(a, b)


def estimate_up(camera_to_world: Tensor) -> Tensor:
    """The mean of the cameras' +y (up) axes, normalised: the world's up for captures taken upright.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4).

    Returns:
        Tensor with shape (3,), float64, unit length.
    """
    poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
    up = poses[:, :3, 1].mean(0)
    if up.norm() < 1e-6:
        raise ValueError("the cameras' up axes cancel out; give the up direction explicitly")
    return up / up.norm()


@dataclass(frozen=True)
class Hemisphere:
    """The upper half, relative to `up`, of the sphere of `radius` about `centre` (world frame).

    It also defines the engine frame the NeRF is trained in: centre at the origin, `up` along +z,
    world x (or y, if `up` is close to x) projected onto the horizontal plane along +x, and
    lengths divided by `radius / ENGINE_RADIUS`.

    Attributes:
        centre: the point looked at, world space.
        radius: distance of the candidate cameras from the centre, world units.
        up: the hemisphere's pole direction (unit length), world space.
    """

    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = ENGINE_RADIUS
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        centre = tuple(float(c) for c in np.asarray(self.centre, dtype=np.float64).reshape(-1))
        up = np.asarray(self.up, dtype=np.float64).reshape(-1)
        if len(centre) != 3 or up.shape != (3,):
            raise ValueError(f"centre and up must be 3-vectors, got {self.centre} and {self.up}")
        if not (math.isfinite(float(self.radius)) and float(self.radius) > 0):
            raise ValueError(f"the hemisphere's radius must be a positive number, got {self.radius}")
        if not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
            raise ValueError(f"up must be a non-zero direction, got {self.up}")
        object.__setattr__(self, "centre", centre)
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "up", tuple(float(u) for u in up / np.linalg.norm(up)))

    @property
    def scale(self) -> float:
        """World units per engine unit."""
        return self.radius / ENGINE_RADIUS

    def rotation(self) -> Tensor:
        """Engine-to-world rotation, float64 (3, 3); its columns are the engine axes in the world."""
        up = torch.tensor(self.up, dtype=torch.float64)
        axis = [1.0, 0.0, 0.0] if abs(float(up[0])) < 0.9 else [0.0, 1.0, 0.0]
        reference = torch.tensor(axis, dtype=torch.float64)
        x = reference - (reference @ up) * up
        x = x / x.norm()
        return torch.stack([x, torch.linalg.cross(up, x), up], dim=1)

    def to_engine(self, camera_to_world: Tensor) -> Tensor:
        """World-frame poses (n, 4, 4) in the engine frame, float32 (n, 4, 4)."""
        poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
        rotation = self.rotation()
        out = poses.clone()
        out[:, :3, :3] = rotation.T @ poses[:, :3, :3]
        offset = poses[:, :3, 3] - torch.tensor(self.centre, dtype=torch.float64)
        out[:, :3, 3] = offset @ rotation / self.scale
        return out.float()

    def to_world(self, camera_to_world: Tensor) -> Tensor:
        """Engine-frame poses (n, 4, 4) in the world frame, float32 (n, 4, 4)."""
        poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
        rotation = self.rotation()
        out = poses.clone()
        out[:, :3, :3] = rotation @ poses[:, :3, :3]
        out[:, :3, 3] = torch.tensor(self.centre, dtype=torch.float64) + self.scale * poses[:, :3, 3] @ rotation.T
        return out.float()

    def angles(self, camera_to_world: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Azimuth and polar angle (radians, about `up`) and distance (world units) of world poses.

        Returns:
            azimuth, polar, radius: Tensors with shape (n,).
        """
        azimuth, polar, radius = angles_from_pose(self.to_engine(camera_to_world))
        return azimuth, polar, radius * self.scale

    def to_dict(self) -> dict:
        return {"centre": list(self.centre), "radius": self.radius, "up": list(self.up)}

    @classmethod
    def from_dict(cls, data: dict) -> "Hemisphere":
        return cls(tuple(data["centre"]), float(data["radius"]), tuple(data["up"]))


def estimate_hemisphere(
    camera_to_world: Tensor, centre=None, radius: float | None = None, up=(0.0, 0.0, 1.0)
) -> Hemisphere:
    """The hemisphere the cameras sit on: what is not given is estimated from them.

    Args:
        camera_to_world: Tensor with shape (n, 4, 4), the existing cameras.
        centre: the point looked at; None for `estimate_centre` (the point closest to all
            optical axes).
        radius: None for the mean distance of the cameras from the centre.
        up: the pole direction; "estimate" for `estimate_up` (the mean camera up axis).

    Returns:
        Hemisphere.
    """
    poses = torch.as_tensor(camera_to_world).double().reshape(-1, 4, 4)
    if isinstance(up, str):
        if up != "estimate":
            raise ValueError(f"up must be a 3-vector or 'estimate', got {up!r}")
        up = estimate_up(poses)
    centre = estimate_centre(poses) if centre is None else torch.as_tensor(centre, dtype=torch.float64)
    if radius is None:
        radius = float((poses[:, :3, 3] - centre).norm(dim=-1).mean())
    return Hemisphere(tuple(centre.tolist()), radius, tuple(torch.as_tensor(up, dtype=torch.float64).tolist()))


# ---- proposals ---------------------------------------------------------------------------------

def proposal_seed(seed: int, number: int) -> int:
    """The seed of proposal `number` of a session seeded with `seed`: independent of the global
    RNG and of everything done before, so a resumed session proposes what the original would."""
    return int(np.random.SeedSequence([int(seed), int(number)]).generate_state(1, np.uint64)[0] >> np.uint64(1))


@dataclass
class Proposal:
    """The views a session proposes to capture next.

    Attributes:
        number: the session's proposal counter (0 for the first).
        method: the selection method (`nerfaug methods`).
        poses: Tensor with shape (n, 4, 4), world-frame OpenGL camera-to-world: where to capture.
        names: n suggested image names (file stems), e.g. "capture_000_00"; `add_views` matches
            captured files to poses by them.
        azimuth, polar: Tensors with shape (n,), radians, about the hemisphere's centre and up.
        indices: Tensor with shape (n,), the chosen candidates' indices.
        candidates: the world-frame cameras that were scored (n_candidates).
        scores: Tensor with shape (n_candidates,), every candidate's score (bright on the map).
        components: name -> Tensor with shape (n_candidates,), the terms behind the scores.
        map_path: the hemisphere map PNG (scores, training views, chosen views), or None.
        step: training step of the model that scored them.
        seed: the seed of the generator used (None when the caller passed a generator).
        camera_angle_x: horizontal field of view of the cameras, radians.
        hemisphere: the session's hemisphere.
    """

    number: int
    method: str
    poses: Tensor
    names: list[str]
    azimuth: Tensor
    polar: Tensor
    indices: Tensor
    candidates: Cameras
    scores: Tensor
    components: dict[str, Tensor]
    map_path: Path | None
    step: int
    seed: int | None
    camera_angle_x: float
    hemisphere: Hemisphere

    def __len__(self) -> int:
        return self.poses.shape[0]

    def transforms(self, include_candidates: bool = False) -> dict:
        """A Blender-style transforms dict, ready for a robot or for Blender:
        {camera_angle_x, w, h, fl_x, fl_y, cx, cy, frames: [{file_path, transform_matrix,
        azimuth, polar, score}], nerfaug: {...}}. The extra keys are ignored by other readers."""
        c = self.candidates
        chosen = self.indices.tolist()
        frames = [
            {"file_path": f"./{name}", "transform_matrix": pose.tolist(), "azimuth": float(a),
             "polar": float(p), "score": float(self.scores[i])}
            for name, pose, a, p, i in zip(self.names, self.poses.double(), self.azimuth, self.polar, chosen)
        ]
        info = {
            "proposal": self.number, "method": self.method, "step": self.step, "seed": self.seed,
            "hemisphere": self.hemisphere.to_dict(), "nerfaug": nerfaug.__version__,
            "map": None if self.map_path is None else str(self.map_path),
        }
        if include_candidates:
            info["candidates"] = {
                "transform_matrix": c.camera_to_world.tolist(), "scores": self.scores.tolist(),
                "components": {k: v.tolist() for k, v in self.components.items()},
                "chosen": chosen,
            }
        return {
            "camera_angle_x": self.camera_angle_x, "w": c.width, "h": c.height,
            "fl_x": float(c.fx[0]), "fl_y": float(c.fy[0]), "cx": float(c.cx[0]), "cy": float(c.cy[0]),
            "frames": frames, "nerfaug": info,
        }

    def write(self, path: str | Path, include_candidates: bool = False) -> Path:
        """Write `transforms()` to `path` (JSON) and the map beside it (`path` with suffix .png).

        Returns the JSON path.
        """
        path = Path(path)
        data = self.transforms(include_candidates)
        if self.map_path is not None and Path(self.map_path).exists():
            map_copy = path.with_suffix(".png")
            if Path(self.map_path).resolve() != map_copy.resolve():
                atomic_write_bytes(map_copy, Path(self.map_path).read_bytes())
            data["nerfaug"]["map"] = map_copy.name
        atomic_write_json(path, data)
        return path


def read_poses(path: str | Path) -> tuple[Tensor, list[str]]:
    """The poses and frame names of a Blender-style transforms JSON (e.g. a written `Proposal`).

    Returns:
        poses: Tensor with shape (n, 4, 4), float32.
        names: n file stems of the frames' `file_path`.

    Raises:
        DatasetError: naming the file, the frame and the value of a missing or malformed entry.
    """
    path = Path(path)
    data = read_json(path)
    frames = data.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(path, "frames must be a non-empty list", field="frames", value=frames)
    poses, names = [], []
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict) or "transform_matrix" not in frame:
            raise DatasetError(path, "each frame needs a transform_matrix", field=f"frames[{i}]", value=frame)
        poses.append(check_pose(frame["transform_matrix"], path, f"frames[{i}].transform_matrix"))
        names.append(Path(str(frame.get("file_path", f"frame_{i:03d}"))).stem)
    return torch.stack(poses), names


# ---- images from any source --------------------------------------------------------------------

@dataclass
class _Capture:
    """One validated image to add: its pixels (for the format check), and how to store it."""

    label: str                     # names it in error messages: the file, or images[i]
    array: np.ndarray              # (H, W, 3 | 4) as decoded, uint8 / uint16 / float
    source: Path | None = None     # the file it came from, copied byte for byte when possible
    name: str | None = None        # the stem a folder match found it under


def _image_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in CAPTURE_SUFFIXES)


def _read_capture(path: Path, label: str | None = None) -> _Capture:
    if not path.is_file():
        raise DatasetError(path, "image file not found", field=label)
    try:
        array = np.asarray(iio.imread(path))
    except Exception as error:  # imageio raises many types; all mean "cannot read"
        raise DatasetError(path, f"cannot read image: {error}", field=label)
    return _Capture(str(path), array, source=path, name=path.stem)


def _as_array(image) -> np.ndarray:
    if torch.is_tensor(image):
        return image.detach().cpu().numpy()
    return np.asarray(image)


def _uncomposite(views: Views, background) -> list[np.ndarray]:
    """Straight RGBA float arrays from views composited over `background` (so that storing them
    with their alpha and loading them again gives back the same composited pixels)."""
    views = views.materialised()
    images = views.images.detach().cpu().double()
    if views.alphas is None:
        return [im.numpy().astype(np.float32) for im in images]
    alphas = views.alphas.detach().cpu().double()[..., None]
    bg = torch.as_tensor(background, dtype=torch.float64)
    straight = (images - (1 - alphas) * bg) / alphas.clamp(min=1e-12)
    straight = torch.where(alphas > 0, straight, torch.zeros_like(images))
    return [torch.cat([s.clamp(0, 1), a], -1).numpy().astype(np.float32) for s, a in zip(straight, alphas)]


def collect_images(images, names: Sequence[str] | None = None, background=(1.0, 1.0, 1.0)) -> list[_Capture]:
    """The images of `images`, in order, without checking their content yet.

    Args:
        images: a folder (matched to `names` by file stem when names are given, else every image
            file in it, sorted by name); a list of files and/or arrays; an array or tensor with
            shape (n, H, W, 3 | 4) (uint8, uint16 or float in [0, 1]); or `Views`.
        names: the expected image names (stems), e.g. a proposal's.
        background: the colour `Views` images were composited over.
    """
    if isinstance(images, Views):
        return [_Capture(f"images[{i}] ({name})", array, name=Path(name).stem)
                for i, (name, array) in enumerate(zip(images.names, _uncomposite(images, background)))]
    if isinstance(images, (str, Path)):
        path = Path(images)
        if path.is_dir():
            files = _image_files(path)
            if names is None:
                if not files:
                    raise DatasetError(path, f"no image files ({', '.join(CAPTURE_SUFFIXES)}) in this folder")
                return [_read_capture(f) for f in files]
            by_stem: dict[str, list[Path]] = {}
            for f in files:
                by_stem.setdefault(f.stem, []).append(f)
            captures = []
            for i, name in enumerate(names):
                found = by_stem.get(name, [])
                if not found:
                    present = ", ".join(f.name for f in files[:8]) + (" ..." if len(files) > 8 else "")
                    raise DatasetError(
                        path, f"no image named {name}.* for pose {i} (the folder holds: {present or 'no images'})",
                        field=f"frames[{i}]", value=name,
                    )
                if len(found) > 1:
                    raise DatasetError(path, f"several images named {name}.*; keep one", field=f"frames[{i}]",
                                       value=[f.name for f in found])
                captures.append(_read_capture(found[0]))
            return captures
        return [_read_capture(path)]
    if isinstance(images, (np.ndarray, Tensor)):
        array = _as_array(images)
        if array.ndim == 3:
            array = array[None]
        if array.ndim != 4:
            raise DatasetError("images", "an array of images must have shape (n, H, W, 3 | 4)",
                               value=f"shape {array.shape}")
        return [_Capture(f"images[{i}]", array[i]) for i in range(array.shape[0])]
    if isinstance(images, (list, tuple)):
        captures = []
        for i, item in enumerate(images):
            if isinstance(item, (str, Path)):
                captures.append(_read_capture(Path(item), f"images[{i}]"))
            else:
                captures.append(_Capture(f"images[{i}]", _as_array(item)))
        return captures
    raise TypeError(
        f"images must be a folder, a list of files or arrays, an (n, H, W, C) array or tensor, or Views; "
        f"got {type(images).__name__}"
    )


def _check_capture(capture: _Capture, width: int, height: int) -> None:
    """Raise DatasetError unless `capture` is an RGB(A) image of the dataset's size with valid values."""
    array = capture.array
    where = capture.label
    if array.ndim != 3 or array.shape[-1] not in (3, 4):
        raise DatasetError(where, "an image must have shape (H, W, 3) or (H, W, 4), channels last (RGB or RGBA)",
                           value=f"shape {array.shape}")
    if array.shape[:2] != (height, width):
        raise DatasetError(where, f"image is {array.shape[1]}x{array.shape[0]} pixels but the dataset's camera "
                                  f"is {width}x{height}", value=f"shape {array.shape}")
    if array.dtype in (np.uint8, np.uint16):
        return
    if not np.issubdtype(array.dtype, np.floating):
        raise DatasetError(where, "image values must be uint8, uint16 or float in [0, 1]", value=str(array.dtype))
    if not np.isfinite(array).all():
        raise DatasetError(where, "image has non-finite values", value=f"{int((~np.isfinite(array)).sum())} NaN/inf")
    low, high = float(array.min()), float(array.max())
    if low < 0.0 or high > 1.0:
        raise DatasetError(where, "float images must lie in [0, 1] (pass uint8 for 0-255 values)",
                           value=f"min {low:.4g}, max {high:.4g}")


def _encode_png(array: np.ndarray) -> bytes:
    if array.dtype not in (np.uint8, np.uint16):
        array = (np.clip(array, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    return iio.imwrite("<bytes>", np.ascontiguousarray(array), extension=".png")


def _stored_bytes(capture: _Capture, png_only: bool) -> tuple[bytes, str]:
    """The bytes to store a capture as, and their suffix: the file itself when every loader reads
    its format (no re-encoding), else a lossless PNG of its pixels."""
    if capture.source is not None:
        suffix = capture.source.suffix.lower()
        if suffix == ".png" or (not png_only and suffix in STORED_SUFFIXES):
            return capture.source.read_bytes(), suffix
    return _encode_png(capture.array), ".png"


# ---- the dataset folder in the run -------------------------------------------------------------

def _dataset_json(root: Path, split: str = "train") -> tuple[Path, str]:
    """The transforms file of a dataset folder and its format ("blender" or "nerfstudio")."""
    if (root / f"transforms_{split}.json").exists():
        return root / f"transforms_{split}.json", "blender"
    if (root / "transforms.json").exists():
        return root / "transforms.json", "nerfstudio"
    load_dataset(root, split)  # raises the dataset layer's own error, naming what is missing
    raise DatasetError(root, "no transforms file")


def _frame_files(root: Path, json_path: Path, frames: list) -> list[Path]:
    return [resolve_image(root, str(frame["file_path"]), json_path, f"frames[{i}].file_path")
            for i, frame in enumerate(frames)]


def _unique_stem(stem: str, taken: set[str]) -> str:
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip(".") or "frame"
    candidate, k = stem, 1
    while candidate in taken:
        candidate, k = f"{stem}_{k}", k + 1
    taken.add(candidate)
    return candidate


def _file_path(fmt: str, folder: str, stem: str, suffix: str) -> str:
    """A frame's `file_path`: Blender omits the extension (PNG), nerfstudio keeps it."""
    return f"./{folder}/{stem}" if fmt == "blender" else f"{folder}/{stem}{suffix}"


def _blender_compatible(cameras: Cameras) -> bool:
    """Whether one `camera_angle_x` describes every camera (square pixels, centred principal point)."""
    fx, fy, cx, cy = cameras.fx.double(), cameras.fy.double(), cameras.cx.double(), cameras.cy.double()
    tolerance = 1e-4 * float(fx.abs().max())
    return bool(
        (fx - fx[0]).abs().max() <= tolerance and (fy - fx).abs().max() <= tolerance
        and (cx - cameras.width / 2).abs().max() <= 1e-3 * cameras.width
        and (cy - cameras.height / 2).abs().max() <= 1e-3 * cameras.height
    )


def _copy_split(source: Path, json_path: Path, out: Path, folder: str, fmt: str,
                camera_angle_x: float | None = None) -> dict:
    """Copy the frames of a transforms file and their images (byte for byte; non-PNG files become
    PNG for the Blender format) into `out/folder`. Returns the new transforms dict (not written).

    Args:
        fmt: the format to write, "blender" (needs `camera_angle_x` unless the file has one)
            or "nerfstudio" (keeps the camera and distortion keys, globally and per frame).
    """
    meta = read_json(json_path)
    frames = meta["frames"]
    files = _frame_files(source, json_path, frames)
    taken: set[str] = set()
    new_frames = []
    for i, (frame, path) in enumerate(zip(frames, files)):
        stem = _unique_stem(Path(str(frame["file_path"])).stem, taken)
        data, suffix = _stored_bytes(_read_capture(path, f"frames[{i}].file_path"), png_only=fmt == "blender")
        atomic_write_bytes(out / folder / f"{stem}{suffix}", data)
        kept = {k: frame[k] for k in _CAMERA_KEYS if k in frame} if fmt == "nerfstudio" else {}
        new_frames.append({"file_path": _file_path(fmt, folder, stem, suffix),
                           "transform_matrix": frame["transform_matrix"], **kept})
    if fmt == "blender":
        angle = meta.get("camera_angle_x", camera_angle_x) if camera_angle_x is None else camera_angle_x
        return {"camera_angle_x": float(angle), "frames": new_frames}
    return {**{k: meta[k] for k in _CAMERA_KEYS if k in meta}, "frames": new_frames}


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


# ---- the session -------------------------------------------------------------------------------

class CaptureSession:
    """Active capture over a dataset folder and a run folder; see the module docstring.

    Make one with `create` (from a dataset) or `open` (a run folder), not the constructor.
    Changes to the model and the proposal history are kept in memory until `save()`; `add_views`
    writes the grown dataset at once (it is the data), and `open` re-reads views the checkpoint
    has not seen yet, so nothing captured is ever lost.

    Example:
        >>> session = CaptureSession.create("data/lego", "runs/lego", split="initial")  # doctest: +SKIP
        >>> session.train(1000)                                      # doctest: +SKIP
        >>> proposal = session.propose(6)                            # doctest: +SKIP
        >>> proposal.write("poses.json")                             # doctest: +SKIP
        >>> session.add_views("captures/", "poses.json")             # doctest: +SKIP
        >>> session.train(1000); session.save()                      # doctest: +SKIP
    """

    def __init__(self, run_dir: Path, trainer, state: dict):
        self.run_dir = Path(run_dir)
        self.trainer = trainer
        self.state = state
        self._saved: tuple[int, int] | None = None  # (step, views) of the checkpoint on disk

    # -- creation and persistence --

    @classmethod
    def create(
        cls, data_dir: str | Path, run_dir: str | Path, preset: str = "cpu", seed: int = 0,
        split: str = "train", *, config=None, centre=None, radius: float | None = None,
        up=(0.0, 0.0, 1.0), downscale: int = 1, background=(1.0, 1.0, 1.0), device="cpu",
        progress: bool = False,
    ) -> "CaptureSession":
        """Start a session: copy `split` of the dataset into `run_dir/dataset`, build the NeRF,
        save. Nothing is trained yet (call `train`).

        Args:
            data_dir: a Blender-format (`transforms_{split}.json`) or nerfstudio-format
                (`transforms.json`) dataset folder: the views captured so far.
            run_dir: the run folder to create (must not hold a session already).
            preset: NeRF engine preset ("cpu", "paper", "test"); ignored if `config` is given.
            seed: seeds the model's initialisation, its training and every proposal.
            split: the Blender split holding the captured views ("initial" for built-in scenes).
            config: a `NerfConfig` to use instead of the preset.
            centre, radius: the hemisphere; None estimates them from the cameras (centre: the
                point closest to all optical axes; radius: the mean camera distance to it).
            up: the hemisphere's pole, world space; "estimate" for the mean camera up axis.
            downscale: train on images shrunk by this integer factor (captures are still added,
                and stored, at the dataset's full size).
            background: colour behind transparent pixels, RGB in [0, 1].
            device: torch device for the NeRF.
            progress: show training progress bars.

        Raises:
            DatasetError: the dataset is missing or malformed (naming the file, frame and value).
            SessionError: `run_dir` already holds a session.
        """
        from nerfaug.nerf.config import NerfConfig
        from nerfaug.nerf.trainer import Trainer

        data_dir, run_dir = Path(data_dir).resolve(), Path(run_dir)
        if (run_dir / SESSION_FILE).exists():
            raise SessionError(f"{run_dir} already holds a capture session; open it with CaptureSession.open")
        if int(seed) < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        if int(downscale) < 1:
            raise ValueError(f"downscale must be a positive integer, got {downscale}")
        source = load_dataset(data_dir, split, lazy=True)  # validates the JSON and every path
        json_path, fmt = _dataset_json(data_dir, split)
        cameras = source.cameras
        if fmt == "nerfstudio" and _blender_compatible(cameras) and not _has_distortion(read_json(json_path)):
            fmt_out = "blender"
        else:
            fmt_out = fmt
        hemisphere = estimate_hemisphere(cameras.camera_to_world, centre, radius, up)
        preset_name = preset if config is None else "custom"
        config = config if config is not None else NerfConfig.preset(preset)

        dataset = run_dir / DATASET_DIR
        if dataset.exists():
            shutil.rmtree(dataset)  # a half-made session (no session.json): start its copy again
        folder = "train" if fmt_out == "blender" else "images"
        copied = _copy_split(data_dir, json_path, dataset, folder, fmt_out, float(cameras.camera_angle_x[0]))
        out_json = dataset / ("transforms_train.json" if fmt_out == "blender" else "transforms.json")
        atomic_write_json(out_json, copied)

        state = {
            "format": SESSION_FORMAT,
            "nerfaug": nerfaug.__version__,
            "created": _now(),
            "source": {"data_dir": str(data_dir), "split": split, "format": fmt},
            "dataset": {"format": fmt_out, "folder": folder, "json": out_json.name},
            "preset": preset_name,
            "engine": config.to_dict(),
            "seed": int(seed),
            "downscale": int(downscale),
            "background": [float(c) for c in background],
            "intrinsics": {
                "width": cameras.width, "height": cameras.height, "fx": float(cameras.fx[0]),
                "fy": float(cameras.fy[0]), "cx": float(cameras.cx[0]), "cy": float(cameras.cy[0]),
                "camera_angle_x": float(cameras.camera_angle_x[0]),
            },
            "hemisphere": hemisphere.to_dict(),
            "hemisphere_estimated": {"centre": centre is None, "radius": radius is None,
                                     "up": isinstance(up, str)},
            "step": 0,
            "views_in_model": 0,
            "proposals": [],
            "additions": [],
        }
        session = cls(run_dir, None, state)
        views = session._engine_views(0)
        session.trainer = Trainer(views, config, seed=int(seed), device=device, background=tuple(background),
                                  progress=progress)
        session.state["views_in_model"] = len(views)
        session.save()
        return session

    @classmethod
    def open(
        cls, run_dir: str | Path, device="cpu", progress: bool = False, load_model: bool = True
    ) -> "CaptureSession":
        """Reopen a session where `save()` left it (plus any views added after that save).

        Args:
            load_model: False skips the checkpoint: enough to read the state or `export`, not to
                train or propose.

        Raises:
            SessionError: naming the missing or inconsistent file.
        """
        from nerfaug.nerf.trainer import Trainer

        run_dir = Path(run_dir)
        state_path = run_dir / SESSION_FILE
        if not state_path.exists():
            raise SessionError(f"{run_dir} is not a capture session: {SESSION_FILE} not found "
                               f"(start one with `nerfaug train DATA --out {run_dir}`)")
        try:
            state = json.loads(state_path.read_text())
        except json.JSONDecodeError as error:
            raise SessionError(f"{state_path}: invalid JSON at line {error.lineno}: {error.msg}")
        if state.get("format") != SESSION_FORMAT:
            raise SessionError(f"{state_path}: unsupported session format {state.get('format')!r}")
        if not load_model:
            return cls(run_dir, None, state)
        checkpoint = run_dir / CHECKPOINT_FILE
        if not checkpoint.exists():
            raise SessionError(f"{checkpoint}: checkpoint not found; the run folder is incomplete")
        trainer = Trainer.load_checkpoint(checkpoint, device=device, progress=progress)
        session = cls(run_dir, trainer, state)
        in_model = len(trainer.train_views)
        session._saved = (trainer.step, in_model)
        frames = read_json(session._json_path())["frames"]
        if len(frames) < in_model:
            raise SessionError(f"{session._json_path()} lists {len(frames)} frames but the checkpoint was "
                               f"trained on {in_model}: the dataset was edited outside the session")
        if len(frames) > in_model:  # added after the last save: train on them too
            trainer.add_views(session._engine_views(in_model))
        state["views_in_model"] = len(frames)
        state["step"] = trainer.step
        return session

    def save(self) -> Path:
        """Write the checkpoint (when the model changed since the last save) and session.json.

        Returns the run folder.
        """
        self._require_model()
        current = (self.trainer.step, len(self.trainer.train_views))
        if self._saved != current or not (self.run_dir / CHECKPOINT_FILE).exists():
            self.trainer.save_checkpoint(self.run_dir / CHECKPOINT_FILE)
            self._saved = current
        self.state["step"] = self.trainer.step
        self.state["views_in_model"] = len(self.trainer.train_views)
        self.state["saved"] = _now()
        atomic_write_json(self.run_dir / SESSION_FILE, self.state)
        return self.run_dir

    # -- what the session holds --

    @property
    def step(self) -> int:
        return self.trainer.step

    @property
    def seed(self) -> int:
        return int(self.state["seed"])

    @property
    def hemisphere(self) -> Hemisphere:
        return Hemisphere.from_dict(self.state["hemisphere"])

    @property
    def dataset_dir(self) -> Path:
        return self.run_dir / DATASET_DIR

    @property
    def proposals(self) -> list[dict]:
        """The proposal history (one record per `propose` call), as stored in session.json."""
        return self.state["proposals"]

    @property
    def cameras(self) -> Cameras:
        """The world-frame cameras of every view in the dataset, at full resolution."""
        return self.dataset().cameras

    def dataset(self) -> Views:
        """The grown dataset, world frame, full resolution (images loaded on access)."""
        return load_dataset(self.dataset_dir, "train", lazy=True, background=tuple(self.state["background"]))

    def template(self, width: int | None = None, height: int | None = None) -> Cameras:
        """One camera with the session's intrinsics at the identity pose (full resolution unless a
        size is given)."""
        k = self.state["intrinsics"]
        camera = Cameras(torch.eye(4), k["fx"], k["fy"], k["cx"], k["cy"], k["width"], k["height"])
        return camera if width is None else camera.resized(width, height)

    def _require_model(self) -> None:
        if self.trainer is None:
            raise SessionError(f"{self.run_dir} was opened with load_model=False; open it with the model to do this")

    def _json_path(self) -> Path:
        return self.dataset_dir / self.state["dataset"]["json"]

    def _engine_views(self, start: int) -> Views:
        """Dataset frames `start:` loaded as the trainer sees them: downscaled, engine frame."""
        json_path = self._json_path()
        frames = read_json(json_path)["frames"][start:]
        files = _frame_files(self.dataset_dir, json_path, frames)
        background = torch.tensor(self.state["background"], dtype=torch.float32)
        downscale = int(self.state["downscale"])
        loaded = [read_image(f, background, downscale, json_path, f"frames[{start + i}].file_path")
                  for i, f in enumerate(files)]
        full = load_dataset(self.dataset_dir, "train", lazy=True).cameras
        cameras = full[list(range(start, len(full)))]
        height, width = full.height // downscale, full.width // downscale
        for i, (image, _) in enumerate(loaded):
            if image.shape[:2] != (height, width):
                raise DatasetError(json_path, f"image size differs from the dataset's {full.width}x{full.height}",
                                   field=f"frames[{start + i}].file_path", value=str(files[i]))
        if (width, height) != (cameras.width, cameras.height):
            cameras = cameras.resized(width, height)
        cameras = Cameras(self.hemisphere.to_engine(cameras.camera_to_world), cameras.fx, cameras.fy,
                          cameras.cx, cameras.cy, cameras.width, cameras.height)
        alphas = None
        if all(a is not None for _, a in loaded):
            alphas = torch.stack([a for _, a in loaded])
        return Views(cameras, torch.stack([im for im, _ in loaded]), [str(f["file_path"]) for f in frames], alphas)

    # -- the loop --

    def train(self, steps: int) -> dict:
        """Train `steps` more steps. Returns the last history entry ({"step", "loss", "psnr"})."""
        self._require_model()
        if steps < 0:
            raise ValueError(f"steps must be >= 0, got {steps}")
        self.trainer.train(self.trainer.step + int(steps))
        return self.trainer.history[-1] if self.trainer.history else {"step": self.trainer.step}

    def candidate_cameras(self, candidates=None, n_candidates: int = 500,
                          generator: torch.Generator | None = None) -> Cameras:
        """The world-frame candidate cameras for `propose` (see its `candidates`), without the
        poses the model already trains on."""
        from nerfaug.selection import hemisphere_candidates, matching_poses

        self._require_model()
        template = self.template()
        engine_train = self.trainer.train_views.cameras.to("cpu")
        if candidates is None or (isinstance(candidates, str) and candidates == "hemisphere"):
            engine = hemisphere_candidates(self.template(engine_train.width, engine_train.height),
                                           n_candidates, generator, radius=ENGINE_RADIUS, training=engine_train)
            return _with_poses(template, self.hemisphere.to_world(engine.camera_to_world))
        if isinstance(candidates, Cameras):
            given = candidates
        elif isinstance(candidates, (str, Path)):
            given = _with_poses(template, read_poses(candidates)[0])
        else:
            poses = np.asarray(_as_array(candidates), dtype=np.float64)
            if poses.ndim != 3 or poses.shape[1:] != (4, 4):
                raise ValueError(f"candidate poses must have shape (n, 4, 4), got {poses.shape}")
            given = _with_poses(template, torch.stack(
                [check_pose(p, Path("candidates"), f"candidates[{i}]") for i, p in enumerate(poses)]))
        # Compared in the engine frame, so the tolerance does not depend on the data's units.
        known = matching_poses(self.hemisphere.to_engine(given.camera_to_world), engine_train.camera_to_world)
        return given[torch.nonzero(~known).reshape(-1).tolist()]

    def propose(
        self, n: int = 6, method: str = "ours", candidates=None, n_candidates: int = 500,
        generator: torch.Generator | None = None, seed: int | None = None, config=None,
        map: bool = True,
    ) -> Proposal:
        """Choose `n` views to capture next.

        Args:
            n: how many views.
            method: a selection method (`nerfaug.selection.METHODS`; "ours" is the paper's).
            candidates: where views may be taken from. None or "hemisphere": `n_candidates`
                poses uniform on the session's hemisphere (minus the training views); Cameras or
                an (C, 4, 4) array of world-frame poses (e.g. what a robot can reach; the
                session's intrinsics are used for poses); or a path to a transforms JSON of them.
            n_candidates: hemisphere candidates to draw.
            generator: random source for the candidates and the selector; None seeds one from
                the session seed and the proposal number (`proposal_seed`), so a resumed session
                proposes exactly what the original would have.
            seed: seed a generator with this instead.
            config: a `nerfaug.selection.SelectionConfig`; None for the paper's defaults.
            map: draw the hemisphere map to `run/proposals/proposal_NNN.png`.

        Returns:
            Proposal (world-frame poses, names, angles, every candidate's score, map path). The
            proposal is recorded in the history (saved with `save()`) and written, with its
            candidates, to `run/proposals/proposal_NNN.json`.
        """
        self._require_model()
        from nerfaug.selection import select_views

        number = len(self.state["proposals"])
        used_seed = None
        if generator is None:
            used_seed = proposal_seed(self.seed, number) if seed is None else int(seed)
            generator = torch.Generator().manual_seed(used_seed)
        world = self.candidate_cameras(candidates, n_candidates, generator)
        if len(world) < n:
            raise ValueError(f"cannot propose {n} views from {len(world)} candidates")
        hemisphere = self.hemisphere
        engine_train = self.trainer.train_views.cameras
        engine = Cameras(hemisphere.to_engine(world.camera_to_world), world.fx, world.fy, world.cx, world.cy,
                         world.width, world.height)
        if (engine.width, engine.height) != (engine_train.width, engine_train.height):
            engine = engine.resized(engine_train.width, engine_train.height)
        selection = select_views(method, self.trainer.model, engine_train, engine.to(self.trainer.device), n,
                                 generator, config)
        chosen = selection.indices.long()
        poses = world.camera_to_world[chosen]
        azimuth, polar, _ = hemisphere.angles(poses)
        names = [f"capture_{number:03d}_{i:02d}" for i in range(n)]
        folder = self.run_dir / PROPOSALS_DIR
        map_path = None
        if map:
            from nerfaug.maps import plot_hemisphere_map

            map_path = plot_hemisphere_map(
                engine.camera_to_world, selection.scores, engine_train.camera_to_world.cpu(),
                engine.camera_to_world[chosen], path=folder / f"proposal_{number:03d}.png",
                title=f"proposal {number}: {method} at step {self.step}",
            )
        angle_x = float(world.camera_angle_x[0])
        proposal = Proposal(number, selection.method or method, poses, names, azimuth, polar, chosen, world,
                            selection.scores.float(), dict(selection.components), map_path, self.step,
                            used_seed, angle_x, hemisphere)
        record_path = proposal.write(folder / f"proposal_{number:03d}.json", include_candidates=True)
        self.state["proposals"].append({
            "number": number, "method": proposal.method, "n": n, "step": self.step, "seed": used_seed,
            "candidates": _describe_candidates(candidates), "n_candidates": len(world),
            "names": names, "poses": poses.tolist(), "azimuth": azimuth.tolist(), "polar": polar.tolist(),
            "file": str(record_path.relative_to(self.run_dir)), "created": _now(),
        })
        return proposal

    def add_views(self, images, poses=None, names: Sequence[str] | None = None) -> list[str]:
        """Add captured images, taken at world-frame `poses`, to the dataset and to training.

        Everything is checked before anything is written; on any error the dataset folder is
        left exactly as it was. Then the images are written, then the transforms JSON (atomically).

        Args:
            images: a folder (matched to the poses' names by file stem when the poses come from
                a transforms JSON or a Proposal, else every image file in it, sorted by name); a
                list of image files and/or arrays; an array or tensor (n, H, W, 3 | 4) of uint8,
                uint16 or float in [0, 1] (RGBA alpha is kept); or `Views` (e.g. an oracle's
                capture, composited over the session's background; its cameras' poses are used
                when `poses` is None).
            poses: world-frame camera-to-world poses: an (n, 4, 4) array or tensor, a `Proposal`,
                or a path to a transforms JSON (e.g. one `Proposal.write` made).
            names: image names (file stems) for the new frames; by default the poses' frame
                names, else the files' stems, else `view_NNNN`.

        Returns:
            The new frames' names.

        Raises:
            DatasetError: naming the file or index and the value: count mismatch, wrong image
                size, unreadable file, values out of range, non-rigid pose, duplicate name.
        """
        self._require_model()
        expected_names: list[str] | None = None
        pose_source = "poses"
        if poses is None:
            if not isinstance(images, Views):
                raise ValueError("poses are needed unless images are Views with their cameras")
            poses = images.cameras.camera_to_world
        if isinstance(poses, Proposal):
            expected_names, poses = list(poses.names), poses.poses
        elif isinstance(poses, (str, Path)):
            pose_source = str(poses)
            poses, expected_names = read_poses(poses)
        array = np.asarray(_as_array(poses), dtype=np.float64)
        if array.ndim == 2:
            array = array[None]
        if array.ndim != 3 or array.shape[1:] != (4, 4):
            raise DatasetError(pose_source, "poses must have shape (n, 4, 4)", value=f"shape {array.shape}")
        checked = torch.stack([check_pose(p, Path(pose_source), f"poses[{i}]") for i, p in enumerate(array)])

        if names is not None:
            expected_names = list(names)
        is_folder = isinstance(images, (str, Path)) and Path(images).is_dir()
        captures = collect_images(images, expected_names if is_folder else None,
                                  tuple(self.state["background"]))
        if len(captures) != len(checked):
            where = str(images) if isinstance(images, (str, Path)) else "images"
            raise DatasetError(where, f"got {len(captures)} images but {len(checked)} poses; "
                                      "give one image per pose", value=f"{len(captures)} images")
        if expected_names is not None and len(expected_names) != len(checked):
            raise DatasetError(pose_source, f"got {len(expected_names)} names but {len(checked)} poses")
        k = self.state["intrinsics"]
        for capture in captures:
            _check_capture(capture, k["width"], k["height"])

        json_path = self._json_path()
        meta = read_json(json_path)
        frames = meta["frames"]
        existing = {Path(str(f["file_path"])).stem for f in frames}
        if expected_names is None:
            from_files = [c.name for c in captures]
            if all(from_files) and len(set(from_files)) == len(from_files):
                expected_names = from_files
            else:
                taken = set(existing)
                expected_names = [_unique_stem(f"view_{len(frames) + i:04d}", taken) for i in range(len(captures))]
        seen: set[str] = set()
        for i, name in enumerate(expected_names):
            if not _NAME.fullmatch(name):
                raise DatasetError(pose_source, "an image name may hold only letters, digits, '.', '_', '-'",
                                   field=f"names[{i}]", value=name)
            if name in existing:
                raise DatasetError(json_path, f"the dataset already has a frame named {name!r}; was this capture "
                                              "added before?", field=f"names[{i}]", value=name)
            if name in seen:
                raise DatasetError(pose_source, "two new images share this name", field=f"names[{i}]", value=name)
            seen.add(name)

        fmt, folder = self.state["dataset"]["format"], self.state["dataset"]["folder"]
        new_frames = []
        for name, capture, pose in zip(expected_names, captures, checked):
            data, suffix = _stored_bytes(capture, png_only=fmt == "blender")
            atomic_write_bytes(self.dataset_dir / folder / f"{name}{suffix}", data)
            frame = {"file_path": _file_path(fmt, folder, name, suffix), "transform_matrix": pose.double().tolist()}
            if fmt == "nerfstudio":
                frame.update({"fl_x": k["fx"], "fl_y": k["fy"], "cx": k["cx"], "cy": k["cy"],
                              "w": k["width"], "h": k["height"]})
            new_frames.append(frame)
        start = len(frames)
        atomic_write_json(json_path, {**meta, "frames": frames + new_frames})

        self.trainer.add_views(self._engine_views(start))
        self.state["views_in_model"] = len(self.trainer.train_views)
        matched = [p["number"] for p in self.state["proposals"] if set(expected_names) <= set(p["names"])]
        self.state["additions"].append({
            "step": self.step, "names": list(expected_names), "proposal": matched[-1] if matched else None,
            "created": _now(),
        })
        return list(expected_names)

    def render(self, poses, width: int | None = None) -> Tensor:
        """What the NeRF sees from world-frame `poses` (n, 4, 4): images (n, H, W, 3) in [0, 1],
        at the training resolution (or `width` pixels across)."""
        self._require_model()
        train = self.trainer.train_views.cameras
        camera = self.template(train.width, train.height)
        if width is not None:
            camera = camera.resized(width, max(1, round(width * train.height / train.width)))
        engine = self.hemisphere.to_engine(torch.as_tensor(_as_array(poses), dtype=torch.float32).reshape(-1, 4, 4))
        cameras = _with_poses(camera, engine).to(self.trainer.device)
        background = torch.tensor(self.state["background"], dtype=torch.float32, device=self.trainer.device)
        return torch.stack([self.trainer.model.render_image(cameras, i, background)["rgb"].cpu()
                            for i in range(len(cameras))])

    def export(self, out: str | Path, format: str = "nerfstudio", source_splits: bool = True) -> Path:
        """Write the grown dataset to `out` so other tools open it.

        "nerfstudio": `transforms.json` (OPENCV camera model, intrinsics global or per frame) and
        `images/`, for nerfstudio (`ns-train nerfacto --data OUT`) and instant-ngp.
        "blender": `transforms_train.json` and `train/*.png` (NeRF-synthetic), plus the source's
        val and test splits when it has them (nerfstudio's blender parser needs a val split).
        Images are copied byte for byte (never decoded and re-encoded), except non-PNG images
        in the Blender format, which become lossless PNGs.

        Returns the transforms JSON path (of the train split for "blender").
        """
        if format not in ("nerfstudio", "blender"):
            raise ValueError(f"format must be 'nerfstudio' or 'blender', got {format!r}")
        out = Path(out)
        json_path = self._json_path()
        meta = read_json(json_path)
        frames = meta["frames"]
        files = _frame_files(self.dataset_dir, json_path, frames)
        cameras = self.cameras
        if format == "blender" and not _blender_compatible(cameras):
            raise ValueError("these cameras do not fit the Blender format (one camera_angle_x, square pixels, "
                             "centred principal point); export with format='nerfstudio'")
        folder = "images" if format == "nerfstudio" else "train"
        taken: set[str] = set()
        new_frames = []
        for i, (frame, path) in enumerate(zip(frames, files)):
            stem = _unique_stem(Path(str(frame["file_path"])).stem, taken)
            data, suffix = _stored_bytes(_read_capture(path, f"frames[{i}].file_path"), png_only=format == "blender")
            atomic_write_bytes(out / folder / f"{stem}{suffix}", data)
            new_frames.append({"file_path": _file_path(format, folder, stem, suffix),
                               "transform_matrix": frame["transform_matrix"]})
        if format == "blender":
            path = out / "transforms_train.json"
            atomic_write_json(path, {"camera_angle_x": float(cameras.camera_angle_x[0]), "frames": new_frames})
            source = Path(self.state["source"]["data_dir"])
            if source_splits and self.state["source"]["format"] == "blender":
                for split in ("val", "test"):
                    split_json = source / f"transforms_{split}.json"
                    if split_json.exists() and split != self.state["source"]["split"]:
                        copied = _copy_split(source, split_json, out, split, "blender")
                        atomic_write_json(out / split_json.name, copied)
            return path
        intrinsics = {"fl_x": cameras.fx, "fl_y": cameras.fy, "cx": cameras.cx, "cy": cameras.cy}
        shared = all(bool((v - v[0]).abs().max() <= 1e-6 * max(1.0, float(v[0].abs()))) for v in intrinsics.values())
        top = {"camera_model": "OPENCV", "w": cameras.width, "h": cameras.height}
        if meta.get("camera_model"):
            top["camera_model"] = meta["camera_model"]
        top.update({k: meta[k] for k in ("k1", "k2", "k3", "k4", "p1", "p2") if k in meta})
        if shared:
            top.update({k: float(v[0]) for k, v in intrinsics.items()})
        else:
            for i, frame in enumerate(new_frames):
                frame.update({k: float(v[i]) for k, v in intrinsics.items()})
        path = out / "transforms.json"
        atomic_write_json(path, {**top, "frames": new_frames})
        return path


def _has_distortion(meta: dict) -> bool:
    keys = ("k1", "k2", "k3", "k4", "p1", "p2")
    frames = meta.get("frames") or []
    return any(float(meta.get(k) or 0) != 0 for k in keys) or any(
        float(f.get(k) or 0) != 0 for f in frames if isinstance(f, dict) for k in keys)


def _with_poses(template: Cameras, poses: Tensor) -> Cameras:
    """Cameras at `poses` (n, 4, 4) with the intrinsics of `template`'s first camera."""
    first = template[0]
    return Cameras(poses, float(first.fx[0]), float(first.fy[0]), float(first.cx[0]), float(first.cy[0]),
                   template.width, template.height)


def _describe_candidates(candidates) -> str:
    if candidates is None or (isinstance(candidates, str) and candidates == "hemisphere"):
        return "hemisphere"
    if isinstance(candidates, (str, Path)):
        return str(candidates)
    return "given"
