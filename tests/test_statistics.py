import itertools
import math

import numpy as np
import pytest
import torch
from scipy import stats

from nerfaug.coverage import (
    mean_pairwise_angle,
    outside_wedge_half_share,
    seen_half_start,
    unseen_half_share,
    view_coverage,
)
from nerfaug.equivalence import paired_equivalence
from nerfaug.hemisphere import half_hemisphere_poses, pose_from_angles
from nerfaug.statistics import (
    bootstrap_median_difference,
    compare,
    markdown_table,
    min_attainable_p,
    min_attainable_paired_p,
    paired_comparison,
    seed_level_comparison,
    sign_flip_p,
    summarise,
    summary_table,
)


def test_summarise_by_hand():
    s = summarise([3, 1, 4, 1, 5, 9, 2, 6, 5, 3])
    # sorted: 1 1 2 3 3 4 5 5 6 9; linear interpolation at positions 2.25, 4.5, 6.75
    assert s == {
        "n": 10,
        "median": 3.5,
        "q1": 2.25,
        "q3": 5.0,
        "iqr": 2.75,
        "mean": 3.9,
        "min": 1.0,
        "max": 9.0,
    }
    assert summarise([1, 2, 3, 4])["iqr"] == pytest.approx(1.5)
    assert summarise([7.0])["iqr"] == 0.0


def test_summarise_rejects_empty_and_nan():
    with pytest.raises(ValueError, match="no values"):
        summarise([])
    with pytest.raises(ValueError, match="NaN"):
        summarise([1.0, float("nan")])


def test_compare_medians_iqr_and_exact_test_by_hand():
    ours = [20.1, 19.9, 20.3, 20.0, 20.2]
    baseline = [12.0, 12.5, 11.8, 13.0, 12.2]
    c = compare(ours, baseline)
    assert c["median_ours"] == pytest.approx(20.1) and c["median_baseline"] == pytest.approx(12.2)
    assert c["median_change"] == pytest.approx((20.1 - 12.2) / 12.2)
    assert c["iqr_ours"] == pytest.approx(0.2) and c["iqr_baseline"] == pytest.approx(0.5)
    assert c["iqr_reduction"] == pytest.approx(0.6)
    assert c["better"] and c["u_statistic"] == 25 and c["prob_ours_greater"] == 1.0
    assert c["test_method"] == "exact"
    assert c["p_value"] == pytest.approx(2 / math.comb(10, 5))  # complete separation
    assert c["p_bonferroni"] == pytest.approx(3 * 2 / math.comb(10, 5))
    assert c["significant"] and not c["too_small"] and c["note"] == ""


def test_compare_matches_scipy_with_overlap():
    ours = [1.2, 3.4, 2.2, 5.1, 4.4, 2.9]
    baseline = [0.5, 1.9, 2.8, 0.1, 1.1]
    expected = stats.mannwhitneyu(ours, baseline, alternative="two-sided", method="exact")
    c = compare(ours, baseline)
    assert c["u_statistic"] == expected.statistic
    assert c["p_value"] == pytest.approx(expected.pvalue, rel=1e-12)
    assert c["p_value"] < 0.05 < c["p_bonferroni"]  # significant alone, not after correction
    assert not c["significant"]


def test_bonferroni_multiplies_and_caps_at_one():
    ours, baseline = [1.0, 2.0, 3.0, 4.5], [1.5, 2.5, 3.5, 4.0]
    p = compare(ours, baseline, n_comparisons=1)["p_value"]
    assert compare(ours, baseline, n_comparisons=1)["p_bonferroni"] == pytest.approx(p)
    assert compare(ours, baseline, n_comparisons=2)["p_bonferroni"] == pytest.approx(min(1, 2 * p))
    assert compare(ours, baseline, n_comparisons=3)["p_bonferroni"] == 1.0
    with pytest.raises(ValueError):
        compare(ours, baseline, n_comparisons=0)


def test_lower_is_better_metrics():
    c = compare([0.13, 0.12, 0.14], [0.30, 0.31, 0.29], higher_is_better=False)
    assert c["better"] and c["median_change"] == pytest.approx((0.13 - 0.30) / 0.30)
    assert not compare([0.13, 0.12, 0.14], [0.30, 0.31, 0.29])["better"]


def test_min_attainable_p_is_complete_separation_of_the_exact_test():
    assert min_attainable_p(2, 2) == pytest.approx(1 / 3)
    for n1, n2 in [(3, 3), (4, 4), (5, 5), (10, 10), (3, 7)]:
        assert min_attainable_p(n1, n2) == pytest.approx(2 / math.comb(n1 + n2, n1))
    assert min_attainable_p(1, 1) == 1.0


def test_too_small_samples_are_flagged_even_when_perfectly_separated():
    c = compare([10.0, 11.0], [1.0, 2.0])
    assert c["p_value"] == pytest.approx(1 / 3)
    assert c["too_small"] and not c["significant"]
    assert "0.333" in c["note"] and "Bonferroni x3" in c["note"]
    # n = 4: 2/70 = 0.029 would pass alone but not after a correction of 3.
    separated = ([5.0, 6.0, 7.0, 8.0], [1.0, 2.0, 3.0, 4.0])
    assert compare(*separated)["too_small"]
    assert not compare(*separated, n_comparisons=1)["too_small"]
    assert compare(*separated, n_comparisons=1)["significant"]


def test_ties_use_an_exact_permutation_test_or_the_normal_approximation():
    ours, baseline = [1.0, 2.0, 2.0, 3.0, 5.0], [2.0, 3.0, 4.0, 4.0, 6.0]
    c = compare(ours, baseline)
    expected = stats.mannwhitneyu(ours, baseline, method=stats.PermutationMethod(n_resamples=np.inf))
    assert c["test_method"].startswith("permutation")
    assert c["p_value"] == pytest.approx(expected.pvalue)
    big_ours, big_baseline = list(np.arange(30) // 2), list(np.arange(30) // 2 + 3)
    c = compare(big_ours, big_baseline)
    assert c["test_method"].startswith("asymptotic")
    assert c["p_value"] == pytest.approx(stats.mannwhitneyu(big_ours, big_baseline, method="asymptotic").pvalue)


def _records():
    ours = {"lego": [20.1, 19.9, 20.3, 20.0, 20.2], "chair": [25.0, 24.0, 26.0]}
    uniform = {"lego": [12.0, 12.5, 11.8, 13.0, 12.2], "chair": [23.0, 22.0, 27.0]}
    records = []
    for method, by_scene in (("ours", ours), ("uniform", uniform)):
        for scene, values in by_scene.items():
            for trial, value in enumerate(values):
                records.append({"scene": scene, "method": method, "trial": trial, "psnr": value, "lpips": None})
    records.append({"scene": "lego", "method": "extra", "trial": 0, "psnr": 15.0})
    records.append({"scene": "lego", "method": "fisherrf", "trial": 0, "psnr": None})
    return records, ours, uniform


def test_summary_table_rows_and_comparisons():
    records, ours, uniform = _records()
    rows = summary_table(records, "psnr", ours="ours", baselines=["fisherrf", "uniform"])
    assert [(r["scene"], r["method"], r["role"]) for r in rows] == [
        ("lego", "ours", "ours"),
        ("lego", "fisherrf", "baseline"),
        ("lego", "uniform", "baseline"),
        ("lego", "extra", "other"),
        ("chair", "ours", "ours"),
        ("chair", "uniform", "baseline"),
    ]
    lego_ours, lego_fisher, lego_uniform, lego_extra, _, chair_uniform = rows
    assert lego_ours["median"] == pytest.approx(20.1) and lego_ours["iqr"] == pytest.approx(0.2)
    assert lego_ours["p_value"] is None and lego_extra["p_value"] is None
    assert lego_fisher["n"] == 0 and lego_fisher["n_missing"] == 1 and lego_fisher["median"] is None
    assert lego_fisher["p_value"] is None
    expected = compare(ours["lego"], uniform["lego"], n_comparisons=2)
    for key in ("median_change", "iqr_reduction", "p_value", "p_bonferroni", "significant"):
        assert lego_uniform[key] == expected[key]
    assert chair_uniform["p_bonferroni"] == compare(ours["chair"], uniform["chair"], 2)["p_bonferroni"]
    assert chair_uniform["too_small"]


def test_summary_table_counts_missing_values_and_checks_input():
    records, _, _ = _records()
    rows = summary_table(records, "lpips", ours="ours", baselines=["uniform"])
    assert all(r["n"] == 0 and r["median"] is None for r in rows if r["method"] != "extra")
    assert rows[0]["n_missing"] == 5
    with pytest.raises(ValueError, match="trial"):
        summary_table(records + [records[0]], "psnr", "ours", ["uniform"])
    with pytest.raises(ValueError, match="higher_is_better"):
        summary_table(records, "depth_error", "ours", ["uniform"])
    assert summary_table(records, "depth_error", "ours", ["uniform"], higher_is_better=False)


def test_markdown_table():
    rows = [
        {"method": "ours", "median": 20.07, "p": None, "significant": True},
        {"method": "a|b", "median": 12.384, "p": 0.00012, "significant": False},
    ]
    table = markdown_table(rows, ["method", ("median", "PSNR", ".2f"), ("p", "p (Bonf.)"), "significant"])
    assert table == (
        "| method | PSNR | p (Bonf.) | significant |\n"
        "|---|---|---|---|\n"
        "| ours | 20.07 | - | yes |\n"
        "| a\\|b | 12.38 | 0.00012 | no |\n"
    )
    # rows may also be sequences, with column indices as keys
    assert markdown_table([["ours", 1.5]], [(0, "method"), (1, "x", ".1f")]) == (
        "| method | x |\n|---|---|\n| ours | 1.5 |\n"
    )


# ---- bootstrap CI of a difference of medians ---------------------------------------------------


def test_bootstrap_ci_equals_a_direct_percentile_computation():
    x = np.array([20.1, 21.4, 19.8, 22.0, 20.9, 21.1])
    y = np.array([18.0, 19.2, 18.7, 20.5, 17.9])
    found = bootstrap_median_difference(x, y, confidence=0.9, n_resamples=2000, seed=7)
    # The same resamples drawn by hand: each sample resampled on its own, x first, one batch.
    rng = np.random.default_rng(7)
    rx = x[rng.integers(0, x.size, (2000, x.size))]
    ry = y[rng.integers(0, y.size, (2000, y.size))]
    differences = np.median(rx, axis=1) - np.median(ry, axis=1)
    low, high = np.percentile(differences, [5.0, 95.0])
    assert found["difference"] == pytest.approx(np.median(x) - np.median(y))
    assert found["low"] == pytest.approx(low, abs=1e-12) and found["high"] == pytest.approx(high, abs=1e-12)
    assert found["low"] <= found["difference"] <= found["high"]


def test_bootstrap_ci_is_seeded_and_degenerate_cases_are_exact():
    x, y = [3.0, 1.0, 2.0, 5.0, 4.0], [1.0, 0.0, 2.0, 0.5, 1.5]
    assert bootstrap_median_difference(x, y, seed=3) == bootstrap_median_difference(x, y, seed=3)
    constant = bootstrap_median_difference([2.0] * 5, [0.5] * 5)
    assert (constant["low"], constant["difference"], constant["high"]) == (1.5, 1.5, 1.5)
    single = bootstrap_median_difference([2.0], [1.0, 3.0])
    assert single["difference"] == 0.0 and math.isnan(single["low"]) and math.isnan(single["high"])


# ---- coverage of the chosen views --------------------------------------------------------------


def test_seen_half_is_centred_on_the_initial_views():
    # Initial views at azimuth 90..180 degrees: their mean direction is 135, the seen half 45..225.
    assert seen_half_start(np.radians([90.0, 180.0])) == pytest.approx(math.radians(45.0))
    assert math.isnan(seen_half_start(np.radians([0.0, 90.0, 180.0, 270.0])))  # surrounding views


@pytest.mark.parametrize(
    ("chosen_deg", "share"),
    [
        ([0.0, 10.0, 350.0], 1.0),  # all opposite the initial views at 180
        ([180.0, 150.0, 210.0], 0.0),  # all beside them
        ([0.0, 180.0, 60.0, 300.0], 0.75),  # 0, 60 and 300 lie within 90 of 0: unseen
    ],
)
def test_unseen_half_share_analytic(chosen_deg, share):
    initial = np.radians([170.0, 180.0, 190.0])  # mean direction 180: the unseen half is centred on 0
    assert unseen_half_share(np.radians(chosen_deg), initial) == pytest.approx(share)


def test_mean_pairwise_angle_analytic():
    axes = np.eye(3)  # three orthogonal directions: every pair 90 degrees apart
    assert mean_pairwise_angle(axes) == pytest.approx(90.0)
    assert mean_pairwise_angle([[1, 0, 0], [-2, 0, 0]]) == pytest.approx(180.0)  # length is ignored
    assert mean_pairwise_angle([[0, 0, 1], [0, 0, 3], [1, 0, 0]]) == pytest.approx((0 + 90 + 90) / 3)
    assert math.isnan(mean_pairwise_angle([[1, 0, 0]]))


def test_view_coverage_of_poses():
    initial = half_hemisphere_poses(6)  # azimuth in [90, 270) degrees: the seen half is centred on 180
    opposite = pose_from_angles(torch.tensor(np.radians([0.0, 20.0])), torch.tensor(np.radians([60.0, 60.0])))
    coverage = view_coverage(opposite, initial)
    assert coverage["unseen_share"] == 1.0
    # Two cameras at polar 60 degrees, 20 degrees apart in azimuth: the angle between their
    # directions is arccos(sin^2 60 cos 20 + cos^2 60).
    expected = math.degrees(
        math.acos(math.sin(math.radians(60)) ** 2 * math.cos(math.radians(20)) + math.cos(math.radians(60)) ** 2)
    )
    assert coverage["spread_deg"] == pytest.approx(expected, abs=1e-4)
    assert view_coverage(initial, initial)["unseen_share"] == 0.0


def test_a_wedge_of_cameras_is_split_by_the_half_its_initial_views_came_from():
    # DTU-like: every camera within azimuth 300..20 degrees (a 80-degree wedge); the initial views
    # came from its first half, 300..340. On the hemisphere's rule every chosen view is "seen".
    half = {"start_deg": 300.0, "width_deg": 40.0}
    initial = pose_from_angles(torch.tensor(np.radians([305.0, 320.0, 335.0])), torch.tensor(np.radians([50.0] * 3)))
    chosen_deg = [310.0, 350.0, 5.0, 15.0]  # one in the initial half, three on the wedge's other side
    chosen = pose_from_angles(torch.tensor(np.radians(chosen_deg)), torch.tensor(np.radians([50.0] * 4)))
    assert outside_wedge_half_share(np.radians(chosen_deg), half) == pytest.approx(0.75)
    assert view_coverage(chosen, initial, half=half)["unseen_share"] == pytest.approx(0.75)
    assert view_coverage(chosen, initial)["unseen_share"] == 0.0  # the hemisphere's far half holds none
    # A half-turn half keeps the hemisphere's rule (the procedural study's numbers stand).
    full = {"start_deg": 90.0, "width_deg": 180.0}
    six = half_hemisphere_poses(6)
    assert view_coverage(chosen, six, half=full) == view_coverage(chosen, six)


# ---- paired comparison (the study's pooled, secondary analysis) -------------------------------


def test_paired_comparison_equals_scipy_and_a_direct_bootstrap():
    x = np.array([25.1, 24.0, 26.3, 23.9, 25.5, 24.8, 26.0])
    y = np.array([24.2, 24.5, 25.0, 23.0, 24.1, 24.9, 24.6])
    found = paired_comparison(x, y, n_comparisons=6, n_resamples=3000, seed=5)
    d = x - y
    p = stats.wilcoxon(d, alternative="two-sided", method="exact").pvalue
    assert found["p_value"] == pytest.approx(p) and found["p_bonferroni"] == pytest.approx(min(1.0, 6 * p))
    assert (found["wins"], found["ties"], found["losses"]) == (5, 0, 2)
    assert found["difference"] == pytest.approx(np.median(d)) and found["better"]
    # The same resamples drawn by hand: pairs resampled together, one batch.
    rng = np.random.default_rng(5)
    medians = np.median(d[rng.integers(0, d.size, (3000, d.size))], axis=1)
    low, high = np.percentile(medians, [2.5, 97.5])
    assert found["low"] == pytest.approx(low, abs=1e-12) and found["high"] == pytest.approx(high, abs=1e-12)


def test_paired_comparison_direction_zeros_and_bad_input():
    # LPIPS: lower is better, so x below y wins.
    lower = paired_comparison([0.1, 0.2, 0.15], [0.2, 0.3, 0.1], higher_is_better=False)
    assert (lower["wins"], lower["losses"], lower["better"]) == (2, 1, True)
    # Zero differences are dropped from the test but counted as ties.
    zeros = paired_comparison([1.0, 2.0, 3.0, 4.0], [1.0, 1.0, 1.0, 1.0])
    assert zeros["ties"] == 1 and zeros["p_value"] == pytest.approx(stats.wilcoxon([1.0, 2.0, 3.0]).pvalue)
    same = paired_comparison([1.0, 2.0], [1.0, 2.0])
    assert same["p_value"] == 1.0 and not same["significant"] and not same["better"]
    # Eight pairs all one way: 2 / 2^8 = 0.0078, significant after x6.
    eight = paired_comparison(np.arange(8) + 1.0, np.zeros(8), n_comparisons=6)
    assert eight["p_value"] == pytest.approx(2 / 2**8) and eight["significant"]
    with pytest.raises(ValueError, match="differ in length"):
        paired_comparison([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="NaN"):
        paired_comparison([1.0, math.nan], [1.0, 2.0])


# ---- seed-level tests across cells (trials that share a seed are not independent) ----------


def test_sign_flip_p_equals_a_direct_enumeration_of_every_sign_pattern():
    values = np.array([0.8, -0.3, 1.1, 0.4, 0.9, -0.2, 0.6, 1.3, 0.05])
    patterns = np.array(list(itertools.product([-1.0, 1.0], repeat=values.size)))
    means = (patterns * values).mean(axis=1)
    expected = np.mean(np.abs(means) >= abs(values.mean()) - 1e-12)
    assert sign_flip_p(values) == pytest.approx(expected)
    assert sign_flip_p(np.zeros(5)) == 1.0
    assert sign_flip_p(np.arange(1.0, 11.0)) == pytest.approx(2 / 2**10)  # all one sign: the smallest p


def test_min_attainable_paired_p_is_scipys_exact_signed_rank_at_complete_agreement():
    for n in (3, 6, 10):
        scipy_p = stats.wilcoxon(np.arange(1.0, n + 1.0), alternative="two-sided", method="exact").pvalue
        assert min_attainable_paired_p(n) == pytest.approx(scipy_p)


def test_seed_level_comparison_takes_one_value_per_seed():
    differences = {
        "lego": {0: 1.0, 1: 0.5, 2: -0.2, 3: 0.7},
        "chair": {0: 0.2, 1: 0.9, 2: 0.1, 3: 0.3, 4: 5.0},  # seed 4 is not in every cell: left out
        "materials": {0: 0.3, 1: -0.1, 2: 0.4, 3: 0.2},
    }
    found = seed_level_comparison(differences, n_comparisons=7, higher_is_better=True)
    means = np.array([np.mean([differences[c][s] for c in differences]) for s in range(4)])
    assert found["seeds"] == [0, 1, 2, 3] and found["n_cells"] == 3
    np.testing.assert_allclose(found["seed_means"], means)
    assert found["p_value"] == pytest.approx(sign_flip_p(means))
    assert found["p_wilcoxon"] == pytest.approx(stats.wilcoxon(means).pvalue)
    assert found["p_bonferroni"] == pytest.approx(min(1.0, 7 * found["p_value"]))
    assert (found["wins"], found["losses"], found["better"]) == (4, 0, True)
    lower = seed_level_comparison({"a": {0: -1.0, 1: -2.0}}, higher_is_better=False)
    assert lower["better"] and lower["wins"] == 2


def _null_cells(rng, n_cells, n_seeds, seed_sd, noise_sd):
    """Paired differences under the null: a zero-mean effect shared by every cell of a seed (the
    seed's picks and initialisation) plus independent zero-mean noise per cell."""
    shared = rng.normal(0.0, seed_sd, n_seeds)
    return {c: {k: shared[k] + rng.normal(0.0, noise_sd) for k in range(n_seeds)} for c in range(n_cells)}


@pytest.mark.slow
def test_seed_level_test_holds_its_false_positive_rate_where_pooling_pairs_does_not():
    rng = np.random.default_rng(0)
    simulations, alpha = 2000, 0.05
    seed_level = pooled = 0
    for _ in range(simulations):
        cells = _null_cells(rng, n_cells=3, n_seeds=10, seed_sd=1.0, noise_sd=0.3)
        seed_level += seed_level_comparison(cells)["p_value"] < alpha
        pairs = np.array([d for cell in cells.values() for d in cell.values()])
        pooled += stats.wilcoxon(pairs).pvalue < alpha
    # At the nominal rate (binomial sd at 2000 draws: 0.005) ...
    assert 0.035 <= seed_level / simulations <= 0.065
    # ... while treating the 30 pairs as independent rejects a true null far too often.
    assert pooled / simulations > 0.15


def test_compare_with_one_trial_each_and_a_tie_answers():
    """A one-trial run (a smoke test) whose values tie: scipy's permutation test refuses samples of
    one, so the tie-corrected asymptotic test answers, as scipy computes it."""
    found = compare([1.0], [1.0], 3)
    assert found["p_value"] == pytest.approx(stats.mannwhitneyu([1.0], [1.0], method="asymptotic").pvalue)
    assert found["too_small"] and not found["significant"]
    assert compare([1.0], [1.0, 2.0])["test_method"].startswith("asymptotic")


def test_paired_equivalence_by_hand():
    x = np.array([20.1, 21.4, 19.8, 22.0, 20.9, 21.7])
    d = np.array([0.05, -0.1, 0.12, 0.0, -0.04, 0.08])
    result = paired_equivalence(x + d, x, bound=0.2)
    n, mean = d.size, d.mean()
    sem = d.std(ddof=1) / math.sqrt(n)
    # The two one-sided t statistics and their tails, from the t distribution's survival function.
    p_lower = stats.t.sf((mean + 0.2) / sem, n - 1)
    p_upper = stats.t.sf((0.2 - mean) / sem, n - 1)
    assert result["p_lower"] == pytest.approx(p_lower, rel=1e-9)
    assert result["p_upper"] == pytest.approx(p_upper, rel=1e-9)
    assert result["p_value"] == pytest.approx(max(p_lower, p_upper), rel=1e-9)
    assert result["mean"] == pytest.approx(mean)
    assert result["max_abs_difference"] == pytest.approx(0.12)
    assert result["equivalent"] is True
    # TOST at alpha is the 90% interval inside the bounds.
    assert -0.2 < result["low"] < result["high"] < 0.2


@pytest.mark.parametrize(
    "d, why",
    [([0.45, 0.5, 0.55, 0.5, 0.48], "shifted past the bound"), ([0.6, -0.6, 0.5, -0.5, 0.05, -0.05], "too noisy")],
)
def test_paired_equivalence_is_not_shown_when_it_does_not_hold(d, why):
    d = np.array(d)
    result = paired_equivalence(d + 10.0, np.full(d.size, 10.0), bound=0.2)
    assert result["equivalent"] is False, why
    assert not (-0.2 < result["low"] and result["high"] < 0.2)


def test_paired_equivalence_refuses_bad_input():
    with pytest.raises(ValueError, match="at least two pairs"):
        paired_equivalence([1.0], [1.0], bound=0.2)
    with pytest.raises(ValueError, match="bound must be > 0"):
        paired_equivalence([1.0, 2.0], [1.0, 2.0], bound=0.0)
