"""Bad inputs of active capture: `nerfaug train`, `propose`, `add`, `export` and damaged run folders."""

from __future__ import annotations

import json
from pathlib import Path

from cases import Bases, case, copy_dataset, edit_json, train_on
from harness import Case, copy, run_cli, write_images


def _session(tmp, bases) -> Path:
    return copy(bases.session, tmp / "run")


def _propose(run: Path, tmp: Path, *extra) -> list:
    # The cases' sessions train a few steps (an empty NeRF): each case is about another input.
    return [
        "propose",
        run,
        "--out",
        tmp / "poses.json",
        "--n-candidates",
        "12",
        "--device",
        "cpu",
        "--allow-empty",
        *extra,
    ]


def _propose_case(tmp, bases, *extra, says=()) -> Case:
    run = _session(tmp, bases)
    return Case(_propose(run, tmp, *extra), [run], says=says)


def _broken_session(tmp, bases, change, *says) -> Case:
    run = _session(tmp, bases)
    edit_json(run / "session.json", change)
    return Case(_propose(run, tmp), [run], says=("session.json", *says))


@case
def train_into_the_folder_holding_the_dataset(tmp, bases):
    """The issue's data loss: `nerfaug train proj/dataset --out proj` deleted proj/dataset."""
    project = tmp / "proj"
    copy(bases.dataset, project / "dataset")
    return Case(
        ["train", project / "dataset", "--out", project, "--engine", "test", "--steps", "1", "--device", "cpu"],
        [project],
        says=(str(project),),
    )


@case
def train_out_is_the_dataset(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(["train", data, "--out", data, "--engine", "test", "--device", "cpu"], [data], says=(str(data),))


@case
def train_out_is_a_users_folder(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "mine").mkdir()
    (tmp / "mine" / "notes.txt").write_text("keep me")
    (tmp / "mine" / "dataset").mkdir()
    (tmp / "mine" / "dataset" / "photo.png").write_bytes(b"1234")
    return Case(
        ["train", data, "--out", tmp / "mine", "--engine", "test", "--device", "cpu"],
        [data, tmp / "mine"],
        says=("mine",),
    )


@case
def train_out_is_a_file(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "out.txt").write_text("x")
    return Case(
        ["train", data, "--out", tmp / "out.txt", "--engine", "test", "--device", "cpu"],
        [data, tmp / "out.txt"],
        says=("out.txt",),
    )


@case
def train_negative_steps(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--steps", "-1").argv, [data, tmp], says=("--steps", "-1"))


@case
def train_downscale_zero(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--downscale", "0").argv, [data, tmp], says=("downscale", "0"))


@case
def train_downscale_larger_than_images(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--downscale", "100").argv, [data, tmp], says=("downscale", "100"))


@case
def train_unknown_engine(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--engine", "fastest").argv, [data, tmp], says=("fastest",), usage=True)


@case
def train_negative_radius(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--radius", "-1").argv, [data, tmp], says=("radius", "-1"))


@case
def train_zero_up(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--up", "0", "0", "0").argv, [data, tmp], says=("up",))


@case
def train_nan_centre(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--centre", "nan", "0", "0").argv, [data, tmp], says=("centre", "nan"))


@case
def train_negative_seed(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--seed", "-1").argv, [data, tmp], says=("seed", "-1"))


@case
def train_dataset_without_out(tmp, bases):
    data = copy_dataset(tmp, bases)
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
def propose_from_an_empty_nerf(tmp, bases):
    """A NeRF that learned nothing (three steps) says nothing about which views would help."""
    run = _session(tmp, bases)
    argv = [a for a in _propose(run, tmp) if a != "--allow-empty"]
    return Case(argv, [run], code=1, says=("no views proposed", "background only", "--allow-empty"))


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
    return Case(
        ["propose", run, "--out", tmp / "poses.json", "--n-candidates", "0", "--device", "cpu"],
        [run],
        says=("--n-candidates", "0"),
    )


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
    data = copy_dataset(tmp, bases)
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
    record = {
        "number": 0,
        "method": "ours",
        "n": 1,
        "step": 3,
        "seed": 1,
        "candidates": "hemisphere",
        "n_candidates": 12,
        "names": ["capture_000_00"],
        "poses": [],
        "azimuth": [],
        "polar": [],
        "file": "../../elsewhere/proposal.json",
        "created": "now",
    }
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
    frames = [
        {"file_path": f"./{name}", "transform_matrix": frame["transform_matrix"]}
        for name, frame in zip(names, test["frames"])
    ]
    data = {"camera_angle_x": test["camera_angle_x"], "frames": frames}
    if change is not None:
        change(data)
    (tmp / "poses.json").write_text(json.dumps(data))
    return tmp / "poses.json"


def _add(
    tmp, bases, images=None, poses=None, *extra, says=(), image_names=("capture_000_00", "capture_000_01"), size=8
) -> Case:
    run = _session(tmp, bases)
    poses = _poses(tmp, bases) if poses is None else poses
    if images is None:
        images = write_images(tmp / "captures", list(image_names), size=size)
    inputs = [run, poses] + ([images] if Path(images).exists() else [])
    return Case(
        ["add", run, "--images", images, "--poses", poses, "--steps", "1", "--device", "cpu", *extra], inputs, says=says
    )


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
    return _add(tmp, bases, poses=_poses(tmp, bases, names=("r_0", "r_1")), image_names=("r_0", "r_1"), says=("r_0",))


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
    data = copy_dataset(tmp, bases)
    return Case(["export", data, "--out", tmp / "out"], [data, tmp], says=("session.json",))


@case
def export_unknown_format(tmp, bases):
    run = _session(tmp, bases)
    return Case(["export", run, "--out", tmp / "out", "--format", "colmap"], [run, tmp], says=("colmap",), usage=True)


@case
def train_zero_radius(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--radius", "0").argv, [data, tmp], says=("radius", "0"))


@case
def train_steps_not_a_number(tmp, bases):
    run = _session(tmp, bases)
    return Case(["train", run, "--steps", "many", "--device", "cpu"], [run], says=("many",), usage=True)


@case
def propose_negative_seed(tmp, bases):
    return _propose_case(tmp, bases, "--seed", "-1", says=("--seed", "-1"))


@case
def propose_candidates_with_a_nan_pose(tmp, bases):
    test = json.loads((bases.dataset / "transforms_test.json").read_text())
    test["frames"][1]["transform_matrix"][2][2] = float("nan")
    (tmp / "reach.json").write_text(json.dumps(test))
    return _propose_case(tmp, bases, "--candidates", tmp / "reach.json", says=("reach.json", "frames[1]"))


@case
def propose_candidates_all_trained_on(tmp, bases):
    """Candidates the model already trains on are left out: none remain, so nothing is proposed."""
    (tmp / "reach.json").write_text((bases.dataset / "transforms_train.json").read_text())
    return _propose_case(
        tmp, bases, "--candidates", tmp / "reach.json", "--n", "2", says=("reach.json", "0 candidates")
    )


@case
def propose_out_is_the_session_file(tmp, bases):
    run = _session(tmp, bases)
    return Case(
        _propose(run, tmp)[:2] + ["--out", run / "session.json", "--n-candidates", "12", "--device", "cpu"],
        [run],
        says=("session.json",),
    )


@case
def session_json_missing(tmp, bases):
    run = _session(tmp, bases)
    (run / "session.json").unlink()
    return Case(_propose(run, tmp), [run], says=("session.json",))


@case
def session_json_not_an_object(tmp, bases):
    run = _session(tmp, bases)
    (run / "session.json").write_text("[]")
    return Case(_propose(run, tmp), [run], says=("session.json",))


@case
def session_json_step_text(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d.update(step="many"), "step", "many")


@case
def session_json_negative_seed(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d.update(seed=-4), "seed", "-4")


@case
def session_json_hemisphere_nan(tmp, bases):
    return _broken_session(tmp, bases, lambda d: d["hemisphere"].update(radius=float("nan")), "hemisphere", "nan")


@case
def session_dataset_frames_removed(tmp, bases):
    """The run's dataset was edited outside the session: fewer frames than the checkpoint knows."""
    run = _session(tmp, bases)
    edit_json(run / "dataset" / "transforms_train.json", lambda d: d.update(frames=d["frames"][:-1]))
    return Case(["train", run, "--steps", "1", "--device", "cpu"], [run], says=("transforms_train.json", "9", "10"))


@case
def export_with_an_image_deleted(tmp, bases):
    run = _session(tmp, bases)
    (run / "dataset" / "train" / "r_0.png").unlink()
    return Case(["export", run, "--out", tmp / "out"], [run, tmp], says=("transforms_train.json", "frames[0]"))


@case
def export_inside_the_source_dataset(tmp, bases):
    run = _session(tmp, bases)
    return Case(["export", run, "--out", bases.dataset / "exported"], [run], says=("exported", "source dataset"))


@case
def add_two_poses_with_one_name(tmp, bases):
    return _add(tmp, bases, poses=_poses(tmp, bases, names=("cap", "cap")), image_names=("cap",), says=("cap",))


@case
def add_pose_not_rigid(tmp, bases):
    def change(d):
        d["frames"][0]["transform_matrix"][0][0] *= 3

    return _add(tmp, bases, poses=_poses(tmp, bases, change=change), says=("poses.json", "frames[0]"))


@case
def add_to_a_dataset_folder(tmp, bases):
    data = copy_dataset(tmp, bases)
    case = _add(tmp, bases)
    case.argv[1] = data
    case.inputs.append(data)
    case.says = ("session.json",)
    return case


def _render_proposals(tmp, bases, *extra, says=()) -> Case:
    run = _session(tmp, bases)
    poses = _poses(tmp, bases)
    return Case(
        ["render-proposals", run, "--poses", poses, "--scene", "lego", "--out", tmp / "renders", *extra],
        [run, poses],
        says=says,
    )


@case
def render_proposals_zero_samples(tmp, bases):
    return _render_proposals(tmp, bases, "--samples", "0", says=("--samples", "0"))


@case
def render_proposals_poses_missing(tmp, bases):
    case = _render_proposals(tmp, bases, says=("nope.json",))
    case.argv[3] = tmp / "nope.json"
    return case


def _train_session_with(tmp, bases, options: list[str], says: tuple[str, ...]) -> Case:
    """`nerfaug train RUN` on an existing session (engine test, seed 0, at step 3) with `options`
    that shape a new session: the refusal names the session's step and the command that goes on."""
    run = _session(tmp, bases)
    go_on = f"nerfaug train {run} --steps 10"
    argv = ["train", run, *options, "--steps", "10", "--device", "cpu"]
    return Case(argv, [run], says=(*says, "at step 3", go_on))


@case
def train_session_with_new_session_options(tmp, bases):
    """Settings other than the session's are refused, not silently ignored, on an existing one."""
    options = ["--engine", "paper", "--seed", "3"]
    return _train_session_with(tmp, bases, options, ("--engine paper (the session's: test)", "--seed 3"))


@case
def train_session_with_new_session_options_at_their_defaults(tmp, bases):
    """Given at their default values, settings other than the session's are still given, and
    still refused (those equal to the session's are not named)."""
    options = ["--engine=cpu", "--seed", "0", "--no-estimate-up"]
    return _train_session_with(tmp, bases, options, ("--engine cpu (the session's: test)",))


@case
def train_over_a_session_that_lost_its_session_json(tmp, bases):
    """A tester's data loss: `train DATA --out RUN` over a damaged session rebuilt RUN/dataset,
    deleting the user's notes and the captured images in it."""
    data = copy_dataset(tmp, bases)
    run = _session(tmp, bases)
    (run / "session.json").unlink()
    (run / "dataset" / "my_notes.txt").write_text("mine")
    argv = ["train", data, "--out", run, "--engine", "test", "--steps", "1", "--device", "cpu"]
    return Case(argv, [data, run], says=(str(run), "session.json"))


@case
def checkpoint_copied_from_another_session(tmp, bases):
    run = _session(tmp, bases)
    other = tmp / "other"
    argv = [
        "train",
        bases.dataset,
        "--out",
        other,
        "--engine",
        "test",
        "--steps",
        "2",
        "--seed",
        "1",
        "--device",
        "cpu",
    ]
    outcome = run_cli(argv)
    assert outcome.code == 0, outcome.err
    (run / "checkpoint.pt").write_bytes((other / "checkpoint.pt").read_bytes())
    return Case(["train", run, "--steps", "1", "--device", "cpu"], [run], says=("checkpoint.pt", "another session"))


@case
def captured_image_deleted_before_train(tmp, bases):
    run = _session(tmp, bases)
    image = sorted((run / "dataset" / "train").glob("*.png"))[1]
    image.unlink()
    return Case(["train", run, "--steps", "1", "--device", "cpu"], [run], says=(image.stem, "deleted"))


@case
def captured_image_edited_before_train(tmp, bases):
    run = _session(tmp, bases)
    image = sorted((run / "dataset" / "train").glob("*.png"))[0]
    write_images(tmp / "other", [image.stem])
    image.write_bytes((tmp / "other" / image.name).read_bytes())
    return Case(["train", run, "--steps", "1", "--device", "cpu"], [run], says=(image.name, "changed"))


@case
def transforms_file_linking_outside_the_dataset(tmp, bases):
    data = copy_dataset(tmp, bases)
    (tmp / "elsewhere.json").write_text((data / "transforms_train.json").read_text())
    (data / "transforms_train.json").unlink()
    (data / "transforms_train.json").symlink_to(tmp / "elsewhere.json")
    return Case(train_on(data, tmp, "--split", "train").argv, [data], says=("transforms_train.json", "outside"))


@case
def train_out_inside_the_dataset(tmp, bases):
    data = copy_dataset(tmp, bases)
    argv = ["train", data, "--out", data / "run", "--engine", "test", "--steps", "1", "--device", "cpu"]
    return Case(argv, [data], says=(str(data / "run"), "inside the dataset"))


@case
def train_checkpoint_every_zero(tmp, bases):
    data = copy_dataset(tmp, bases)
    return Case(train_on(data, tmp, "--checkpoint-every", "0").argv, [data, tmp], says=("--checkpoint-every",))


@case
def train_zero_threads(tmp, bases):
    run = _session(tmp, bases)
    return Case(["train", run, "--threads", "0", "--device", "cpu"], [run], says=("--threads", "0"))


@case
def uncertainty_threads_beyond_any_machine(tmp, bases):
    """A thread count beyond the C int torch takes: one line naming the option, not an overflow."""
    run = _session(tmp, bases)
    argv = ["uncertainty", run, "--poses", tmp / "poses.json", "--out", tmp / "maps", "--threads", "1099511627776"]
    return Case(argv, [run, tmp], says=("--threads", "1099511627776"))


@case
def propose_over_an_edited_poses_file(tmp, bases):
    """README: edit transform_matrix to the pose the robot reached; a later propose must not erase that."""
    run = _session(tmp, bases)
    first = run_cli(_propose(run, tmp, "--n", "1"))
    assert first.code == 0, first.err
    edit_json(tmp / "poses.json", lambda d: d["frames"][0]["transform_matrix"][0].__setitem__(3, 0.5))
    return Case(_propose(run, tmp), [run, tmp / "poses.json"], says=("poses.json", "--force"))


@case
def eval_out_over_a_users_file(tmp, bases):
    run = _session(tmp, bases)
    (tmp / "metrics.json").write_text('{"mine": 1}')
    argv = ["eval", run, "--data", bases.dataset, "--out", tmp / "metrics.json", "--device", "cpu"]
    return Case(argv, [run, tmp / "metrics.json"], says=("metrics.json",))


@case
def eval_out_inside_the_dataset(tmp, bases):
    run = _session(tmp, bases)
    data = copy_dataset(tmp, bases)
    argv = ["eval", run, "--data", data, "--out", data / "metrics.json", "--device", "cpu"]
    return Case(argv, [run, data], says=("metrics.json", "inside the dataset"))


@case
def eval_split_missing(tmp, bases):
    run = _session(tmp, bases)
    argv = ["eval", run, "--data", bases.dataset, "--split", "nosuch", "--device", "cpu"]
    return Case(argv, [run], says=("nosuch",))
