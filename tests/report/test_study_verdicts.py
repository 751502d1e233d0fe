"""The GPU study's hypotheses G1-G4 computed from a constructed table whose answers are known, the
smallest detectable effect beside "not supported", and the dead runs' sensitivity line."""

import importlib.util
import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from nerfaug.hemisphere import half_hemisphere_poses
from nerfaug.report.document import to_markdown
from nerfaug.report.study import collect_study
from nerfaug.report.study_hypotheses import plan_kind
from nerfaug.report.study_page import study_blocks
from nerfaug.report.study_table import RunRow, make_table, rounded_poses
from nerfaug.report.study_verdicts import (
    GPU_HELD_BACK,
    GPU_METHODS,
    GPU_SCENES,
    GPU_TRIALS,
    g_family,
    gpu_rows,
    min_detectable_effect,
)

ROOT = Path(__file__).resolve().parents[2]
SEEDS = range(10)


def gpu_table(offsets: dict[str, float], engine: str = "paper", held_back: dict | None = None, dead=()) -> dict:
    """The plan's 4 scenes (+ the held-back one) x its 6 methods x 10 seeds: uniform varies by
    scene and seed; a method is uniform + its offset + noise (SD 0.5 dB). `dead`: (scene, method,
    seed) whose run rendered background only (PSNR 8 dB, flagged)."""
    rng = np.random.default_rng(3)
    rows = []
    near = rounded_poses(half_hemisphere_poses(3).numpy())
    for scene in (*GPU_SCENES, GPU_HELD_BACK):
        shifts = offsets if scene != GPU_HELD_BACK else (held_back or offsets)
        for seed in SEEDS:
            base = 24.0 + rng.normal(0, 2)
            for method in GPU_METHODS:
                psnr = base + (0.0 if method == "uniform" else shifts.get(method, 0.0) + rng.normal(0, 0.5))
                empty = (scene, method, seed) in dead
                rows.append(
                    RunRow(
                        engine, scene, method, seed, seed, 8.0 if empty else psnr, 0.8, 0.2, "ok", [0, 1, 2], near,
                        "v", "f", empty=empty,
                    )
                )  # fmt: skip
    plan = {"engines": [engine], "scenes": [*GPU_SCENES, GPU_HELD_BACK], "methods": list(GPU_METHODS), "trials": 10}
    initial = rounded_poses(half_hemisphere_poses(6).numpy())
    return make_table(plan, rows, {s: {"initial_poses": initial} for s in (*GPU_SCENES, GPU_HELD_BACK)})


def verdicts(table: dict, engine: str = "paper") -> dict[str, list[str]]:
    return {row[0]: row for row in gpu_rows(collect_study(table), engine)}


def sign_flip_by_enumeration(values) -> float:
    """Two-sided sign-flip p by every one of the 2^n sign patterns (independent of scipy)."""
    x = np.asarray(values)
    observed = abs(x.mean())
    means = [abs(np.mean(x * np.array(signs))) for signs in itertools.product((-1, 1), repeat=x.size)]
    return float(np.mean([m >= observed - 1e-12 for m in means]))


def seed_means(table: dict, method: str, reference: str = "uniform", skip=()) -> list[float]:
    """Each seed's mean over the four scenes of method - reference, computed from the rows."""
    psnr = {(r["scene"], r["method"], r["seed"]): r["psnr"] for r in table["runs"]}
    return [
        float(np.mean([psnr[(s, method, k)] - psnr[(s, reference, k)] for s in GPU_SCENES if (s, k) not in skip]))
        for k in SEEDS
    ]


def test_a_gain_on_every_scene_holds_and_its_p_is_the_enumerated_sign_flip_p_times_five():
    table = gpu_table({"ours": 2.0, "ours-batch-sharp": 0.0, "entropy-sampling": 0.0, "fisherrf": -1.0})
    found = verdicts(table)
    family = g_family(collect_study(table), "paper")
    means = seed_means(table, "ours")
    assert family["ours"]["seed_means"] == pytest.approx(means)
    expected = min(1.0, 5 * sign_flip_by_enumeration(means))
    assert family["ours"]["p_bonferroni"] == pytest.approx(expected)
    assert f"sign-flip p x 5 = {expected:.3f}" in found["G1"][4] or f"{expected:.1e}" in found["G1"][4]
    assert found["G1"][3] == "**holds**"
    assert found["G2"][3] == "**holds**"  # +2 over entropy-sampling, +3 over fisherrf on every seed
    assert found["G3"][3] == "**contradicted**"  # ours beats uniform
    assert found["G4"][3] == "**holds**"  # the held-back scene has the same +2 dB
    assert found["G1"][5] == "" and found["G1"][6] == "no dead run in these pairs"


def test_no_gain_is_not_supported_with_the_smallest_effect_the_study_could_have_seen():
    table = gpu_table({"ours": 0.0})
    found = verdicts(table)
    assert found["G1"][3] == "**not supported**" and found["G2"][3] == "**not supported**"
    means = np.array(seed_means(table, "ours"))
    sd = means.std(ddof=1)
    mde = min_detectable_effect(10, 5)
    assert "10 seed pairs, x5: smallest attainable p x 5 = 0.010" in found["G1"][5]
    assert f"{mde:.2f} per-seed SDs = {mde * sd:.2f} dB at the observed SD {sd:.2f} dB" in found["G1"][5]
    # G3 holds as the plan defines it, and says what that does not show.
    assert found["G3"][3] == "**holds**" and "not evidence that none is" in found["G3"][5]
    assert found["G4"][3] == "**not applicable**"


def test_a_significant_loss_contradicts_and_a_partial_table_decides_nothing():
    table = gpu_table({"ours": -2.0})
    assert verdicts(table)["G1"][3] == "**contradicted**"
    table["runs"] = [r for r in table["runs"] if not (r["scene"] == "lego" and r["method"] == "furthest")]
    found = verdicts(table)
    planned = len(GPU_SCENES) * len(GPU_METHODS) * GPU_TRIALS
    for name in ("G1", "G2", "G3", "G4"):
        assert found[name][3] == f"**partial: {planned - 10} of {planned} runs**", name
    assert "-2." in found["G1"][4]  # the numbers as they stand are still shown


def test_a_dead_run_is_kept_in_the_planned_test_and_left_out_of_the_sensitivity_line():
    """Uniform dead on mic, seed 3: every method gains about 16 dB there."""
    alive = gpu_table({"ours": 0.3})
    dead = gpu_table({"ours": 0.3}, dead={("mic", "uniform", 3)})
    planned, without = verdicts(dead)["G1"], verdicts(alive)["G1"]
    assert without[6] == "no dead run in these pairs"
    assert planned[6].startswith("without the 1 dead run(s)' pairs")
    kept = seed_means(dead, "ours")
    assert kept[3] > 3.0  # the dead pair dominates seed 3's mean in the planned analysis
    left_out = seed_means(dead, "ours", skip={("mic", 3)})
    assert f"mean {np.mean(kept):+.2f} dB" in planned[4]
    assert f"mean {np.mean(left_out):+.2f} dB" in planned[6]
    assert "mic 1 (uniform seed 3)" in to_markdown(study_blocks(collect_study(dead), {}), ROOT)


def test_the_minimum_detectable_effect_matches_the_analytic_power():
    # Many values: the t-test's power is the normal one, (z_{1-a/2k} + z_power) / sqrt(n).
    n = 20_000
    analytic = (stats.norm.ppf(1 - 0.05 / 5 / 2) + stats.norm.ppf(0.8)) / math.sqrt(n)
    assert min_detectable_effect(n, 5) == pytest.approx(analytic, rel=2e-3)
    # Ten values: a simulated t-test at that effect rejects about 4 times in 5.
    effect = min_detectable_effect(10, 5)
    draws = np.random.default_rng(0).normal(effect, 1.0, (20_000, 10))
    rejected = stats.ttest_1samp(draws, 0.0, axis=1).pvalue < 0.01
    assert rejected.mean() == pytest.approx(0.8, abs=0.02)
    # Five seeds and x5: the exact tests' smallest p (2/32 x 5) cannot reach 0.05.
    assert math.isinf(min_detectable_effect(5, 5)) and math.isfinite(min_detectable_effect(8, 5))


def test_a_gpu_study_table_gets_g1_to_g4_with_mic_or_lego_alone():
    for scene in ("mic", "lego"):
        table = gpu_table({"ours": 0.5})
        table["runs"] = [r for r in table["runs"] if r["scene"] == scene]
        study = collect_study(table)
        assert plan_kind(study) == "gpu", scene
        page = to_markdown(study_blocks(study, {}), ROOT)
        for name in ("G1", "G2", "G3", "G4"):
            assert f"| {name} |" in page and f"| {name} |" in page
        assert "| R1 |" not in page and "partial: 60 of 240 runs" in page
    smoke = gpu_table({"ours": 0.5}, engine="nerfacto-cpu+batch_size=64")
    assert plan_kind(collect_study(smoke)) != "gpu"
    assert plan_kind(collect_study(smoke), "gpu") == "gpu"
    assert "| G1 |" in to_markdown(study_blocks(collect_study(smoke), {}, "gpu"), ROOT)


def test_the_page_opens_with_one_verdict_line_naming_the_engine():
    page = to_markdown(study_blocks(collect_study(gpu_table({"ours": 2.0})), {}), ROOT)
    first = [line for line in page.splitlines() if line.strip()][1]
    assert first.startswith("**Verdict") and "engine paper: " in first and "beats uniform" in first


def test_the_verdicts_plan_is_the_gpu_studys_plan():
    from nerfaug.experiment import study

    assert (*GPU_SCENES, GPU_HELD_BACK) == study.GPU_STUDY_SCENES
    assert (GPU_HELD_BACK,) == study.GPU_STUDY_HELD_BACK
    spec = importlib.util.spec_from_file_location("gpu_study", ROOT / "benchmarks" / "gpu_study.py")
    script = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(script)
    assert tuple(script.PLAN["methods"]) == GPU_METHODS and script.PLAN["trials"] == GPU_TRIALS
