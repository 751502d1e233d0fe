"""SIGTERM stops `nerfaug` as Ctrl-C does: `finally` blocks run, so `nerfaug scene render` stops its
Blender render worker (a child process) instead of leaving it running, and exits 143 with one line."""

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [
    pytest.mark.slow,
    pytest.mark.blender,
    pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy (the render worker is Blender)"),
]


def render_workers(pid: int) -> list[int]:
    """Process ids of the render workers (`nerfaug.scenes.worker`) whose parent is `pid` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                command = (entry / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if int(fields[1]) == pid and b"nerfaug.scenes.worker" in command:
                found.append(int(entry.name))
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads child processes from /proc")
def test_sigterm_stops_the_render_worker_with_its_parent(tmp_path):
    command = [sys.executable, "-m", "nerfaug.cli", "scene", "render", "lego", "--out", str(tmp_path / "lego")]
    # Frames slow enough (seconds each) that a worker left behind would still be running when checked:
    # it would die only on its next write to the parent's closed pipe.
    command += ["--res", "400", "--pool", "100", "--test", "10", "--samples", "64"]
    parent = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 120  # a guard against a hang, not a timing assertion
        while time.monotonic() < deadline and parent.poll() is None and not workers:
            workers = render_workers(parent.pid)
            time.sleep(0.1)
        assert workers, f"no render worker started: {parent.poll()}"
        # Once a frame is written the worker renders the next one, writing nothing to its parent
        # for seconds: a worker left behind would live on until that write fails.
        while time.monotonic() < deadline and parent.poll() is None and not any(tmp_path.rglob("*.png")):
            time.sleep(0.1)
        parent.send_signal(signal.SIGTERM)
        code = parent.wait(60)
        err = parent.stderr.read()
        deadline = time.monotonic() + 1  # stopped at once by the parent (SIGKILL), not left to finish a frame
        while time.monotonic() < deadline and any(alive(pid) for pid in workers):
            time.sleep(0.1)
        left = [pid for pid in workers if alive(pid)]
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        for pid in workers:  # never leave Blender running, whatever the outcome
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert not left, f"render worker(s) {left} still running after the parent's SIGTERM"
    assert code == 143, err[-2000:]
    assert err.strip().splitlines()[-1].startswith("nerfaug: stopped (SIGTERM)")
