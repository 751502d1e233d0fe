"""Reading and checking what both transforms formats share: JSON files, 4x4 poses, RGBA images."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
from torch import Tensor

from nerfaug.data.errors import DatasetError

_UMASK = os.umask(0o022)
os.umask(_UMASK)
IMAGE_SUFFIXES = ("", ".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".exr")


def read_json(path: Path) -> dict:
    """The JSON object in `path`, or a DatasetError saying why not."""
    if not path.exists():
        raise DatasetError(path, "file not found")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise DatasetError(path, f"invalid JSON at line {error.lineno} column {error.colno}: {error.msg}")
    if not isinstance(data, dict):
        raise DatasetError(path, "expected a JSON object at the top level", value=type(data).__name__)
    return data


def require(data: dict, key: str, path: Path, where: str = ""):
    if key not in data:
        raise DatasetError(path, f"missing required field{where}", field=key)
    return data[key]


def check_pose(matrix, path: Path, field: str) -> Tensor:
    """A validated rigid 4x4 camera-to-world matrix as float32 of shape (4, 4)."""
    try:
        pose = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(path, "transform_matrix is not numeric", field=field, value=matrix)
    if pose.shape != (4, 4):
        raise DatasetError(path, f"transform_matrix must be 4x4, has shape {pose.shape}", field=field, value=matrix)
    if not np.all(np.isfinite(pose)):
        raise DatasetError(path, "transform_matrix has non-finite entries", field=field, value=pose.tolist())
    rotation = pose[:3, :3]
    # Blender exports are float32; 1e-3 accepts their round-off, rejects scaled or sheared matrices.
    if np.abs(rotation.T @ rotation - np.eye(3)).max() > 1e-3 or abs(np.linalg.det(rotation) - 1) > 1e-3:
        raise DatasetError(
            path, "transform_matrix rotation is not rigid (R^T R != I or det(R) != 1)",
            field=field, value=np.round(rotation, 4).tolist(),
        )
    if np.abs(pose[3] - np.array([0, 0, 0, 1])).max() > 1e-6:
        raise DatasetError(path, "transform_matrix last row must be [0, 0, 0, 1]", field=field, value=pose[3].tolist())
    return torch.from_numpy(pose).float()


def resolve_image(root: Path, file_path: str, json_path: Path, field: str) -> Path:
    """The image file a frame's `file_path` names (the Blender format omits the extension)."""
    base = (root / file_path).resolve()
    for suffix in IMAGE_SUFFIXES:
        candidate = base.with_name(base.name + suffix) if suffix else base
        if candidate.is_file():
            return candidate
    raise DatasetError(json_path, f"image file not found: {base}[.png]", field=field, value=file_path)


def read_image(path: Path, background: Tensor, downscale: int, json_path: Path, field: str) -> tuple[Tensor, Tensor | None]:
    """An image composited over `background`, as float32 (h, w, 3) in [0, 1], and its alpha (h, w).

    Args:
        background: Tensor with shape (3,), the colour behind transparent pixels.
        downscale: integer factor; the image is area-averaged (premultiplied) by it.
    """
    try:
        array = iio.imread(path)
    except Exception as error:  # imageio raises many types; all mean "cannot read"
        raise DatasetError(json_path, f"cannot read image {path}: {error}", field=field)
    if array.ndim == 2 or array.shape[-1] not in (3, 4):
        raise DatasetError(json_path, f"image {path} must be RGB or RGBA", field=field, value=f"shape {array.shape}")
    if array.dtype == np.uint8:
        image = torch.from_numpy(array.astype(np.float32) / 255.0)
    elif array.dtype == np.uint16:
        image = torch.from_numpy(array.astype(np.float32) / 65535.0)
    else:
        image = torch.from_numpy(array.astype(np.float32)).clamp(0, 1)
    alpha = image[..., 3] if image.shape[-1] == 4 else None
    rgb = image[..., :3]
    if alpha is not None:
        rgb = rgb * alpha[..., None]  # premultiply so downscaling does not bleed background colour
    if downscale > 1:
        h, w = rgb.shape[0] // downscale * downscale, rgb.shape[1] // downscale * downscale
        pool = lambda x: x[:h, :w].reshape(h // downscale, downscale, w // downscale, downscale, -1).mean((1, 3))
        rgb = pool(rgb)
        if alpha is not None:
            alpha = pool(alpha[..., None])[..., 0]
    if alpha is not None:
        rgb = rgb + (1.0 - alpha[..., None]) * background
    return rgb.contiguous(), alpha


def write_image(path: Path, image: Tensor, alpha: Tensor | None = None, background: Tensor | None = None) -> None:
    """Write an (h, w, 3) image in [0, 1] (and optional (h, w) alpha) as an 8-bit PNG, atomically.

    With an alpha, `image` is taken as composited over `background` (white by default), as the
    loader returns it, and is un-composited before writing so that loading gives it back.
    """
    array = image.detach().cpu().clamp(0, 1)
    if alpha is not None:
        alpha = alpha.detach().cpu().clamp(0, 1)[..., None]
        if background is None:
            background = torch.ones(3)
        straight = (array - (1.0 - alpha) * background) / alpha.clamp_min(1e-6)
        array = torch.cat([torch.where(alpha > 0, straight, torch.zeros_like(array)).clamp(0, 1), alpha], dim=-1)
    data = (array.numpy() * 255.0 + 0.5).astype(np.uint8)
    atomic_write_bytes(path, iio.imwrite("<bytes>", data, extension=".png"))


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write `data` to `path` so that readers see the old file or the whole new one, never a part."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp makes 0600 files; give the usual permissions
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_json(path: Path, data) -> None:
    atomic_write_bytes(path, (json.dumps(data, indent=2) + "\n").encode())
