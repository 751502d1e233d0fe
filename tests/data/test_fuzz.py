"""Property-based test of the dataset readers: malformed transforms files and images give a
`DatasetError` naming a file inside the dataset folder, in one line, and nothing else.

Each example starts from a valid Blender or nerfstudio dataset (a few 8x8 PNGs) in a fresh
temporary folder and applies a random list of mutations: any JSON value (wrong types, NaN/inf,
huge numbers, nasty strings) in any field, deleted keys, non-rigid or misshapen matrices, paths
leaving the folder (`..`, absolute, through a symlink), truncated/garbage/odd images, broken JSON
text, empty or odd frame lists. A load that succeeds must give finite images in [0, 1] and finite
cameras whose every image lies inside the folder. 800 + 600 examples, derandomized so that CI runs
the same cases every time; the test counts the outcomes and requires >= 1,000 refused (malformed)
datasets, so a change that makes the mutations harmless cannot pass unnoticed.
"""

from __future__ import annotations

import io
import json
import math
import os
import tempfile
from collections import Counter
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerfaug.data import DatasetError, load_dataset

SIZE = 8
FUZZ = settings(
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=list(HealthCheck),
)


def _png(array: np.ndarray) -> bytes:
    return iio.imwrite("<bytes>", array, extension=".png")


def _images() -> dict[str, bytes]:
    """Image files by name: valid ones of other kinds and sizes, and broken ones."""
    rng = np.random.default_rng(0)
    rgba = rng.integers(0, 256, (SIZE, SIZE, 4), dtype=np.uint8)
    valid = _png(rgba)
    gif = io.BytesIO()
    iio.imwrite(gif, rng.integers(0, 256, (3, SIZE, SIZE, 3), dtype=np.uint8), extension=".gif")
    return {
        "rgba": valid,
        "rgb": _png(rgba[..., :3]),
        "grey16": _png(rgba[..., 0].astype(np.uint16) * 257),
        "grey": _png(rgba[..., 0]),
        "grey_alpha": _png(rgba[..., :2]),
        "other_size": _png(rng.integers(0, 256, (SIZE + 3, SIZE - 2, 4), dtype=np.uint8)),
        "one_pixel": _png(rgba[:1, :1]),
        "jpeg": iio.imwrite("<bytes>", rgba[..., :3], extension=".jpg"),
        "animated_gif": gif.getvalue(),
        "truncated": valid[: len(valid) // 2],
        "header_only": valid[:33],
        "garbage": bytes(rng.integers(0, 256, 200, dtype=np.uint8)),
        "empty": b"",
        "text": b"not an image\n",
        # A PNG header claiming 60000 x 60000 pixels followed by nothing: must not allocate it.
        "huge_header": valid[:16] + (60000).to_bytes(4, "big") * 2 + valid[24:33],
    }


IMAGES = _images()
OUTCOMES: Counter = Counter()  # "refused" (DatasetError) and "accepted" examples of the last run
BLENDER_EXAMPLES, NERFSTUDIO_EXAMPLES = 800, 600
OUTSIDE_SIZE = (5, 7)  # the image outside the dataset folder: a size no dataset image has


def _pose(i: int) -> list[list[float]]:
    angle = 0.7 * i
    c, s = math.cos(angle), math.sin(angle)
    return [[c, -s, 0.0, 4 * s], [s, c, 0.0, -4 * c], [0.0, 0.0, 1.0, 1.5], [0.0, 0.0, 0.0, 1.0]]


def _base(fmt: str, n: int) -> tuple[str, dict, dict[str, bytes]]:
    """(transforms file name, its content, image files by relative path) of a valid dataset."""
    if fmt == "blender":
        frames = [{"file_path": f"./train/r_{i}", "transform_matrix": _pose(i)} for i in range(n)]
        files = {f"train/r_{i}.png": IMAGES["rgba"] for i in range(n)}
        return "transforms_train.json", {"camera_angle_x": 0.69, "frames": frames}, files
    frames = [{"file_path": f"images/f_{i}.png", "transform_matrix": _pose(i)} for i in range(n)]
    files = {f"images/f_{i}.png": IMAGES["rgba"] for i in range(n)}
    meta = {
        "camera_model": "OPENCV",
        "fl_x": 9.0,
        "fl_y": 9.5,
        "cx": 4.0,
        "cy": 4.0,
        "w": SIZE,
        "h": SIZE,
        "frames": frames,
    }
    return "transforms.json", meta, files


NASTY_STRINGS = [
    "",
    ".",
    "..",
    "../outside",
    "/etc/passwd",
    "a\x00b",
    "~",
    "x" * 5000,
    "C:\\windows",
    "file:///etc/hosts",
    "images",
    "train",
    "./train/",
    "é",
    "\u202e",
    " ",
]
scalars = (
    st.none()
    | st.booleans()
    | st.integers(-(10**30), 10**30)
    | st.just(10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from([0, -1, 1e-300, 1e300, 3.2])
    | st.text(max_size=12)
    | st.sampled_from(NASTY_STRINGS)
)
json_values = st.recursive(
    scalars,
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)
TOP_KEYS = ["camera_angle_x", "frames", "fl_x", "fl_y", "cx", "cy", "w", "h", "camera_model", "k1"]
FRAME_KEYS = ["file_path", "transform_matrix", "fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x"]
frame_index = st.integers(0, 3)  # taken modulo the number of frames
mutations = st.one_of(
    st.tuples(st.just("set_top"), st.sampled_from(TOP_KEYS), json_values),
    st.tuples(st.just("delete_top"), st.sampled_from(TOP_KEYS)),
    st.tuples(st.just("set_frame"), frame_index, st.sampled_from(FRAME_KEYS), json_values),
    st.tuples(st.just("delete_frame_key"), frame_index, st.sampled_from(FRAME_KEYS)),
    st.tuples(st.just("set_entry"), frame_index, st.integers(0, 4), st.integers(0, 4), json_values),
    st.tuples(
        st.just("matrix"),
        frame_index,
        st.sampled_from(
            [
                "scale",
                "shear",
                "reflect",
                "nan",
                "inf",
                "last_row",
                "3x4",
                "4x4x1",
                "flat",
                "huge_translation",
                "tiny_noise",
                "rows_of_strings",
                "bools",
                "empty",
            ]
        ),
    ),
    st.tuples(
        st.just("path"),
        frame_index,
        st.sampled_from(
            [
                "dotdot",
                "absolute_outside",
                "absolute_inside",
                "symlink_file_out",
                "symlink_dir_out",
                "symlink_in",
                "symlink_loop",
                "empty",
                "dot",
                "folder",
                "nul",
                "long",
                "missing",
                "dotdot_back_inside",
                "root_itself",
            ]
        ),
    ),
    st.tuples(st.just("image"), frame_index, st.sampled_from(sorted(IMAGES))),
    st.tuples(st.just("remove_image"), frame_index),
    st.tuples(
        st.just("frames"),
        st.sampled_from(["empty", "object", "string", "null", "frame_not_object", "duplicate", "many"]),
    ),
    st.tuples(
        st.just("raw"),
        st.sampled_from(["truncated", "not_utf8", "array", "null", "nan_literal", "huge_int", "deep", "empty", "bom"]),
    ),
)


def _symlink(link: Path, target: Path) -> None:
    link.unlink(missing_ok=True)  # a mutation may be applied twice: the last link wins
    link.symlink_to(target)


def _mutate(root: Path, outside: Path, name: str, meta: dict, files: dict[str, bytes], mutation) -> str | None:
    """Apply one mutation to `meta`/`files` (or the folder); returns raw JSON text if it replaces it."""
    kind, *args = mutation
    frames = meta.get("frames") if isinstance(meta.get("frames"), list) else []
    frame = None
    if kind in ("set_frame", "delete_frame_key", "set_entry", "matrix", "path", "image", "remove_image"):
        if not frames:
            return None
        args[0] %= len(frames)  # any index names a frame, so the mutation is never a no-op
        if not isinstance(frames[args[0]], dict):
            return None
        frame = frames[args[0]]

    def image_of(f):
        return next(
            (p for p in files if isinstance(f.get("file_path"), str) and Path(p).stem == Path(f["file_path"]).stem),
            None,
        )

    if kind == "set_top":
        meta[args[0]] = args[1]
    elif kind == "delete_top":
        meta.pop(args[0], None)
    elif kind == "set_frame":
        frame[args[1]] = args[2]
    elif kind == "delete_frame_key":
        frame.pop(args[1], None)
    elif kind == "set_entry":
        matrix = frame.get("transform_matrix")
        if (
            isinstance(matrix, list)
            and args[1] < len(matrix)
            and isinstance(matrix[args[1]], list)
            and args[2] < len(matrix[args[1]])
        ):
            matrix[args[1]][args[2]] = args[3]
    elif kind == "matrix":
        m = np.array(_pose(args[0]))
        how = args[1]
        value = {
            "scale": lambda: (m * np.array([2, 1, 1, 1])).tolist(),
            "shear": lambda: (m + np.array([[0, 0.3, 0, 0], [0] * 4, [0] * 4, [0] * 4])).tolist(),
            "reflect": lambda: (m * np.array([[1], [1], [-1], [1]])).tolist(),
            "nan": lambda: [[float("nan")] + r[1:] for r in m.tolist()],
            "inf": lambda: [r[:3] + [float("inf")] for r in m.tolist()],
            "last_row": lambda: m.tolist()[:3] + [[0, 0, 1, 1]],
            "3x4": lambda: m.tolist()[:3],
            "4x4x1": lambda: m[..., None].tolist(),
            "flat": lambda: m.flatten().tolist(),
            "huge_translation": lambda: [r[:3] + [1e300] for r in m.tolist()[:3]] + [[0, 0, 0, 1]],
            "tiny_noise": lambda: (m + 1e-7).tolist(),
            "rows_of_strings": lambda: [[str(x) for x in r] for r in m.tolist()],
            "bools": lambda: [[bool(x) for x in r] for r in np.eye(4)],
            "empty": list,
        }[how]()
        frame["transform_matrix"] = value
    elif kind == "path":
        how, i = args[1], args[0]
        link = root / f"link_{i}"
        if how == "dotdot":
            frame["file_path"] = os.path.relpath(outside / "img.png", root)
        elif how == "absolute_outside":
            frame["file_path"] = str(outside / "img.png")
        elif how == "absolute_inside":
            target = image_of(frame)
            if target is not None:
                frame["file_path"] = str(root / target)
        elif how == "symlink_file_out":
            _symlink(link.with_suffix(".png"), outside / "img.png")
            frame["file_path"] = f"link_{i}.png"
        elif how == "symlink_dir_out":
            _symlink(link, outside)
            frame["file_path"] = f"link_{i}/img.png"
        elif how == "symlink_in":
            target = image_of(frame)
            if target is not None:
                (root / target).parent.mkdir(parents=True, exist_ok=True)
                _symlink(link.with_suffix(".png"), root / target)
                frame["file_path"] = f"link_{i}.png"
        elif how == "symlink_loop":
            _symlink(link, link)
            frame["file_path"] = f"link_{i}"
        else:
            frame["file_path"] = {
                "empty": "",
                "dot": ".",
                "folder": "images" if "images/f_0.png" in files else "train",
                "nul": "train/r\x000",
                "long": "a/" * 3000 + "b",
                "missing": "./train/nope",
                "dotdot_back_inside": f"../{root.name}/{image_of(frame) or 'x'}",
                "root_itself": str(root),
            }[how]
    elif kind == "image":
        target = image_of(frame)
        if target is not None:
            files[target] = IMAGES[args[1]]
    elif kind == "remove_image":
        target = image_of(frame)
        if target is not None:
            del files[target]
    elif kind == "frames":
        meta["frames"] = {
            "empty": list,
            "object": lambda: {"0": frames[0] if frames else {}},
            "string": lambda: "frames",
            "null": lambda: None,
            "frame_not_object": lambda: frames[:1] + [[1, 2]],
            "duplicate": lambda: frames + frames,
            "many": lambda: (frames * 12)[:30],
        }[args[0]]()
    elif kind == "raw":
        text = json.dumps(meta)
        return {
            "truncated": text[: len(text) // 2],
            "not_utf8": "\udcff",
            "array": "[1, 2]",
            "null": "null",
            "nan_literal": "NaN",
            "huge_int": '{"camera_angle_x": ' + "7" * 5000 + "}",
            "deep": "[" * 50_000 + "]" * 50_000,
            "empty": "",
            "bom": "\ufeff" + text,
        }[args[0]]
    return None


def _inside(path: str, root: Path) -> bool:
    """Whether `path` (relative to `root`, or absolute) with any image suffix resolves inside root;
    computed with os.path, independently of the reader."""
    real_root = os.path.realpath(root)
    base = os.path.join(root, path)
    found = [c for c in (base, base + ".png") if os.path.isfile(c)]
    return bool(found) and all(os.path.commonpath([os.path.realpath(c), real_root]) == real_root for c in found)


def _check(fmt: str, n: int, mutation_list, downscale: int, lazy: bool) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root, outside = Path(tmp) / "dataset", Path(tmp) / "outside"
        root.mkdir()
        outside.mkdir()
        (outside / "img.png").write_bytes(_png(np.full((*OUTSIDE_SIZE, 4), 200, np.uint8)))
        name, meta, files = _base(fmt, n)
        raw = None
        for mutation in mutation_list:
            raw = _mutate(root, outside, name, meta, files, mutation) or raw
        for rel, data in files.items():
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(data)
        if raw is None:
            (root / name).write_text(json.dumps(meta))
        else:
            (root / name).write_bytes(raw.encode("utf-8", "surrogateescape"))
        try:
            views = load_dataset(root, "train", downscale=downscale, lazy=lazy).materialised()
        except DatasetError as error:
            message = str(error)
            assert "\n" not in message and "\r" not in message, message
            assert message.startswith(str(root)), message  # names the file (inside the dataset)
            assert len(message) < 1200, message
            OUTCOMES["refused"] += 1
            return
        # Accepted: then it is a sound dataset whose every image lies inside the folder.
        assert views.images.ndim == 4 and views.images.shape[0] == len(views.names) >= 1
        assert views.images.shape[1:] == (views.cameras.height, views.cameras.width, 3)
        assert min(views.images.shape[1:3]) >= 1 and views.images.shape[1:3] != OUTSIDE_SIZE
        assert torch.isfinite(views.images).all() and views.images.min() >= 0 and views.images.max() <= 1
        cams = views.cameras
        for values in (cams.camera_to_world, cams.fx, cams.fy, cams.cx, cams.cy):
            assert torch.isfinite(values).all()
        assert (cams.fx > 0).all() and (cams.fy > 0).all()
        assert all(_inside(n, root) for n in views.names), views.names
        OUTCOMES["accepted"] += 1


@settings(FUZZ, max_examples=BLENDER_EXAMPLES)
@given(
    n=st.integers(1, 3),
    mutation_list=st.lists(mutations, min_size=1, max_size=4),
    downscale=st.sampled_from([1, 1, 1, 1, 2, 3, 16]),
    lazy=st.booleans(),
)
def _blender_examples(n, mutation_list, downscale, lazy):
    _check("blender", n, mutation_list, downscale, lazy)


@settings(FUZZ, max_examples=NERFSTUDIO_EXAMPLES)
@given(
    n=st.integers(1, 3),
    mutation_list=st.lists(mutations, min_size=1, max_size=4),
    downscale=st.sampled_from([1, 1, 1, 2, 16]),
    lazy=st.booleans(),
)
def _nerfstudio_examples(n, mutation_list, downscale, lazy):
    _check("nerfstudio", n, mutation_list, downscale, lazy)


def test_readers_accept_sound_data_or_raise_dataset_error_only():
    """Both readers over every generated dataset; at least 1,000 of them are malformed (refused)."""
    OUTCOMES.clear()
    _blender_examples()
    _nerfstudio_examples()
    assert OUTCOMES["refused"] >= 1000, dict(OUTCOMES)
    assert OUTCOMES["accepted"] >= 20, dict(OUTCOMES)  # the mutations also leave sound datasets: both paths run
