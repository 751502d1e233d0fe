"""Exit codes and `--debug`: 2 for bad input, 1 for a failure of the work (one line saying to run
again with --debug), and with `--debug` or NERFAUG_DEBUG=1 the traceback instead of the line."""

import pytest
from cases import TINY
from harness import copy, run_cli

from nerfaug.capture import CaptureSession


def test_a_failure_of_the_work_exits_1_with_one_line(bases, tmp_path, monkeypatch):
    def broken(self, steps, callback=None):
        raise RuntimeError("the GPU fell off")

    monkeypatch.setattr(CaptureSession, "train", broken)
    run = copy(bases.session, tmp_path / "run")
    outcome = run_cli(["train", run, "--steps", "5", "--device", "cpu"])
    assert outcome.code == 1 and not outcome.traceback, outcome.err
    (line,) = outcome.error_lines()
    assert "RuntimeError: the GPU fell off" in line and "--debug" in line


def test_a_failed_run_of_a_sweep_exits_1_and_keeps_the_others(bases, tmp_path, monkeypatch):
    from nerfaug.experiment import sweep

    run_trials = sweep.run_trials

    def second_fails(keys, *args, **kwargs):
        if any(key.trial == 1 for key in keys):
            raise RuntimeError("out of memory")
        return run_trials(keys, *args, **kwargs)

    monkeypatch.setattr(sweep, "run_trials", second_fails)
    out = tmp_path / "results"
    outcome = run_cli(["run", "--data", bases.dataset, "--out", out, *TINY, "--trials", "2", "--workers", "1"])
    assert outcome.code == 1 and not outcome.traceback, outcome.err
    assert "1 run(s) failed; re-run the same command to retry them" in outcome.err
    assert [p.parent.name for p in out.glob("runs/*/*/*/result.json")] == ["trial_000"]
    assert "out of memory" in outcome.err


@pytest.mark.parametrize("how", ["flag", "environment"])
def test_debug_shows_the_traceback_instead_of_the_line(bases, tmp_path, monkeypatch, how):
    argv = ["propose", bases.session, "--n", "0", "--out", tmp_path / "p.json"]
    if how == "flag":
        argv.append("--debug")
    else:
        # run_cli clears NERFAUG_DEBUG around the command; main reads it while it runs
        import nerfaug.cli

        main = nerfaug.cli.main

        def main_with_debug(args):
            monkeypatch.setenv("NERFAUG_DEBUG", "1")
            return main(args)

        monkeypatch.setattr(nerfaug.cli, "main", main_with_debug)
    outcome = run_cli(argv)
    assert outcome.escaped is not None and "ValueError: --n 0: must be >= 1" in outcome.escaped
    assert not outcome.error_lines()


def test_a_refused_run_prints_no_plan_before_its_refusal(bases, tmp_path):
    # the size line ("N runs ... about T") is a promise; a setting that is refused must come first
    outcome = run_cli(["run", "--data", bases.dataset, "--out", tmp_path / "r", *TINY, "--resolution", "7"])
    assert outcome.code == 2 and "--resolution 7" in outcome.err, outcome.err
    assert "runs" not in outcome.out and not (tmp_path / "r").exists()
