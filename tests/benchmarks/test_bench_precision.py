"""benchmarks/bench_precision.py on the CPU at toy size: float32 repeated is the same step, half
precision changes the gradients a little, and the networks' methods are restored afterwards."""

from pathlib import Path

import pytest
import torch

from nerfaug.nerf import field

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_precision.py"


def test_probe_compares_each_variant_with_float32_on_the_same_draws(bench, dataset, tmp_path):
    methods = (field.DensityField.forward, field.NerfField.density, field.NerfField.color)
    report = bench.main(
        ["--data", str(dataset), "--engine", "nerfacto-cpu", "--at-steps", "3", "--resolution", "24"]
        + ["--train-half", "4", "--train-keep", "proposal", "--json", str(tmp_path / "p.json")]
    )
    assert (field.DensityField.forward, field.NerfField.density, field.NerfField.color) == methods
    (probe,) = report["probes"]
    assert probe["step"] == 3
    assert all(g["rel_error"] == 0.0 for g in probe["float32_repeated"].values())  # the CPU repeats a step exactly
    everywhere = probe["variants"]["half everywhere"]["groups"]
    # another batch moves the table's gradient far more than float16 does (what a change is read against)
    other_batch = probe["float32_other_batch"]["field.encoding/table"]["rel_error"]
    assert other_batch > 0.3 and other_batch > 10 * everywhere["field.encoding/table"]["rel_error"]
    assert set(everywhere) >= {"field.encoding/table", "field.density_mlp", "field.color_mlp"}
    # float16 keeps about 3 decimal digits: the gradients move, by little, at step 3
    assert all(0.0 < g["rel_error"] < 0.05 for name, g in everywhere.items() if name.startswith("field"))
    # with the proposal networks in float32 they place the samples exactly as float32 does
    assert probe["variants"]["proposal nets float32"]["samples_moved_max"] == 0.0
    assert probe["variants"]["half everywhere"]["samples_moved_max"] > 0.0
    assert (tmp_path / "p.json").is_file()
    baseline, everything, proposal_kept = report["train_half"]
    assert [t["precision"] for t in report["train_half"]] == ["float32", "float16", "float16"]
    assert (everything["float32"], proposal_kept["float32"]) == ([], ["proposal"])
    assert baseline["skipped"] == 0 and baseline["trace"][-1]["scale"] == 1.0
    assert everything["steps"] == 4 and everything["trace"][-1]["step"] == 4


def test_compare_counts_lost_entries_and_relative_error(bench):
    reference = {"field.mlp.0.weight": torch.tensor([3.0, 4.0, 0.0])}
    other = {"field.mlp.0.weight": torch.tensor([0.0, 4.0, 1.0])}
    (group,) = bench.compare(reference, other).values()
    assert group["underflow"] == pytest.approx(1 / 2)  # 3.0 became 0 (of 2 non-zero entries)
    assert group["rel_error"] == pytest.approx((9 + 1) ** 0.5 / 5)
