"""The whole protocol at toy size: files, resume after a kill, Ray == local."""

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.store import RunKey, read_result
from nerfaug.experiment.sweep import run_sweep

pytestmark = [pytest.mark.slow]


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    """The built-in lego at toy size, rendered once for the module (used as a user dataset)."""
    if importlib.util.find_spec("bpy") is None:  # not importorskip: bpy stays out of this process
        pytest.skip("bpy is not installed")
    from nerfaug.scenes import render_scene_dataset

    config = PROTOCOL_PRESETS.choose("tiny")
    out = tmp_path_factory.mktemp("scene") / "lego"
    return render_scene_dataset(
        "lego",
        out,
        resolution=config.resolution,
        pool=config.pool,
        test=config.n_test,
        initial=config.n_initial,
        samples=config.render_samples,
        seed=0,
        progress=False,
    )


def tiny_config(scene: Path, **changes):
    return PROTOCOL_PRESETS.choose("tiny").replace(scenes=(str(scene),), **changes)


def test_tiny_sweep_writes_every_file_and_a_report(tiny_scene, tmp_path):
    from nerfaug.cli.run_work import paper_tables
    from nerfaug.report import write_report

    config = tiny_config(tiny_scene)
    outcome = run_sweep(config, tmp_path, progress=False)
    assert not outcome.failed and len(outcome.results) == 4
    for key in (RunKey("lego", m, t) for m in config.methods for t in range(config.trials)):
        folder = key.folder(tmp_path)
        for name in ("result.json", "selection.json", "metrics.json", "history.json", "config.json", "uncertainty.png"):
            assert (folder / name).is_file(), f"{folder / name} missing"
        result = read_result(folder)
        assert 5.0 < result["metrics"]["psnr"] < 60.0
        selection = json.loads((folder / "selection.json").read_text())
        assert len(selection["chosen_poses"]) == config.n_new
        assert len(selection["scores"]) == config.pool
        assert len(set(selection["indices"])) == config.n_new  # never the same view twice
    paths = write_report(tmp_path, paper_tables())
    assert any(p.name == "report.html" for p in paths) and (tmp_path / "report.md").is_file()
    # A second identical sweep computes nothing.
    again = run_sweep(config, tmp_path, progress=False)
    assert again.skipped == 4 and len(again.results) == 4


def test_killed_sweep_resumes_without_recomputing(tiny_scene, tmp_path):
    out = tmp_path / "out"
    command = [
        sys.executable,
        "-m",
        "nerfaug.cli",
        "run",
        "--preset",
        "tiny",
        "--data",
        str(tiny_scene),
        "--out",
        str(out),
        "--trials",
        "3",
        "--no-report",
    ]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen(
        command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    deadline = time.time() + 300
    while time.time() < deadline and len(list(out.glob("runs/*/*/*/result.json"))) < 2:
        time.sleep(0.2)
    os.killpg(process.pid, signal.SIGKILL)  # mid-sweep: some runs done, one in flight
    process.wait()
    finished = {p: p.stat().st_mtime_ns for p in out.glob("runs/*/*/*/result.json")}
    assert 2 <= len(finished) < 6, "the kill should land mid-sweep"

    subprocess.run(command, env=env, check=True, capture_output=True, timeout=600)
    results = list(out.glob("runs/*/*/*/result.json"))
    assert len(results) == 6
    for path, mtime in finished.items():
        assert path.stat().st_mtime_ns == mtime, f"{path} was recomputed"


def test_corrupted_run_is_redone_not_aggregated(tiny_scene, tmp_path):
    config = tiny_config(tiny_scene, methods=("uniform",), trials=1)
    first = run_sweep(config, tmp_path, progress=False)
    path = RunKey("lego", "uniform", 0).folder(tmp_path) / "result.json"
    path.write_text(path.read_text()[:40])  # truncated, as by a disk-full write
    second = run_sweep(config, tmp_path, progress=False)
    assert second.skipped == 0 and len(second.results) == 1
    assert second.results[0]["metrics"] == first.results[0]["metrics"]  # deterministic redo


@pytest.mark.ray
def test_ray_backend_matches_local(tiny_scene, tmp_path):
    pytest.importorskip("ray")
    config = tiny_config(tiny_scene, trials=1)
    local = run_sweep(config, tmp_path / "local", progress=False)
    remote = run_sweep(config, tmp_path / "ray", backend="ray", workers=1, progress=False)
    assert not remote.failed

    def by_key(results):
        return {(r["method"], r["trial"]): r for r in results}

    local_results, ray_results = by_key(local.results), by_key(remote.results)
    assert local_results.keys() == ray_results.keys()
    for key in local_results:
        assert ray_results[key]["metrics"] == local_results[key]["metrics"]
        assert ray_results[key]["chosen"] == local_results[key]["chosen"]
