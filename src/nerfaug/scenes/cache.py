"""Downscaled datasets cached on disk: every run of a sweep reads a split's images decoded and
shrunk once, instead of decoding (and area-averaging) every PNG again.

A cache entry holds one split's images (and alphas) exactly as `load_dataset(folder, split,
downscale=d)` returns them, float32, under a name made of a digest of the dataset folder's files
(their relative paths and bytes), the split and the factor: editing, adding or removing any file
of the dataset gives another name, so a stale entry is never read. Cameras and names still come
from the transforms file (a lazy load, which decodes one image).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import torch

from nerfaug import runfiles
from nerfaug.data import Views, load_dataset

CACHE_FORMAT = 1
"""Bumped whenever what an entry holds, or how the loader makes it, changes."""


def folder_digest(folder: str | Path) -> str:
    """SHA-256 (hex) over the relative path and bytes of every regular file under `folder`, in
    sorted order; files and folders whose names start with "." (e.g. a renderer's partial output)
    are skipped."""
    folder = Path(folder)
    digest = hashlib.sha256()
    for path in sorted(folder.rglob("*")):
        relative = path.relative_to(folder)
        if any(part.startswith(".") for part in relative.parts) or not path.is_file():
            continue
        digest.update(relative.as_posix().encode() + b"\0")
        digest.update(path.stat().st_size.to_bytes(8, "little"))
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def cache_path(cache_dir: str | Path, digest: str, split: str, downscale: int) -> Path:
    """Where the entry of (dataset digest, split, downscale factor) lives."""
    return Path(cache_dir) / f"{digest[:32]}-{split}-x{downscale}-v{CACHE_FORMAT}.pt"


def load_split_cached(
    folder: str | Path, split: str, downscale: int, cache_dir: str | Path, digest: str | None = None
) -> Views:
    """`load_dataset(folder, split, downscale=downscale)`, with the images read from, or written
    to, `cache_dir`.

    Args:
        folder: a Blender or nerfstudio dataset folder.
        split: "train", "test", "initial", ...
        downscale: integer factor the images are area-averaged by.
        cache_dir: the cache's folder (created when needed); entries are written atomically, so
            runs in several processes may share it.
        digest: `folder_digest(folder)`, when the caller already has it.

    Returns:
        Views with every image in memory, equal (bit for bit) to an uncached load.

    Raises:
        PathRefused: the entry leads out of `cache_dir` (a link planted in its place): neither
            read nor replaced.
    """
    digest = digest or folder_digest(folder)
    path = runfiles.path_in(cache_dir, cache_path(cache_dir, digest, split, downscale).name)
    if path.exists():
        lazy = load_dataset(folder, split, downscale=downscale, lazy=True)
        try:
            entry = torch.load(path, weights_only=True)
            images, alphas = entry["images"], entry["alphas"]
        except Exception:  # noqa: BLE001 -- an unreadable entry (a damaged disk, a foreign file) is rebuilt
            images = None
        expected = (len(lazy), lazy.cameras.height, lazy.cameras.width, 3)
        if images is not None and tuple(images.shape) == expected:
            return Views(lazy.cameras, images, list(lazy.names), alphas)
    views = load_dataset(folder, split, downscale=downscale)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(handle)
    try:
        torch.save({"images": views.images, "alphas": views.alphas}, temporary)
        os.replace(temporary, path)
    finally:
        Path(temporary).unlink(missing_ok=True)
    return views
