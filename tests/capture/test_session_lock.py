"""Sessions are locked while a command changes them: two `nerfaug train RUN` at once both train
(neither's steps are lost), a command waits for another with one line saying for whom, and a
session an earlier nerfaug saved (no digests) is opened with a warning naming its checkpoint.

Commands run as real processes (the lock is between processes); every wait is bounded."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, SessionSettings, SessionState
from nerfaug.capture.lock import SERVICE, SessionBusy, acquire, describe, holder_of, try_lock
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses


def tiny_dataset(root: Path, n: int = 4, size: int = 8) -> Path:
    generator = torch.Generator().manual_seed(0)
    poses = sample_uniform_poses(n, generator)
    images = torch.rand(n, size, size, 3, generator=generator)
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)
    write_blender_split(root, "train", Views(cameras, images, [f"./train/r_{i}" for i in range(n)]))
    return root


@pytest.fixture
def run(tmp_path) -> Path:
    CaptureSession.create(tiny_dataset(tmp_path / "data"), tmp_path / "run", SessionSettings(engine="test", seed=2))
    return tmp_path / "run"


def nerfaug(*argv) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    command = [sys.executable, "-m", "nerfaug.cli", *map(str, argv)]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def test_a_second_holder_is_refused_or_waits_and_is_told_whom_for(run):
    with acquire(run, "nerfaug train") as held:
        assert try_lock(run, "nerfaug propose") is None
        assert holder_of(run)["holder"] == "nerfaug train" and holder_of(run)["pid"] == os.getpid()
        with pytest.raises(SessionBusy, match="`nerfaug train` \\(pid"):
            acquire(run, "nerfaug propose", wait=False)
        told = []
        with pytest.raises(SessionBusy, match="try again"):
            acquire(run, "nerfaug propose", timeout=0.5, on_wait=told.append)
        assert len(told) == 1 and told[0].startswith("waiting for `nerfaug train`")
        assert held.handle is not None
    with acquire(run, SERVICE):
        with pytest.raises(SessionBusy, match="HTTP API"):  # a command never waits for a service
            acquire(run, "nerfaug train", wait=True, timeout=60)
    assert describe({}) == "another process"


@pytest.mark.slow
def test_a_command_waits_for_the_command_changing_the_session(run):
    with acquire(run, "nerfaug add"):
        waiting = nerfaug("train", run, "--steps", "2", "--device", "cpu")
        line, deadline = "", time.monotonic() + 240
        while "waiting for" not in line and time.monotonic() < deadline and waiting.poll() is None:
            line = waiting.stderr.readline()
        assert "waiting for `nerfaug add`" in line and str(os.getpid()) in line, line
        time.sleep(0.5)
        assert waiting.poll() is None  # still waiting while the lock is held
    out, err = waiting.communicate(timeout=300)
    assert waiting.returncode == 0, err
    assert SessionState.read(run).step == 2


@pytest.mark.slow
def test_two_trains_of_one_session_at_once_both_reach_their_step(run):
    """`--steps N` is the step to reach: two trains of one session at once, to 60 and to 120, end
    at 120 whichever takes the lock first (the other waits, then goes on from the first's save or
    finds its step reached), each exiting 0, and the session opens at that step."""
    first, second = (nerfaug("train", run, "--steps", steps, "--device", "cpu") for steps in ("60", "120"))
    for process in (first, second):
        _, err = process.communicate(timeout=600)
        assert process.returncode == 0, err
    assert SessionState.read(run).step == 120
    assert CaptureSession.open(run).step == 120


def test_a_train_that_waited_finds_its_step_reached_by_the_holder(run):
    """The order the test above leaves to chance, made certain: `train --steps 60` waits while this
    process holds the session and trains it to 120; once let in, it says its step is reached."""
    with acquire(run, "nerfaug train"):
        waiting = nerfaug("train", run, "--steps", "60", "--device", "cpu")
        deadline = time.monotonic() + 120
        while "waiting for" not in (line := waiting.stderr.readline()) and time.monotonic() < deadline:
            assert line, "the second command ended before it waited"
        session = CaptureSession.open(run)
        session.train(120 - session.step)
        session.save()
    out, err = waiting.communicate(timeout=600)
    assert waiting.returncode == 0, err
    assert "already at step 120 (--steps 60)" in out
    assert SessionState.read(run).step == 120


def test_a_session_saved_before_digests_opens_with_a_warning_naming_its_checkpoint(run):
    data = json.loads((run / "session.json").read_text())
    data.pop("integrity")
    (run / "session.json").write_text(json.dumps(data))
    with pytest.warns(UserWarning, match="checkpoint.pt: session.json records no digest"):
        session = CaptureSession.open(run)
    session.save()  # records the digest, although the model did not change: no warning from now on
    assert json.loads((run / "session.json").read_text())["integrity"]["checkpoint"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        CaptureSession.open(run)


def test_a_command_scope_releases_what_it_held_and_holding_twice_does_not_wait(run):
    from nerfaug.capture.lock import command_scope, hold

    with command_scope():
        first = hold(run, "nerfaug train", wait=False)
        assert hold(run, "nerfaug propose", wait=False) is first  # this process holds it already
        assert try_lock(run, "other") is None
    lock = try_lock(run, "other")
    assert lock is not None
    lock.release()
