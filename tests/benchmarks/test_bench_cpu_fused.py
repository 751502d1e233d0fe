"""benchmarks/bench_cpu_fused.py at toy size: each arm times its own engine version, alternating,
and the process's choice of kernels is restored afterwards."""

from pathlib import Path

import pytest

from nerfaug.nerf import hash_cpu, sampler_cpu
from nerfaug.nerf.encoding import HashEncoding

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_cpu_fused.py"


@pytest.mark.skipif(not (hash_cpu.available() and sampler_cpu.available()), reason="no C compiler")
def test_the_three_arms_alternate_on_their_own_engine_versions(bench, dataset, tmp_path):
    chosen = (HashEncoding.default_kernel, sampler_cpu.MODE)
    figures = bench.main(
        [
            "--data",
            str(dataset),
            "--after",
            "3",
            "--blocks",
            "2",
            "--block-steps",
            "2",
            "--json",
            str(tmp_path / "f.json"),
        ]
    )
    assert (HashEncoding.default_kernel, sampler_cpu.MODE) == chosen
    arms = figures["arms"]
    assert [a["engine_version"] for a in arms.values()] == [None, "hash-cpu-1", "cpu-fused-3"]
    for arm in arms.values():
        assert len(arm["measurements"]) == 2
        assert all(m["step_ms"] > 0 and m["view_ms"] > 0 for m in arm["measurements"])
    assert arms["reference"]["step_speedup_over_reference"] == 1.0
    assert (tmp_path / "f.json").exists()
