"""Ctrl-C through the `nerfaug` CLI: long commands keep what they did (periodic and final
checkpoints, finished runs) and end with one line saying what was kept (exit 130).

Ctrl-C is a real SIGINT sent by this process to itself at a chosen training step, so each test
is deterministic: Python runs the handler before the next bytecode of the main thread.
"""

import itertools
import json
import os
import signal

import torch
from cases import TINY
from harness import copy, run_cli, write_images

from nerfaug.capture import CaptureSession
from nerfaug.capture import session as capture_session


def _interrupt_at(monkeypatch, step: int, times: int = 1) -> None:
    """Send SIGINT `times` times once a training chunk ends at `step`."""
    train = CaptureSession.train

    def train_then_interrupt(self, steps, callback=None):
        last = train(self, steps, callback)
        if self.step == step:
            for _ in range(times):
                os.kill(os.getpid(), signal.SIGINT)
        return last

    monkeypatch.setattr(CaptureSession, "train", train_then_interrupt)
    # A clock that advances one second per reading: read once at the start, once after each
    # 10-step chunk and once after each save, so with a 2 s period the session saves every 20 steps.
    monkeypatch.setattr(capture_session, "monotonic", itertools.count().__next__)


def _saved_step(run) -> tuple[int, int]:
    """(step in session.json, step in checkpoint.pt)."""
    state = json.loads((run / "session.json").read_text())
    checkpoint = torch.load(run / "checkpoint.pt", map_location="cpu", weights_only=True)
    return state["step"], int(checkpoint["step"])


def _one_line(outcome) -> str:
    assert not outcome.traceback, outcome.escaped or outcome.err
    assert outcome.code == 130, outcome.err
    lines = outcome.error_lines()
    assert len(lines) == 1, outcome.err
    return lines[0]


def test_first_ctrl_c_saves_the_session_where_training_stopped(bases, tmp_path, monkeypatch):
    run = copy(bases.session, tmp_path / "run")
    start = _saved_step(run)[0]
    _interrupt_at(monkeypatch, start + 30)
    line = _one_line(run_cli(["train", run, "--steps", "100", "--device", "cpu", "--checkpoint-every", "2"]))
    assert f"saved at step {start + 30}" in line and str(run) in line
    assert f"`nerfaug train {run} --steps 100` goes on from there" in line  # the same target
    assert _saved_step(run) == (start + 30, start + 30)
    assert CaptureSession.open(run).step == start + 30


def test_second_ctrl_c_stops_at_once_and_keeps_the_periodic_checkpoint(bases, tmp_path, monkeypatch):
    run = copy(bases.session, tmp_path / "run")
    start = _saved_step(run)[0]
    _interrupt_at(monkeypatch, start + 30, times=2)  # checkpoints every 20 steps: the last one at +20
    line = _one_line(run_cli(["train", run, "--steps", "100", "--device", "cpu", "--checkpoint-every", "2"]))
    assert f"interrupted at step {start + 30}" in line and f"saved at step {start + 20}" in line
    assert _saved_step(run) == (start + 20, start + 20)
    assert CaptureSession.open(run).step == start + 20


def test_ctrl_c_while_training_after_add_keeps_the_added_views(bases, tmp_path, monkeypatch):
    run = copy(bases.session, tmp_path / "run")
    start = _saved_step(run)[0]
    test = json.loads((bases.dataset / "transforms_test.json").read_text())
    names = ["capture_000_00", "capture_000_01"]
    frames = [{"file_path": f"./{n}", "transform_matrix": f["transform_matrix"]} for n, f in zip(names, test["frames"])]
    (tmp_path / "poses.json").write_text(json.dumps({"camera_angle_x": test["camera_angle_x"], "frames": frames}))
    images = write_images(tmp_path / "captures", names)
    _interrupt_at(monkeypatch, start + 10, times=2)  # stopped at once, before any periodic checkpoint
    line = _one_line(
        run_cli(
            ["add", run, "--images", images, "--poses", tmp_path / "poses.json", "--steps", "100", "--device", "cpu"]
            + ["--checkpoint-every", "2"]
        )
    )
    # add's --steps counts from the step it adds at; the command that finishes names the step to reach.
    assert f"`nerfaug train {run} --steps {start + 100}` goes on from there" in line
    state = json.loads((run / "session.json").read_text())
    assert state["additions"][-1]["names"] == names
    session = CaptureSession.open(run)
    assert session.step == start and len(session.trainer.train_views) == 10 + len(names)


def test_ctrl_c_during_a_sweep_keeps_finished_runs_and_resumes(bases, tmp_path, monkeypatch):
    from nerfaug.experiment import sweep

    interrupted_run = 1  # the second run: the first is finished and must be kept

    calls, run_trials = [], sweep.run_trials

    def run_or_interrupt(*args, **kwargs):
        calls.append(args[0])
        if len(calls) == interrupted_run + 1:
            raise KeyboardInterrupt
        return run_trials(*args, **kwargs)

    monkeypatch.setattr(sweep, "run_trials", run_or_interrupt)
    out = tmp_path / "results"
    argv = ["run", "--data", bases.dataset, "--out", out, *TINY, "--trials", "2", "--workers", "1"]
    line = _one_line(run_cli(argv))
    assert str(out) in line and f"{interrupted_run} finished run(s) are kept" in line
    kept = sorted(p.parent.name for p in out.glob("runs/*/*/*/result.json"))
    assert kept == ["trial_000"]

    monkeypatch.setattr(sweep, "run_trials", run_trials)
    again = run_cli(argv)
    assert again.code == 0, again.err
    assert "1 completed run(s) kept, 1 to run" in again.err
    assert len(list(out.glob("runs/*/*/*/result.json"))) == 2
