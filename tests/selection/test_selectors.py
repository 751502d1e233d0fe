import math
import warnings
from collections import Counter

import numpy as np
import pytest
import torch
from scipy import stats

from nerfaug.hemisphere import pose_from_angles
from nerfaug.selection.selectors import (
    DirectDraw,
    greedy_farthest,
    rejection_sample,
    sample_then_fill,
    select_top_k,
    select_uniform,
)

TOY = torch.tensor([0.5, 1.0, 2.0, 4.0, 0.0, 2.5])


def test_accepted_draws_follow_the_target_distribution():
    generator = torch.Generator().manual_seed(0)
    n = 6000
    counts = Counter(int(rejection_sample(TOY, 1, generator)[0]) for _ in range(n))
    assert counts[4] == 0  # zero score, never accepted
    positive = [i for i in range(len(TOY)) if TOY[i] > 0]
    observed = np.array([counts[i] for i in positive])
    expected = n * TOY[positive].numpy() / TOY.sum().item()
    assert stats.chisquare(observed, expected).pvalue > 0.01
    uniform = np.full(len(positive), n / len(positive))
    assert stats.chisquare(observed, uniform).pvalue < 1e-6  # the test can tell the difference


def test_a_valid_larger_m_only_slows_sampling_down():
    generator = torch.Generator().manual_seed(1)
    n = 3000
    counts = Counter(int(rejection_sample(TOY, 1, generator, scale_m=20.0)[0]) for _ in range(n))
    positive = [i for i in range(len(TOY)) if TOY[i] > 0]
    expected = n * TOY[positive].numpy() / TOY.sum().item()
    assert stats.chisquare([counts[i] for i in positive], expected).pvalue > 0.01


def test_second_draw_is_from_the_remaining_candidates():
    scores = torch.tensor([1.0, 2.0, 3.0, 4.0])
    generator = torch.Generator().manual_seed(2)
    n = 6000
    pairs = Counter(tuple(rejection_sample(scores, 2, generator).tolist()) for _ in range(n))
    assert all(i != j for i, j in pairs)
    total = scores.sum().item()
    keys = [(i, j) for i in range(4) for j in range(4) if i != j]
    expected = [n * scores[i].item() / total * scores[j].item() / (total - scores[i].item()) for i, j in keys]
    assert stats.chisquare([pairs[k] for k in keys], expected).pvalue > 0.01


def test_without_replacement_k_can_take_every_positive_candidate():
    chosen = rejection_sample(TOY, 5, torch.Generator().manual_seed(3))
    assert sorted(chosen.tolist()) == [0, 1, 2, 3, 5]


def test_same_seed_same_choice():
    scores = torch.rand(50, generator=torch.Generator().manual_seed(0))
    a = rejection_sample(scores, 6, torch.Generator().manual_seed(9))
    b = rejection_sample(scores.clone(), 6, torch.Generator().manual_seed(9))
    assert torch.equal(a, b)


def test_too_small_m_warns_with_the_valid_m_and_clips():
    with pytest.warns(UserWarning, match=r"valid M is any M >= 4"):
        chosen = rejection_sample(TOY, 2, torch.Generator().manual_seed(0), scale_m=1.0)
    assert len(set(chosen.tolist())) == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rejection_sample(TOY, 2, torch.Generator().manual_seed(0), scale_m=4.0)  # M = max is valid


def test_nothing_acceptable_is_a_clear_error():
    with pytest.raises(ValueError, match="only 0 of 4 candidates can ever be accepted"):
        rejection_sample(torch.zeros(4), 1, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match="only 5 of 6"):
        rejection_sample(TOY, 6, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match=">= 0"):
        rejection_sample(torch.tensor([1.0, -0.5]), 1)
    with pytest.raises(ValueError, match="finite"):
        rejection_sample(torch.tensor([1.0, math.nan]), 1)
    with pytest.raises(ValueError, match="positive"):
        rejection_sample(TOY, 1, scale_m=0.0)


def test_endless_loops_are_cut_off():
    """The paper's loop ends after max_draws by drawing directly (saying so); the authors' sweep,
    which has no such distribution to draw from, gives up."""
    scores = torch.tensor([1e-9, 0.0, 0.0])
    with pytest.warns(DirectDraw, match="0 of 1 views in 500 draws"):
        chosen = rejection_sample(scores, 1, torch.Generator().manual_seed(0), scale_m=1.0, max_draws=500)
    assert chosen.tolist() == [0]  # the only candidate that can ever be accepted
    with pytest.raises(RuntimeError, match="gave up after 50 draws"):
        rejection_sample(torch.tensor([0.8, 0.0]), 1, torch.Generator().manual_seed(0), variant="authors", max_draws=50)


def test_drawing_directly_after_max_draws_keeps_the_samplers_distribution():
    """Pairs chosen with a loop cut off after a single proposal (then drawn directly) follow the
    sampler's law: first i with w_i / sum w, then j with w_j / (sum w - w_i)."""
    scores = torch.tensor([1.0, 2.0, 3.0, 4.0])
    generator = torch.Generator().manual_seed(3)
    n = 6000
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DirectDraw)
        pairs = Counter(tuple(rejection_sample(scores, 2, generator, max_draws=1).tolist()) for _ in range(n))
    assert all(i != j for i, j in pairs)
    total = scores.sum().item()
    keys = [(i, j) for i in range(4) for j in range(4) if i != j]
    expected = [n * scores[i].item() / total * scores[j].item() / (total - scores[i].item()) for i, j in keys]
    assert stats.chisquare([pairs[k] for k in keys], expected).pvalue > 0.01
    uniform = [n / len(keys)] * len(keys)
    assert stats.chisquare([pairs[k] for k in keys], uniform).pvalue < 1e-6  # the test can tell


def test_a_loop_that_finishes_is_not_changed_by_the_cut_off():
    """The choice for a seed is the loop's whenever it accepts k within max_draws."""
    for seed in range(20):
        with warnings.catch_warnings():
            warnings.simplefilter("error", DirectDraw)
            a = rejection_sample(TOY, 3, torch.Generator().manual_seed(seed))
            b = rejection_sample(TOY, 3, torch.Generator().manual_seed(seed), max_draws=10_000)
        assert a.tolist() == b.tolist()


def test_authors_variant_accepts_only_scores_above_fifteen_times_nu():
    scores = torch.tensor([1.0, 0.5, 0.9, 0.7, 0.8])  # only w > 15 * 0.05 = 0.75 can pass
    for seed in range(20):
        chosen = rejection_sample(scores, 3, torch.Generator().manual_seed(seed), variant="authors")
        assert sorted(chosen.tolist()) == [0, 2, 4]
    with pytest.raises(ValueError, match="only 3 of 5"):
        rejection_sample(scores, 4, variant="authors")
    scaled = rejection_sample(100.0 * scores, 3, torch.Generator().manual_seed(0), variant="authors")
    assert sorted(scaled.tolist()) == [0, 2, 4]  # scores are divided by their max first
    with pytest.raises(ValueError, match="paper"):
        rejection_sample(scores, 1, variant="metropolis")


def test_top_k_is_best_first_with_ties_to_the_lower_index():
    assert select_top_k(torch.tensor([1.0, 3.0, 2.0, 3.0]), 3).tolist() == [1, 3, 2]
    with pytest.raises(ValueError, match="cannot choose"):
        select_top_k(torch.tensor([1.0]), 2)


def test_uniform_is_distinct_and_seeded():
    a = select_uniform(30, 6, torch.Generator().manual_seed(4))
    assert len(set(a.tolist())) == 6 and a.max() < 30
    assert torch.equal(a, select_uniform(30, 6, torch.Generator().manual_seed(4)))


def test_greedy_farthest_spreads_views_away_from_training_and_each_other():
    azimuth = torch.linspace(0, 2 * math.pi, 13)[:-1]
    candidates = pose_from_angles(azimuth, torch.full((12,), 1.2))[:, :3, :3]
    training = pose_from_angles(torch.tensor([0.0]), torch.tensor([1.2]))[:, :3, :3]
    chosen = greedy_farthest(candidates, training, 3).tolist()
    assert chosen[0] == 6  # opposite the training view
    assert sorted(chosen[1:]) == [3, 9]  # then halfway between
    assert greedy_farthest(candidates, training[:0], 1).tolist() == [0]


def test_sample_then_fill_takes_every_positive_score_first_then_the_rest_uniformly():
    """The limit of the paper's sampler on scores + eps: positives first, in score-weighted order,
    then uniform among the zero scores (checked against the expected frequencies with scipy)."""
    scores = torch.tensor([0.0, 3.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    n = 4000
    firsts, fills = Counter(), Counter()
    for seed in range(n):
        chosen = sample_then_fill(scores, 4, torch.Generator().manual_seed(seed)).tolist()
        assert len(set(chosen)) == 4 and set(chosen[:2]) == {1, 4}
        firsts[chosen[0]] += 1
        fills.update(chosen[2:])
    assert stats.binomtest(firsts[1], n, 0.75).pvalue > 0.01  # 3 / (3 + 1)
    zeros = [0, 2, 3, 5, 6]
    assert set(fills) == set(zeros)
    assert stats.chisquare([fills[i] for i in zeros]).pvalue > 0.01


def test_sample_then_fill_keeps_to_the_eligible_candidates_and_refuses_what_it_cannot_do():
    scores = torch.tensor([0.0, 2.0, 0.0, 0.0, 0.0])
    eligible = torch.tensor([True, False, True, True, False])
    for seed in range(50):
        chosen = sample_then_fill(scores, 3, torch.Generator().manual_seed(seed), eligible).tolist()
        assert sorted(chosen) == [0, 2, 3]  # 1 is positive but not eligible; 4 is not eligible
    with pytest.raises(ValueError, match="only 3 of 5 candidates are eligible"):
        sample_then_fill(scores, 4, None, eligible)
    with pytest.raises(ValueError, match="sample 1 of them with rejection_sample"):
        sample_then_fill(scores, 1)
    a = sample_then_fill(torch.zeros(6), 3, torch.Generator().manual_seed(5))
    assert torch.equal(a, sample_then_fill(torch.zeros(6), 3, torch.Generator().manual_seed(5)))
