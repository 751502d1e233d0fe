"""The study's per-run table: its checks, and the page's statistics and verdicts computed from a
constructed table whose answers are known."""

import json

import numpy as np
import pytest
import torch

from nerfaug.hemisphere import half_hemisphere_poses, pose_from_angles
from nerfaug.report.collect import ReportError
from nerfaug.report.document import to_markdown
from nerfaug.report.study import collect_study
from nerfaug.report.study_hypotheses import h1, h2, h3
from nerfaug.report.study_page import study_blocks
from nerfaug.report.study_table import RunRow, make_table, read_table, rounded_poses, table_rows, write_table
from nerfaug.statistics import seed_level_comparison

ENGINE = "nerfacto-cpu-last-sample"
SCENES = ("lego", "chair", "materials")
SEEDS = range(10)


def poses_at(azimuths_deg):
    azimuth = torch.tensor(azimuths_deg, dtype=torch.float64).deg2rad()
    return rounded_poses(pose_from_angles(azimuth, torch.full_like(azimuth, 1.0)).numpy())


def synthetic_table(offsets: dict[str, float | dict[str, float]]) -> dict:
    """10 seeds x 3 scenes; uniform's PSNR varies by seed and scene, every other method is
    uniform + its offset (one number, or one per scene) + a small seed-dependent term (of the
    offset's sign; alternating where the offset is 0). ours-paper-sum picks views on the far side
    (azimuth 180), ours near the seen side."""
    rng = np.random.default_rng(0)
    rows = []
    far, near = poses_at([170, 180, 190]), poses_at([10, 20, 30])
    for scene in SCENES:
        for seed in SEEDS:
            base = 20.0 + rng.normal(0, 2)
            for method, offset in {"uniform": 0.0, **offsets}.items():
                offset = offset[scene] if isinstance(offset, dict) else offset
                sign = (-1) ** seed if offset == 0 else np.sign(offset)  # offset 0: no consistent sign
                jitter = 0.0 if method == "uniform" else 0.01 * (seed + 1) * sign
                poses = far if method == "ours-paper-sum" else near
                rows.append(
                    RunRow(
                        ENGINE,
                        scene,
                        method,
                        seed,
                        seed,
                        base + offset + jitter,
                        0.8,
                        0.2,
                        "ok",
                        [0, 1, 2],
                        poses,
                        "v1",
                        "f",
                    )
                )
    initial = rounded_poses(half_hemisphere_poses(6).numpy())
    plan = {
        "engines": [ENGINE],
        "scenes": list(SCENES),
        "methods": ["ours", "ours-paper-sum", "uniform", "fisherrf"],
        "trials": 10,
        "engine_settings": {ENGINE: {"background_mode": "last_sample"}},
    }
    return make_table(plan, rows, {scene: {"initial_poses": initial} for scene in SCENES})


def test_paired_tests_regimes_and_verdicts_on_a_constructed_study(tmp_path):
    table = synthetic_table({"ours": 1.0, "ours-paper-sum": 0.0, "fisherrf": -2.0})
    path = write_table(tmp_path / "table.json", table)
    study = collect_study(read_table(path))
    assert [c.scene for c in study.cells] == list(SCENES) and all(c.complete for c in study.cells)
    for cell in study.cells:
        entry = cell.methods["ours"].vs_reference["psnr"]
        # 10 of 10 pairs favour ours: the exact signed-rank test's smallest p, x3 methods compared.
        assert entry["wins"] == 10 and entry["p_value"] == pytest.approx(2 / 2**10)
        assert entry["p_bonferroni"] == pytest.approx(3 * 2 / 2**10) and entry["significant"]
        assert cell.significant(True) == ["ours"] and cell.significant(False) == ["fisherrf"]
    # The regime test takes each seed's mean over the three scenes.
    regime = study.regimes[ENGINE]["ours"]
    by_seed = {
        scene: {seed: 1.0 + 0.01 * (seed + 1) for seed in SEEDS} for scene in SCENES
    }  # ours - uniform, by construction
    expected = seed_level_comparison(by_seed, 3)
    assert regime["seed_means"] == pytest.approx(expected["seed_means"]) and regime["p_value"] == expected["p_value"]
    assert h1(study)[0] == "supported"
    assert h2(study)[0] == "open"  # worse in the paper's regime, but cpu has not run
    assert h3(study)[0] == "open"  # far side in 3 of 9 planned cells: not yet most
    text = to_markdown(study_blocks(study, {}), tmp_path)
    assert f"engine {ENGINE} (background last_sample): use **ours**" in text
    assert "Worse than uniform: fisherrf (-2.06 dB)" in text


def test_which_method_names_per_scene_wins_when_no_method_wins_across_scenes(tmp_path):
    # ours wins every seed on lego and loses every seed on chair by as much: per seed, the mean
    # over the scenes is about 0, so the regime test finds nothing; the per-cell test finds lego.
    study = collect_study(
        synthetic_table(
            {"ours": {"lego": 1.0, "chair": -1.0, "materials": 0.0}, "ours-paper-sum": 0.0, "fisherrf": 0.0}
        )
    )
    assert not study.regimes[ENGINE]["ours"]["significant"]
    text = to_markdown(study_blocks(study, {}), tmp_path)
    line = next(x for x in text.splitlines() if x.startswith(f"- engine {ENGINE}"))
    assert "no method beats uniform" in line and "as good a choice" not in line
    assert line.endswith("Per scene (the primary test), better than uniform: ours (lego).")
    level = to_markdown(
        study_blocks(collect_study(synthetic_table({"ours": 0.0, "ours-paper-sum": 0.0, "fisherrf": 0.0})), {}),
        tmp_path,
    )
    # Not significant is what was measured, never "as good a choice": the smallest detectable gain stands beside it.
    assert "as good a choice" not in level and "Per scene (the primary test)" not in level
    assert "That is not a finding that they are equal: with 10 seeds and p x 3" in level


def test_h1_is_not_supported_when_ours_loses(tmp_path):
    study = collect_study(synthetic_table({"ours": -0.5, "ours-paper-sum": 0.2, "fisherrf": 0.0}))
    verdict, evidence = h1(study)
    assert verdict == "not supported" and "0 of 3 complete scene(s)" in evidence


def test_rows_of_a_changed_configuration_replace_the_old_rows_of_that_method():
    table = synthetic_table({"ours": 1.0})
    new = RunRow(ENGINE, "lego", "ours", 0, 0, 30.0, 0.9, 0.1, "ok", [0], poses_at([0]), "v2", "g")
    merged = make_table(table["plan"], [new], {}, table)
    ours = [r for r in merged["runs"] if r["method"] == "ours"]
    assert len(ours) == 1 and ours[0]["fingerprint"] == "g"  # no mix of fingerprints f and g
    assert sum(r["method"] == "uniform" for r in merged["runs"]) == 30


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda t: t.update(format="other"), "format: not a nerfaug-study-table"),
        (lambda t: t.update(version=9), "version: 9, this nerfaug reads version 1"),
        (lambda t: t["runs"][3].pop("psnr"), "runs[3]: missing ['psnr']"),
        (lambda t: t["runs"][0].update(psnr="high"), "runs[0].psnr: 'high' is not a number"),
        (lambda t: t["runs"][0].update(lpips=float("nan")), "runs[0].lpips: nan is not a number"),
        (lambda t: t["runs"][1].update(trial="1"), "runs[1].trial: '1' is not a int"),
        (lambda t: t["runs"][2].update(chosen_poses=[[1, 2]]), "runs[2].chosen_poses: not a list of 3x4 matrices"),
        (lambda t: t["runs"].append(dict(t["runs"][0])), "a second row for nerfacto-cpu-last-sample/chair/ours/0"),
        (lambda t: t["runs"][0].update(scene="kitchen"), "runs[0].scene: 'kitchen' has no initial views"),
        (lambda t: t.update(runs={}), "runs: missing or not a list"),
        (lambda t: t["runs"][0].update(uniform_fill="6"), "runs[0].uniform_fill: '6' is not a int"),
    ],
)
def test_a_damaged_table_is_refused_naming_the_field(tmp_path, change, message):
    table = json.loads(write_table(tmp_path / "t.json", synthetic_table({"ours": 1.0})).read_text())
    change(table)
    path = tmp_path / "damaged.json"
    path.write_text(json.dumps(table))
    with pytest.raises(ReportError, match=r"damaged\.json: ") as refused:
        read_table(path)
    assert message in str(refused.value) and "\n" not in str(refused.value)


def test_summary_only_without_a_study_or_a_table_says_so(tmp_path, capsys):
    from nerfaug.cli import main

    with pytest.raises(SystemExit) as stopped:
        main(["study", "--out", str(tmp_path / "none"), "--summary-only"])
    assert stopped.value.code != 0
    assert "nothing to summarise" in capsys.readouterr().err
    assert not (tmp_path / "none").exists()


def test_the_regime_test_uses_complete_cells_only():
    """A cell part-way through (chair at 2 of 10 trials) does not cut the other scenes' seeds."""
    table = synthetic_table({"ours": 1.0, "ours-paper-sum": 0.0, "fisherrf": -2.0})
    table["runs"] = [r for r in table["runs"] if r["scene"] != "chair" or r["trial"] < 2]
    study = collect_study(table)
    regime = study.regimes[ENGINE]["ours"]
    assert (regime["n_cells"], regime["n_seeds"]) == (2, 10)
    assert not next(c for c in study.cells if c.scene == "chair").complete


def test_runs_of_several_layouts_keep_each_layouts_initial_views_and_their_coverage(tmp_path):
    from nerfaug.report.study import coverage_of
    from nerfaug.report.study_table import initial_poses_by_layout

    seen_west, seen_east = poses_at([170, 180, 190]), poses_at([350, 0, 10])
    chosen = poses_at([0, 5, 10])  # east: the unseen side of layout 0, the seen side of layout 1
    rows = [
        RunRow(ENGINE, "mic", "uniform", k, k, 20.0, 0.8, 0.2, "ok", [0, 1, 2], chosen, "v", "f", k) for k in (0, 1)
    ]
    scenes = {"mic": {"initial_poses": seen_west, "layouts": {"1": seen_east}, "test_views": ["./test/r_0"]}}
    table = make_table({"engines": [ENGINE], "scenes": ["mic"], "methods": ["uniform"], "trials": 2}, rows, scenes)
    assert "layout" not in table["runs"][0] and table["runs"][1]["layout"] == 1  # layout 0 stays implicit
    back = read_table(write_table(tmp_path / "t.json", table))
    assert [r.layout for r in table_rows(back)] == [0, 1]
    assert back["scenes"]["mic"]["test_views"] == ["./test/r_0"]
    coverage = coverage_of(table_rows(back), initial_poses_by_layout(back["scenes"]["mic"]))
    assert coverage[0]["unseen_share"] == 1.0 and coverage[1]["unseen_share"] == 0.0
    back["runs"][1]["layout"] = 2
    (tmp_path / "bad.json").write_text(json.dumps(back))
    with pytest.raises(ReportError, match="runs\\[1\\].scene: 'mic' has no initial views of layout 2"):
        read_table(tmp_path / "bad.json")


def real_table(offsets: dict, engine: str = "nerfacto-cpu") -> dict:
    """10 seeds x the four planned real scenes on one engine: every method uniform + its offset +
    a small seed-dependent term of the offset's sign (offset 0: alternating signs)."""
    from nerfaug.report.study_hypotheses import REAL_SCENES

    rng, rows = np.random.default_rng(1), []
    near = poses_at([10, 20, 30])
    for scene in REAL_SCENES:
        for seed in SEEDS:
            base = 18.0 + rng.normal(0, 2)
            for method, offset in {"uniform": 0.0, **offsets}.items():
                sign = (-1) ** seed if offset == 0 else np.sign(offset)
                psnr = base + offset + (0.0 if method == "uniform" else 0.01 * (seed + 1) * sign)
                rows.append(RunRow(engine, scene, method, seed, seed, psnr, 0.8, 0.2, "ok", [0, 1, 2], near, "v", "f"))
    plan = {"engines": [engine], "scenes": list(REAL_SCENES), "methods": ["uniform", *offsets], "trials": 10}
    initial = rounded_poses(half_hemisphere_poses(6).numpy())
    return make_table(plan, rows, {scene: {"initial_poses": initial} for scene in REAL_SCENES})


def test_the_real_scene_hypotheses_are_judged_from_the_table_as_planned():
    from nerfaug.report.study_hypotheses import REAL_HYPOTHESES, hypotheses_of, r1, r2, r3, r4

    offsets = {"ours-batch-sharp": 1.0, "ours": 0.5, "entropy-sampling": 0.0, "fisherrf-sampling": -1.0}
    study = collect_study(real_table(offsets))
    assert hypotheses_of(study) is REAL_HYPOTHESES
    assert r1(study)[0] == "supported" and r3(study)[0] == "supported"
    # ours > entropy-sampling holds by +0.5 on every seed, but entropy-sampling - fisherrf-sampling
    # is +1 on every seed too: the ranking holds on nerfacto-cpu (the other engine is not run).
    assert r2(study)[0] == "holds" and "nerfacto-cpu: holds" in r2(study)[1]
    assert r4(study)[0] == "open" and "not run yet" in r4(study)[1]  # the held-back scene
    reversed_ranking = collect_study(real_table({"ours": -1.0, "entropy-sampling": 0.0, "fisherrf-sampling": 1.0}))
    assert r2(reversed_ranking)[0] == "contradicted"
    flat = collect_study(real_table({"ours-batch-sharp": 0.0, "ours": 0.0}))
    assert r1(flat)[0] == "open"  # one engine of two complete: not yet decided
    assert r3(flat)[0] == "not supported"  # nerfacto-cpu complete, no gain
    assert hypotheses_of(collect_study(synthetic_table({"ours": 1.0}))) is not REAL_HYPOTHESES
    both = real_table({"ours-batch-sharp": 0.0, "ours": 0.0})
    other = real_table({"ours-batch-sharp": 0.0, "ours": 0.0}, engine="nerfacto-cpu-last-sample")
    both["runs"] += other["runs"]
    both["plan"]["engines"] += other["plan"]["engines"]
    decided = collect_study(both)
    assert r1(decided)[0] == "not supported"  # both engines complete, no gain on either
    assert r4(decided) == ("not applicable", "no method passed R1: there is nothing to replicate")


def test_a_regime_part_way_through_decides_no_real_scene_hypothesis():
    """The plan tests the mean over the four scenes: one complete scene whose ten seeds all favour
    ours (significant on its own) or reverse the paper's ranking leaves R1-R4 open."""
    from nerfaug.report.study_hypotheses import r1, r1_winners, r2, r3, r4

    for engine in ("nerfacto-cpu", "nerfacto-cpu-last-sample"):
        offsets = {"ours-batch-sharp": 1.0, "ours": -1.0, "entropy-sampling": 0.0, "fisherrf-sampling": 1.0}
        table = real_table(offsets, engine=engine)
        whole = collect_study(table)
        assert r1(whole)[0] == "supported" and r2(whole)[0] == "contradicted"
        table["runs"] = [r for r in table["runs"] if r["scene"] == "mic"]
        part = collect_study(table)
        assert "ours-batch-sharp +1.06 dB (10/10 seeds, p x 4 = 0.008)" in r1(part)[1]  # mic alone: significant ...
        assert r1_winners(part) == {"nerfacto-cpu": [], "nerfacto-cpu-last-sample": []}
        assert r1(part)[0] == "open" and r2(part)[0] == "open" and r3(part)[0] == "open"  # ... decides nothing
        assert r4(part)[0] == "open"


def test_the_optional_cpu_engine_decides_nothing_until_its_four_scenes_are_complete():
    """Both planned engines complete without a winner; `cpu`, run after them, with a winner: part
    of its scenes leaves the verdicts as they were (and says so), all four make R1 supported."""
    from nerfaug.report.study_hypotheses import r1, r1_winners, r2, r4

    def study_with_cpu(cpu_scenes):
        flat = {"ours-batch-sharp": 0.0, "ours": 0.0, "entropy-sampling": 0.0, "fisherrf-sampling": 0.0}
        table = real_table(flat)
        for engine, offsets in (
            ("nerfacto-cpu-last-sample", flat),
            ("cpu", {"ours-batch-sharp": 1.0, "ours": -1.0, "entropy-sampling": 0.0, "fisherrf-sampling": 1.0}),
        ):
            other = real_table(offsets, engine=engine)
            table["runs"] += [r for r in other["runs"] if engine != "cpu" or r["scene"] in cpu_scenes]
            table["plan"]["engines"] += other["plan"]["engines"]
        return collect_study(table)

    part = study_with_cpu({"mic", "maryRose"})
    assert r1(part)[0] == "not supported" and "cpu: 2 of 4 scenes complete, decides nothing yet" in r1(part)[1]
    assert "cpu" not in r1_winners(part)
    assert r2(part)[0] != "contradicted" and "decides nothing yet" in r2(part)[1]
    assert r4(part)[0] == "not applicable"
    whole = study_with_cpu({"mic", "maryRose", "dtu_scan24", "cow"})
    assert r1_winners(whole)["cpu"] == ["ours-batch-sharp"] and r1(whole)[0] == "supported"
    assert r2(whole)[0] == "contradicted"  # entropy-sampling below fisherrf-sampling on every seed
    assert r4(whole)[0] == "open" and "ours-batch-sharp on cpu: not run yet" in r4(whole)[1]


def test_the_held_back_scene_is_judged_on_its_own_never_in_the_mean_across_scenes(tmp_path):
    """The plan's regime test is the mean over its four scenes; the held-back scene replicates it.
    Its runs (ours far ahead there) move neither the regime nor the advice's scenes."""
    from nerfaug.experiment.study import with_design

    engine = "nerfacto-cpu"

    four = real_table({"ours": 0.5})
    held = real_table({"ours": 5.0})
    four["runs"] += [dict(run, scene="moldGoldCape") for run in held["runs"] if run["scene"] == "mic"]
    four["scenes"]["moldGoldCape"] = four["scenes"]["mic"]
    four["plan"]["scenes"].append("moldGoldCape")
    record = {"scenes": ["mic", "moldGoldCape"], "engines": [], "design": {"engines": [engine], "scenes": ["mic"]}}
    four["plan"]["design"] = with_design(record, tmp_path)["design"]
    assert four["plan"]["design"] == {"engines": [engine], "scenes": ["mic"], "held_back": ["moldGoldCape"]}
    study = collect_study(four)
    assert study.held_back == ("moldGoldCape",)
    regime = study.regimes[engine]["ours"]
    assert regime["n_cells"] == 4 and regime["difference"] < 1.0  # the four scenes' +0.5, not +5 pulled in
    text = to_markdown(study_blocks(study, {}), tmp_path)
    assert "moldGoldCape: held back" in text and "moldGoldCape not run" not in text
    pooled = collect_study({**four, "plan": {**four["plan"], "design": {"engines": [engine], "scenes": ["mic"]}}})
    assert pooled.regimes[engine]["ours"]["n_cells"] == 5  # a study without a held-back scene pools all
    # The procedural study and a user's own scenes hold nothing back.
    for scenes in (["lego"], ["my_capture"]):
        assert "held_back" not in with_design({"scenes": scenes, "engines": []}, tmp_path)["design"]


def test_a_one_trial_study_of_a_users_own_scene_has_its_page_without_the_projects_plan(tmp_path):
    """One trial per method is a sign-flip test of one value (p = 1, scipy refuses n < 2), and a
    scene of the user's own is in neither of this project's plans: no hypotheses of them, no
    planned scenes named as not run."""
    from nerfaug.report.study_hypotheses import hypotheses_of
    from nerfaug.report.study_page import write_study
    from nerfaug.statistics import sign_flip_p

    assert sign_flip_p([0.7]) == 1.0
    near = poses_at([10, 20, 30])
    rows = [
        RunRow(ENGINE, "my_capture", method, 0, 0, psnr, 0.8, 0.2, "ok", [0, 1, 2], near, "v", "f")
        for method, psnr in (("uniform", 18.0), ("ours", 19.0))
    ]
    plan = {"engines": [ENGINE], "scenes": ["my_capture"], "methods": ["uniform", "ours"], "trials": 1}
    initial = rounded_poses(half_hemisphere_poses(6).numpy())
    table = make_table(plan, rows, {"my_capture": {"initial_poses": initial}})
    study = collect_study(table)
    assert hypotheses_of(study) == ()
    text = write_study(tmp_path, table)[0].read_text()
    assert "my_capture" in text and "+1.00" in text
    assert "planned hypotheses" not in text and "moldGoldCape" not in text and "maryRose" not in text
    # Where every method loses on average, the page does not call a loss the "largest gain".
    rows[1] = RunRow(ENGINE, "my_capture", "ours", 0, 0, 17.0, 0.8, 0.2, "ok", [0, 1, 2], near, "v", "f")
    worse = make_table(plan, rows, {"my_capture": {"initial_poses": initial}})
    text = write_study(tmp_path / "worse", worse)[0].read_text()
    assert "none gains on average (the closest is ours, -1.00 dB" in text and "the largest mean gain is" not in text


def test_runs_whose_views_were_partly_drawn_uniformly_are_kept_and_named_on_the_page(tmp_path):
    """A sampler that found fewer positive scores than views (a NeRF that renders nothing) drew the
    rest uniformly: the table keeps how many, and the page says which runs."""
    table = synthetic_table({"ours": 1.0, "fisherrf": -2.0})
    filled = [r for r in table["runs"] if r["method"] == "fisherrf" and r["scene"] == "chair"][:3]
    for run, views in zip(filled, (6, 6, 2)):
        run["uniform_fill"] = views
    back = read_table(write_table(tmp_path / "t.json", table))
    assert [r.uniform_fill for r in table_rows(back) if r.method == "fisherrf" and r.scene == "chair"][:4] == [
        6,
        6,
        2,
        0,
    ]
    assert sum("uniform_fill" in r for r in back["runs"]) == 3  # 0 stays implicit
    text = to_markdown(study_blocks(collect_study(back), {}), tmp_path)
    assert f"drew the others uniformly: 3 (fisherrf on chair, {ENGINE}: 3 runs, 14 views)" in text
    plain = to_markdown(study_blocks(collect_study(synthetic_table({"ours": 1.0})), {}), tmp_path)
    assert "uniformly:" not in plain


def test_a_run_folders_row_carries_its_selections_uniform_fill(tmp_path):
    from nerfaug.experiment.runfolder import write_selection
    from nerfaug.report.collect import Run
    from nerfaug.report.study_table import row_of
    from nerfaug.selection import Selection

    pool = half_hemisphere_poses(8)
    result = {"seed": 3, "metrics": {"psnr": 14.0}, "code_version": "v", "fingerprint": "f", "chosen": [1, 4]}
    rows = []
    for name, fill in (("filled", 2), ("chosen", 0)):
        folder = tmp_path / name
        folder.mkdir()
        selection = Selection(torch.tensor([1, 4]), torch.zeros(8), {}, "fisherrf-sampling", fill)
        write_selection(folder, selection.to_dict(), ["a", "b"], pool, pool[:2])
        row, _ = row_of(ENGINE, Run("mic", "fisherrf-sampling", 3, folder, result))
        rows.append(row)
    assert [r.uniform_fill for r in rows] == [2, 0]
