"""benchmarks/bench_hash_cpu.py at toy size: runs of the study protocol on each CPU engine version
chosen, alternating, each recording the version it ran, with each arm's ratio to the reference's
runs per core-hour; the process's choice of kernels restored afterwards."""

import json
import os
from pathlib import Path

import pytest
import torch

from nerfaug.data import write_blender_split
from nerfaug.hemisphere import sample_uniform_poses
from nerfaug.nerf import hash_cpu, sampler_cpu
from nerfaug.nerf.encoding import HashEncoding
from nerfaug.scenes.sphere import sphere_views

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_hash_cpu.py"


@pytest.mark.slow
@pytest.mark.skipif(not (hash_cpu.available() and sampler_cpu.available()), reason="no C compiler")
def test_every_engine_version_runs_the_protocol_and_is_compared_with_the_reference(bench, tmp_path):
    # the protocol's 6 initial views chosen from a pool of 14, 6 added, 50 test views: no initial split
    dataset = tmp_path / "sphere"
    write_blender_split(dataset, "train", sphere_views(sample_uniform_poses(14, torch.Generator().manual_seed(0)), "r"))
    write_blender_split(dataset, "test", sphere_views(sample_uniform_poses(50, torch.Generator().manual_seed(1)), "t"))
    chosen = (HashEncoding.default_kernel, sampler_cpu.MODE)
    environment = {name: os.environ.get(name) for name in ("NERFAUG_HASH_KERNEL", "NERFAUG_CPU_KERNELS")}
    argv = ["--data", str(dataset), "--runs", "1", "--steps", "201", "--step-repeats", "0", "--resolution", "24"]
    assert bench.main([*argv, "--out", str(tmp_path / "runs"), "--json", str(tmp_path / "f.json")]) == 0
    # the process's own choice back, and no later test's processes inherit the last arm
    assert (HashEncoding.default_kernel, sampler_cpu.MODE) == chosen
    assert {name: os.environ.get(name) for name in environment} == environment
    arms = json.loads((tmp_path / "f.json").read_text())["arms"]
    assert list(arms) == ["reference", "hash-cpu-1", "cpu-fused-3"]
    versions = [[r["engine_version"] for r in arm["records"]] for arm in arms.values()]
    assert versions == [[None], ["hash-cpu-1"], ["cpu-fused-3"]]
    assert arms["reference"]["runs_per_core_hour_ratio"] == 1.0
    for arm in arms.values():
        assert arm["cpu_s"] > 0 and arm["runs"] == 1
        ratio = arm["runs_per_core_hour"] / arms["reference"]["runs_per_core_hour"]
        assert arm["runs_per_core_hour_ratio"] == pytest.approx(ratio)


def test_the_reference_must_be_an_arm(bench, tmp_path, capsys):
    with pytest.raises(SystemExit) as refused:
        bench.main(["--data", str(tmp_path), "--out", str(tmp_path), "--arms", "cpu-fused-3"])
    assert refused.value.code == 2
    assert "--arms must include reference" in capsys.readouterr().err
