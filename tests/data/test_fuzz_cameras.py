"""Property-based test of the camera schema through every format: malformed folders of LLFF, IDR,
nerfstudio (each lens model) and Blender datasets, prepared as `nerfaug scene prepare` prepares
them (`prepare_dataset`), give a one-line `DatasetError` naming a file inside the folder, or a
prepared dataset whose cameras a lens can make and which loads again; never another exception,
never a file written or changed outside the output folder.

Each example starts from a valid folder (three 16x12 photos, masks where the format has them) in
a fresh temporary folder and applies a few mutations aimed at the cameras: any number (NaN, inf,
1e308, 1e-30, -999, ...) in any entry of a pose, intrinsics or distortion coefficient, projection
and scale matrices scaled, zeroed, sheared or mirrored, odd array shapes and types, masks missing,
of another size, unreadable or linked outside. Derandomized, so CI runs the same cases every time;
the test counts the outcomes and requires both refusals and accepted datasets for every format,
so that neither a reader refusing everything nor mutations made harmless pass unnoticed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from collections import Counter
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerfaug import camera_schema
from nerfaug.data import DatasetError, load_dataset
from nerfaug.data.prepare import prepare_dataset
from nerfaug.hemisphere import half_hemisphere_poses

H, W, N, WIDTH = 12, 16, 3, 8
EXAMPLES = 120  # per format: the four take about 40 s on one loaded core
FUZZ = settings(
    max_examples=EXAMPLES, derandomize=True, database=None, deadline=None, suppress_health_check=list(HealthCheck)
)
OUTCOMES: Counter = Counter()

numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-3, 3),
    st.sampled_from([0.0, -1.0, 1e-30, 1e-6, 1e6, 1e30, 1e308, -999.0, 500.0, 2.0, 0.5]),
)
small = st.integers(0, N - 1)
mask_changes = st.sampled_from(["none", "missing", "other_size", "text", "link_outside", "grey16"])
image_changes = st.sampled_from(["link_outside", "text", "other_size"])


def poses() -> np.ndarray:
    return half_hemisphere_poses(N, radius=3.0).double().numpy()


def png(array: np.ndarray) -> bytes:
    return iio.imwrite("<bytes>", array, extension=".png")


PHOTO = png(np.random.default_rng(0).integers(0, 256, (H, W, 3), dtype=np.uint8))
MASK = png(np.tile((np.arange(H) < H // 2)[:, None] * np.uint8(255), (1, W)))


def write_photos(root: Path, images: str, masks: str | None, mask_names: list[str]) -> None:
    (root / images).mkdir(parents=True)
    for i in range(N):
        (root / images / f"{i:06d}.png").write_bytes(PHOTO)
    if masks is not None:
        (root / masks).mkdir()
        for name in mask_names:
            (root / masks / name).write_bytes(MASK)


def change_file(path: Path, change: str, outside: Path) -> None:
    """Make the image or mask `path` something else: a link out of the dataset, text, another size."""
    if change == "none":
        return
    path.unlink(missing_ok=True)
    if change == "link_outside":
        os.symlink(outside, path)
    elif change == "text":
        path.write_text("not an image")
    elif change == "other_size":
        path.write_bytes(png(np.zeros((H + 2, W, 3), np.uint8)))
    elif change == "grey16":
        path.write_bytes(png(np.full((H, W), 40000, np.uint16)))


# --- the formats: a valid folder, and what mutates it --------------------------------------------


def llff(root: Path, outside: Path, mutations) -> None:
    rows = []
    for pose in poses():
        matrix = np.stack([-pose[:3, 1], pose[:3, 0], pose[:3, 2], pose[:3, 3], [H, W, 14.0]], axis=1)
        rows.append(np.concatenate([matrix.reshape(-1), [1.0, 5.0]]))
    array = np.stack(rows)
    write_photos(root, "images", "masks", [f"{i:06d}_mask.png" for i in range(N)])
    shape = None
    for kind, *args in mutations:
        if kind == "entry":
            row, column, value = args
            array[row, column] = value
        elif kind == "shape":
            shape = args[0]
        elif kind == "mask":
            change_file(root / "masks" / f"{args[0]:06d}_mask.png", args[1], outside)
        elif kind == "image":
            change_file(root / "images" / f"{args[0]:06d}.png", args[1], outside)
    if shape is not None:
        array = {"column": array[:, :16], "row": array[:2], "flat": array.reshape(-1), "text": array.astype(str)}[shape]
    np.save(root / "poses_bounds.npy", array)


llff_mutations = st.one_of(
    # the camera's columns (height, width, focal; the centre; the depth bounds) more often than the rotation's
    st.tuples(st.just("entry"), small, st.sampled_from([4, 9, 14, 3, 8, 13, 15, 16]) | st.integers(0, 16), numbers),
    st.tuples(st.just("shape"), st.sampled_from(["column", "row", "flat", "text"])),
    st.tuples(st.just("mask"), small, mask_changes),
    st.tuples(st.just("image"), small, image_changes),
)


def idr(root: Path, outside: Path, mutations) -> None:
    intrinsics = np.array([[14.0, 0.0, 8.0], [0.0, 14.5, 6.0], [0.0, 0.0, 1.0]])
    scale = np.diag([2.0, 2.0, 2.0, 1.0])
    scale[:3, 3] = (0.5, -1.0, 0.25)
    arrays = {}
    for i, pose in enumerate(poses()):
        world_pose = scale @ pose
        w2c = (world_pose[:3, :3] / 2.0 @ np.diag([1.0, -1.0, -1.0])).T
        world = np.eye(4)
        world[:3, :4] = intrinsics @ np.concatenate([w2c, (-w2c @ world_pose[:3, 3])[:, None]], 1)
        arrays[f"world_mat_{i}"], arrays[f"scale_mat_{i}"] = world, scale.copy()
    write_photos(root, "image", "mask", [f"{i:03d}.png" for i in range(N)])
    for kind, i, *args in mutations:
        world, similarity = f"world_mat_{i}", f"scale_mat_{i}"
        if (kind.startswith("world") and world not in arrays) or (kind == "scale_mat" and similarity not in arrays):
            continue  # dropped by an earlier mutation
        if kind == "world_entry":
            arrays[world][args[0], args[1]] = args[2]
        elif kind == "world_scale":
            with np.errstate(over="ignore"):
                arrays[world] = arrays[world] * args[0]
        elif kind == "scale_mat":
            usable = arrays[similarity].shape == (4, 4) and arrays[similarity].dtype.kind == "f"
            current = arrays[similarity] if usable else scale
            arrays[similarity] = SCALE_MATS[args[0]](current.astype(np.float64))
        elif kind == "drop":
            arrays.pop(world if args[0] else similarity, None)
        elif kind == "mask":
            change_file(root / "mask" / f"{i:03d}.png", args[0], outside)
        elif kind == "image":
            change_file(root / "image" / f"{i:06d}.png", args[0], outside)
    with np.errstate(all="ignore"):
        np.savez(root / "cameras_sphere.npz", **arrays)


SCALE_MATS = {
    "zero": lambda m: np.zeros((4, 4)),
    "tiny": lambda m: m * np.array([1e-30, 1e-30, 1e-30, 1.0])[None, :],  # cameras ~1e30 radii away
    "scaled_1e-6": lambda m: m * 1e-6,  # up to scale: the same similarity (last row scaled too)
    "uneven": lambda m: m @ np.diag([1.0, 3.0, 1.0, 1.0]),
    "mirrored": lambda m: m @ np.diag([1.0, 1.0, -1.0, 1.0]),
    "rotated": lambda m: m @ np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),
    "far_shift": lambda m: m + np.pad(np.array([[1e35], [0], [0]]), ((0, 1), (3, 0))),
    "3x4": lambda m: m[:3],
    "text": lambda m: np.array([["a"] * 4] * 4),
    "nan": lambda m: m * np.nan,
}
idr_mutations = st.one_of(
    st.tuples(st.just("world_entry"), small, st.integers(0, 3), st.integers(0, 3), numbers),
    st.tuples(st.just("world_scale"), small, st.sampled_from([0.0, 1e-300, 1e-6, 1e6, 1e300, -1.0])),
    st.tuples(st.just("scale_mat"), small, st.sampled_from(sorted(SCALE_MATS))),
    st.tuples(st.just("drop"), small, st.booleans()),
    st.tuples(st.just("mask"), small, mask_changes),
    st.tuples(st.just("image"), small, image_changes),
)

LENS_KEYS = ["k1", "k2", "k3", "k4", "p1", "p2"]
CAMERA_KEYS = ["fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x"]
MODELS = ["OPENCV", "OPENCV_FISHEYE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "FOV", 3]


def nerfstudio(root: Path, outside: Path, mutations) -> None:
    write_photos(root, "images", None, [])
    frames = [{"file_path": f"images/{i:06d}.png", "transform_matrix": pose.tolist()} for i, pose in enumerate(poses())]
    listing = {"camera_model": "OPENCV", "fl_x": 14.0, "fl_y": 14.5, "cx": 8.0, "cy": 6.0, "w": W, "h": H, "k1": -0.1}
    for kind, *args in mutations:
        if kind == "model":
            listing["camera_model"] = args[0]
        elif kind == "set":
            where, key, value = args
            (listing if where is None else frames[where])[key] = value
        elif kind == "pose":
            i, row, column, value = args
            frames[i]["transform_matrix"][row][column] = value
        elif kind == "image":
            change_file(root / "images" / f"{args[0]:06d}.png", args[1], outside)
    (root / "transforms.json").write_text(json.dumps(listing | {"frames": frames}))


nerfstudio_mutations = st.one_of(
    st.tuples(st.just("model"), st.sampled_from(MODELS)),
    st.tuples(st.just("set"), st.none() | small, st.sampled_from(LENS_KEYS + CAMERA_KEYS), numbers),
    st.tuples(st.just("set"), st.none() | small, st.sampled_from(LENS_KEYS), st.floats(-1.5, 1.5)),
    st.tuples(st.just("pose"), small, st.integers(0, 3), st.integers(0, 3), numbers),
    st.tuples(st.just("image"), small, image_changes),
)


def blender(root: Path, outside: Path, mutations) -> None:
    write_photos(root, "train", None, [])
    frames = [{"file_path": f"./train/{i:06d}", "transform_matrix": pose.tolist()} for i, pose in enumerate(poses())]
    listing = {"camera_angle_x": 0.69}
    for kind, *args in mutations:
        if kind == "angle":
            listing["camera_angle_x"] = args[0]
        elif kind == "pose":
            i, row, column, value = args
            frames[i]["transform_matrix"][row][column] = value
        elif kind == "scale_pose":
            i, factor = args
            frames[i]["transform_matrix"] = (np.array(frames[i]["transform_matrix"]) * factor).tolist()
        elif kind == "image":
            change_file(root / "train" / f"{args[0]:06d}.png", args[1], outside)
    for split in ("train", "test"):
        (root / f"transforms_{split}.json").write_text(json.dumps(listing | {"frames": frames}))


blender_mutations = st.one_of(
    st.tuples(st.just("angle"), numbers | st.floats(0, 3.2)),
    st.tuples(st.just("pose"), small, st.integers(0, 3), st.integers(0, 3), numbers),
    st.tuples(st.just("scale_pose"), small, st.sampled_from([1e-6, -1.0, 2.0, 1.0001])),
    st.tuples(st.just("image"), small, image_changes),
)

FORMATS = {
    "llff": (llff, llff_mutations),
    "idr": (idr, idr_mutations),
    "nerfstudio": (nerfstudio, nerfstudio_mutations),
    "blender": (blender, blender_mutations),
}


# --- the property ---------------------------------------------------------------------------------


def snapshot(folder: Path, skip: Path) -> dict[str, str]:
    """Every path under `folder` but `skip`, with a digest of what it is (a link's target, a file's bytes)."""
    found = {}
    for path in sorted(folder.rglob("*")):
        if path == skip or skip in path.parents:
            continue
        if path.is_symlink():
            found[str(path)] = "link:" + os.readlink(path)
        elif path.is_file():
            found[str(path)] = hashlib.sha256(path.read_bytes()).hexdigest()
        else:
            found[str(path)] = "folder"
    return found


def hold_to_the_schema(views, where: Path) -> None:
    cameras = views.cameras
    for i in range(len(cameras)):
        fx, fy, cx, cy = (float(v[i]) for v in (cameras.fx, cameras.fy, cameras.cx, cameras.cy))
        camera_schema.check_pinhole(fx, fy, cx, cy, cameras.width, cameras.height, where, f"camera {i}")
        camera_schema.check_pose(cameras.camera_to_world[i].double().numpy(), where, f"camera {i}")


def prepare_or_refuse(fmt: str, mutations) -> None:
    build, _ = FORMATS[fmt]
    with tempfile.TemporaryDirectory(prefix="nerfaug-fuzz-") as tmp:
        tmp = Path(tmp)
        source, out, outside = tmp / "source", tmp / "out", tmp / "outside.png"
        outside.write_bytes(png(np.zeros((5, 7, 3), np.uint8)))  # a size no dataset image has
        build(source, outside, mutations)
        before = snapshot(tmp, out)
        try:
            prepare_dataset(source, out, WIDTH)
        except DatasetError as error:
            message = str(error)
            assert "\n" not in message and message.strip(), message
            assert error.path == source or source in error.path.parents, message
            OUTCOMES[fmt, "refused"] += 1
        else:
            OUTCOMES[fmt, "accepted"] += 1
            hold_to_the_schema(load_dataset(source, lazy=True), source)
            prepared = load_dataset(out)  # what was prepared loads again, and is a camera a lens makes
            hold_to_the_schema(prepared, out)
            images = prepared.images
            assert torch.isfinite(images).all() and images.min() >= 0 and images.max() <= 1
            assert math.isclose(prepared.cameras.width, WIDTH)
        assert snapshot(tmp, out) == before, "a file outside the output folder was written or changed"


@FUZZ
@given(st.lists(llff_mutations, min_size=1, max_size=3))
def test_llff_folders(mutations):
    prepare_or_refuse("llff", mutations)


@FUZZ
@given(st.lists(idr_mutations, min_size=1, max_size=3))
def test_idr_folders(mutations):
    prepare_or_refuse("idr", mutations)


@FUZZ
@given(st.lists(nerfstudio_mutations, min_size=1, max_size=3))
def test_nerfstudio_folders(mutations):
    prepare_or_refuse("nerfstudio", mutations)


@FUZZ
@given(st.lists(blender_mutations, min_size=1, max_size=3))
def test_blender_folders(mutations):
    prepare_or_refuse("blender", mutations)


@pytest.mark.parametrize("fmt", sorted(FORMATS))
def test_the_mutations_reach_both_outcomes(fmt):
    """Run after the property tests above (file order): each format saw refusals and accepted datasets."""
    if not OUTCOMES:
        pytest.skip("the property tests did not run in this session")
    assert OUTCOMES[fmt, "refused"] >= EXAMPLES // 4, OUTCOMES
    assert OUTCOMES[fmt, "accepted"] >= 3, OUTCOMES
