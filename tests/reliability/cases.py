"""The bad inputs: each builds what it needs in a fresh folder and says what `nerfaug` must answer.

A case is a function (tmp, bases) -> Case. `bases` holds inputs made once (a dataset, a capture
session, a finished results folder); a case copies what it changes, and lists in `inputs` every
folder the command must leave byte for byte unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from harness import Case, copy, make_dataset, write_images

TINY = ["--preset", "tiny", "--methods", "uniform", "--trials", "1", "--resolution", "8", "--steps", "21",
        "--no-report", "--device", "cpu"]


@dataclass
class Bases:
    dataset: Path    # Blender format, 10 train (8x8), 3 test, 3 initial views
    session: Path    # a capture session on `dataset`, trained 3 steps (preset test)
    results: Path    # a finished `nerfaug run` of `dataset` (TINY)


CASES: dict = {}


def case(function):
    CASES[function.__name__] = function
    return function


def _edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _dataset(tmp: Path, bases: Bases, name: str = "data") -> Path:
    return copy(bases.dataset, tmp / name)


def _train_on(data: Path, tmp: Path, *extra) -> Case:
    return Case(["train", data, "--out", tmp / "run", "--preset", "test", "--steps", "1", "--device", "cpu", *extra],
                [data])


def _bad_train_json(tmp, bases, change, *says) -> Case:
    data = _dataset(tmp, bases)
    _edit_json(data / "transforms_train.json", change)
    return Case(_train_on(data, tmp).argv, [data], says=("transforms_train.json", *says))


# ---- datasets ----------------------------------------------------------------------------------

@case
def dataset_folder_missing(tmp, bases):
    return Case(_train_on(tmp / "nope", tmp).argv, says=("nope",))


@case
def dataset_folder_empty(tmp, bases):
    (tmp / "empty").mkdir()
    return Case(_train_on(tmp / "empty", tmp).argv, [tmp / "empty"], says=("empty",))


@case
def dataset_path_is_a_file(tmp, bases):
    (tmp / "file.txt").write_text("not a dataset")
    return Case(_train_on(tmp / "file.txt", tmp).argv, [tmp / "file.txt"], says=("file.txt",))


@case
def transforms_invalid_json(tmp, bases):
    data = _dataset(tmp, bases)
    (data / "transforms_train.json").write_text('{"frames": [')
    return Case(_train_on(data, tmp).argv, [data], says=("transforms_train.json", "JSON"))


@case
def transforms_top_level_list(tmp, bases):
    data = _dataset(tmp, bases)
    (data / "transforms_train.json").write_text("[]")
    return Case(_train_on(data, tmp).argv, [data], says=("transforms_train.json",))


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
    return _bad_train_json(tmp, bases, lambda d: d["frames"][1].update(transform_matrix=d["frames"][1]
                                                                         ["transform_matrix"][:3]), "frames[1]")


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
    data = _dataset(tmp, bases)
    (data / "train" / "r_4.png").unlink()
    return Case(_train_on(data, tmp).argv, [data], says=("transforms_train.json", "frames[4]"))


@case
def frame_path_escapes_relative(tmp, bases):
    data = _dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_0.png").read_bytes())
    _edit_json(data / "transforms_train.json", lambda d: d["frames"][0].update(file_path="../secret"))
    return Case(_train_on(data, tmp).argv, [data, tmp / "secret.png"], says=("transforms_train.json", "frames[0]"))


@case
def frame_path_escapes_absolute(tmp, bases):
    data = _dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_0.png").read_bytes())
    _edit_json(data / "transforms_train.json", lambda d: d["frames"][1].update(file_path=str(tmp / "secret")))
    return Case(_train_on(data, tmp).argv, [data, tmp / "secret.png"], says=("transforms_train.json", "frames[1]"))


@case
def image_corrupt(tmp, bases):
    data = _dataset(tmp, bases)
    (data / "train" / "r_2.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    return Case(_train_on(data, tmp).argv, [data], says=("r_2",))


@case
def image_of_another_size(tmp, bases):
    data = _dataset(tmp, bases)
    write_images(data / "train", ["r_5"], size=6)
    return Case(_train_on(data, tmp).argv, [data], says=("r_5",))


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
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--split", "nosuch").argv, [data], says=("nosuch",))


@case
def nerfstudio_without_focal_length(tmp, bases):
    data = tmp / "ns"
    write_images(data / "images", ["a", "b", "c"])
    frames = [{"file_path": f"images/{n}.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 4 + i],
                                                                       [0, 0, 0, 1]]} for i, n in enumerate("abc")]
    (data / "transforms.json").write_text(json.dumps({"w": 8, "h": 8, "cx": 4, "cy": 4, "frames": frames}))
    return Case(_train_on(data, tmp).argv, [data], says=("transforms.json", "fl_x"))


# ---- active capture ----------------------------------------------------------------------------

def _session(tmp, bases) -> Path:
    return copy(bases.session, tmp / "run")


def _propose(run: Path, tmp: Path, *extra) -> list:
    return ["propose", run, "--out", tmp / "poses.json", "--n-candidates", "12", "--device", "cpu", *extra]


def _propose_case(tmp, bases, *extra, says=()) -> Case:
    run = _session(tmp, bases)
    return Case(_propose(run, tmp, *extra), [run], says=says)


def _broken_session(tmp, bases, change, *says) -> Case:
    run = _session(tmp, bases)
    _edit_json(run / "session.json", change)
    return Case(_propose(run, tmp), [run], says=("session.json", *says))


@case
def train_into_the_folder_holding_the_dataset(tmp, bases):
    """The issue's data loss: `nerfaug train proj/dataset --out proj` deleted proj/dataset."""
    project = tmp / "proj"
    copy(bases.dataset, project / "dataset")
    return Case(["train", project / "dataset", "--out", project, "--preset", "test", "--steps", "1",
                 "--device", "cpu"], [project], says=(str(project),))


@case
def train_out_is_the_dataset(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(["train", data, "--out", data, "--preset", "test", "--device", "cpu"], [data], says=(str(data),))


@case
def train_out_is_a_users_folder(tmp, bases):
    data = _dataset(tmp, bases)
    (tmp / "mine").mkdir()
    (tmp / "mine" / "notes.txt").write_text("keep me")
    (tmp / "mine" / "dataset").mkdir()
    (tmp / "mine" / "dataset" / "photo.png").write_bytes(b"1234")
    return Case(["train", data, "--out", tmp / "mine", "--preset", "test", "--device", "cpu"], [data, tmp / "mine"],
                says=("mine",))


@case
def train_out_is_a_file(tmp, bases):
    data = _dataset(tmp, bases)
    (tmp / "out.txt").write_text("x")
    return Case(["train", data, "--out", tmp / "out.txt", "--preset", "test", "--device", "cpu"],
                [data, tmp / "out.txt"], says=("out.txt",))


@case
def train_negative_steps(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--steps", "-1").argv, [data, tmp], says=("--steps", "-1"))


@case
def train_downscale_zero(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--downscale", "0").argv, [data, tmp], says=("downscale", "0"))


@case
def train_downscale_larger_than_images(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--downscale", "100").argv, [data, tmp], says=("downscale", "100"))


@case
def train_unknown_preset(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--preset", "fastest").argv, [data, tmp], says=("fastest",), usage=True)


@case
def train_negative_radius(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--radius", "-1").argv, [data, tmp], says=("radius", "-1"))


@case
def train_zero_up(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--up", "0", "0", "0").argv, [data, tmp], says=("up",))


@case
def train_nan_centre(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--centre", "nan", "0", "0").argv, [data, tmp], says=("centre", "nan"))


@case
def train_negative_seed(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_train_on(data, tmp, "--seed", "-1").argv, [data, tmp], says=("seed", "-1"))


@case
def train_dataset_without_out(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(["train", data, "--device", "cpu"], [data, tmp], says=("--out",))


@case
def train_session_with_out(tmp, bases):
    run = _session(tmp, bases)
    return Case(["train", run, "--out", tmp / "other", "--device", "cpu"], [run, tmp], says=(str(run),))


@case
def train_session_negative_steps(tmp, bases):
    run = _session(tmp, bases)
    return Case(["train", run, "--steps", "-2", "--device", "cpu"], [run], says=("--steps", "-2"))


@case
def propose_zero_views(tmp, bases):
    return _propose_case(tmp, bases, "--n", "0", says=("--n", "0"))


@case
def propose_negative_views(tmp, bases):
    return _propose_case(tmp, bases, "--n", "-3", says=("--n", "-3"))


@case
def propose_unknown_method(tmp, bases):
    return _propose_case(tmp, bases, "--method", "best-views", says=("best-views",))


@case
def propose_zero_candidates(tmp, bases):
    run = _session(tmp, bases)
    return Case(["propose", run, "--out", tmp / "poses.json", "--n-candidates", "0", "--device", "cpu"], [run],
                says=("--n-candidates", "0"))


@case
def propose_more_views_than_candidates(tmp, bases):
    return _propose_case(tmp, bases, "--n", "50", says=("50",))


@case
def propose_candidates_file_missing(tmp, bases):
    return _propose_case(tmp, bases, "--candidates", tmp / "reach.json", says=("reach.json",))


@case
def propose_candidates_file_invalid(tmp, bases):
    (tmp / "reach.json").write_text("{oops")
    return _propose_case(tmp, bases, "--candidates", tmp / "reach.json", says=("reach.json",))


@case
def propose_on_a_dataset(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(_propose(data, tmp), [data], says=(str(data), "session.json"))


@case
def propose_over_a_users_file(tmp, bases):
    run = _session(tmp, bases)
    (tmp / "poses.json").write_text('{"my": "notes"}')
    return Case(_propose(run, tmp), [run, tmp / "poses.json"], says=("poses.json",))


@case
def session_json_truncated(tmp, bases):
    run = _session(tmp, bases)
    text = (run / "session.json").read_text()
    (run / "session.json").write_text(text[: len(text) // 2])
    return Case(_propose(run, tmp), [run], says=("session.json",))


@case
def session_json_dataset_file_outside(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d["dataset"].update(json="../../../etc/passwd"), "dataset.json")


@case
def session_json_dataset_folder_absolute(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d["dataset"].update(folder="/tmp"), "dataset.folder")


@case
def session_json_unknown_format(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d.update(format=99), "format", "99")


@case
def session_json_without_intrinsics(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d.pop("intrinsics"), "intrinsics")


@case
def session_json_bad_background(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d.update(background=[2, 0, 0]), "background")


@case
def session_json_proposal_file_outside(tmp, bases):
    record = {"number": 0, "method": "ours", "n": 1, "step": 3, "seed": 1, "candidates": "hemisphere",
              "n_candidates": 12, "names": ["capture_000_00"], "poses": [], "azimuth": [], "polar": [],
              "file": "../../elsewhere/proposal.json", "created": "now"}
    return _broken_session(tmp, bases, lambda d: d.update(proposals=[record]), "proposals[0].file")


@case
def checkpoint_missing(tmp, bases):
    run = _session(tmp, bases)
    (run / "checkpoint.pt").unlink()
    return Case(_propose(run, tmp), [run], says=("checkpoint.pt",))


@case
def checkpoint_corrupt(tmp, bases):
    run = _session(tmp, bases)
    (run / "checkpoint.pt").write_bytes(b"not a checkpoint")
    return Case(_propose(run, tmp), [run], says=("checkpoint.pt",))


def _poses(tmp: Path, bases: Bases, names=("capture_000_00", "capture_000_01"), change=None) -> Path:
    """A poses JSON as `nerfaug propose` writes it (two poses of the dataset's test split)."""
    test = json.loads((bases.dataset / "transforms_test.json").read_text())
    frames = [{"file_path": f"./{name}", "transform_matrix": frame["transform_matrix"]}
              for name, frame in zip(names, test["frames"])]
    data = {"camera_angle_x": test["camera_angle_x"], "frames": frames}
    if change is not None:
        change(data)
    (tmp / "poses.json").write_text(json.dumps(data))
    return tmp / "poses.json"


def _add(tmp, bases, images=None, poses=None, *extra, says=(), image_names=("capture_000_00", "capture_000_01"),
         size=8) -> Case:
    run = _session(tmp, bases)
    poses = _poses(tmp, bases) if poses is None else poses
    if images is None:
        images = write_images(tmp / "captures", list(image_names), size=size)
    inputs = [run, poses] + ([images] if Path(images).exists() else [])
    return Case(["add", run, "--images", images, "--poses", poses, "--steps", "1", "--device", "cpu", *extra],
                inputs, says=says)


@case
def add_images_folder_missing(tmp, bases):
    return _add(tmp, bases, images=tmp / "nope", says=("nope",))


@case
def add_poses_missing(tmp, bases):
    return _add(tmp, bases, poses=tmp / "nope.json", says=("nope.json",))


@case
def add_poses_invalid_json(tmp, bases):
    (tmp / "bad.json").write_text("{")
    return _add(tmp, bases, poses=tmp / "bad.json", says=("bad.json",))


@case
def add_poses_nan(tmp, bases):
    def change(d):
        d["frames"][1]["transform_matrix"][1][1] = float("nan")
    return _add(tmp, bases, poses=_poses(tmp, bases, change=change), says=("poses.json", "frames[1]"))


@case
def add_images_of_another_size(tmp, bases):
    return _add(tmp, bases, size=6, says=("capture_000_00",))


@case
def add_fewer_images_than_poses(tmp, bases):
    return _add(tmp, bases, image_names=("capture_000_00",), says=("capture_000_01",))


@case
def add_images_folder_empty(tmp, bases):
    (tmp / "empty").mkdir()
    return _add(tmp, bases, images=tmp / "empty", says=("empty",))


@case
def add_image_corrupt(tmp, bases):
    images = write_images(tmp / "captures", ["capture_000_00", "capture_000_01"])
    (images / "capture_000_01.png").write_bytes(b"garbage")
    return _add(tmp, bases, images=images, says=("capture_000_01",))


@case
def add_negative_steps(tmp, bases):
    """`add` must check --steps before it writes: a refused call changes nothing."""
    return _add(tmp, bases, None, None, "--steps", "-5", says=("--steps", "-5"))


@case
def add_a_frame_already_in_the_dataset(tmp, bases):
    return _add(tmp, bases, poses=_poses(tmp, bases, names=("r_0", "r_1")), image_names=("r_0", "r_1"),
                says=("r_0",))


@case
def add_image_names_with_separators(tmp, bases):
    poses = _poses(tmp, bases, names=("a b", "c"))
    return _add(tmp, bases, poses=poses, image_names=("a b", "c"), says=("a b",))


@case
def export_into_a_users_folder(tmp, bases):
    run = _session(tmp, bases)
    (tmp / "mine").mkdir()
    (tmp / "mine" / "transforms.json").write_text("{}")
    return Case(["export", run, "--out", tmp / "mine"], [run, tmp / "mine"], says=("mine",))


@case
def export_into_the_run_folder(tmp, bases):
    run = _session(tmp, bases)
    return Case(["export", run, "--out", run], [run], says=(str(run),))


@case
def export_over_the_source_dataset(tmp, bases):
    run = _session(tmp, bases)
    source = Path(json.loads((run / "session.json").read_text())["source"]["data_dir"])
    return Case(["export", run, "--out", source], [run, source], says=(str(source),))


@case
def export_from_a_dataset(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(["export", data, "--out", tmp / "out"], [data, tmp], says=("session.json",))


@case
def export_unknown_format(tmp, bases):
    run = _session(tmp, bases)
    return Case(["export", run, "--out", tmp / "out", "--format", "colmap"], [run, tmp], says=("colmap",), usage=True)


# ---- experiments -------------------------------------------------------------------------------

def _run(tmp, bases, *extra, data=None, out=None, says=(), inputs=()) -> Case:
    data = bases.dataset if data is None else data
    out = tmp / "results" if out is None else out
    return Case(["run", "--data", data, "--out", out, *TINY, *extra], [data, *inputs], says=says)


@case
def run_unknown_method(tmp, bases):
    """The issue's example: an unknown method was reported only after training to step 200."""
    return _run(tmp, bases, "--methods", "best-views", says=("best-views",), inputs=[tmp])


@case
def run_method_listed_twice(tmp, bases):
    return _run(tmp, bases, "--methods", "uniform", "uniform", says=("uniform",), inputs=[tmp])


@case
def run_unknown_scene(tmp, bases):
    return Case(["run", "--scenes", "teapot", "--out", tmp / "results", *TINY], [tmp], says=("teapot",))


@case
def run_zero_trials(tmp, bases):
    return _run(tmp, bases, "--trials", "0", says=("--trials", "0"), inputs=[tmp])


@case
def run_negative_trials(tmp, bases):
    return _run(tmp, bases, "--trials", "-1", says=("--trials", "-1"), inputs=[tmp])


@case
def run_steps_below_add_at_step(tmp, bases):
    """The issue's example: views were added at step 20 and never trained on."""
    return _run(tmp, bases, "--steps", "10", says=("--steps", "10"), inputs=[tmp])


@case
def run_zero_resolution(tmp, bases):
    return _run(tmp, bases, "--resolution", "0", says=("--resolution", "0"), inputs=[tmp])


@case
def run_resolution_above_the_source(tmp, bases):
    return _run(tmp, bases, "--resolution", "1000", says=("--resolution", "1000"), inputs=[tmp])


@case
def run_resolution_not_a_whole_factor(tmp, bases):
    return _run(tmp, bases, "--resolution", "3", says=("--resolution", "3"), inputs=[tmp])


@case
def run_negative_seed(tmp, bases):
    return _run(tmp, bases, "--seed", "-1", says=("--seed", "-1"), inputs=[tmp])


@case
def run_zero_workers(tmp, bases):
    return _run(tmp, bases, "--workers", "0", says=("--workers", "0"), inputs=[tmp])


@case
def run_unknown_engine(tmp, bases):
    case = _run(tmp, bases, "--engine", "warp", says=("warp",), inputs=[tmp])
    case.usage = True
    return case


@case
def run_data_missing(tmp, bases):
    return _run(tmp, bases, data=tmp / "nope", says=("nope",), inputs=[tmp])


@case
def run_data_without_test_split(tmp, bases):
    data = _dataset(tmp, bases)
    (data / "transforms_test.json").unlink()
    return _run(tmp, bases, data=data, says=("transforms_test.json",))


@case
def run_data_with_too_few_views(tmp, bases):
    data = make_dataset(tmp / "small", train=4, initial=None)
    return _run(tmp, bases, data=data, says=("transforms_train.json", "4"))


@case
def run_data_initial_split_too_small(tmp, bases):
    data = make_dataset(tmp / "small", initial=2)
    return _run(tmp, bases, data=data, says=("transforms_initial.json", "n-initial"))


@case
def run_data_test_split_too_small(tmp, bases):
    data = make_dataset(tmp / "small", test=1)
    return _run(tmp, bases, data=data, says=("transforms_test.json", "n-test"))


@case
def run_data_path_escapes(tmp, bases):
    data = _dataset(tmp, bases)
    (tmp / "secret.png").write_bytes((data / "train" / "r_0.png").read_bytes())
    _edit_json(data / "transforms_test.json", lambda d: d["frames"][0].update(file_path="../secret"))
    return _run(tmp, bases, data=data, says=("transforms_test.json", "frames[0]"), inputs=[tmp / "secret.png"])


@case
def run_two_scenes_with_one_name(tmp, bases):
    a, b = _dataset(tmp / "a", bases, "ds"), _dataset(tmp / "b", bases, "ds")
    return Case(["run", "--scenes", a, b, "--out", tmp / "results", *TINY], [a, b], says=("ds",))


@case
def run_folder_shadowing_a_builtin_scene(tmp, bases):
    """A folder ./lego must not silently replace the built-in lego scene."""
    copy(bases.dataset, tmp / "lego")
    return Case(["run", "--scenes", "lego", "--out", tmp / "results", *TINY], [tmp / "lego"], cwd=tmp,
                says=("lego", "ambiguous"))


@case
def run_out_is_a_file(tmp, bases):
    (tmp / "out.txt").write_text("x")
    return _run(tmp, bases, out=tmp / "out.txt", says=("out.txt",), inputs=[tmp / "out.txt"])


@case
def run_out_is_a_users_folder(tmp, bases):
    (tmp / "mine").mkdir()
    (tmp / "mine" / "thesis.tex").write_text("keep me")
    return _run(tmp, bases, out=tmp / "mine", says=("mine",), inputs=[tmp / "mine"])


def _results(tmp, bases) -> Path:
    return copy(bases.results, tmp / "results")


@case
def results_sweep_json_deleted(tmp, bases):
    """The issue's example: without sweep.json, another --steps deleted every finished run."""
    results = _results(tmp, bases)
    (results / "sweep.json").unlink()
    return _run(tmp, bases, "--steps", "22", out=results, says=("sweep.json", "--force"), inputs=[results])


@case
def results_sweep_json_truncated(tmp, bases):
    results = _results(tmp, bases)
    text = (results / "sweep.json").read_text()
    (results / "sweep.json").write_text(text[:30])
    return _run(tmp, bases, "--steps", "22", out=results, says=("sweep.json", "--force"), inputs=[results])


@case
def results_changed_steps(tmp, bases):
    results = _results(tmp, bases)
    return _run(tmp, bases, "--steps", "22", out=results, says=("steps", "21", "22", "--force"), inputs=[results])


@case
def results_of_another_dataset(tmp, bases):
    """One results folder never mixes runs of two datasets that share a folder name."""
    results = _results(tmp, bases)
    other = make_dataset(tmp / "elsewhere" / bases.dataset.name, train=11)
    return _run(tmp, bases, data=other, out=results, says=(bases.dataset.name, "dataset"), inputs=[results])


@case
def results_run_folder_with_a_users_file(tmp, bases):
    results = _results(tmp, bases)
    folder = next((results / "runs").glob("*/*/*"))
    (folder / "result.json").unlink()
    (folder / "my_notes.txt").write_text("keep me")
    return _run(tmp, bases, out=results, says=(folder.name,), inputs=[results])


@case
def report_on_a_missing_folder(tmp, bases):
    return Case(["report", tmp / "nope"], [tmp], says=("nope",))


@case
def report_on_a_dataset(tmp, bases):
    data = _dataset(tmp, bases)
    return Case(["report", data], [data], says=(str(data),))
