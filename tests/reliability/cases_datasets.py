"""Bad datasets: transforms files, frames, images and cameras, read through `nerfaug train`."""

from __future__ import annotations

import json
from pathlib import Path

from cases import case, copy_dataset, edit_json, train_on
from harness import Case, write_images


def _bad_train_json(tmp, bases, change, *says) -> Case:
    data = copy_dataset(tmp, bases)
    edit_json(data / "transforms_train.json", change)
    return Case(train_on(data, tmp).argv, [data], says=("transforms_train.json", *says))


@case
def dataset_folder_missing(tmp, bases):
    return Case(train_on(tmp / "nope", tmp).argv, says=("nope",))


@case
def dataset_folder_empty(tmp, bases):
    (tmp / "empty").mkdir()
    return Case(train_on(tmp / "empty", tmp).argv, [tmp / "empty"], says=("empty",))


@case
def dataset_path_is_a_file(tmp, bases):
    (tmp / "file.txt").write_text("not a dataset")
    return Case(train_on(tmp / "file.txt", tmp).argv, [tmp / "file.txt"], says=("file.txt",))


@case
def transforms_invalid_json(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "transforms_train.json").write_text('{"frames": [')
    return Case(train_on(data, tmp).argv, [data], says=("transforms_train.json", "JSON"))


@case
def transforms_top_level_list(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "transforms_train.json").write_text("[]")
    return Case(train_on(data, tmp).argv, [data], says=("transforms_train.json",))


@case
def transforms_without_frames(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.pop("frames"), "frames")


@case
def transforms_frames_empty(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.update(frames=[]), "frames")


@case
def transforms_frames_not_a_list(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.update(frames={"a": 1}), "frames")


@case
def frame_without_matrix(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d["frames"][0].pop("transform_matrix"), "frames[0]")


@case
def frame_matrix_3x4(tmp, bases):
    return _bad_train_json(
        tmp,
        bases,
        lambda d: d["frames"][1].update(transform_matrix=d["frames"][1]["transform_matrix"][:3]),
        "frames[1]",
    )


@case
def frame_matrix_nan(tmp, bases):
    def change(d):
        d["frames"][2]["transform_matrix"][0][3] = float("nan")

    return _bad_train_json(tmp, bases, change, "frames[2]")


@case
def frame_matrix_strings(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d["frames"][0].update(transform_matrix=[["a"] * 4] * 4), "frames[0]")


@case
def frame_matrix_not_rigid(tmp, bases):
    def change(d):
        d["frames"][0]["transform_matrix"][0][0] = 5.0

    return _bad_train_json(tmp, bases, change, "frames[0]")


@case
def frame_without_file_path(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d["frames"][3].pop("file_path"), "frames[3]")


@case
def frame_image_missing(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "train" / "r_4.png").unlink()
    return Case(train_on(data, tmp).argv, [data], says=("transforms_train.json", "frames[4]"))


@case
def frame_path_escapes_relative(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_0.png").read_bytes())
    edit_json(data / "transforms_train.json", lambda d: d["frames"][0].update(file_path="../secret"))
    return Case(train_on(data, tmp).argv, [data, tmp / "secret.png"], says=("transforms_train.json", "frames[0]"))


@case
def frame_path_escapes_absolute(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_0.png").read_bytes())
    edit_json(data / "transforms_train.json", lambda d: d["frames"][1].update(file_path=str(tmp / "secret")))
    return Case(train_on(data, tmp).argv, [data, tmp / "secret.png"], says=("transforms_train.json", "frames[1]"))


@case
def image_corrupt(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "train" / "r_2.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    return Case(train_on(data, tmp).argv, [data], says=("r_2",))


@case
def image_of_another_size(tmp, bases):
    data = copy_dataset(tmp, bases)
    write_images(data / "train", ["r_5"], size=6)
    return Case(train_on(data, tmp).argv, [data], says=("r_5",))


@case
def camera_angle_missing(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.pop("camera_angle_x"), "camera_angle_x")


@case
def camera_angle_negative(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.update(camera_angle_x=-0.5), "camera_angle_x")


@case
def camera_angle_text(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.update(camera_angle_x="wide"), "camera_angle_x")


@case
def split_missing(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--split", "nosuch").argv, [data], says=("nosuch",))


@case
def nerfstudio_without_focal_length(tmp, bases):
    data = tmp / "ns"
    write_images(data / "images", ["a", "b", "c"])
    frames = [
        {
            "file_path": f"images/{n}.png",
            "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4 + i], [0, 0, 0, 1]],
        }
        for i, n in enumerate("abc")
    ]
    (data / "transforms.json").write_text(json.dumps({"w": 8, "h": 8, "cx": 4, "cy": 4, "frames": frames}))
    return Case(train_on(data, tmp).argv, [data], says=("transforms.json", "fl_x"))


def _nerfstudio(tmp, bases, change=None, **top) -> Path:
    """A nerfstudio-format dataset (transforms.json + images/) of the base dataset's first 4 views."""
    data = tmp / "ns"
    write_images(data / "images", ["a", "b", "c", "d"])
    poses = [f["transform_matrix"] for f in json.loads((bases.dataset / "transforms_train.json").read_text())["frames"]]
    frames = [{"file_path": f"images/{n}.png", "transform_matrix": poses[i]} for i, n in enumerate("abcd")]
    meta = {"w": 8, "h": 8, "fl_x": 9.0, "fl_y": 9.0, "cx": 4.0, "cy": 4.0, "frames": frames, **top}
    if change is not None:
        change(meta)
    (data / "transforms.json").write_text(json.dumps(meta))
    return data


@case
def nerfstudio_negative_focal_length(tmp, bases):
    data = _nerfstudio(tmp, bases, fl_x=-9.0)
    return Case(train_on(data, tmp).argv, [data], says=("transforms.json", "fl_x"))


@case
def nerfstudio_image_missing(tmp, bases):
    data = _nerfstudio(tmp, bases)
    (data / "images" / "c.png").unlink()
    return Case(train_on(data, tmp).argv, [data], says=("transforms.json", "frames[2]"))


@case
def nerfstudio_path_escapes(tmp, bases):
    (tmp / "secret.png").write_bytes(next((bases.dataset / "train").glob("*.png")).read_bytes())
    data = _nerfstudio(tmp, bases, lambda m: m["frames"][2].update(file_path="../secret.png"))
    return Case(train_on(data, tmp).argv, [data, tmp / "secret.png"], says=("transforms.json", "frames[2]"))


@case
def camera_angle_zero(tmp, bases):
    return _bad_train_json(tmp, bases, lambda d: d.update(camera_angle_x=0), "camera_angle_x")


@case
def transforms_file_is_a_folder(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "transforms_train.json").unlink()
    (data / "transforms_train.json").mkdir()
    return Case(train_on(data, tmp).argv, [data], says=("transforms_train.json",))


@case
def image_is_a_folder(tmp, bases):
    data = copy_dataset(tmp, bases)
    (data / "train" / "r_3.png").unlink()
    (data / "train" / "r_3.png").mkdir()
    return Case(train_on(data, tmp).argv, [data], says=("transforms_train.json", "frames[3]"))


@case
def image_symlink_leaving_the_folder(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_6.png").read_bytes())
    (data / "train" / "r_6.png").unlink()
    (data / "train" / "r_6.png").symlink_to(tmp / "secret.png")
    return Case(train_on(data, tmp).argv, [data, tmp / "secret.png"], says=("transforms_train.json", "frames[6]"))


@case
def scene_prepare_over_an_interrupted_folder_holding_a_users_file(tmp, bases):
    """A folder nerfaug marked for a preparation that never finished (no prepared.json), into
    which the user put a file: the file is never removed; the command names it."""
    data = copy_dataset(tmp, bases)
    out = tmp / "prepared"
    out.mkdir()
    (out / ".nerfaug").write_text(json.dumps({"kind": "prepared-dataset", "created": "2026-01-01T00:00:00+00:00"}))
    (out / "thesis.tex").write_text("keep me")
    return Case(["scene", "prepare", data, "--out", out, "--width", "4"], [data, out], says=(str(out), "thesis.tex"))


@case
def scene_prepare_out_inside_the_source(tmp, bases):
    """The source of `scene prepare` is only read: an --out inside it is refused before anything is written."""
    data = copy_dataset(tmp, bases)
    argv = ["scene", "prepare", data, "--out", data / "prepared", "--width", "4"]
    return Case(argv, [data], says=("--out", str(data / "prepared"), "only read"))


@case
def split_name_leaving_the_folder(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--split", "../x").argv, [data], says=("../x",))


@case
def cameras_looking_the_same_way(tmp, bases):
    """The hemisphere cannot be estimated from parallel optical axes: say so, and what to give."""

    def parallel(d):
        for frame in d["frames"]:
            m = frame["transform_matrix"]
            frame["transform_matrix"] = [[1, 0, 0, m[0][3]], [0, 1, 0, m[1][3]], [0, 0, 1, 4], [0, 0, 0, 1]]

    data = copy_dataset(tmp, bases)
    edit_json(data / "transforms_train.json", parallel)
    return Case(train_on(data, tmp).argv, [data], says=("centre", "radius"))


def _scene_render(tmp, *extra, says=()) -> Case:
    return Case(
        [
            "scene",
            "render",
            "lego",
            "--out",
            tmp / "lego",
            "--res",
            "8",
            "--pool",
            "2",
            "--test",
            "1",
            "--initial",
            "1",
            "--samples",
            "1",
            *extra,
        ],
        [tmp],
        says=says,
    )


@case
def scene_render_zero_resolution(tmp, bases):
    return _scene_render(tmp, "--res", "0", says=("resolution", "0"))


@case
def scene_render_zero_samples(tmp, bases):
    return _scene_render(tmp, "--samples", "0", says=("samples", "0"))


@case
def scene_render_over_a_users_folder(tmp, bases):
    (tmp / "lego").mkdir()
    (tmp / "lego" / "thesis.tex").write_text("keep me")
    return _scene_render(tmp, says=(str(tmp / "lego"),))


# Cameras no lens makes, in each captured-set format (the camera schema, `nerfaug.camera_schema`).


def _llff(tmp, hwf=(8.0, 8.0, 9.0)) -> Path:
    """An LLFF folder of 3 8x8 photos, each pose's (height, width, focal) `hwf`."""
    import numpy as np

    from nerfaug.hemisphere import half_hemisphere_poses

    data = tmp / "llff"
    write_images(data / "images", ["a", "b", "c"])
    rows = []
    for pose in half_hemisphere_poses(3, radius=3.0).double().numpy():
        matrix = np.stack([-pose[:3, 1], pose[:3, 0], pose[:3, 2], pose[:3, 3], hwf], axis=1)
        rows.append(np.concatenate([matrix.reshape(-1), [1.0, 5.0]]))
    np.save(data / "poses_bounds.npy", np.stack(rows))
    return data


def _idr(tmp, scale_mat) -> Path:
    """An IDR folder of 3 8x8 photos whose cameras lie 3 units from the origin, with `scale_mat`."""
    import numpy as np

    from nerfaug.hemisphere import half_hemisphere_poses

    data = tmp / "dtu"
    write_images(data / "image", ["000000", "000001", "000002"])
    arrays = {}
    for i, pose in enumerate(half_hemisphere_poses(3, radius=3.0).double().numpy()):
        w2c = (pose[:3, :3] @ np.diag([1.0, -1.0, -1.0])).T
        world = np.eye(4)
        world[:3, :4] = np.array([[9.0, 0, 4], [0, 9.0, 4], [0, 0, 1]]) @ np.c_[w2c, -w2c @ pose[:3, 3]]
        arrays[f"world_mat_{i}"], arrays[f"scale_mat_{i}"] = world, np.asarray(scale_mat, dtype=float)
    np.savez(data / "cameras_sphere.npz", **arrays)
    return data


def _prepare(data: Path, tmp: Path, *says) -> Case:
    return Case(["scene", "prepare", data, "--out", tmp / "prepared", "--width", "4"], [data], says=says)


@case
def idr_scale_mat_singular(tmp, bases):
    return _prepare(_idr(tmp, [[0.0] * 4] * 4), tmp, "cameras_sphere.npz", "scale_mat_0", "singular")


@case
def idr_scale_putting_the_cameras_3e30_away(tmp, bases):
    data = _idr(tmp, [[1e-30, 0, 0, 0], [0, 1e-30, 0, 0], [0, 0, 1e-30, 0], [0, 0, 0, 1]])
    return Case(train_on(data, tmp).argv, [data], says=("cameras_sphere.npz", "scale_mat_0", "3e+30"))


@case
def llff_focal_1e_minus_30(tmp, bases):
    return _prepare(_llff(tmp, (8.0, 8.0, 1e-30)), tmp, "poses_bounds.npy", "row 0", "1e-30")


@case
def llff_image_size_1e308(tmp, bases):
    return _prepare(_llff(tmp, (1e308, 8.0, 9.0)), tmp, "poses_bounds.npy", "row 0", "1e+308")


@case
def nerfstudio_lens_k1_minus_999(tmp, bases):
    data = _nerfstudio(tmp, bases, camera_model="OPENCV", k1=-999)
    return _prepare(data, tmp, "transforms.json", "k1=-999")


@case
def nerfstudio_lens_p1_500(tmp, bases):
    data = _nerfstudio(tmp, bases, camera_model="OPENCV", p1=500)
    return Case(train_on(data, tmp).argv, [data], says=("transforms.json", "p1=500"))
