"""A killed `nerfaug run` leaves no process behind: its pool's workers and multiprocessing's
resource tracker end with it (`nerfaug.experiment.workers`)."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cases import TINY

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads processes from /proc")


def members(session: int) -> dict[int, str]:
    """{pid: command line} of the live (not zombie) processes of a process session."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # ended meanwhile
            continue
        state, _ppid, _group, sid = stat.rsplit(")", 1)[1].split()[:4]
        if int(sid) == session and state != "Z":
            found[int(entry.name)] = cmdline
    return found


def test_killing_a_sweep_ends_its_workers_and_its_resource_tracker(bases, tmp_path):
    # Two runs that outlast the test (later options win over TINY's).
    argv = ["run", "--data", str(bases.dataset), "--out", str(tmp_path / "out"), *TINY]
    argv += ["--trials", "2", "--steps", "100000", "--workers", "2"]
    sweep = subprocess.Popen(
        [sys.executable, "-m", "nerfaug.cli", *argv],
        start_new_session=True,  # its session holds it and every process it starts
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 120
        while True:
            children = [cmd for pid, cmd in members(sweep.pid).items() if pid != sweep.pid]
            workers = [cmd for cmd in children if "spawn_main" in cmd]
            trackers = [cmd for cmd in children if "resource_tracker" in cmd]
            if len(workers) == 2 and trackers:
                break
            assert sweep.poll() is None, sweep.stderr.read().decode()
            assert time.monotonic() < deadline, f"no two workers after 120 s: {children}"
            time.sleep(0.2)
        time.sleep(2.0)  # the workers past their start, into their runs
        os.kill(sweep.pid, signal.SIGKILL)
        sweep.wait()
        deadline = time.monotonic() + 5.0
        while members(sweep.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not members(sweep.pid), members(sweep.pid)
    finally:
        for pid in members(sweep.pid):  # the test's own clean-up where the check above failed
            os.kill(pid, signal.SIGKILL)
        if sweep.poll() is None:
            sweep.kill()
            sweep.wait()
        sweep.stderr.close()


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_or_ctrl_c_stops_a_sweep_at_once_and_ends_its_workers(bases, tmp_path, stop):
    """A stopped sweep does not wait for its running runs (which would take minutes here): it
    kills its workers, exits with the signal's code and one line, and leaves no process behind."""
    argv = ["run", "--data", str(bases.dataset), "--out", str(tmp_path / "out"), *TINY]
    argv += ["--trials", "2", "--steps", "100000", "--workers", "2"]
    sweep = subprocess.Popen(
        [sys.executable, "-m", "nerfaug.cli", *argv],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 120
        while len([cmd for cmd in members(sweep.pid).values() if "spawn_main" in cmd]) < 2:
            assert sweep.poll() is None, sweep.stderr.read().decode()
            assert time.monotonic() < deadline, "no two workers after 120 s"
            time.sleep(0.2)
        time.sleep(2.0)  # the workers into their runs
        os.kill(sweep.pid, stop)
        code = sweep.wait(30)  # a guard: the runs themselves would take far longer
        err = sweep.stderr.read().decode()
        deadline = time.monotonic() + 5.0
        while members(sweep.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not members(sweep.pid), members(sweep.pid)
    finally:
        for pid in members(sweep.pid):
            os.kill(pid, signal.SIGKILL)
        if sweep.poll() is None:
            sweep.kill()
            sweep.wait()
        sweep.stderr.close()
    assert code == (143 if stop == signal.SIGTERM else 130), err[-2000:]
    why = "stopped (SIGTERM)" if stop == signal.SIGTERM else "interrupted"
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"nerfaug: {tmp_path / 'out'}: {why}; "), last
    assert last.endswith("re-run the same command to resume"), last
