"""benchmarks/bench_service_load.py end to end at toy size: a server under two clients for a few
seconds, training throughout, every kind of request answered and reported, no 5xx."""

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow]
SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_service_load.py"
TOY = ["--clients", "2", "--sessions", "1", "--duration", "6", "--size", "8", "--views", "4"]
TOY += ["--candidates", "16", "--entropy-resolution", "4", "--propose-every", "2", "--capture-every", "2"]


def test_the_load_benchmark_runs_at_toy_size(tmp_path):
    if importlib.util.find_spec("fastapi") is None:
        pytest.skip("needs the service's packages")
    done = subprocess.run(
        [sys.executable, str(SCRIPT), *TOY, "--out", str(tmp_path / "out")],
        cwd=tmp_path,
        env={**os.environ, "MPLBACKEND": "Agg"},
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads((tmp_path / "out" / "bench_service_load.json").read_text())
    kinds = record["kinds"]
    assert {"state", "health", "proposal", "capture"} <= set(kinds)
    assert kinds["state"]["ok"] > 0 and kinds["health"]["ok"] > 0 and kinds["capture"]["ok"] > 0
    assert 0 < kinds["health"]["p50_ms"] <= kinds["health"]["p99_ms"] <= kinds["health"]["max_ms"]
    assert record["server_errors_5xx"] == 0 and record["transport_errors"] == 0
    assert record["server_rss_mb"]["peak"] > 0 and record["training_steps_reached"]["load0"] > 0
    assert "p99" in done.stdout
