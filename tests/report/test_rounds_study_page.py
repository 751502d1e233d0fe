"""A tiny study of rounds made by the real code (the `test` engine on the analytic sphere, 16 px,
40 steps, 3 rounds of one view): the table keeps each run's learning curve as its result.json
recorded it, and the page draws the curves and judges the plan of rounds (partial here: none of
its scenes is run)."""

import json
from pathlib import Path

import pytest
import torch

from nerfaug.data import write_blender_split
from nerfaug.hemisphere import half_hemisphere_poses, sample_uniform_poses
from nerfaug.report.learning_curve import curve_mean
from nerfaug.report.study_table import read_table
from nerfaug.scenes.sphere import sphere_views

SIZE = 16


@pytest.fixture(scope="module")
def study(tmp_path_factory) -> tuple[Path, Path]:
    from nerfaug.cli import main

    root = tmp_path_factory.mktemp("rounds")
    data = root / "sphere"
    write_blender_split(data, "initial", sphere_views(half_hemisphere_poses(3), "i", SIZE))
    write_blender_split(
        data, "train", sphere_views(sample_uniform_poses(12, torch.Generator().manual_seed(0)), "r", SIZE)
    )
    write_blender_split(
        data, "test", sphere_views(sample_uniform_poses(4, torch.Generator().manual_seed(1)), "t", SIZE)
    )
    out, table = root / "study", root / "table.json"
    options = ["--preset", "tiny", "--engines", "test", "--scenes", str(data), "--methods", "uniform", "furthest"]
    options += ["--trials", "2", "--resolution", str(SIZE), "--steps", "40", "--add-at-step", "10", "--n-new", "1"]
    options += ["--rounds", "3", "--round-every", "10", "--workers", "1", "--device", "cpu"]
    main(["study", "--out", str(out), *options, "--table", str(table)])
    return out, table


def test_the_table_keeps_each_runs_curve_as_its_record_has_it(study):
    out, table_path = study
    table = read_table(table_path)
    assert len(table["runs"]) == 4 and table["plan"]["config"]["rounds"] == 3
    for run in table["runs"]:
        result = json.loads(
            (out / "test" / "runs" / "sphere" / run["method"] / f"trial_{run['trial']:03d}" / "result.json").read_text()
        )
        points = [result["before_rounds"], *result["rounds"]]
        assert run["curve"] == [[p["views"], p["metrics"]["psnr"]] for p in points]
        assert [v for v, _ in run["curve"]] == [3, 4, 5, 6] and run["curve"][-1][1] == run["psnr"]
    # A table with a curve that goes backwards is refused, naming the field.
    table["runs"][0]["curve"] = [[4, 20.0], [3, 21.0]]
    table_path.with_name("bad.json").write_text(json.dumps(table))
    with pytest.raises(Exception, match=r"runs\[0\]\.curve"):
        read_table(table_path.with_name("bad.json"))


def test_the_page_draws_the_curves_and_judges_the_plan_of_rounds(study):
    out, table_path = study
    page = (out / "study.md").read_text()
    assert (out / "figures" / "learning_curves_test.png").read_bytes().startswith(b"\x89PNG")
    assert "## Learning curves, engine test" in page and "figures/learning_curves_test.png" in page
    assert "The planned hypotheses (the study of rounds)" in page
    for name in ("Q1", "Q3", "Q4"):
        assert f"| {name} |" in page and "**partial: 0 of 240 runs**" in page
    # The per-scene table's curve mean is the median of each run's area / span, from the table's rows.
    table = read_table(table_path)
    means = sorted(curve_mean(r["curve"]) for r in table["runs"] if r["method"] == "furthest")
    assert "| furthest | 2 |" in page and f"{(means[0] + means[1]) / 2:.2f} [" in page
