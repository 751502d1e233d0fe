"""The camera schema: what a real camera can be, checked wherever cameras enter nerfaug (every
dataset reader, the capture service's intrinsics), each refusal one `DatasetError` line naming the
file, the field and the value.

The rules and why (a camera that breaks one is a typo, a unit mix-up or a broken export, never a
lens someone owns):
- Field of view, horizontal and vertical, between `MIN_FOV_DEGREES` and `MAX_FOV_DEGREES`: the
  longest production lenses (a 1700 mm on full frame) see about 1 degree, a rectilinear image
  cannot reach 180 degrees, and the widest pinhole view nerfaug makes (a fisheye undistorted to
  `nerfaug.data.lens.MAX_FISHEYE_HALF_ANGLE`, 80 degrees off axis) is 160 degrees across.
  Focal lengths are thus judged against the image size, whatever the units of the listing.
- Image sides of 1 to `MAX_IMAGE_SIDE` pixels: the largest sensors are about 20,000 pixels across.
- The principal point inside the image (the optical axis meets the sensor).
- Poses rigid (R^T R = I and det R = +1 within `ROTATION_TOLERANCE`) and finite in float32.
- A projection (IDR's `world_mat`) is judged scale-free: P and s P are one camera, so it is
  singular only when its condition number passes `MAX_CONDITION`; a similarity (IDR's
  `scale_mat`) is a rotation times one positive scale, whatever that scale is.
- Cameras lie at most `MAX_DISTANCE_IN_SCENE_RADII` radii from the scene's centre: from farther,
  the object spans less than a tenth of the narrowest field of view above. Where a format gives
  the scene's scale (IDR's unit sphere) that is the scene; elsewhere it is the one the cameras
  frame (`check_camera_spread`).
- A lens's undistorted image draws on at least `MIN_PHOTO_PIXELS_PER_PIXEL` of a photo pixel
  (area) at every pixel: a pinhole view of a fisheye's 80-degree edge draws on about 0.08 (the
  least a real lens needs), while k1 = -999 or p1 = 500 would leave each pixel a millionth of one.

Nothing here imports torch, nor numpy until a check needs it: the service's request schemas
(`nerfaug.capture.requests`), which every command's `--help` reads, use it.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from nerfaug.errors import DatasetError

# numpy is imported inside the checks that use it: every command's `--help` reads this module.
if TYPE_CHECKING:
    import numpy as np

MIN_FOV_DEGREES = 0.1
MAX_FOV_DEGREES = 170.0
MIN_FOV, MAX_FOV = math.radians(MIN_FOV_DEGREES), math.radians(MAX_FOV_DEGREES)
FOV_DIGITS = 1e-9  # relative: a bound's angle in radians, rounded where a listing writes it
MAX_IMAGE_SIDE = 65536
ROTATION_TOLERANCE = 1e-3  # Blender exports are float32: this accepts their round-off, not a scale or shear
MAX_CONDITION = 1e12
MAX_DISTANCE_IN_SCENE_RADII = 1e4
MIN_PHOTO_PIXELS_PER_PIXEL = 1.0 / 16.0

# The names a listing gives the quantities of a pinhole camera: one for all, or key -> name.
FieldNames = str | Callable[[str], str]


def _name(field: FieldNames, key: str) -> str:
    return field if isinstance(field, str) else field(key)


def check_field_of_view(angle, path: str | Path, field: str) -> float:
    """`angle` (radians, a listing's `camera_angle_x`) as a float, if a lens can see it; else a
    DatasetError naming `path` and `field`."""
    usable = isinstance(angle, numbers.Real) and not isinstance(angle, bool)
    try:
        # The bounds themselves are lenses' (README: 0.1 to 170 degrees), as written in radians
        # to a listing's last digits.
        usable = usable and MIN_FOV * (1 - FOV_DIGITS) <= float(angle) <= MAX_FOV * (1 + FOV_DIGITS)
    except OverflowError:  # an integer beyond float range
        usable = False
    if not usable:
        raise DatasetError(
            path,
            f"{field} must be a number in [{MIN_FOV:.4g}, {MAX_FOV:.4g}] radians "
            f"({MIN_FOV_DEGREES:g} to {MAX_FOV_DEGREES:g} degrees: the fields of view of real lenses)",
            field=field,
            value=angle,
        )
    return float(angle)


def check_image_size(width, height, path: str | Path, field: FieldNames) -> None:
    """Refuse an image size (pixels) outside 1..`MAX_IMAGE_SIDE` a side."""
    for key, value in (("width", width), ("height", height)):
        if not (isinstance(value, numbers.Real) and not isinstance(value, bool) and 1 <= value <= MAX_IMAGE_SIDE):
            raise DatasetError(
                path,
                f"image {key} must be 1 to {MAX_IMAGE_SIDE} pixels (the largest sensors are about 20,000 across)",
                field=_name(field, key),
                value=value,
            )


def check_pinhole(fx, fy, cx, cy, width, height, path: str | Path, field: FieldNames) -> None:
    """Refuse a pinhole camera (pixels) no lens makes: an image size out of bounds, a field of view
    outside `MIN_FOV_DEGREES`..`MAX_FOV_DEGREES` along either axis, or a principal point off the image.

    Args:
        field: the listing's name for every quantity, or a function from "fx", "fy", "cx", "cy",
            "width", "height" to the name of each (e.g. "fx" -> "frames[3].fl_x").
    """
    check_image_size(width, height, path, field)
    for key, focal, side, axis in (("fx", fx, width, "horizontal"), ("fy", fy, height, "vertical")):
        if not (math.isfinite(focal) and focal > 0):
            raise DatasetError(
                path, f"focal length {key} must be a number > 0 pixels", field=_name(field, key), value=focal
            )
        angle = 2.0 * math.atan(0.5 * side / focal)
        if not MIN_FOV <= angle <= MAX_FOV:
            raise DatasetError(
                path,
                f"focal length {key} = {focal:.4g} px for an image {side:g} px {'wide' if key == 'fx' else 'high'} "
                f"gives a {axis} field of view of {math.degrees(angle):.4g} degrees; a lens sees "
                f"{MIN_FOV_DEGREES:g} to {MAX_FOV_DEGREES:g}",
                field=_name(field, key),
                value=focal,
            )
    for key, centre, side in (("cx", cx, width), ("cy", cy, height)):
        if not (math.isfinite(centre) and 0 <= centre <= side):
            raise DatasetError(
                path,
                f"principal point {key} must lie inside the image (0 to {side:g} px)",
                field=_name(field, key),
                value=centre,
            )


def check_pose(matrix, path: str | Path, field: str) -> np.ndarray:
    """A rigid, finite 4x4 camera-to-world matrix as float64 (4, 4); else a DatasetError.

    Args:
        matrix: nested lists (as read from JSON) or an array; its entries must be numbers (no
            strings or bools) that stay finite in float32.
    """
    import numpy as np

    try:
        pose = np.asarray(matrix)
    except (TypeError, ValueError, OverflowError):  # ragged rows and the like
        pose = None
    if pose is None or pose.dtype.kind not in "iuf":  # strings, bools, None, huge ints (object)
        raise DatasetError(path, "transform_matrix must be 4 rows of 4 numbers", field=field, value=matrix)
    if pose.shape != (4, 4):
        raise DatasetError(path, f"transform_matrix must be 4x4, has shape {pose.shape}", field=field, value=matrix)
    pose = pose.astype(np.float64)
    with np.errstate(over="ignore"):
        finite = np.isfinite(pose.astype(np.float32)).all()
    if not finite:
        raise DatasetError(
            path, "transform_matrix has non-finite entries (or beyond float32 range)", field=field, value=pose.tolist()
        )
    rotation = pose[:3, :3]
    if not _is_rotation(rotation):
        raise DatasetError(
            path,
            "transform_matrix rotation is not rigid (R^T R != I or det(R) != 1)",
            field=field,
            value=np.round(rotation, 4).tolist(),
        )
    if np.abs(pose[3] - np.array([0, 0, 0, 1])).max() > 1e-6:
        raise DatasetError(path, "transform_matrix last row must be [0, 0, 0, 1]", field=field, value=pose[3].tolist())
    return pose


def _is_rotation(matrix: np.ndarray) -> bool:
    import numpy as np

    return bool(
        np.abs(matrix.T @ matrix - np.eye(3)).max() <= ROTATION_TOLERANCE
        and abs(np.linalg.det(matrix) - 1) <= ROTATION_TOLERANCE
    )


def check_projection(matrix: np.ndarray, path: str | Path, field: str) -> None:
    """Refuse a 3x3 (or wider) projection K R whose first three columns are singular, judged
    scale-free: its condition number (largest over smallest singular value) above `MAX_CONDITION`."""
    import numpy as np

    singular_values = np.linalg.svd(np.asarray(matrix, dtype=np.float64)[:3, :3], compute_uv=False)
    if not singular_values[-1] > singular_values[0] / MAX_CONDITION:
        raise DatasetError(
            path,
            f"projection matrix is singular (condition number above {MAX_CONDITION:g}, at any scale)",
            field=field,
            value=np.asarray(matrix).tolist(),
        )


def check_similarity(matrix: np.ndarray, path: str | Path, field: str) -> float:
    """A 4x4 similarity (a rotation times one positive scale, then a shift; last row [0, 0, 0, 1],
    all up to scale) checked; returns its scale. DatasetError naming `field` otherwise."""
    import numpy as np

    matrix = np.asarray(matrix, dtype=np.float64)
    linear = matrix[:3, :3]
    with np.errstate(all="ignore"):  # a determinant beyond float range is refused below, not warned about
        scale = float(np.cbrt(np.linalg.det(linear))) if np.isfinite(linear).all() else 0.0
        similar = scale > 0 and math.isfinite(scale) and _is_rotation(linear / scale)
    if not similar:
        raise DatasetError(
            path,
            "must map the unit sphere into the world by a rotation, one positive scale and a shift "
            "(its 3x3 part is singular, mirrored, sheared or scaled unevenly)",
            field=field,
            value=np.asarray(matrix).tolist(),
        )
    bottom = matrix[3] / matrix[3, 3] if matrix[3, 3] != 0 else matrix[3]
    if np.abs(bottom - np.array([0, 0, 0, 1])).max() > 1e-9 * max(1.0, float(np.abs(matrix[3]).max())):
        raise DatasetError(path, "last row must be [0, 0, 0, 1]", field=field, value=matrix[3].tolist())
    return scale


def check_scene_distance(distance: float, path: str | Path, field: str) -> None:
    """Refuse a camera `distance` scene radii from the scene's centre beyond `MAX_DISTANCE_IN_SCENE_RADII`."""
    if not distance <= MAX_DISTANCE_IN_SCENE_RADII:
        raise DatasetError(
            path,
            f"puts the camera {distance:.4g} scene radii from the scene's centre; from beyond "
            f"{MAX_DISTANCE_IN_SCENE_RADII:g} the object spans less than a tenth of the narrowest lens's view",
            field=field,
            value=distance,
        )


def check_camera_spread(positions, path: str | Path, field_of) -> None:
    """Where a format gives no scene scale, the scene is the one the cameras frame: its centre their
    median position, its radius their median distance from it (a hemisphere's cameras lie about
    one radius out). Refuse a camera beyond `MAX_DISTANCE_IN_SCENE_RADII` such radii, naming the
    field `field_of(i)` of the i-th camera (a unit mix-up or a broken export, never a capture).

    Args:
        positions: (n, 3) camera centres, world space; fewer than 3 are not judged.
    """
    import numpy as np

    points = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(points) < 3:
        return
    distances = np.linalg.norm(points - np.median(points, axis=0), axis=1)
    radius, farthest = float(np.median(distances)), int(np.argmax(distances))
    if radius > 0 and not distances[farthest] <= MAX_DISTANCE_IN_SCENE_RADII * radius:
        raise DatasetError(
            path,
            f"puts the camera {distances[farthest] / radius:.4g} scene radii from the centre the cameras frame "
            f"(its radius: the cameras' median distance, {radius:.4g}); from beyond {MAX_DISTANCE_IN_SCENE_RADII:g} "
            "the object spans less than a tenth of the narrowest lens's view",
            field=field_of(farthest),
            value=points[farthest].tolist(),
        )


def check_photo_pixels(drawn: float) -> None:
    """Refuse an undistortion whose output draws on less than `MIN_PHOTO_PIXELS_PER_PIXEL` of a photo
    pixel (area) somewhere: `drawn` is the least over the image.

    Raises:
        ValueError: saying so (the reader names the file and field).
    """
    if not drawn >= MIN_PHOTO_PIXELS_PER_PIXEL:
        raise ValueError(
            f"no lens distorts so: its pinhole image would draw on {max(drawn, 0.0):.3g} photo pixels per pixel at "
            f"best somewhere{' (the lens folds over)' if drawn <= 0 else ''} (a real lens: at least "
            f"{MIN_PHOTO_PIXELS_PER_PIXEL:g}); check the calibration's units and signs"
        )


__all__ = [
    "MAX_FOV_DEGREES",
    "MAX_IMAGE_SIDE",
    "MIN_FOV_DEGREES",
    "MIN_PHOTO_PIXELS_PER_PIXEL",
    "check_field_of_view",
    "check_image_size",
    "check_pinhole",
    "check_photo_pixels",
    "check_pose",
    "check_projection",
    "check_scene_distance",
    "check_similarity",
]
