"""Captured images from any source (a folder, files, arrays, tensors, `Views`): collected in
order, checked against the dataset's camera, and stored byte for byte when every loader reads
their format (else as lossless PNG)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
from torch import Tensor

from nerfaug.capture.dataset import NAME
from nerfaug.containment import inside
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import STORED_SUFFIXES, decode_image, encode_png
from nerfaug.data.views import Views

# Image files a capture folder may hold; anything else in it is ignored.
CAPTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".bmp", ".webp")


@dataclass
class Capture:
    """One validated image to add: its pixels (for the format check), and how to store it."""

    label: str  # names it in error messages: the file, or images[i]
    array: np.ndarray  # (H, W, 3 | 4) as decoded, uint8 / uint16 / float
    source: Path | None = None  # the file it came from, copied byte for byte when possible
    name: str | None = None  # the stem a folder match found it under


@dataclass(frozen=True)
class ImageFile:
    """An image file as captured, e.g. uploaded: its name (the new view's), suffix and bytes."""

    name: str
    suffix: str
    data: bytes


def check_file_name(name: str, suffix: str, label: str) -> None:
    """Refuse an image file's name (stem) that cannot name a view (`NAME`: no separators, so it
    stays inside the folder it is written to), or a suffix that is not an image's.

    Raises:
        DatasetError: naming the file by `label`.
    """
    if suffix.lower() not in CAPTURE_SUFFIXES:
        raise DatasetError(label, f"the file name must end in one of {', '.join(CAPTURE_SUFFIXES)}")
    if not NAME.fullmatch(name):
        raise DatasetError(label, "a file name may hold only letters, digits, '.', '_', '-'")


def file_label(index: int, file: ImageFile) -> str:
    """How errors name file `index` of a list: "images[2] (shot_2.png)"."""
    return f"images[{index}] ({file.name}{file.suffix})"


def check_files(files: Sequence[ImageFile]) -> None:
    """Refuse a file whose name cannot name a view (`check_file_name`), or two files of one name
    (a view's), whatever their suffixes: the second would take the first one's place.

    Raises:
        DatasetError: naming the file (and the first of its name) by its index in `files`.
    """
    seen: dict[str, int] = {}
    for i, f in enumerate(files):
        check_file_name(f.name, f.suffix, file_label(i, f))
        if f.name in seen:
            raise DatasetError(file_label(i, f), f"the same name as images[{seen[f.name]}]")
        seen[f.name] = i


def check_image_files(files: Sequence[ImageFile], width: int, height: int) -> None:
    """Refuse what `check_files` refuses, and a file whose bytes do not decode to an RGB(A) image
    of `width` x `height` pixels (`check_capture`), before anything is written.

    Raises:
        DatasetError: naming the file by its index in `files`.
    """
    check_files(files)
    for i, f in enumerate(files):
        try:
            array = np.asarray(iio.imread(f.data, extension=f.suffix.lower()))
        except Exception:  # noqa: BLE001 -- imageio raises many types; all mean "cannot read"
            raise DatasetError(file_label(i, f), f"cannot read image (its bytes do not decode as {f.suffix})") from None
        check_capture(Capture(file_label(i, f), array, name=f.name), width, height)


def write_files(files: Sequence[ImageFile], folder: Path) -> list[Path]:
    """Write the files' bytes, unchanged, into `folder` (`check_files` first); returns the files
    in order."""
    check_files(files)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [folder / f"{f.name}{f.suffix}" for f in files]
    for path, f in zip(paths, files):
        path.write_bytes(f.data)
    return paths


def image_files(folder: Path) -> list[Path]:
    return sorted(
        p
        for p in folder.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in CAPTURE_SUFFIXES
    )


def read_capture(path: Path, label: str | None = None, folder: Path | None = None) -> Capture:
    """The image file `path` as a capture named by its stem; given the `folder` it was found in,
    read only where it lies inside it (`PathRefused` for a link out of it)."""
    real = path if folder is None else inside(folder, path, "image")  # its pixels and bytes are read from here
    return Capture(str(path), decode_image(real, label), source=real, name=path.stem)


def as_array(image) -> np.ndarray:
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


def collect_images(images, names: Sequence[str] | None = None, background=(1.0, 1.0, 1.0)) -> list[Capture]:
    """The images of `images`, in order, without checking their content yet.

    Args:
        images: a folder (matched to `names` by file stem when names are given, else every image
            file in it, sorted by name); a list of files and/or arrays; an array or tensor with
            shape (n, H, W, 3 | 4) (uint8, uint16 or float in [0, 1]); or `Views`.
        names: the expected image names (stems), e.g. a proposal's.
        background: the colour `Views` images were composited over.
    """
    if isinstance(images, Views):
        return [
            Capture(f"images[{i}] ({name})", array, name=Path(name).stem)
            for i, (name, array) in enumerate(zip(images.names, _uncomposite(images, background)))
        ]
    if isinstance(images, (str, Path)):
        path = Path(images)
        if path.is_dir():
            files = image_files(path)
            if names is None:
                if not files:
                    raise DatasetError(path, f"no image files ({', '.join(CAPTURE_SUFFIXES)}) in this folder")
                return [read_capture(f, folder=path) for f in files]
            by_stem: dict[str, list[Path]] = {}
            for f in files:
                by_stem.setdefault(f.stem, []).append(f)
            captures = []
            for i, name in enumerate(names):
                found = by_stem.get(name, [])
                if not found:
                    present = ", ".join(f.name for f in files[:8]) + (" ..." if len(files) > 8 else "")
                    raise DatasetError(
                        path,
                        f"no image named {name}.* for pose {i} (the folder holds: {present or 'no images'})",
                        field=f"frames[{i}]",
                        value=name,
                    )
                if len(found) > 1:
                    raise DatasetError(
                        path,
                        f"several images named {name}.*; keep one",
                        field=f"frames[{i}]",
                        value=[f.name for f in found],
                    )
                captures.append(read_capture(found[0], folder=path))
            return captures
        return [read_capture(path)]
    if isinstance(images, (np.ndarray, Tensor)):
        array = as_array(images)
        if array.ndim == 3:
            array = array[None]
        if array.ndim != 4:
            raise DatasetError(
                "images", "an array of images must have shape (n, H, W, 3 | 4)", value=f"shape {array.shape}"
            )
        return [Capture(f"images[{i}]", array[i]) for i in range(array.shape[0])]
    if isinstance(images, (list, tuple)):
        captures = []
        for i, item in enumerate(images):
            if isinstance(item, (str, Path)):
                captures.append(read_capture(Path(item), f"images[{i}]"))
            else:
                captures.append(Capture(f"images[{i}]", as_array(item)))
        return captures
    raise TypeError(
        f"images must be a folder, a list of files or arrays, an (n, H, W, C) array or tensor, or Views; "
        f"got {type(images).__name__}"
    )


def check_capture(capture: Capture, width: int, height: int) -> None:
    """Raise DatasetError unless `capture` is an RGB(A) image of the dataset's size with valid values."""
    array = capture.array
    where = capture.label
    if array.ndim != 3 or array.shape[-1] not in (3, 4):
        raise DatasetError(
            where,
            "an image must have shape (H, W, 3) or (H, W, 4), channels last (RGB or RGBA)",
            value=f"shape {array.shape}",
        )
    if array.shape[:2] != (height, width):
        raise DatasetError(
            where,
            f"image is {array.shape[1]}x{array.shape[0]} pixels but the dataset's camera is {width}x{height}",
            value=f"shape {array.shape}",
        )
    if array.dtype in (np.uint8, np.uint16):
        return
    if not np.issubdtype(array.dtype, np.floating):
        raise DatasetError(where, "image values must be uint8, uint16 or float in [0, 1]", value=str(array.dtype))
    if not np.isfinite(array).all():
        raise DatasetError(where, "image has non-finite values", value=f"{int((~np.isfinite(array)).sum())} NaN/inf")
    low, high = float(array.min()), float(array.max())
    if low < 0.0 or high > 1.0:
        raise DatasetError(
            where,
            "float images must lie in [0, 1] (pass uint8 for 0-255 values)",
            value=f"min {low:.4g}, max {high:.4g}",
        )


def stored_bytes(capture: Capture, png_only: bool) -> tuple[bytes, str]:
    """The bytes to store a capture as, and their suffix: the file itself when every loader reads
    its format (no re-encoding), else a lossless PNG of its pixels."""
    if capture.source is not None:
        suffix = capture.source.suffix.lower()
        if suffix == ".png" or (not png_only and suffix in STORED_SUFFIXES):
            return capture.source.read_bytes(), suffix
    return encode_png(capture.array), ".png"
