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


def test_each_kept_part_and_each_loss_scale_is_its_own_training(bench, dataset):
    report = bench.main(
        ["--data", str(dataset), "--engine", "nerfacto-cpu", "--at-steps", "1", "--resolution", "24"]
        + ["--train-half", "2", "--train-keep", "color", "sigmoid", "--train-each", "--train-scales", "20"]
        + ["--probe-scales", "20"]
    )
    variants = report["probes"][0]["variants"]
    # a power-of-two scale changes float16's rounding only where values underflow: never worse
    scaled, plain = variants["half everywhere, loss x 2^20"]["groups"], variants["half everywhere"]["groups"]
    assert scaled["field.color_mlp"]["rel_error"] <= plain["field.color_mlp"]["rel_error"] + 1e-6
    trainings = report["train_half"]
    assert [t["float32"] for t in trainings] == [[], [], ["color"], ["sigmoid"], []]
    assert [t["init_scale"] for t in trainings] == [None, 2.0**16, 2.0**16, 2.0**16, 2.0**20]
    assert trainings[-1]["trace"][0]["scale"] == 2.0**20


def test_the_sigmoid_part_keeps_only_the_colour_output_in_float32(bench):
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.registry import build_field

    torch.manual_seed(0)
    nerf_field = build_field(NerfConfig.preset("test"))
    geometry = torch.randn(5, nerf_field.geo_feat_dim)
    directions = torch.nn.functional.normalize(torch.randn(5, 3), dim=-1)
    with torch.autocast("cpu", dtype=torch.float16):
        half = nerf_field.color(geometry, directions)
        with bench.float32_parts(("sigmoid",), "cpu"):
            output_float32 = nerf_field.color(geometry, directions)
        with bench.float32_parts(("color",), "cpu"):
            all_float32 = nerf_field.color(geometry, directions)
    assert half.dtype == torch.float16 and output_float32.dtype == torch.float32
    # the network itself still ran in float16: its output differs from a float32 network's
    assert torch.allclose(output_float32, all_float32, atol=2e-3) and not torch.equal(output_float32, all_float32)
    assert nerf_field.color(geometry, directions).dtype == torch.float32  # restored outside
