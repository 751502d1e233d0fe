"""benchmarks/bench_service.py end to end at toy size: a service started and stopped, the same
proposal over HTTP and in process (the same poses), and the example loop's PSNR per round."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow]
SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_service.py"
TOY = ["--resolution", "24", "--samples", "2", "--engine", "test", "--steps", "10", "--candidates", "20"]
TOY += ["--entropy-resolution", "4", "--repeat", "2", "--rounds", "1", "--views-per-round", "2"]
TOY += ["--steps-per-round", "10", "--eval-views", "2", "--status-steps", "300", "--status-polls", "3"]


def test_the_service_benchmark_runs_at_toy_size(tmp_path):
    if importlib.util.find_spec("bpy") is None or importlib.util.find_spec("fastapi") is None:
        pytest.skip("needs bpy and the service's packages")
    env = {**os.environ, "MPLBACKEND": "Agg"}
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *TOY, "--out", str(tmp_path / "out")],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads((tmp_path / "out" / "bench_service.json").read_text())
    propose = record["propose"]
    assert propose["same_poses"] and propose["step"] == 10
    assert len(propose["times_s"]["http"]) == len(propose["times_s"]["in_process"]) == 2
    assert propose["ratio"] == pytest.approx(propose["median_s"]["http"] / propose["median_s"]["in_process"])
    status = propose["status_while_training"]
    assert status["polls"] == 3 and 0 < status["state"]["median_s"] <= status["state"]["max_s"]
    assert status["health"]["max_s"] > 0 and "while training" in done.stdout
    assert [(r["round"], r["views"]) for r in record["loop"]["rounds"]] == [(0, 6), (1, 8)]
    assert "ratio" in done.stdout and "loop round 1" in done.stdout
