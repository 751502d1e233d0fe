"""What a client uploads, checked before anything is written: images (size limit, a format whose
header gives the size, the pixel count and the session camera's size read from the header before
any pixel is decoded, decodable, RGB(A), a usable name; stored under the suffix of the format their
bytes are) and poses (4x4, finite, rigid), each error one line naming the field
(`images[2] (capture_000_02.png)`, `poses[1]`)."""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path, PurePath

import imageio.v3 as iio
import numpy as np
import torch
from torch import Tensor

from nerfaug.capture.dataset import NAME
from nerfaug.capture.images import CAPTURE_SUFFIXES
from nerfaug.data import DatasetError
from nerfaug.data.frames import check_pose
from nerfaug.service.errors import ServiceError, bad_input
from nerfaug.service.limits import MAX_IMAGE_PIXELS, MEGABYTE

# The formats an upload may be, by what Pillow reads in its header, and the suffixes that name them
# (the first is the one an upload is stored under when its name says another format).
UPLOAD_FORMATS = {
    "PNG": (".png",),
    "JPEG": (".jpg", ".jpeg"),
    "TIFF": (".tif", ".tiff"),
    "BMP": (".bmp",),
    "WEBP": (".webp",),
}


@dataclass
class Upload:
    """One uploaded image, checked: its name (file stem), suffix, bytes and decoded pixels."""

    name: str
    suffix: str
    data: bytes
    shape: tuple[int, ...]


def read_upload(
    file, index: int, limit_bytes: int, size: tuple[int, int] | None, max_pixels: int = MAX_IMAGE_PIXELS
) -> Upload:
    """Read and check uploaded image `index`.

    Args:
        file: an object with `.filename` and a binary `.file` (FastAPI's `UploadFile`).
        index: its position in the request's `images` field.
        limit_bytes: the largest accepted file.
        size: (width, height) the image must have, or None to accept any.
        max_pixels: the most pixels an image may have (checked in its header, before decoding).

    Raises:
        ServiceError: 413 over the byte or pixel limit; 422 for a bad name, a format other than
            `UPLOAD_FORMATS`, an undecodable file, a wrong size or shape.
    """
    filename = PurePath(str(file.filename or "")).name
    label = f"images[{index}] ({filename or 'no file name'})"
    stem, suffix = PurePath(filename).stem, PurePath(filename).suffix.lower()
    if suffix not in CAPTURE_SUFFIXES:
        raise bad_input(f"{label}: the file name must end in one of {', '.join(CAPTURE_SUFFIXES)}")
    if not NAME.fullmatch(stem):
        raise bad_input(f"{label}: a file name may hold only letters, digits, '.', '_', '-'")
    data = file.file.read(limit_bytes + 1)
    if len(data) > limit_bytes:
        raise ServiceError(413, f"{label}: larger than the upload limit of {limit_bytes / MEGABYTE:.3g} MB")
    kind, width, height = image_header(data, label)
    if width * height > max_pixels:
        raise ServiceError(
            413, f"{label}: {width}x{height} pixels is over the limit of {max_pixels} pixels per image (not decoded)"
        )
    if size is not None and (width, height) != tuple(size):
        raise bad_input(f"{label}: image is {width}x{height} pixels but the camera is {size[0]}x{size[1]}")
    if suffix not in UPLOAD_FORMATS[kind]:  # stored under the name its bytes say
        suffix = UPLOAD_FORMATS[kind][0]
    try:
        array = np.asarray(iio.imread(data, extension=suffix))
    except Exception:  # noqa: BLE001 -- imageio raises many types; all mean "not an image"
        raise bad_input(f"{label}: not an image this service can read ({suffix} could not be decoded)") from None
    if array.ndim != 3 or array.shape[-1] not in (3, 4):
        raise bad_input(f"{label}: an image must be RGB or RGBA, got pixels of shape {list(array.shape)}")
    if size is not None and (array.shape[1], array.shape[0]) != tuple(size):
        raise bad_input(
            f"{label}: image is {array.shape[1]}x{array.shape[0]} pixels but the camera is {size[0]}x{size[1]}"
        )
    return Upload(stem, suffix, data, tuple(array.shape))


def image_header(data: bytes, label: str) -> tuple[str, int, int]:
    """The format ("PNG", "JPEG", ...: a key of `UPLOAD_FORMATS`) and the size in pixels an image's
    header states, read without decoding its pixels; 422 naming `label` for anything else."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:  # reads the header only
            kind, (width, height) = image.format, image.size
    except Image.DecompressionBombError:
        raise ServiceError(413, f"{label}: the image header states far too many pixels (not decoded)") from None
    except Exception:  # noqa: BLE001 -- Pillow raises many types; all mean "no header it knows"
        kind, width, height = None, 0, 0
    if kind not in UPLOAD_FORMATS:
        names = ", ".join(s for suffixes in UPLOAD_FORMATS.values() for s in suffixes)
        raise bad_input(f"{label}: not an image this service can read (send one of {names})")
    return kind, int(width), int(height)


def check_names(uploads: list[Upload]) -> None:
    """Raise 422 when two uploaded images share a name."""
    seen: dict[str, int] = {}
    for i, upload in enumerate(uploads):
        if upload.name in seen:
            raise bad_input(f"images[{i}] ({upload.name}{upload.suffix}): the same name as images[{seen[upload.name]}]")
        seen[upload.name] = i


def parse_json_field(text: str, field: str):
    """A form field holding JSON, parsed; 422 naming the field when it is not JSON."""
    try:
        return json.loads(text)
    except (json.JSONDecodeError, TypeError) as error:
        raise bad_input(f"{field}: not valid JSON ({getattr(error, 'msg', error)})") from None


def check_poses(value, field: str = "poses", count: int | None = None) -> Tensor:
    """World-frame camera-to-world poses from JSON lists.

    Args:
        value: a list of 4x4 nested lists (or one 4x4).
        field: the field's name in messages.
        count: the number of poses expected (one per image), or None.

    Returns:
        Tensor with shape (n, 4, 4), float32.

    Raises:
        ServiceError: 422 naming `field[i]`: not 4x4, non-finite, not rigid, or the wrong count.
    """
    if isinstance(value, list) and len(value) == 4 and all(isinstance(r, list) and len(r) == 4 for r in value):
        if all(isinstance(x, (int, float)) for r in value for x in r):
            value = [value]
    if not isinstance(value, list) or not value:
        raise bad_input(f"{field}: must be a non-empty list of 4x4 camera-to-world matrices")
    poses = []
    for i, matrix in enumerate(value):
        name = f"{field}[{i}]"
        if any(isinstance(x, float) and not math.isfinite(x) for x in _entries(matrix)):
            raise bad_input(f"{name}: not finite (every entry of a pose must be a finite number)")
        try:
            poses.append(check_pose(matrix, Path(field), name))
        except DatasetError as error:
            raise bad_input(f"{name}: {error.problem}") from None
        except ValueError:
            raise bad_input(f"{name}: transform_matrix must be 4 rows of 4 numbers") from None
    if count is not None and len(poses) != count:
        raise bad_input(f"{field}: {len(poses)} poses for {count} images; give one pose per image")
    return torch.stack(poses)


def _entries(value):
    """Every scalar of nested lists."""
    if isinstance(value, list):
        for item in value:
            yield from _entries(item)
    else:
        yield value


def write_uploads(folder: Path, uploads: list[Upload]) -> list[Path]:
    """Write the uploads' bytes, unchanged, into `folder` (new); returns the files in order."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for upload in uploads:
        path = folder / f"{upload.name}{upload.suffix}"
        path.write_bytes(upload.data)
        paths.append(path)
    return paths
