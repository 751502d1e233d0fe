"""Batch-aware sampling and the posterior's sharpness: analytic checks."""

import math

import pytest
import torch
from scipy import stats

from nerfaug.hemisphere import half_hemisphere_poses, sample_uniform_poses
from nerfaug.selection import batch_aware_sample, batch_posterior, rejection_sample
from nerfaug.selection.posterior import exponent_for_ess, kish_ess, posterior_exponent, sharpen
from nerfaug.uncertainty.entropy import minmax_normalise
from nerfaug.uncertainty.so3 import coverage_distance, so3_geodesic_sq


@pytest.fixture(scope="module")
def rotations():
    """Candidates uniform on the hemisphere and six training views on one half."""
    candidates = sample_uniform_poses(120, torch.Generator().manual_seed(3))[:, :3, :3].double()
    training = half_hemisphere_poses(6)[:, :3, :3].double()
    return candidates, training


def test_update_equals_recomputing_d_with_the_accepted_views_added(rotations):
    candidates, training = rotations
    base = coverage_distance(candidates, training)
    pairwise = 0.5 * so3_geodesic_sq(candidates[:, None], candidates[None])
    accepted = [5, 17, 42]
    recomputed = coverage_distance(candidates, torch.cat([training, candidates[accepted]]))
    raw = batch_posterior(None, base, pairwise, accepted, (0.0, 1.0), "none")
    assert torch.allclose(raw, recomputed, atol=1e-9)
    normalised = batch_posterior(None, base, pairwise, accepted, (0.0, 1.0), "minmax")
    assert torch.allclose(normalised, minmax_normalise(recomputed), atol=1e-9)


def _min_pairwise_angle(rotations, chosen) -> float:
    angles = so3_geodesic_sq(rotations[chosen][:, None], rotations[chosen][None]).sqrt()
    angles = angles + torch.eye(len(chosen), dtype=angles.dtype) * 10
    return float(angles.min())


def test_with_a_flat_entropy_the_local_penalty_spreads_the_batch(rotations):
    """A flat H leaves U = D' (min-max), and the paper's D (a sum of squared angles) barely moves
    when a view is added: updating it alone spreads a batch no more than the plain sampler
    (measured: mean smallest pairwise angle 0.33 rad both). Discounting the entropy near
    accepted views does: a neighbour of an accepted view loses its H'."""
    candidates, training = rotations
    flat = torch.ones(len(candidates), dtype=torch.float64)
    base = coverage_distance(candidates, training)
    plain_scores = minmax_normalise(base)
    plain, local = [], []
    for seed in range(40):
        chosen = rejection_sample(plain_scores, 6, torch.Generator().manual_seed(seed))
        plain.append(_min_pairwise_angle(candidates, chosen))
        chosen = batch_aware_sample(flat, base, candidates, 6, torch.Generator().manual_seed(seed), entropy_sigma=0.35)
        assert len(set(chosen.tolist())) == 6
        local.append(_min_pairwise_angle(candidates, chosen))
    assert sum(local) / len(local) > 1.2 * sum(plain) / len(plain)
    assert stats.mannwhitneyu(local, plain, alternative="greater").pvalue < 1e-3


def test_one_view_is_the_plain_sampler_and_seeds_repeat(rotations):
    candidates, training = rotations
    entropy = torch.linspace(0.0, 1.0, len(candidates), dtype=torch.float64)
    base = coverage_distance(candidates, training)
    scores = batch_posterior(entropy, base, None, [], (1.0, 1.0), "minmax")
    for seed in range(5):
        one = batch_aware_sample(entropy, base, candidates, 1, torch.Generator().manual_seed(seed))
        assert torch.equal(one, rejection_sample(scores, 1, torch.Generator().manual_seed(seed)))
    first = batch_aware_sample(entropy, base, candidates, 6, torch.Generator().manual_seed(7))
    again = batch_aware_sample(entropy, base, candidates, 6, torch.Generator().manual_seed(7))
    other = batch_aware_sample(entropy, base, candidates, 6, torch.Generator().manual_seed(8))
    assert torch.equal(first, again) and not torch.equal(first, other)


def test_entropy_discount_is_the_gaussian_local_penalty(rotations):
    candidates, _ = rotations
    entropy = torch.rand(len(candidates), generator=torch.Generator().manual_seed(0), dtype=torch.float64) + 0.5
    angle_sq = so3_geodesic_sq(candidates[:, None], candidates[None])
    sigma, accepted = 0.3, [3, 9]
    got = batch_posterior(entropy, None, None, accepted, (1.0, 0.0), "none", angle_sq, sigma)
    expected = entropy.clone()
    for a in accepted:
        expected = expected * (1 - torch.exp(-angle_sq[:, a] / (2 * sigma**2)))
    assert torch.allclose(got, expected)
    assert got[accepted].abs().max() < 1e-12  # an accepted view has nothing left to resolve
    far = angle_sq[:, accepted].min(dim=1).values.sqrt() > 5 * sigma
    assert torch.allclose(got[far], entropy[far], rtol=1e-5)


def test_ineligible_candidates_are_never_chosen(rotations):
    candidates, training = rotations
    base = coverage_distance(candidates, training)
    eligible = torch.arange(len(candidates)) % 3 == 0
    for seed in range(5):
        chosen = batch_aware_sample(
            None, base, candidates, 6, torch.Generator().manual_seed(seed), (0.0, 1.0), eligible=eligible
        )
        assert eligible[chosen].all()


def test_kish_ess_analytic_values():
    assert kish_ess(torch.ones(50)) == pytest.approx(50.0)
    assert kish_ess(torch.tensor([0.0, 3.0, 0.0])) == pytest.approx(1.0)
    assert kish_ess(torch.tensor([1.0, 1.0, 2.0])) == pytest.approx(16 / 6)


def test_exponent_reaches_the_target_ess_and_sharpens_monotonically():
    scores = torch.rand(300, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 2
    for target in (150.0, 42.0, 10.0):
        exponent = exponent_for_ess(scores, target)
        assert exponent > 1.0
        assert kish_ess(sharpen(scores, exponent)) == pytest.approx(target, rel=1e-6)
    # Already sharper than asked: left alone (only sharpening is solved for).
    assert exponent_for_ess(scores, 299.0) == 1.0
    # Geometric mean of uniform's C and NBV's n.
    exponent = posterior_exponent(scores, 6, 1.0, 0.5)
    assert kish_ess(sharpen(scores, exponent)) == pytest.approx(math.sqrt(300 * 6), rel=1e-6)
    assert posterior_exponent(scores, 6, 0.25, None) == 4.0


def test_sharpened_sampler_draws_in_proportion_to_w_to_the_one_over_t():
    """k = 1: P(i) = w_i^(1/T) / sum_j w_j^(1/T), checked with a chi-square test."""
    w = torch.tensor([0.2, 0.5, 1.0, 1.5, 2.0], dtype=torch.float64)
    exponent = 2.5
    density = sharpen(w, exponent)
    generator = torch.Generator().manual_seed(0)
    counts = torch.zeros(len(w))
    draws = 4000
    for _ in range(draws):
        counts[int(rejection_sample(density, 1, generator)[0])] += 1
    expected = (w**exponent / (w**exponent).sum() * draws).numpy()
    assert stats.chisquare(counts.numpy(), expected).pvalue > 1e-3
    assert counts[-1] > 0.5 * draws  # far sharper than w itself (which gives it 2 / 5.2 = 38%)
