"""`nerfaug train/add/eval` beyond the bad inputs of tests/reliability: which split a new session
trains on, warnings for repeated views, the thread policy, `--steps` as the step to reach, a
SIGKILLed `train` resumed by the same command, settings other than the session's refused with the
command that goes on, a save interrupted between its two writes, and `eval` on a known case."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession
from nerfaug.cli import main
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

SIZE = 8


def views(n: int, seed: int, poses=None) -> Views:
    generator = torch.Generator().manual_seed(seed)
    poses = sample_uniform_poses(n, generator) if poses is None else poses
    images = (torch.rand(n, SIZE, SIZE, 3, generator=generator) * 255).round() / 255
    return Views(Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE), images, [f"./x/r_{i}" for i in range(n)])


def dataset(root: Path, rendered: bool = True, train=None) -> Path:
    """A Blender dataset with a 12-view train split and a 3-view initial split; `rendered` adds the
    manifest `nerfaug scene render` writes."""
    write_blender_split(root, "train", views(12, 0) if train is None else train)
    write_blender_split(root, "initial", views(3, 1))
    write_blender_split(root, "test", views(3, 2))
    if rendered:
        (root / "scene.json").write_text(json.dumps({"format": 1, "scene": {"builtin": "lego"}}))
    return root


def train_new(data: Path, run: Path, *extra) -> None:
    main(["train", str(data), "--out", str(run), "--engine", "test", "--steps", "2", "--device", "cpu", *extra])


@pytest.mark.parametrize(
    ("rendered", "extra", "expected"),
    [(True, (), 3), (True, ("--split", "train"), 12), (False, (), 12)],
)
def test_a_new_session_trains_on_a_rendered_scenes_initial_views(tmp_path, capsys, rendered, extra, expected):
    data = dataset(tmp_path / "data", rendered)
    train_new(data, tmp_path / "run", *extra)
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith(f"training on {expected} views: ")
    assert ("initial views" in first) == (expected == 3)
    assert len(CaptureSession.open(tmp_path / "run").trainer.train_views) == expected


def test_duplicate_frames_in_a_dataset_are_named_in_a_warning(tmp_path, capsys):
    poses = views(12, 0).cameras.camera_to_world.clone()
    poses[7] = poses[2]
    data = dataset(tmp_path / "data", rendered=False, train=views(12, 0, poses))
    train_new(data, tmp_path / "run")
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1
    assert all(name in warnings[0] for name in ("r_2", "r_7", "transforms_train.json"))


def test_the_same_view_added_twice_is_named_in_a_warning(tmp_path, capsys):
    data = dataset(tmp_path / "data", rendered=False)
    run = tmp_path / "run"
    train_new(data, run)
    frames = json.loads((run / "dataset" / "transforms_train.json").read_text())["frames"]
    new = [frames[4]["transform_matrix"], frames[4]["transform_matrix"]]  # already there, and twice
    poses = {"camera_angle_x": BLENDER_CAMERA_ANGLE_X, "frames": [{"file_path": f"./new_{i}"} for i in range(2)]}
    for frame, matrix in zip(poses["frames"], new):
        frame["transform_matrix"] = matrix
    (tmp_path / "poses.json").write_text(json.dumps(poses))
    captures = tmp_path / "captures"
    captures.mkdir()
    for i in range(2):
        iio.imwrite(captures / f"new_{i}.png", np.full((SIZE, SIZE, 3), 100 + i, np.uint8))
    capsys.readouterr()
    main(["add", str(run), "--images", str(captures), "--poses", str(tmp_path / "poses.json"), "--steps", "0"])
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    stem = Path(frames[4]["file_path"]).stem
    assert any("new_0" in w and stem in w for w in warnings), warnings
    assert any("new_1" in w and "new_0" in w for w in warnings), warnings


def test_session_training_takes_one_torch_thread_unless_told(tmp_path, monkeypatch):
    import nerfaug.cli.train_work

    calls = []
    monkeypatch.setattr(nerfaug.cli.train_work, "configure_process", lambda threads=None: calls.append(threads))
    data = dataset(tmp_path / "data")
    train_new(data, tmp_path / "run")
    main(["train", str(tmp_path / "run"), "--steps", "3", "--threads", "2", "--device", "cpu"])
    assert calls == [1, 2]


def test_a_session_saved_between_its_two_writes_still_opens(tmp_path):
    """`save` records the new checkpoint's digest as pending before replacing the file: a process
    killed after session.json but before the checkpoint keeps a checkpoint the session knows."""
    run = tmp_path / "run"
    train_new(dataset(tmp_path / "data"), run)
    state = json.loads((run / "session.json").read_text())
    state["integrity"]["pending"], state["integrity"]["checkpoint"] = state["integrity"]["checkpoint"], "0" * 64
    (run / "session.json").write_text(json.dumps(state))
    assert CaptureSession.open(run).step == 2


def nerfaug(*argv, check: bool = True) -> subprocess.CompletedProcess:
    """`nerfaug ARGV` as a real process (bounded in time: a guard against a hang)."""
    command = [sys.executable, "-m", "nerfaug.cli", *map(str, argv)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert not check or done.returncode == 0, done.stderr
    return done


@pytest.mark.slow
def test_a_killed_train_resumes_with_the_same_command_and_stops_at_the_requested_step(tmp_path):
    """A real SIGKILL of `nerfaug train DATA --out RUN --steps N` once a periodic checkpoint is on
    disk: the same command resumes from that save, says so, and ends at step N; once more, it only
    says the session is there already."""
    # Enough steps that a loaded machine still finds the child running after its first save.
    data, run, target = dataset(tmp_path / "data"), tmp_path / "run", 1500
    argv = ["train", data, "--out", run, "--engine", "test", "--steps", target, "--device", "cpu"]
    argv += ["--checkpoint-every", "0.2"]
    child = subprocess.Popen(
        [sys.executable, "-m", "nerfaug.cli", *map(str, argv)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        deadline = time.monotonic() + 300  # a guard against a hang, not a timing assertion
        while time.monotonic() < deadline and child.poll() is None:
            try:
                state = json.loads((run / "session.json").read_text())
                if state["step"] > 0 and state["integrity"]["pending"] is None:  # a first save, complete
                    break
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.05)
        assert child.poll() is None, child.stderr.read().decode()
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait()
    # The save the session holds: a kill between a save's two writes (session.json, then the
    # checkpoint) leaves the checkpoint before it, which the session recognises and resumes from.
    saved = CaptureSession.open(run).step
    assert 0 < saved < target

    again = nerfaug(*argv)
    assert f"resuming from step {saved}, its last save, until step {target}" in again.stdout
    assert f"step {target}" in again.stdout.splitlines()[-1]
    assert CaptureSession.open(run).step == target

    checkpoint = (run / "checkpoint.pt").read_bytes()
    once_more = nerfaug(*argv)
    assert f"already at step {target}" in once_more.stdout and "nothing to do" in once_more.stdout
    assert (run / "checkpoint.pt").read_bytes() == checkpoint


def test_train_steps_is_the_step_to_reach_not_steps_to_add(tmp_path, capsys):
    run = tmp_path / "run"
    train_new(dataset(tmp_path / "data"), run)  # until step 2
    main(["train", str(run), "--steps", "5", "--device", "cpu"])
    assert "training from step 2, its last save, until step 5" in capsys.readouterr().out
    assert CaptureSession.open(run).step == 5
    main(["train", str(run), "--steps", "3", "--device", "cpu"])
    assert "already at step 5 (--steps 3); nothing to do" in capsys.readouterr().out
    assert CaptureSession.open(run).step == 5


def test_the_same_command_with_other_settings_is_refused_naming_the_command_that_goes_on(tmp_path, capsys):
    data, run = dataset(tmp_path / "data"), tmp_path / "run"
    train_new(data, run)
    before = (run / "session.json").read_text()
    capsys.readouterr()
    argv = ["train", str(data), "--out", str(run), "--engine", "test", "--steps", "9", "--device", "cpu"]
    with pytest.raises(SystemExit) as refused:
        main([*argv, "--seed", "4", "--downscale", "2"])
    assert refused.value.code == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1
    assert "--seed 4 (the session's: 0)" in error and "--downscale 2 (the session's: 1)" in error
    assert "(at step 2)" in error and f"`nerfaug train {run} --steps 9`" in error
    assert "CaptureSession" not in error and "--engine" not in error  # the engine is the session's
    assert (run / "session.json").read_text() == before
    # A run folder as the path: options equal to the session's are fine, others refused.
    main(["train", str(run), "--engine", "test", "--seed", "0", "--steps", "3", "--device", "cpu"])
    assert CaptureSession.open(run).step == 3
    with pytest.raises(SystemExit):
        main(["train", str(run), "--engine", "cpu", "--steps", "4", "--device", "cpu"])
    assert "--engine cpu (the session's: test)" in capsys.readouterr().err


def test_a_setting_given_at_its_default_value_is_still_compared_with_the_sessions(tmp_path, capsys):
    """`--seed 0` is the default, yet given: a session seeded 4 refuses it; `--no-estimate-up`,
    also the default and equal to the session's, is not named."""
    run = tmp_path / "run"
    train_new(dataset(tmp_path / "data"), run, "--seed", "4")
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:
        main(["train", str(run), "--seed", "0", "--no-estimate-up", "--steps", "3", "--device", "cpu"])
    assert refused.value.code == 2
    error = capsys.readouterr().err
    assert "--seed 0 (the session's: 4)" in error and "estimate-up" not in error
    assert CaptureSession.open(run).step == 2
    main(["train", str(run), "--steps", "3", "--device", "cpu"])  # nothing given: the session's own settings
    assert CaptureSession.open(run).step == 3


@pytest.mark.parametrize(
    "command",
    [
        ["train", "RUN", "--steps", "1", "--device", "cpu"],
        ["add", "RUN", "--images", "DIR", "--poses", "POSES", "--device", "cpu"],
        ["propose", "RUN", "--device", "cpu"],
        ["eval", "RUN", "--data", "DIR", "--device", "cpu"],
        ["uncertainty", "RUN", "--poses", "POSES", "--out", "OUT", "--device", "cpu"],
        ["render-proposals", "RUN", "--poses", "POSES", "--scene", "lego", "--out", "OUT"],
        ["serve", "--root", "ROOT", "--device", "cpu"],
    ],
)
def test_every_command_refuses_threads_below_one_in_one_line_before_any_read(command, tmp_path, capsys):
    paths = [str(tmp_path / arg) if arg.isupper() else arg for arg in command]
    with pytest.raises(SystemExit) as refused:
        main([*paths, "--threads", "0"])
    assert refused.value.code == 2
    assert capsys.readouterr().err.strip() == "nerfaug: --threads 0: must be >= 1"
    assert not any(tmp_path.iterdir())


def test_train_threads_policy_agrees_with_a_sweeps():
    from nerfaug.cli.train import THREADS
    from nerfaug.experiment.config import ExperimentConfig

    assert ExperimentConfig().threads_per_run == THREADS


def test_eval_scores_renders_of_the_nerf_itself_as_near_perfect(tmp_path, capsys):
    """The known case: a test split made of the session's own renders (8-bit PNGs) differs from
    them by quantisation alone, so PSNR >= 20 log10(510) = 54.2 dB and SSIM > 0.99."""
    run = tmp_path / "run"
    train_new(dataset(tmp_path / "data"), run)
    session = CaptureSession.open(run)
    poses = sample_uniform_poses(3, torch.Generator().manual_seed(5))
    renders = (session.render(poses) * 255).round() / 255
    own = tmp_path / "own"
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    write_blender_split(own, "test", Views(cameras, renders, [f"./x/own_{i}" for i in range(3)]))
    write_blender_split(own, "noise", views(3, 9, poses))
    out = tmp_path / "metrics.json"
    capsys.readouterr()
    main(["eval", str(run), "--data", str(own), "--out", str(out), "--device", "cpu"])
    printed = capsys.readouterr().out
    result = json.loads(out.read_text())
    assert result["step"] == 2 and len(result["per_view"]) == 3
    assert min(v["psnr"] for v in result["per_view"]) > 54.0
    assert result["mean"]["ssim"] > 0.99
    assert f"PSNR {result['mean']['psnr']:.2f} dB" in printed
    # Random images at the same poses score far worse; eval's own JSON may be overwritten.
    main(["eval", str(run), "--data", str(own), "--split", "noise", "--out", str(out), "--device", "cpu"])
    assert json.loads(out.read_text())["mean"]["psnr"] < 20.0


def test_an_estimated_pole_is_one_setting_of_the_session(tmp_path, capsys):
    data, run = dataset(tmp_path / "data"), tmp_path / "run"
    train_new(data, run, "--estimate-up")
    capsys.readouterr()
    argv = ["train", str(data), "--out", str(run), "--engine", "test", "--steps", "2", "--device", "cpu"]
    with pytest.raises(SystemExit):
        main(argv)  # the same command without --estimate-up: one difference, named once
    error = capsys.readouterr().err
    assert "--estimate-up off (the session's: on)" in error and "--up" not in error
    main([*argv, "--estimate-up"])  # the same command: at step 2 already
    assert "already at step 2" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["train", str(run), "--up", "0", "0", "1", "--steps", "3", "--device", "cpu"])
    assert "--up 0 0 1 (the session's: estimated)" in capsys.readouterr().err


def test_a_proposal_drawn_partly_uniformly_says_so_in_one_line(capsys):
    """`propose` shows the sampler's fill (the model gave too few candidates a positive score) as
    one `warning:` line, not Python's two-line warning with a source path."""
    import torch

    from nerfaug.cameras import Cameras
    from nerfaug.cli.train_work import warning_lines
    from nerfaug.hemisphere import half_hemisphere_poses
    from nerfaug.selection import SelectionConfig
    from nerfaug.selection.interface import Estimate, Request
    from nerfaug.selection.selectors import sample_views

    cameras = Cameras.from_fov(half_hemisphere_poses(8), BLENDER_CAMERA_ANGLE_X, 8, 8)
    request = Request(
        "fisherrf-sampling", None, cameras, cameras, 3, torch.Generator().manual_seed(0), SelectionConfig()
    )
    capsys.readouterr()
    with warning_lines():
        _, estimate = sample_views(request, Estimate(torch.tensor([0.0, 2.0, 0, 0, 0, 0, 0, 0])))
    assert estimate.uniform_fill == 2
    assert capsys.readouterr().err.splitlines() == [
        "warning: method 'fisherrf-sampling': 1 of 8 eligible candidates score above 0, fewer than the 3 views "
        "asked for, so 2 views are drawn uniformly from the others (the model gives them no information to choose by)"
    ]


def test_a_proposal_whose_sampler_drew_directly_says_so_in_one_line(capsys):
    """`propose` shows the sampler's direct draw after `max_draws` (one candidate holds nearly all
    the score) as one `warning:` line, and the views are still distinct."""
    import torch

    from nerfaug.cameras import Cameras
    from nerfaug.cli.train_work import warning_lines
    from nerfaug.hemisphere import half_hemisphere_poses
    from nerfaug.selection import SelectionConfig
    from nerfaug.selection.interface import Estimate, Request
    from nerfaug.selection.selectors import sample_views

    cameras = Cameras.from_fov(half_hemisphere_poses(8), BLENDER_CAMERA_ANGLE_X, 8, 8)
    config = SelectionConfig(max_draws=1000)
    request = Request("fisherrf-sampling", None, cameras, cameras, 3, torch.Generator().manual_seed(0), config)
    capsys.readouterr()
    with warning_lines():
        indices, _ = sample_views(
            request, Estimate(torch.tensor([1.0, 1e-12, 2e-12, 3e-12, 1e-12, 1e-12, 1e-12, 1e-12]))
        )
    assert len(set(indices.tolist())) == 3 and indices[0] == 0
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("warning: rejection sampling accepted 1 of 3 views in 1000 draws")
