"""The study of rounds' hypotheses Q1-Q4 (docs/study-plan.md, plan of 2026-11-28) computed from
constructed tables whose answers are known: p values against an enumeration of every sign pattern,
Q2's pairing with the one-shot arm's table by seed, layout and engine version (and only runs whose
fingerprint is current; not judged without that table), Q3's three outcomes, the secondary curve
area, and partial tables deciding nothing."""

import itertools

import numpy as np
import pytest

from nerfaug.hemisphere import half_hemisphere_poses
from nerfaug.report.document import to_markdown
from nerfaug.report.rounds_verdicts import (
    ROUNDS_HELD_BACK,
    ROUNDS_METHODS,
    ROUNDS_SCENES,
    ROUNDS_TRIALS,
    OneShotArm,
    auc_test,
    rounds_blocks,
    rounds_rows,
)
from nerfaug.report.study import collect_study
from nerfaug.report.study_hypotheses import plan_kind
from nerfaug.report.study_table import RunRow, make_table, rounded_poses
from nerfaug.report.study_verdicts import min_detectable_effect

ENGINE = "nerfacto-cpu"
SEEDS = range(ROUNDS_TRIALS)
SCENES = (*ROUNDS_SCENES, ROUNDS_HELD_BACK)


def curve(final: float, gain: float) -> tuple:
    """A curve of 4 to 12 views rising linearly by `gain` a view to `final`."""
    return tuple((v, final - gain * (12 - v)) for v in range(4, 13))


def table(offsets: dict[str, float], held_back: dict | None = None, shift: float = 0.0, rounds: int = 8) -> dict:
    """4 scenes + the held-back one x 6 methods x 10 seeds (layout seed mod 3): uniform varies by
    scene and seed; a method is uniform + its offset + noise (SD 0.5 dB); every PSNR + `shift`.
    Curves (rounds > 1) rise by 0.5 dB a view, ours's by 0.7."""
    rng = np.random.default_rng(5)
    rows = []
    near = rounded_poses(half_hemisphere_poses(3).numpy())
    for scene in SCENES:
        shifts = offsets if scene != ROUNDS_HELD_BACK else (held_back or offsets)
        for seed in SEEDS:
            base = 22.0 + rng.normal(0, 2)
            for method in ROUNDS_METHODS:
                psnr = shift + base + (0.0 if method == "uniform" else shifts.get(method, 0.0) + rng.normal(0, 0.5))
                points = curve(psnr, 0.7 if method == "ours" else 0.5) if rounds > 1 else ()
                rows.append(
                    RunRow(
                        ENGINE, scene, method, seed, seed, psnr, 0.8, 0.2, "ok", [0, 1, 2], near, "v",
                        f"fp-{method}-{rounds}", layout=seed % 3, curve=points,
                    )
                )  # fmt: skip
    plan = {
        "engines": [ENGINE],
        "scenes": list(SCENES),
        "methods": list(ROUNDS_METHODS),
        "trials": 10,
        "config": {"rounds": rounds, "n_initial": 4 if rounds > 1 else 6},
    }
    initial = rounded_poses(half_hemisphere_poses(4).numpy())
    layouts = {"1": initial, "2": initial}
    return make_table(plan, rows, {s: {"initial_poses": initial, "layouts": layouts} for s in SCENES})


def arm(one_shot: dict, current: set, source: str = "tables/rounds-oneshot-table.json") -> OneShotArm:
    """`one_shot` as the one-shot arm's table, its runs with a fingerprint in `current` counted."""
    return OneShotArm(one_shot, frozenset(current), source)


def verdicts(rounds: dict, one_shot: dict | None = None, current: set | None = None) -> dict[str, list[str]]:
    given = None if one_shot is None else arm(one_shot, current)
    return {row[0]: row for row in rounds_rows(collect_study(rounds), ENGINE, given)}


def sign_flip_by_enumeration(values) -> float:
    """Two-sided sign-flip p by every one of the 2^n sign patterns (independent of scipy)."""
    x = np.asarray(values)
    observed = abs(x.mean())
    means = [abs(np.mean(x * np.array(signs))) for signs in itertools.product((-1, 1), repeat=x.size)]
    return float(np.mean([m >= observed - 1e-12 for m in means]))


def seed_means(a: dict, method: str, b: dict | None = None, other: str = "uniform", key: str = "psnr") -> list[float]:
    """Each seed's mean over the four scenes of a's `method` - b's `other` (b: a itself)."""
    b = b or a
    mine = {(r["scene"], r["method"], r["seed"], r.get("layout", 0)): r for r in a["runs"]}
    theirs = {(r["scene"], r["method"], r["seed"], r.get("layout", 0)): r for r in b["runs"]}

    def value(row):
        if key == "psnr":
            return row["psnr"]
        views, psnr = np.array(row["curve"], dtype=float).T
        return float(np.sum(np.diff(views) * (psnr[1:] + psnr[:-1]) / 2) / (views[-1] - views[0]))

    return [
        float(
            np.mean([value(mine[(s, method, k, k % 3)]) - value(theirs[(s, other, k, k % 3)]) for s in ROUNDS_SCENES])
        )
        for k in SEEDS
    ]


def test_ours_ahead_everywhere_holds_with_the_enumerated_p_and_replicates_on_the_held_back_scene():
    rounds = table({"ours": 2.0, "fisherrf": -1.0})
    assert plan_kind(collect_study(rounds)) == "rounds"
    found = verdicts(rounds)
    expected = min(1.0, 5 * sign_flip_by_enumeration(seed_means(rounds, "ours")))
    assert expected < 0.05
    assert found["Q1"][3] == "**holds**" and f"sign-flip p x 5 = {expected:.3f}" in found["Q1"][4]
    # Q3: furthest is worse than ours and better than fisherrf: neither side wins.
    assert found["Q3"][3] == "**not supported**"
    for a, b in (("furthest", "ours"), ("furthest", "fisherrf")):
        p = min(1.0, 2 * sign_flip_by_enumeration(seed_means(rounds, a, other=b)))
        assert f"{a} - {b}: mean {np.mean(seed_means(rounds, a, other=b)):+.2f} dB" in found["Q3"][4]
        assert f"p x 2 = {p:.3f}" in found["Q3"][4] or f"p x 2 = {p:.1e}" in found["Q3"][4]
    assert found["Q4"][3] == "**holds**"  # ours alone was found better; +2 dB on the held-back scene too
    # Without the one-shot arm's table, Q2 is not judged, and its row names the option that gives it.
    assert found["Q2"][3] == "**not judged**"
    assert "no one-shot table was given (nerfaug study --one-shot-table FILE" in found["Q2"][4]


def test_the_secondary_curve_area_is_shown_beside_q1_and_decides_nothing():
    rounds = table({"ours": 0.0})
    entry = auc_test([c for c in collect_study(rounds).cells if c.scene in ROUNDS_SCENES], "ours")
    means = seed_means(rounds, "ours", key="auc")
    assert entry["seed_means"] == pytest.approx(means)
    # ours's curves rise faster to the same end: a smaller mean height by 0.2 x 4 = 0.8 dB plus noise.
    assert np.mean(means) < -0.5 and entry["significant"] and not entry["better"]
    found = verdicts(rounds)
    assert (
        f"secondary, deciding nothing: ours - uniform, curve area / span: mean {np.mean(means):+.2f}"
        in (found["Q1"][4])
    )
    assert found["Q1"][3] == "**not supported**"  # the primary outcome decides


def test_no_gain_is_not_supported_with_the_smallest_effect_and_nothing_to_replicate():
    rounds = table({})
    found = verdicts(rounds)
    sd = np.std(seed_means(rounds, "ours"), ddof=1)
    mde = min_detectable_effect(10, 5)
    assert found["Q1"][3] == "**not supported**"
    assert f"{mde:.2f} per-seed SDs = {mde * sd:.2f} dB at the observed SD {sd:.2f} dB" in found["Q1"][5]
    assert found["Q4"][3] == "**not applicable**"


@pytest.mark.parametrize(
    ("offsets", "outcome"),
    [({"furthest": 2.0}, "coverage wins"), ({"ours": 2.0, "fisherrf": 2.0}, "uncertainty wins")],
)
def test_q3_names_the_side_that_beats_both(offsets, outcome):
    assert verdicts(table(offsets))["Q3"][3] == f"**{outcome}**"


def test_q2_pairs_each_rounds_run_with_the_one_shot_run_of_its_seed_and_layout():
    rounds, one_shot = table({"ours": 0.5}), table({"ours": 0.5}, shift=-1.5, rounds=1)
    current = {"fp-uniform-1", "fp-ours-1"}
    found = verdicts(rounds, one_shot, current)
    for method in ("uniform", "ours"):
        means = seed_means(rounds, method, one_shot, method)
        p = min(1.0, 2 * sign_flip_by_enumeration(means))
        assert f"{method}: rounds - one-shot: mean {np.mean(means):+.2f} dB" in found["Q2"][4]
        assert f"p x 2 = {p:.3f}" in found["Q2"][4]
    assert found["Q2"][3] == "**holds**"
    # One-shot runs worse than rounds' contradicts when reversed.
    assert verdicts(rounds, table({"ours": 0.5}, shift=1.5, rounds=1), current)["Q2"][3] == "**contradicted**"
    # Fingerprints that no longer match their settings: those runs are no arm of the comparison.
    stale = verdicts(rounds, one_shot, {"fp-uniform-1"})["Q2"]
    assert stale[3] == "**not judged: no current one-shot runs of ours**"
    assert "left out: their fingerprints no longer match" in stale[4]
    # The arm part-way decides nothing.
    part = one_shot | {"runs": [r for r in one_shot["runs"] if r["trial"] < 9]}
    assert verdicts(rounds, part, current)["Q2"][3] == "**partial: 72 of 80 one-shot runs**"
    # One-shot runs of another engine version are not paired with the runs in rounds.
    other = one_shot | {"runs": [r | {"engine_version": "hash-cpu-1"} for r in one_shot["runs"]]}
    assert verdicts(rounds, other, current)["Q2"][3] == "**not judged: no current one-shot runs of uniform, ours**"
    # Another layout for each seed: no pair at all.
    moved = table({"ours": 0.5}, shift=-1.5, rounds=1)
    for run in moved["runs"]:
        run["layout"] = (run["seed"] + 1) % 3
    assert verdicts(rounds, moved, current)["Q2"][3].startswith("**not judged: no current one-shot runs")


def test_a_partial_table_decides_nothing_and_shows_its_numbers():
    rounds = table({"ours": 2.0})
    rounds["runs"] = [r for r in rounds["runs"] if not (r["scene"] == "mic" and r["method"] == "furthest")]
    found = verdicts(rounds)
    planned = len(ROUNDS_SCENES) * len(ROUNDS_METHODS) * ROUNDS_TRIALS
    for name in ("Q1", "Q3", "Q4"):
        assert found[name][3] == f"**partial: {planned - 10} of {planned} runs**", name
    assert f"ours - uniform: mean {np.mean(seed_means(rounds, 'ours')):+.2f} dB" in found["Q1"][4]
    # The held-back scene part-way: Q4 waits for it.
    rounds = table({"ours": 2.0})
    rounds["runs"] = [r for r in rounds["runs"] if not (r["scene"] == ROUNDS_HELD_BACK and r["trial"] == 9)]
    assert verdicts(rounds)["Q4"][3] == f"**partial: {len(ROUNDS_METHODS) * 9} of {len(ROUNDS_METHODS) * 10} runs**"


def test_a_dead_run_stays_in_the_test_and_leaves_the_sensitivity_line():
    rounds = table({"ours": 2.0})
    for run in rounds["runs"]:
        if (run["scene"], run["method"], run["seed"]) == ("cow", "ours", 3):
            run.update(psnr=8.0, empty=True)
    found = verdicts(rounds)
    assert f"mean {np.mean(seed_means(rounds, 'ours')):+.2f} dB" in found["Q1"][4]
    assert found["Q1"][6].startswith("without the 1 dead run(s)' pairs: holds")
    text = to_markdown(rounds_blocks(collect_study(rounds)), None)
    assert "dead runs per cell, engine nerfacto-cpu: mic 0; maryRose 0; dtu_scan24 0; cow 1 (ours seed 3)" in text


def test_the_page_names_the_one_shot_table_or_says_that_q2_waits_for_it():
    rounds, one_shot = table({"ours": 0.5}), table({"ours": 0.5}, shift=1.5, rounds=1)
    for run in one_shot["runs"]:
        if (run["scene"], run["method"], run["seed"]) == ("mic", "ours", 2):
            run.update(psnr=8.0, empty=True)
    text = to_markdown(rounds_blocks(collect_study(rounds), arm(one_shot, {"fp-uniform-1", "fp-ours-1"})), None)
    assert "in the study's own one-shot arm" in text and "same table" not in text
    assert "one round, read from the table rounds-oneshot-table.json)" in text  # its file name, not its path
    assert "tables/" not in text
    assert "dead one-shot runs, engine nerfacto-cpu: 1 (mic ours seed 2)" in text
    alone = to_markdown(rounds_blocks(collect_study(rounds)), None)
    assert "given with --one-shot-table: none was given, so Q2 is not judged" in alone
    assert "dead one-shot runs" not in alone and "| Q2 | " in alone and "**not judged**" in alone
