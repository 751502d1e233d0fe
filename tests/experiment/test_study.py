"""The study command end to end at toy size (the `test` engine, 2 methods x 2 trials x 1 scene,
on an analytic dataset so no Blender is needed), and its summary's numbers against a
recomputation from the run folders with scipy and numpy."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data import Views, write_blender_split
from nerfaug.experiment.study import default_engines, engine_presets, min_trials
from nerfaug.hemisphere import (
    BLENDER_CAMERA_ANGLE_X,
    fibonacci_angles,
    half_hemisphere_poses,
    pose_from_angles,
    sample_uniform_poses,
)

SIZE = 24


def render_sphere(poses, prefix: str) -> Views:
    """Exact renders of a unit sphere at the origin coloured by its normal, on white."""
    cameras = Cameras.from_fov(poses.float(), BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    images = []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        b = (origins * directions).sum(-1)
        disc = b**2 - ((origins**2).sum(-1) - 1.0)
        hit = disc > 0
        normal = origins + (-b - disc.clamp(min=0).sqrt())[:, None] * directions
        rgb = torch.where(hit[:, None], 0.5 + 0.5 * normal, torch.ones(3)).clamp(0, 1)
        images.append(rgb.reshape(SIZE, SIZE, 3))
    images = (torch.stack(images) * 255).round() / 255  # survives the PNG round trip exactly
    return Views(cameras, images, [f"./{prefix}/r_{i}" for i in range(len(cameras))])


@pytest.fixture(scope="module")
def sphere(tmp_path_factory) -> Path:
    """A Blender-format dataset: a pool of 12 views, 3 initial views on one half, 3 test views."""
    root = tmp_path_factory.mktemp("data") / "sphere"
    write_blender_split(
        root, "train", render_sphere(sample_uniform_poses(12, torch.Generator().manual_seed(0)), "train")
    )
    write_blender_split(root, "initial", render_sphere(half_hemisphere_poses(3), "initial"))
    write_blender_split(root, "test", render_sphere(pose_from_angles(*fibonacci_angles(3)), "test"))
    return root


def toy_study(sphere: Path) -> list[str]:
    """The options of the toy study every test here runs: the test engine, 2 methods x 2 trials."""
    return ["--preset", "tiny", "--engines", "test", "--scenes", str(sphere), "--methods", "ours", "uniform"] + [
        "--trials",
        "2",
        "--resolution",
        str(SIZE),
        "--steps",
        "60",
        "--workers",
        "1",
        "--device",
        "cpu",
    ]


@pytest.fixture(scope="module")
def study_out(sphere, tmp_path_factory):
    from nerfaug.cli import main

    out = tmp_path_factory.mktemp("study")
    docs = out.parent / f"{out.name}_docs" / "results.md"
    table = docs.parent / "results" / "study-table.json"
    main(["study", "--out", str(out), *toy_study(sphere), "--table", str(table), "--results-doc", str(docs)])
    return out, docs


def run_folders(out: Path, method: str) -> list[Path]:
    return sorted((out / "test" / "runs" / "sphere" / method).glob("trial_*"))


def psnrs(out: Path, method: str) -> list[float]:
    return [json.loads((f / "result.json").read_text())["metrics"]["psnr"] for f in run_folders(out, method)]


def unseen_share(folder: Path) -> float:
    """Recomputed with numpy alone: chosen views more than 90 degrees in azimuth from the initial
    views' mean direction."""
    selection = json.loads((folder / "selection.json").read_text())
    chosen = np.asarray(selection["chosen_poses"])[:, :3, 3]
    initial = np.asarray(selection["train_poses"])[:, :3, 3]
    mean = np.arctan2(
        np.sin(np.arctan2(initial[:, 1], initial[:, 0])).mean(), np.cos(np.arctan2(initial[:, 1], initial[:, 0])).mean()
    )
    offset = np.angle(np.exp(1j * (np.arctan2(chosen[:, 1], chosen[:, 0]) - mean)))
    return float((np.abs(offset) > math.pi / 2).mean())


def table_of(out: Path) -> dict:
    from nerfaug.report.study_table import read_table

    return read_table(out.parent / f"{out.name}_docs" / "results" / "study-table.json")


def test_study_writes_every_run_a_table_and_a_summary(study_out):
    out, docs = study_out
    plan = json.loads((out / "study.json").read_text())
    assert plan["engines"] == ["test"] and plan["methods"] == ["ours", "uniform"] and plan["trials"] == 2
    assert plan["machine"]["cpu_count"] and plan["machine"]["torch"] == torch.__version__
    assert plan["engine_settings"]["test"]["background_mode"] == "fixed"
    for method in ("ours", "uniform"):
        assert len(run_folders(out, method)) == 2
    assert (out / "study.md").is_file() and (out / "figures" / "coverage_test.png").is_file()
    assert (out / "figures" / "boxplots_test_sphere.png").is_file() and (out / "figures" / "paired_psnr.png").is_file()
    text = docs.read_text()
    assert "nerfaug study --summary-only --table" in text and "torch " + torch.__version__ in text
    assert (docs.parent / "results" / "coverage_test.png").is_file()  # figures beside the page
    assert "](results/coverage_test.png)" in text
    assert len(table_of(out)["runs"]) == 4


def test_table_rows_are_the_run_folders(study_out):
    from nerfaug.experiment.store import code_version

    out, _ = study_out
    runs = {(r["method"], r["trial"]): r for r in table_of(out)["runs"]}
    for method in ("ours", "uniform"):
        for folder in run_folders(out, method):
            result = json.loads((folder / "result.json").read_text())
            selection = json.loads((folder / "selection.json").read_text())
            row = runs[(method, result["trial"])]
            assert row["engine"] == "test" and row["scene"] == "sphere" and row["seed"] == result["seed"]
            assert (row["psnr"], row["ssim"], row["lpips"]) == tuple(
                result["metrics"][k] for k in ("psnr", "ssim", "lpips")
            )
            assert row["fingerprint"] == result["fingerprint"] and row["code_version"] == result["code_version"]
            assert row["code_version"] == code_version() and row["chosen"] == selection["indices"]
            np.testing.assert_allclose(row["chosen_poses"], np.asarray(selection["chosen_poses"])[:, :3], atol=1e-6)


def test_the_tables_runs_re_derive_their_fingerprints_from_its_plan(study_out):
    """What `nerfaug study --one-shot-table` counts a run by: the fingerprint the table's recorded
    plan gives it now, with its recorded engine version, equals the one the run recorded."""
    from nerfaug.experiment.study import rederived_fingerprints

    table = table_of(study_out[0])
    keys = {(r["engine"], r.get("engine_version") or None, r["method"]): r["fingerprint"] for r in table["runs"]}
    assert rederived_fingerprints(table["plan"], keys) == keys and len(keys) == 2


def test_summary_numbers_equal_a_recomputation(study_out):
    from nerfaug.report.study import BOOTSTRAP_SEED, collect_study

    out, _ = study_out
    (cell,) = collect_study(table_of(out)).cells
    ours, uniform = psnrs(out, "ours"), psnrs(out, "uniform")
    assert cell.methods["ours"].values["psnr"] == ours and cell.methods["uniform"].values["psnr"] == uniform
    assert cell.winner == ("ours" if np.median(ours) > np.median(uniform) else "uniform")
    entry = cell.methods["ours"].vs_reference["psnr"]
    d = np.array(ours) - np.array(uniform)  # trial k pairs with trial k: the same seed
    assert entry["difference"] == pytest.approx(np.median(d), abs=1e-12)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    medians = np.median(d[rng.integers(0, d.size, (9999, d.size))], axis=1)
    assert (entry["low"], entry["high"]) == pytest.approx(tuple(np.percentile(medians, [2.5, 97.5])), abs=1e-12)
    p = stats.wilcoxon(d, alternative="two-sided", method="exact").pvalue
    assert entry["p_value"] == pytest.approx(p) and entry["p_bonferroni"] == pytest.approx(min(1.0, p * 1))
    for method in ("ours", "uniform"):
        found = sorted(c["unseen_share"] for c in cell.methods[method].coverage)
        assert found == pytest.approx(sorted(unseen_share(f) for f in run_folders(out, method)))
    # ... and the page shows them as computed.
    text = (out / "study.md").read_text()
    shown = [round(entry[k], 2) + 0.0 for k in ("difference", "low", "high")]  # "+0.00", never "-0.00"
    assert f"{shown[0]:+.2f} [{shown[1]:.2f}, {shown[2]:.2f}]" in text
    assert f"{cell.winner} ({np.median(ours if cell.winner == 'ours' else uniform):.2f} dB)" in text


def without_provenance(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.startswith("Generated on "))


def test_the_page_is_rederived_from_the_table_alone(study_out, tmp_path):
    """Without the run folders (a study folder that does not exist), --summary-only from the table
    writes the same page, byte for byte but for its timestamp line."""
    from nerfaug.cli import main

    out, docs = study_out
    before = docs.read_text()
    table = docs.parent / "results" / "study-table.json"
    table_bytes = table.read_bytes()
    main(
        ["study", "--out", str(tmp_path / "gone"), "--summary-only", "--table", str(table), "--results-doc", str(docs)]
    )
    assert without_provenance(docs.read_text()) == without_provenance(before)
    assert table.read_bytes() == table_bytes  # read, not rewritten


def test_a_study_resumes_from_its_table_without_run_folders(study_out, sphere, tmp_path, capsys):
    from nerfaug.cli import main

    out, docs = study_out
    table = docs.parent / "results" / "study-table.json"
    again = tmp_path / "again"
    main(["study", "--out", str(again), "--table", str(table), *toy_study(sphere)])
    assert "4 recorded in the table, 0 to run" in capsys.readouterr().err
    assert not list((again / "test" / "runs").glob("*/*/*"))  # nothing was run again
    assert len(table_of(out)["runs"]) == 4


def test_summary_names_engines_not_run_and_lpips(study_out, tmp_path):
    from nerfaug.report.study_page import write_study

    out, _ = study_out
    table = table_of(out)
    table["plan"]["engines"].append("cpu")  # planned but never run: its cells are incomplete
    text = write_study(tmp_path, table)[0].read_text()
    incomplete = text.split("## Incomplete cells", 1)[1]
    assert "engine cpu: not run yet" in incomplete
    lpips = [json.loads((f / "result.json").read_text())["metrics"]["lpips"] for f in run_folders(out, "ours")]
    assert ("LPIPS n/a" in text) == (None in lpips)


def test_default_engines_and_trials():
    engines, left_out = default_engines("cpu")
    assert "test" in left_out and "test" not in engines
    assert set(engines) | set(left_out) == set(engine_presets())
    if "paper" in engine_presets():
        assert "paper" in left_out and "GPU" in left_out["paper"] and "paper" in default_engines("cuda")[0]
    # 10 trials by default; 9 seed-paired trials are the fewest at which the signed-rank test,
    # Bonferroni x7, can reach 0.05 (2 / 2^9 x 7 = 0.027; 2 / 2^8 x 7 = 0.055).
    assert min_trials(7) == 10 and min_trials(7, start=1) == 9 and min_trials(200, start=1) == 13


def test_a_study_run_in_sittings_keeps_every_engine_and_scene(tmp_path):
    from nerfaug.experiment.study import merged_record

    path = tmp_path / "study.json"
    first = {
        "engines": ["cpu"],
        "left_out": {"paper": "needs a GPU", "nerfacto-cpu": "not asked"},
        "scenes": ["lego"],
        "datasets": {"lego": "/d/lego"},
        "command": ["nerfaug", "study", "a"],
    }
    assert merged_record(path, first) == first  # nothing to merge with yet
    path.write_text(json.dumps(first))
    second = {
        "engines": ["nerfacto-cpu"],
        "left_out": {},
        "scenes": ["chair"],
        "datasets": {"chair": "/d/chair"},
        "command": ["nerfaug", "study", "b"],
    }
    merged = merged_record(path, second)
    assert merged["engines"] == ["cpu", "nerfacto-cpu"] and merged["scenes"] == ["lego", "chair"]
    assert merged["datasets"] == {"lego": "/d/lego", "chair": "/d/chair"}
    assert merged["left_out"] == {"paper": "needs a GPU"}  # an engine run is no longer left out
    assert merged["commands"] == [first["command"], second["command"]]
    path.write_text("{not json")
    assert merged_record(path, second) == second  # an unreadable plan is replaced, never merged


def test_bad_study_options_are_refused_before_any_dataset_is_rendered(tmp_path):
    from nerfaug.cli import main

    out = tmp_path / "study"
    with pytest.raises(SystemExit) as refused:
        main(["study", "--out", str(out), "--engines", "test", "--scenes", "lego", "--trials", "0", "--device", "cpu"])
    assert refused.value.code == 2
    assert not (out / "datasets").exists()


def test_the_hand_written_reading_is_kept_when_the_page_is_regenerated(study_out, tmp_path):
    from nerfaug.report.study_page import READING_END, READING_START, write_results_doc

    out, _ = study_out
    table, source = table_of(out), Path("study-table.json")
    page = tmp_path / "results.md"
    write_results_doc(table, source, page)
    reading = f"{READING_START}\nOurs did not beat uniform here; see the coverage figure.\n{READING_END}"
    page.write_text(page.read_text() + "\n" + reading + "\n")
    write_results_doc(table, source, page)
    text = page.read_text()
    assert text.count("Ours did not beat uniform here") == 1
    assert text.index(READING_END) < text.index("## Which method to use")
    write_results_doc(table, source, page)  # and again: still once
    assert page.read_text().count(READING_START) == 1


def test_paired_values_are_matched_by_trial():
    from nerfaug.report.collect import Results, Run
    from nerfaug.report.pooled import paired_values, plot_paired_differences

    # A trial one method lacks, or whose metric is missing, pairs with nothing.
    def run(method, trial, psnr):
        return Run("s", method, trial, Path("."), {"metrics": {"psnr": psnr}})

    fake = Results(
        Path("."),
        {},
        [
            run("a", 0, 20.0),
            run("a", 2, 22.0),
            run("a", 3, None),
            run("u", 3, 19.0),
            run("u", 2, 21.0),
            run("u", 0, 18.0),
        ],
        [],
        [],
    )
    assert paired_values(fake, "s", "a", "u", "psnr") == ([20.0, 22.0], [18.0, 21.0], [0, 2])
    assert plot_paired_differences([(fake, "s", "s")], ["b", "u"], "u", Path("never.png")) is None  # no pairs


def collect_results_of(out: Path):
    from nerfaug.report.collect import collect_results

    return collect_results(out / "test")


@pytest.mark.parametrize("engine", ["cpu+encoding=nope", "cpu+sampler=grid", "nerfacto"])
def test_an_unknown_engine_or_part_is_one_line_before_any_dataset_is_rendered(tmp_path, capsys, engine):
    from nerfaug.cli import main

    out = tmp_path / "study"
    with pytest.raises(SystemExit) as refused:
        main(["study", "--out", str(out), "--engines", engine, "--scenes", "lego", "--device", "cpu"])
    assert refused.value.code == 2
    message = capsys.readouterr().err.strip()
    assert message.startswith("nerfaug: --engines: ") and "\n" not in message
    assert engine.rpartition("=")[2] in message and not (out / "datasets").exists()
