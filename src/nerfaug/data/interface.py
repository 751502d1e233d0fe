"""`Format`: every operation on a dataset folder in one on-disk format (detect, read, write views,
append frames, copy frames in from another dataset, "fits these cameras"), and `DatasetSplit`, one
split of a folder in a known format.

A split is listed by one file, its listing (e.g. `transforms_train.json`). In memory a listing is
its header (every key but `frames`) and its frames: dicts with `file_path` (the image, relative to
the dataset folder) and `transform_matrix` (4x4 camera-to-world, OpenGL), plus the format's own
per-frame keys. The base class reads and writes listings as JSON objects with a `frames` list; a
format stored otherwise overrides `read_listing` and `write_listing`.

The registry of formats is `nerfaug.data.formats`; this module imports none of them.
"""

from __future__ import annotations

import re
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import torch

from nerfaug import runfiles
from nerfaug.cameras import Cameras
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import resolve_image, stored_image, write_image_and_mask
from nerfaug.data.views import Views
from nerfaug.jsonio import atomic_write_json, read_json


@dataclass(frozen=True)
class NewFrame:
    """An image to append to a split, as the bytes of its file.

    Attributes:
        stem: the image's file name without extension (unique in the split).
        data: the file's bytes (PNG, or JPEG where the format takes it).
        suffix: the file's extension, e.g. ".png".
        pose: 4x4 camera-to-world as nested lists (OpenGL convention).
    """

    stem: str
    data: bytes
    suffix: str
    pose: list


class Format(ABC):
    """One on-disk dataset format; subclasses implement the abstract methods.

    Attributes:
        name: the short name users give ("blender", "nerfstudio").
        fits_rule: which cameras the format can describe, for messages.
        camera_keys: header and per-frame keys describing the camera, kept when a listing is
            copied into the same format.
        png_only: whether the format's readers take PNG images only (others become PNG).
        has_splits: whether a folder holds several splits (False: one listing every split reads).
        z_up: whether the format's world is z-up: True by its convention (NeRF-synthetic), False
            where it records no up direction (LLFF, IDR/DTU: photogrammetry frames), None where
            listings of both kinds are common (nerfstudio). A session's pole, when none is given,
            follows it (`nerfaug.data.world_frame.pole_is_estimated`).
    """

    name: ClassVar[str]
    fits_rule: ClassVar[str] = "any pinhole cameras"
    camera_keys: ClassVar[tuple[str, ...]] = ()
    png_only: ClassVar[bool] = False
    has_splits: ClassVar[bool] = True
    z_up: ClassVar[bool | None] = True

    def __repr__(self) -> str:
        return f"<{self.name} format>"

    # -- where things are --

    @abstractmethod
    def listing(self, root: Path, split: str) -> Path:
        """The file listing `split` under `root`; its presence marks the folder as this format."""

    @abstractmethod
    def image_folder(self, split: str) -> str:
        """The folder (relative to the dataset folder) new images of `split` are written to."""

    @abstractmethod
    def file_path(self, folder: str, stem: str, suffix: str) -> str:
        """The `file_path` a frame lists for the image `folder/stem+suffix`."""

    def detect(self, root: str | Path, split: str) -> bool:
        """Whether `root` holds `split` in this format."""
        return self.listing(Path(root), split).exists()

    # -- reading --

    @abstractmethod
    def load(
        self, root: str | Path, split: str = "train", background=(1.0, 1.0, 1.0), downscale: int = 1, lazy: bool = False
    ) -> Views:
        """Read `split` as `Views`; DatasetError naming file, field and value for any bad input."""

    def read_listing(self, root: Path, split: str) -> tuple[dict, list]:
        """The listing's header and its frames (DatasetError unless `frames` is a list)."""
        path = self.listing(root, split)
        meta = read_json(path)
        if not isinstance(meta, dict):
            raise DatasetError(path, "expected a JSON object at the top level", value=type(meta).__name__)
        frames = meta.get("frames")
        if not isinstance(frames, list):
            raise DatasetError(path, "frames must be a list", field="frames", value=frames)
        return {k: v for k, v in meta.items() if k != "frames"}, frames

    # -- cameras --

    @abstractmethod
    def fits(self, cameras: Cameras) -> bool:
        """Whether this format can describe `cameras` exactly (see `fits_rule`)."""

    @abstractmethod
    def describe(self, cameras: Cameras) -> tuple[dict, list[dict]]:
        """The header keys and each frame's own keys that describe `cameras` (n of them; they fit)."""

    def frame_keys(self, camera: Cameras) -> dict:
        """The keys a frame appended to an existing listing carries for its one `camera`."""
        return {}

    def appended_keys(self, header: dict, camera: Cameras) -> dict:
        """The keys a frame appended under the listing's `header` carries for its one `camera`."""
        return self.frame_keys(camera)

    def lens_distortion(self, header: dict, frames: list) -> bool:
        """Whether any frame of the listing has a lens distortion (its images are distorted photos)."""
        return False

    def has_masks(self, root: Path) -> bool:
        """Whether the folder keeps masks apart from its images (its reader makes them the alpha)."""
        return False

    # -- writing --

    @abstractmethod
    def write(self, root: str | Path, split: str, views: Views, background=(1.0, 1.0, 1.0)) -> Path:
        """Write `views` (decoded images) as a new `split`; returns the listing's path."""

    def write_listing(self, root: Path, split: str, header: dict, frames: list) -> Path:
        """Write a listing (atomically); returns its path."""
        path = self.listing(root, split)
        atomic_write_json(path, {**header, "frames": frames})
        return path

    def append(self, root: Path, split: str, new: Sequence[NewFrame], camera: Cameras) -> list[dict]:
        """Write the images of `new` and list them after the split's frames (the listing last,
        atomically), starting the split when it does not exist yet. `camera`: one camera with the
        intrinsics of every new frame.

        Returns the new frames as listed.
        """
        if self.detect(root, split):
            header, frames = self.read_listing(root, split)
        elif self.fits(camera):
            header, frames = self.describe(camera)[0], []
        else:
            raise ValueError(f"this camera does not fit the {self.name} format ({self.fits_rule})")
        folder = self.image_folder(split)
        added = []
        for frame in new:
            # Into the dataset folder only (a session's dataset copy may hold a link out of it).
            runfiles.write_bytes(root, Path(folder) / f"{frame.stem}{frame.suffix}", frame.data)
            added.append(
                {
                    "file_path": self.file_path(folder, frame.stem, frame.suffix),
                    "transform_matrix": frame.pose,
                    **self.appended_keys(header, camera),
                }
            )
        self.write_listing(root, split, header, frames + added)
        return added

    def copy(self, source: DatasetSplit, out: Path, split: str) -> Path:
        """Copy the frames of `source` (any format) into `out` as `split` of this format.

        Every image is found before anything is written; images are copied byte for byte,
        except those this format's readers do not take (`png_only`), which become lossless PNGs,
        distorted photos going to another format, which are written undistorted (resampled), and
        photos with masks kept apart (`has_masks`), which are written as the source's reader gives
        them: the masks as their alpha (RGBA images, or this format's own masks).
        From the same format the listing's camera keys are kept as they are; from another the
        cameras are described anew (ValueError unless they fit).

        Returns the new listing's path.
        """
        header, frames = source.read()
        distorted = type(source.format) is not type(self) and source.format.lens_distortion(header, frames)
        if distorted or source.format.has_masks(Path(source.root)):
            # Another format would describe distorted photos as pinhole images, and a byte copy of
            # the photos would leave their masks behind: write the views the source's reader gives.
            views = source.load()
            if not self.fits(views.cameras):
                raise ValueError(f"these cameras do not fit the {self.name} format ({self.fits_rule})")
            return self.write(out, split, views)
        files = source.frame_files(frames)
        if type(source.format) is type(self):
            header = {k: header[k] for k in self.camera_keys if k in header}
            own = [{k: f[k] for k in self.camera_keys if k in f} for f in frames]
        else:
            cameras = source.load(lazy=True).cameras
            if not self.fits(cameras):
                raise ValueError(f"these cameras do not fit the {self.name} format ({self.fits_rule})")
            header, own = self.describe(cameras)
        folder = self.image_folder(split)
        taken: set[str] = set()
        copied = []
        for i, (frame, path, keys) in enumerate(zip(frames, files, own)):
            stem = unique_stem(Path(str(frame["file_path"])).stem, taken)
            data, suffix = stored_image(path, self.png_only, f"frames[{i}].file_path")
            runfiles.write_bytes(out, Path(folder) / f"{stem}{suffix}", data)  # never through a link out of `out`
            copied.append(
                {
                    "file_path": self.file_path(folder, stem, suffix),
                    "transform_matrix": frame["transform_matrix"],
                    **keys,
                }
            )
        return self.write_listing(Path(out), split, header, copied)


class CapturedSetFormat(Format):
    """A format of captured sets: one listing for every view (no splits), the images in one
    folder and their masks (the alpha) in another, paired by name or order. Subclasses give the
    folder names, read and write the listing, and describe the cameras (`describe` per frame)."""

    has_splits = False
    listing_name: ClassVar[str]
    images: ClassVar[str]
    masks: ClassVar[str]

    def listing(self, root: Path, split: str) -> Path:
        return Path(root) / self.listing_name

    def image_folder(self, split: str) -> str:
        return self.images

    def file_path(self, folder: str, stem: str, suffix: str) -> str:
        return f"{folder}/{stem}{suffix}"

    def frame_keys(self, camera: Cameras) -> dict:
        return self.describe(camera)[1][0]

    def stored_names(self, views: Views) -> list[tuple[str, str]]:
        """Each view's image stem and mask file name as `write` stores them."""
        stems = [Path(name).stem or f"frame_{i:05d}" for i, name in enumerate(views.names)]
        return [(stem, f"{stem}.png") for stem in stems]

    def write(self, root, split, views, background=(1.0, 1.0, 1.0)) -> Path:
        """Images as PNG in the image folder (their alpha, when known, as mask PNGs) and the listing."""
        root = Path(root)
        views = views.materialised()
        if not self.fits(views.cameras):
            raise ValueError(f"these cameras do not fit the {self.name} format ({self.fits_rule})")
        background = torch.as_tensor(background, dtype=torch.float32)
        _, keys = self.describe(views.cameras)
        frames = []
        for i, (stem, mask) in enumerate(self.stored_names(views)):
            alpha = None if views.alphas is None else views.alphas[i]
            image_path = root / self.images / f"{stem}.png"
            write_image_and_mask(image_path, root / self.masks / mask, views.images[i], alpha, background)
            pose = views.cameras.camera_to_world[i].tolist()
            frames.append({"file_path": f"{self.images}/{stem}.png", "transform_matrix": pose} | keys[i])
        return self.write_listing(root, split, {}, frames)


@dataclass(frozen=True)
class DatasetSplit:
    """One split of a dataset folder in a known format: the narrow handle code that reads or
    grows a dataset on disk takes."""

    root: Path
    format: Format
    split: str = "train"
    only: tuple[int, ...] | None = None
    """the frames this handle holds (indices into the listing, in this order); None: every one."""

    @property
    def listing(self) -> Path:
        return self.format.listing(Path(self.root), self.split)

    def read(self) -> tuple[dict, list]:
        """The listing's header and frames (those of `only`)."""
        header, frames = self.format.read_listing(Path(self.root), self.split)
        return header, frames if self.only is None else [frames[i] for i in self.only]

    def frames(self) -> list:
        return self.read()[1]

    def frame_files(self, frames: list | None = None, start: int = 0) -> list[Path]:
        """The image file of each frame (default: every frame), resolved as the reader resolves
        it: inside the dataset folder. `start` numbers the frames in error messages."""
        frames = self.frames() if frames is None else frames
        return [
            resolve_image(Path(self.root), str(frame["file_path"]), self.listing, f"frames[{start + i}].file_path")
            for i, frame in enumerate(frames)
        ]

    def load(self, **kwargs) -> Views:
        """The split (the frames of `only`) as `Views` (kwargs: background, downscale, lazy)."""
        views = self.format.load(Path(self.root), self.split, **kwargs)
        return views if self.only is None else views.subset(list(self.only))

    def append(self, new: Sequence[NewFrame], camera: Cameras) -> list[dict]:
        return self.format.append(Path(self.root), self.split, new, camera)


def unique_stem(stem: str, taken: set[str]) -> str:
    """`stem` made a safe file name and distinct from `taken` (which it is added to)."""
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip(".") or "frame"
    candidate, k = stem, 1
    while candidate in taken:
        candidate, k = f"{stem}_{k}", k + 1
    taken.add(candidate)
    return candidate
