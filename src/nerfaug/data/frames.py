"""What both transforms formats share: checking 4x4 poses and frame entries, finding and reading
RGBA images, and turning a list of frames into `Views` (`load_frames`).

JSON reading and atomic writes live in `nerfaug.jsonio` (torch-free).
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
from torch import Tensor

from nerfaug import camera_schema
from nerfaug.cameras import Cameras
from nerfaug.containment import inside
from nerfaug.data.errors import DatasetError
from nerfaug.data.views import Views
from nerfaug.jsonio import atomic_write_bytes

IMAGE_SUFFIXES = ("", ".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".exr")
# Image files every reader of every format takes as they are; others are stored as PNG.
STORED_SUFFIXES = (".png", ".jpg", ".jpeg")


def require(data: dict, key: str, path: Path, where: str = ""):
    if key not in data:
        raise DatasetError(path, f"missing required field{where}", field=key)
    return data[key]


def require_frames(meta: dict, json_path: Path) -> list:
    """A transforms JSON's `frames`: a non-empty list (its entries are checked where read)."""
    frames = require(meta, "frames", json_path)
    if not isinstance(frames, list) or not frames:
        raise DatasetError(
            json_path,
            "frames must be a non-empty list",
            field="frames",
            value=frames if not isinstance(frames, list) else [],
        )
    return frames


def atomic_write_numpy(path: Path, save: Callable, *args, **kwargs) -> Path:
    """Write to `path`, atomically, what numpy's `save` (`np.save`, `np.savez`) writes for `args`
    and `kwargs`; returns `path`."""
    buffer = io.BytesIO()
    save(buffer, *args, **kwargs)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def is_number(value) -> bool:
    """Whether `value` is a JSON number (int or float, not a bool) with a finite float value."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer beyond float range
        return False


def check_number(value, path: Path, field: str, low: float = -math.inf, high: float = math.inf) -> float:
    """`value` as a float, if it is a finite number with low < value < high; else a DatasetError."""
    if not is_number(value) or not low < float(value) < high:
        bounds = " and ".join(b for b in (f"> {low:g}" * (low > -math.inf), f"< {high:g}" * (high < math.inf)) if b)
        raise DatasetError(path, f"must be a finite number{' ' + bounds if bounds else ''}", field=field, value=value)
    return float(value)


def check_pose(matrix, path: Path, field: str) -> Tensor:
    """A rigid, finite 4x4 camera-to-world matrix (`nerfaug.camera_schema.check_pose`) as float32
    of shape (4, 4)."""
    return torch.from_numpy(camera_schema.check_pose(matrix, path, field)).float()


def check_file_path(value, path: Path, field: str) -> str:
    """A frame's `file_path`: a non-empty string without NUL characters."""
    if not isinstance(value, str) or not value.strip() or "\x00" in value:
        raise DatasetError(
            path, "file_path must be a non-empty path string (relative to the dataset folder)", field=field, value=value
        )
    return value


def resolve_image(root: Path, file_path: str, json_path: Path, field: str) -> Path:
    """The image file a frame's `file_path` names (the Blender format omits the extension),
    resolved (symlinks followed); it must lie inside `root` (`nerfaug.containment.inside`).

    Raises:
        DatasetError: naming `json_path`, `field` and `file_path`, when no image file exists, the
            path cannot be used (too long, a symlink loop), or the file lies outside `root`
            (through `..`, an absolute path or a symlink): a dataset never reads other files.
    """
    file_path = check_file_path(file_path, json_path, field)
    for suffix in IMAGE_SUFFIXES:
        # Checked before the file is looked at: a refusal says nothing of what lies outside.
        real = inside(
            root, root / (file_path + suffix), "image path", listed_in=json_path, field=field, value=file_path
        )
        try:
            if real.is_file():
                return real
        except (OSError, ValueError) as error:  # a name too long; a NUL byte
            reason = getattr(error, "strerror", None) or type(error).__name__
            raise DatasetError(
                json_path, f"cannot use this image path ({reason})", field=field, value=file_path
            ) from None
    base = os.path.normpath(root.absolute() / file_path)  # no resolve(): a symlink loop would raise
    raise DatasetError(json_path, f"image file not found: {base}[.png]", field=field, value=file_path)


def resolve_mask(root: Path, mask: Path, json_path: Path, field: str) -> Path:
    """A mask file beside a captured set's images, resolved; it must lie inside `root`, as an
    image must (`resolve_image`), and is refused before it is opened."""
    shown = mask.relative_to(root).as_posix() if mask.is_relative_to(root) else str(mask)
    return inside(root, mask, "mask path", listed_in=json_path, field=field, value=shown)


def _first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return (text[0] if text else type(error).__name__)[:300]


def read_mask(path: Path, json_path: Path, field: str) -> np.ndarray:
    """A mask image (grey, RGB or RGBA; 8 or 16 bit) as a binary float32 (h, w) array: 1 where
    its first channel is above half. Thresholded at full resolution so that JPEG noise around 0
    and 255 does not become a faint haze; downscaling then averages the edges into a soft alpha."""
    try:
        array = np.asarray(iio.imread(path))
    except Exception as error:  # noqa: BLE001 -- imageio's plugins raise many types; all mean "cannot read"
        raise DatasetError(json_path, f"cannot read mask {path}: {_first_line(error)}", field=field) from None
    if array.ndim == 3:
        array = array[..., 0]
    if array.ndim != 2 or array.dtype.kind not in "uifb":
        raise DatasetError(
            json_path, f"mask {path} must be a grey or RGB image", field=field, value=f"shape {array.shape}"
        )
    high = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(array.dtype, 1.0)
    return (array.astype(np.float32) > 0.5 * high).astype(np.float32)


def read_image(
    path: Path,
    background: Tensor,
    downscale: int,
    json_path: Path,
    field: str,
    mask: Path | None = None,
    warp: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[Tensor, Tensor | None]:
    """An image composited over `background`, as float32 (h, w, 3) in [0, 1], and its alpha (h, w).

    Args:
        background: Tensor with shape (3,), the colour behind transparent pixels.
        downscale: integer factor; the image is area-averaged (premultiplied) by it.
        mask: a mask image of the same size (`read_mask`) that becomes the alpha, over any
            alpha channel the image has (captured datasets keep masks beside the photos).
        warp: resamples the image once downscaled, float32 (h, w, 3 or 4: colour premultiplied by
            the alpha, then the alpha) in [0, 1], to the same size (a lens's undistortion,
            `nerfaug.data.lens`, which is the same at any scale of the intrinsics).
    """
    try:
        array = np.asarray(iio.imread(path))
    except Exception as error:  # noqa: BLE001 -- imageio's plugins raise many types; all mean "cannot read"
        raise DatasetError(json_path, f"cannot read image {path}: {_first_line(error)}", field=field) from None
    if mask is not None and array.ndim == 3:
        matte = read_mask(mask, json_path, field)
        if matte.shape != array.shape[:2]:
            raise DatasetError(
                json_path,
                f"mask {mask} differs in size from its image {path}",
                field=field,
                value=f"{matte.shape[1]}x{matte.shape[0]} against {array.shape[1]}x{array.shape[0]}",
            )
        high = {np.dtype(np.uint8): 255, np.dtype(np.uint16): 65535}.get(array.dtype, 1.0)
        array = np.concatenate([array[..., :3], (matte * high).astype(array.dtype)[..., None]], axis=-1)
    if array.ndim != 3 or array.shape[-1] not in (3, 4):
        raise DatasetError(
            json_path,
            f"image {path} must be an RGB or RGBA image (one frame)",
            field=field,
            value=f"shape {array.shape}",
        )
    if min(array.shape[:2]) < downscale:
        raise DatasetError(
            json_path,
            f"image {path} is smaller than the downscale factor {downscale}",
            field=field,
            value=f"{array.shape[1]}x{array.shape[0]}",
        )
    if array.dtype == np.uint8:
        image = torch.from_numpy(array.astype(np.float32) / 255.0)
    elif array.dtype == np.uint16:
        image = torch.from_numpy(array.astype(np.float32) / 65535.0)
    elif array.dtype.kind == "f":
        if not np.isfinite(array).all():
            raise DatasetError(json_path, f"image {path} has non-finite pixel values", field=field)
        image = torch.from_numpy(array.astype(np.float32)).clamp(0, 1)
    else:
        raise DatasetError(
            json_path, f"image {path} has an unsupported pixel type", field=field, value=str(array.dtype)
        )
    alpha = image[..., 3] if image.shape[-1] == 4 else None
    rgb = image[..., :3]
    if alpha is not None:
        rgb = rgb * alpha[..., None]  # premultiply so downscaling does not bleed background colour
    if downscale > 1:
        h, w = rgb.shape[0] // downscale * downscale, rgb.shape[1] // downscale * downscale

        def pool(x):
            return x[:h, :w].reshape(h // downscale, downscale, w // downscale, downscale, -1).mean((1, 3))

        rgb = pool(rgb)
        if alpha is not None:
            alpha = pool(alpha[..., None])[..., 0]
    if warp is not None:  # after shrinking: d^2 fewer pixels to resample; premultiplied, so no halo
        stacked = rgb if alpha is None else torch.cat([rgb, alpha[..., None]], dim=-1)
        warped = torch.from_numpy(np.clip(warp(stacked.numpy()), 0.0, 1.0).astype(np.float32))
        rgb, alpha = warped[..., :3], (None if alpha is None else warped[..., 3])
        if alpha is not None:
            rgb = torch.minimum(rgb, alpha[..., None])  # premultiplied colour never exceeds its alpha
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


def write_image_and_mask(
    image_path: Path, mask_path: Path, image: Tensor, alpha: Tensor | None, background: Tensor
) -> None:
    """Write an (h, w, 3) image composited over `background` as a straight RGB PNG at
    `image_path`, and its (h, w) alpha, when known, as a grey mask PNG at `mask_path`: the layout
    of captured datasets, whose readers composite the photo with its mask again."""
    if alpha is not None:
        a = alpha[..., None]
        image = ((image - (1 - a) * background) / a.clamp_min(1e-6)).where(a > 0, 0).clamp(0, 1)
        write_image(mask_path, alpha[..., None].expand(-1, -1, 3))
    write_image(image_path, image)


def encode_png(array: np.ndarray) -> bytes:
    """A lossless PNG of an (H, W, 3 | 4) image: uint8 and uint16 as they are, floats in [0, 1] as 8 bits."""
    if array.dtype not in (np.uint8, np.uint16):
        array = (np.clip(array, 0, 1) * 255.0 + 0.5).astype(np.uint8)
    return iio.imwrite("<bytes>", np.ascontiguousarray(array), extension=".png")


def decode_image(path: Path, label: str | None = None) -> np.ndarray:
    """The pixels of an image file as decoded (DatasetError naming `path` and `label` if it cannot be read)."""
    if not path.is_file():
        raise DatasetError(path, "image file not found", field=label)
    try:
        return np.asarray(iio.imread(path))
    except Exception as error:  # noqa: BLE001 -- imageio raises many types; all mean "cannot read"
        raise DatasetError(path, f"cannot read image: {error}", field=label) from None


def stored_image(path: Path, png_only: bool, label: str | None = None) -> tuple[bytes, str]:
    """The bytes an image file is stored as in a dataset, and their suffix: the file itself when
    the format's readers take it (PNG; JPEG too unless `png_only`), else a lossless PNG of its
    pixels. The file is decoded either way: an unreadable image is refused (DatasetError)."""
    array = decode_image(path, label)
    suffix = path.suffix.lower()
    if suffix == ".png" or (not png_only and suffix in STORED_SUFFIXES):
        return path.read_bytes(), suffix
    return encode_png(array), ".png"


# (camera_angle_x, None) or (None, (fx, fy, cx, cy)) for frame i at a file resolution (w, h).
IntrinsicsOf = Callable[[int, int, int], tuple[float | None, tuple[float, float, float, float] | None]]


def load_frames(
    root: Path,
    json_path: Path,
    frames: Sequence,
    background,
    downscale: int,
    lazy: bool,
    intrinsics_of: IntrinsicsOf,
    masks: Sequence[Path] | None = None,
    warp_of: Callable[[int], Callable[[np.ndarray], np.ndarray] | None] | None = None,
    camera_field: Callable[[int], camera_schema.FieldNames] = lambda i: f"frames[{i}]",
    pose_field: Callable[[int], str] = lambda i: f"frames[{i}].transform_matrix",
) -> Views:
    """The views a listing's `frames` list describes, for any format.

    Args:
        root: the dataset folder; every `file_path` must resolve inside it.
        json_path: the transforms file, named in every error.
        frames: its non-empty `frames` list (objects with `file_path` and `transform_matrix`).
        background: RGB in [0, 1] composited behind transparent pixels.
        downscale: integer factor to shrink images (and intrinsics) by.
        lazy: read only the first image now (for its size) and the rest on access.
        intrinsics_of: `intrinsics_of(w, h, i)` gives (camera_angle_x, None) or
            (None, (fx, fy, cx, cy)) for frame i at the file's full resolution.
        masks: one mask file per frame (`read_image`), or None to take alpha from the images.
        warp_of: `warp_of(i)` resamples frame i's image (`read_image`'s `warp`), or is None;
            `intrinsics_of` then gives the intrinsics of the resampled image.
        camera_field: where the listing gives frame i's camera, as errors name it: one name, or
            a function of "fx", "fy", "cx", "cy", "width", "height"; every camera is held to
            `nerfaug.camera_schema.check_pinhole`.
        pose_field: where the listing gives frame i's pose, as errors name it; the poses are held
            to `nerfaug.camera_schema.check_camera_spread`.
    """
    background = torch.as_tensor(background, dtype=torch.float32)
    poses, paths, names = [], [], []
    for i, frame in enumerate(frames):
        field = f"frames[{i}]"
        if not isinstance(frame, dict):
            raise DatasetError(json_path, "each frame must be an object", field=field, value=frame)
        file_path = require(frame, "file_path", json_path, f" in {field}")
        matrix = require(frame, "transform_matrix", json_path, f" in {field}")
        poses.append(check_pose(matrix, json_path, f"{field}.transform_matrix"))
        paths.append(resolve_image(root, file_path, json_path, f"{field}.file_path"))
        names.append(file_path)
    camera_schema.check_camera_spread([pose[:3, 3].tolist() for pose in poses], json_path, pose_field)
    if masks is not None:  # each refused before any is opened, as an image is
        masks = [resolve_mask(root, mask, json_path, f"frames[{i}].mask") for i, mask in enumerate(masks)]

    def load(i: int):
        mask = None if masks is None else masks[i]
        warp = None if warp_of is None else warp_of(i)
        return read_image(paths[i], background, downscale, json_path, f"frames[{i}].file_path", mask, warp)

    def check_size(i: int, image: Tensor) -> None:
        """Every image has the first one's size (for a lazy Views, checked as each is read)."""
        if image.shape[:2] != (height, width):
            raise DatasetError(
                json_path,
                f"image size differs from frames[0]'s {width}x{height}",
                field=f"frames[{i}].file_path",
                value=f"{image.shape[1]}x{image.shape[0]} ({paths[i]})",
            )

    first, first_alpha = load(0)
    height, width = first.shape[:2]
    loaded = [(first, first_alpha)] + ([] if lazy else [load(i) for i in range(1, len(frames))])
    for i, (image, _) in enumerate(loaded):
        check_size(i, image)
    full_w, full_h = width * downscale, height * downscale
    c2w = torch.stack(poses)
    per_frame = [intrinsics_of(full_w, full_h, i) for i in range(len(frames))]
    for i, (angle, intrinsics) in enumerate(per_frame):
        focal = None if angle is None else 0.5 * full_w / math.tan(0.5 * angle)
        fx, fy, cx, cy = intrinsics or (focal, focal, full_w / 2.0, full_h / 2.0)
        camera_schema.check_pinhole(fx, fy, cx, cy, full_w, full_h, json_path, camera_field(i))
    if per_frame[0][0] is not None:
        cameras = Cameras.from_fov(c2w, per_frame[0][0], full_w, full_h)
    else:
        fx, fy, cx, cy = (torch.tensor([p[1][k] for p in per_frame]) for k in range(4))
        cameras = Cameras(c2w, fx, fy, cx, cy, full_w, full_h)
    cameras = cameras.resized(width, height) if downscale > 1 else cameras

    if lazy:

        def checked_load(i: int):
            image, alpha = load(i)
            check_size(i, image)
            return image, alpha

        return Views(cameras, None, names, None, loader=checked_load)
    images = torch.stack([im for im, _ in loaded])
    alphas = torch.stack([a for _, a in loaded]) if all(a is not None for _, a in loaded) else None
    return Views(cameras, images, names, alphas)
