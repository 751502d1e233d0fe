"""benchmarks/bench_gpu.py end to end on the CPU at toy size: pack a dataset into one file, unpack
it as the GPU machine would, run a timed trial and the resumable protocol, without Blender."""

import json
import math
import os
import sys
import tarfile
from pathlib import Path

import pytest
import torch

from nerfaug.data import load_dataset

pytestmark = [pytest.mark.slow]
SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_gpu.py"
TOY = [
    "--device",
    "cpu",
    "--engine",
    "test",
    "--steps",
    "24",
    "--add-at",
    "8",
    "--n-new",
    "2",
    "--test-views",
    "2",
    "--threads",
    "1",
    "--save-renders",
    "0",
]


@pytest.fixture(scope="module")
def packed(bench, dataset, tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("pack") / "toy.npz"
    figures = bench.main(
        ["pack", "--from", str(dataset), "--out", str(out), "--quality", "95", "--max-test", "3", "--no-lpips"]
    )
    return out, figures


def test_pack_is_one_file_that_unpacks_to_the_same_views(bench, dataset, packed, tmp_path):
    out, figures = packed
    assert figures["views"] == {"initial": 3, "train": 8, "test": 3}  # --max-test kept the first 3 of 4
    assert out.is_file() and figures["mib"] == pytest.approx(out.stat().st_size / 2**20)
    assert figures["jpeg_round_trip_psnr_db"] > 30.0
    folder, meta = bench.unpack(out, tmp_path / "unpacked")
    assert meta["width"] == meta["height"] == 24
    for split, n in figures["views"].items():
        original, restored = load_dataset(dataset, split), load_dataset(folder, split)
        assert len(restored) == n and restored.alphas is None  # JPEG: composited over white
        assert torch.allclose(restored.cameras.camera_to_world, original.cameras.camera_to_world[:n], atol=1e-6)
        assert torch.allclose(restored.cameras.fx, original.cameras.fx[:n])
        error = (restored.images - original.images[:n]).abs().mean()
        assert error < 0.02, f"{split}: mean JPEG error {error:.4f}"
    assert not (folder / "alexnet.ckpt").exists()


def test_pack_refuses_a_file_over_the_size_limit(bench, dataset, tmp_path):
    out = tmp_path / "big.npz"
    with pytest.raises(SystemExit, match="--max-mib"):
        bench.main(["pack", "--from", str(dataset), "--out", str(out), "--max-mib", "0.001", "--no-lpips"])
    assert not out.exists()


def test_pack_embeds_small_lpips_weights_and_the_unpack_points_lpips_at_them(bench, dataset, tmp_path, monkeypatch):
    weights = tmp_path / "alexnet.ckpt"
    weights.write_bytes(b"not really weights, only carried")
    out = tmp_path / "w.npz"
    bench.pack(dataset, out, lpips_weights=weights)
    monkeypatch.setenv(bench.LPIPS_ENV, "")  # unset for unpack; restored after the test
    folder, meta = bench.unpack(out, tmp_path / "unpacked")
    assert (folder / "alexnet.ckpt").read_bytes() == weights.read_bytes()
    assert os.environ[bench.LPIPS_ENV] == str((folder / "alexnet.ckpt").resolve())


def test_trial_prints_and_returns_the_figures(bench, packed, tmp_path, capsys):
    out, _ = packed
    figures = bench.main(
        [
            "trial",
            "--data",
            str(out),
            "--unpack-to",
            str(tmp_path / "data"),
            *TOY,
            "--warmup-steps",
            "2",
            "--out",
            str(tmp_path / "trial"),
            "--json",
            str(tmp_path / "t.json"),
        ]
    )
    printed = capsys.readouterr().out
    for label in ("s/step", "trial time", "peak GPU memory", "test PSNR / SSIM / LPIPS"):
        assert label in printed
    assert figures["steps"] == 24 and figures["test_views"] == 2 and figures["device"] == "cpu"
    assert 0 < figures["s_per_step"] < figures["trial_s"] <= figures["trial_wall_s"] + 1e-6
    assert figures["peak_gpu_mib"] is None  # no GPU: not a made-up number
    assert 5.0 < figures["psnr"] < 60.0 and 0.0 < figures["ssim"] <= 1.0
    assert figures["lpips"] is None  # 24-px images are below LPIPS's minimum size; the status says so
    assert "not computed" in figures["lpips_status"]
    assert json.loads((tmp_path / "t.json").read_text())["psnr"] == figures["psnr"]
    assert "bpy" not in sys.modules


def test_protocol_runs_every_method_and_resumes_within_its_budget(bench, packed, tmp_path, capsys):
    out, _ = packed
    common = [
        "protocol",
        "--data",
        str(out),
        "--unpack-to",
        str(tmp_path / "data"),
        *TOY,
        "--methods",
        "ours",
        "uniform",
        "--out",
        str(tmp_path / "protocol"),
        "--no-report",
    ]
    first = bench.main([*common, "--trials", "2"])
    assert first["complete"] and first["trials_done"] == 2
    assert {m: r["trials"] for m, r in first["methods"].items()} == {"ours": 2, "uniform": 2}
    assert all(math.isfinite(r["psnr"]) and r["run_s"] > 0 for r in first["methods"].values())
    # A budget that fits no further run: the finished runs are read back, none is started.
    again = bench.main([*common, "--trials", "3", "--budget-s", "0"])
    assert not again["complete"] and again["trials_done"] == 2
    assert {m: r["run_s"] for m, r in again["methods"].items()} == {m: r["run_s"] for m, r in first["methods"].items()}
    assert "run the same command again" in capsys.readouterr().out


def test_protocol_with_workers_runs_whole_trials_at_once_and_gives_the_same_numbers(bench, packed, tmp_path):
    out, _ = packed
    common = ["protocol", "--data", str(out), "--unpack-to", str(tmp_path / "data"), *TOY]
    common += ["--methods", "ours", "uniform", "--trials", "2", "--no-report"]
    alone = bench.main([*common, "--out", str(tmp_path / "alone")])
    # 4 workers and 2 methods: both trials in one round, four runs in their own processes.
    together = bench.main([*common, "--out", str(tmp_path / "together"), "--workers", "4"])
    assert together["complete"] and together["workers"] == 4 and together["peak_gpu_mib"] is None
    for method in ("ours", "uniform"):
        assert together["methods"][method]["trials"] == 2
        # On the CPU a run's numbers depend on its seed alone, not on the processes beside it.
        assert together["methods"][method]["psnr"] == alone["methods"][method]["psnr"]


def test_protocol_resumes_on_a_bare_machine_from_its_archive(bench, packed, tmp_path, capsys):
    out, _ = packed
    common = ["protocol", "--data", str(out), "--unpack-to", str(tmp_path / "data"), *TOY]
    common += ["--methods", "ours", "uniform", "--no-report"]
    archive = tmp_path / "OUT" / "protocol.tar.gz"
    first = bench.main([*common, "--trials", "1", "--out", str(tmp_path / "machine1"), "--archive", str(archive)])
    assert first["archive"] == str(archive) and archive.is_file()
    names = tarfile.open(archive).getnames()
    assert "sweep.json" in names and not any("datasets" in n or n.endswith(".png") for n in names)
    # A bare machine: a new results folder, the archive carried in; a budget of 0 starts no round,
    # so the trial in the summary can only come from the archive.
    again = bench.main(
        [
            *common,
            "--trials",
            "2",
            "--out",
            str(tmp_path / "machine2"),
            "--resume-from",
            str(archive),
            "--budget-s",
            "0",
        ]
    )
    assert again["trials_done"] == 1 and not again["complete"]
    # The same seconds: read back, not run again (a rerun would give the same PSNR on the CPU).
    for method in ("ours", "uniform"):
        assert again["methods"][method]["run_s"] == first["methods"][method]["run_s"]
    assert "redoing" not in capsys.readouterr().out
    with pytest.raises(SystemExit, match="archive not found"):
        bench.main([*common, "--out", str(tmp_path / "machine3"), "--resume-from", str(tmp_path / "none.tar.gz")])
