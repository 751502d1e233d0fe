"""Lens distortion of captured images: what a listing's `camera_model` and k1..k4, p1, p2 say, and
the images resampled to the pinhole cameras the NeRF casts its rays with.

nerfstudio listings from phones and COLMAP (`ns-process-data`) carry OpenCV's distortion: "OPENCV"
(radial k1, k2, k3 and tangential p1, p2) or "OPENCV_FISHEYE" (equidistant, k1..k4). Every pixel
of the undistorted image is a pinhole ray; its place in the photo is the model's closed-form
forward map, so no inverse is solved. Hand-written because OpenCV's wheels need numpy 2 while
this project pins numpy 1.26; the resampling itself is scipy's `map_coordinates`.

Pixel convention: as `nerfaug.cameras`, pixel (i, j)'s centre is at (i + 0.5, j + 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy import ndimage

from nerfaug.camera_schema import MIN_PHOTO_PIXELS_PER_PIXEL, check_photo_pixels
from nerfaug.data.errors import DatasetError
from nerfaug.data.frames import check_number

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")
RADIAL_MODELS = ("OPENCV", "SIMPLE_RADIAL", "RADIAL")  # COLMAP's names nerfstudio writes as OpenCV's terms
FISHEYE_MODEL = "OPENCV_FISHEYE"
DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")
# The largest field of view (from the axis) a fisheye is undistorted to: a pinhole image cannot
# hold 90 degrees, and near it a few photo pixels would stretch over most of the image.
MAX_FISHEYE_HALF_ANGLE = math.radians(80)


@dataclass(frozen=True)
class Lens:
    """A distortion model: "opencv" (k1, k2, k3, p1, p2) or "fisheye" (k1, k2, k3, k4)."""

    model: str
    k: tuple[float, ...]
    p: tuple[float, float] = (0.0, 0.0)

    def describe(self) -> str:
        terms = ("k1", "k2", "k3", "k4")[: len(self.k)]
        named = [f"{n}={v:g}" for n, v in zip(terms, self.k)] + [f"p{i + 1}={v:g}" for i, v in enumerate(self.p) if v]
        return f"{self.model}: {', '.join(named)}"

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the pinhole ray through normalised image point (x, y) lands in the photo (normalised).

        x, y: arrays of one shape (x = X/Z, y = Y/Z of the ray, in OpenCV's y-down image frame).
        """
        r2 = x * x + y * y
        if self.model == "fisheye":
            r = np.sqrt(r2)
            theta = np.arctan(r)
            t2 = theta * theta
            theta_d = theta * (1 + t2 * (self.k[0] + t2 * (self.k[1] + t2 * (self.k[2] + t2 * self.k[3]))))
            scale = np.where(r > 1e-12, theta_d / np.maximum(r, 1e-12), 1.0)
            return x * scale, y * scale
        k1, k2, k3 = self.k
        p1, p2 = self.p
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd


def lens_of(get, field, json_path: Path) -> Lens | None:
    """The frame's lens from its listing's keys, or None for a pinhole camera.

    Args:
        get: key -> the frame's value, else the listing's (None when neither has it).
        field: key -> the name an error gives it (e.g. "frames[3].k1" or "k1").

    Raises:
        DatasetError: an unknown camera model, a coefficient that is not a finite number, or one
            the model does not have (k4 under OPENCV: nerfstudio and OpenCV read it differently).
    """
    model = get("camera_model")
    if model is not None and not isinstance(model, str):
        raise DatasetError(json_path, "camera_model must be a string", field=field("camera_model"), value=model)
    model = (model or "OPENCV").upper()
    if model not in (*PINHOLE_MODELS, *RADIAL_MODELS, FISHEYE_MODEL):
        raise DatasetError(
            json_path,
            f"camera model not supported (nerfaug reads {', '.join((*PINHOLE_MODELS, *RADIAL_MODELS, FISHEYE_MODEL))})",
            field=field("camera_model"),
            value=get("camera_model"),
        )
    values = {}
    for key in DISTORTION_KEYS:
        value = get(key)
        values[key] = 0.0 if value is None else check_number(value, json_path, field(key), -1e3, 1e3)
    if model in PINHOLE_MODELS:
        return None
    if model == FISHEYE_MODEL:
        for key in ("p1", "p2"):
            if values[key] != 0:
                raise DatasetError(
                    json_path, "OPENCV_FISHEYE has no tangential terms", field=field(key), value=get(key)
                )
        return Lens("fisheye", tuple(values[k] for k in ("k1", "k2", "k3", "k4")))
    if values["k4"] != 0:
        raise DatasetError(
            json_path,
            "k4 under the OPENCV model is read differently by nerfstudio (a radial term) and OpenCV "
            "(a rational one); give the photos undistorted, or a calibration without k4 (k1, k2, k3, p1, p2)",
            field=field("k4"),
            value=get("k4"),
        )
    if all(values[k] == 0 for k in ("k1", "k2", "k3", "p1", "p2")):
        return None
    return Lens("opencv", (values["k1"], values["k2"], values["k3"]), (values["p1"], values["p2"]))


def _photo_pixels(lens: Lens, intrinsics, new, u: np.ndarray, v: np.ndarray):
    """Photo pixel coordinates (centres at i + 0.5) of the new pinhole camera's pixel positions (u, v)."""
    fx, fy, cx, cy = intrinsics
    nfx, nfy, ncx, ncy = new
    xd, yd = lens.distort((u - ncx) / nfx, (v - ncy) / nfy)
    return xd * fx + cx, yd * fy + cy


@lru_cache(maxsize=64)
def undistorted_camera(lens: Lens, intrinsics: tuple[float, float, float, float], width: int, height: int):
    """The pinhole camera (fx, fy, cx, cy) a photo of this lens is undistorted to.

    It keeps the photo's size and principal point; its focal lengths are the photo's times the
    smallest s (at least 1/8) for which every pixel lies inside the photo and the distortion does
    not fold over inside the frame (as OpenCV's "alpha = 0": no pixel made up), and every pixel
    draws on at least `MIN_PHOTO_PIXELS_PER_PIXEL` of a photo pixel (near a fold the lens squeezes
    many rays into one photo pixel: the frame narrows until it leaves that ring). s is the same at
    any image scale (the border's normalised coordinates do not change when the intrinsics and the
    size scale together), so a shrunk photo's camera is the full photo's, shrunk.

    Raises:
        ValueError: no focal length keeps the frame inside the photo, or none draws on enough of
            it (`nerfaug.camera_schema.check_photo_pixels`: a calibration no lens has).
    """
    fx, fy, cx, cy = intrinsics
    # The border of the new image: where a pixel is likeliest to leave the photo.
    edge = np.linspace(0.0, 1.0, 257)
    border_u = np.concatenate([edge * width, edge * width, np.zeros_like(edge), np.full_like(edge, width)])
    border_v = np.concatenate([np.zeros_like(edge), np.full_like(edge, height), edge * height, edge * height])
    corner = math.hypot(max(cx, width - cx) / fx, max(cy, height - cy) / fy)  # normalised, at s = 1

    def fits(s: float) -> bool:
        if _folds(lens, corner / s):
            return False
        pu, pv = _photo_pixels(lens, intrinsics, (fx * s, fy * s, cx, cy), border_u, border_v)
        return bool(
            np.all(
                (pu >= -1e-6 * width)
                & (pu <= width * (1 + 1e-6))
                & (pv >= -1e-6 * height)
                & (pv <= height * (1 + 1e-6))
            )
        )

    low, high = 1.0 / 8, 1.0  # fits(high) holds and fits(low) does not, after these two loops
    while not fits(high):
        low, high = high, high * 2
        if high > 1e4:
            raise ValueError("no pinhole camera of this size sees only what the photo holds")
    if fits(low):
        high = low
    else:
        for _ in range(50):  # bisection to ~1e-15 relative
            middle = 0.5 * (low + high)
            low, high = (low, middle) if fits(middle) else (middle, high)
    scale = _drawing_enough(lens, intrinsics, width, height, high)
    return fx * scale, fy * scale, cx, cy


def _drawing_enough(lens: Lens, intrinsics, width: int, height: int, scale: float) -> float:
    """The smallest s >= `scale` (to 1 %) at which every pixel of the pinhole image draws on at
    least `MIN_PHOTO_PIXELS_PER_PIXEL` of a photo pixel; ValueError when none does.

    A pixel at the image's centre draws on 1/s^2 of one (the lens is a pinhole there), so s stays
    below 1/sqrt(MIN_PHOTO_PIXELS_PER_PIXEL); narrowing the frame only helps near its border."""
    fx, fy, cx, cy = intrinsics
    grid = np.linspace(0.0, 1.0, 65)
    x, y = np.meshgrid((grid * width - cx) / fx, (grid * height - cy) / fy)
    largest = 1.0 / math.sqrt(MIN_PHOTO_PIXELS_PER_PIXEL)

    def drawn(s: float) -> float:
        return float(_area_ratio(lens, x / s, y / s).min()) / s**2

    best = least = drawn(scale)
    while least < MIN_PHOTO_PIXELS_PER_PIXEL and scale * 1.01 <= largest:
        scale *= 1.01
        least = drawn(scale)
        best = max(best, least)
    check_photo_pixels(best)
    return scale


def _area_ratio(lens: Lens, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """det of the distortion's Jacobian at normalised points (x, y): the photo's area (normalised)
    per unit area of the pinhole image; <= 0 where the lens folds over."""
    step = 1e-6
    xr, yr = lens.distort(x + step, y)
    xl, yl = lens.distort(x - step, y)
    xu, yu = lens.distort(x, y + step)
    xd, yd = lens.distort(x, y - step)
    return ((xr - xl) * (yu - yd) - (xu - xd) * (yr - yl)) / (4 * step * step)


@lru_cache(maxsize=2)  # frames mostly share one camera; a map is two float32 a pixel
def undistortion(lens: Lens, intrinsics: tuple[float, float, float, float], width: int, height: int):
    """The pinhole camera an undistorted photo is taken with (`undistorted_camera`), and where each
    of its pixels lies in the photo.

    Returns:
        new: (fx, fy, cx, cy) of the pinhole camera.
        rows, cols: float32 arrays (height, width): each pixel's position in the photo's array
            (row, column), for `scipy.ndimage.map_coordinates`.

    Raises:
        ValueError: no focal length keeps the frame inside the photo.
    """
    new = undistorted_camera(lens, intrinsics, width, height)
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pu, pv = _photo_pixels(lens, intrinsics, new, u, v)
    return new, (pv - 0.5).astype(np.float32), (pu - 0.5).astype(np.float32)


def _folds(lens: Lens, largest_radius: float) -> bool:
    """Whether the distorted radius stops growing before `largest_radius` (normalised), along either
    axis: past that point two rays land on one photo pixel. A fisheye folds, for this purpose,
    beyond MAX_FISHEYE_HALF_ANGLE."""
    if lens.model == "fisheye" and math.atan(largest_radius) > MAX_FISHEYE_HALF_ANGLE:
        return True
    r = np.linspace(0.0, largest_radius, 2049)
    zero = np.zeros_like(r)
    along_x = lens.distort(r, zero)[0]
    along_y = lens.distort(zero, r)[1]
    return bool(np.any(np.diff(along_x) <= 0) or np.any(np.diff(along_y) <= 0))


def undistort(array: np.ndarray, lens: Lens, intrinsics, json_path: Path, field: str) -> tuple[np.ndarray, tuple]:
    """The photo `array` (h, w, c) resampled (bilinear) to its pinhole camera; returns it (float32, in
    the photo's value range) and that camera's (fx, fy, cx, cy).

    Raises:
        DatasetError: the lens cannot be undistorted (naming the listing and the frame's field).
    """
    height, width = array.shape[:2]
    try:
        new, rows, cols = undistortion(lens, tuple(float(v) for v in intrinsics), width, height)
    except ValueError as error:
        raise DatasetError(json_path, str(error), field=field, value=lens.describe()) from None
    source = array.astype(np.float32)
    channels = [
        ndimage.map_coordinates(source[..., c], [rows, cols], order=1, mode="nearest") for c in range(array.shape[-1])
    ]
    return np.stack(channels, axis=-1), new


__all__ = ["DISTORTION_KEYS", "Lens", "lens_of", "undistort", "undistorted_camera", "undistortion"]
