"""AUSE and sparsification curves on constructed cases with known answers: a perfect ranking,
a reversed one and a random one (ties) on 4 pixels by hand, a random permutation against its
analytic expectation, and the pooling that matches a small uncertainty image to a large error image."""

import numpy as np
import pytest

from nerfaug.uncertainty.sparsification import ause, mean_pool, sparsification_curves

ERROR = np.array([1.0, 2.0, 3.0, 4.0])


def test_uncertainty_equal_to_the_error_scores_zero():
    rng = np.random.default_rng(0)
    error = rng.random((12, 9)) ** 2
    assert ause(error, error) == 0.0
    # Any increasing function of the error ranks the same.
    assert ause(np.sqrt(error) * 3 + 1, error) == 0.0
    assert ause(error, error, steps=7, normalise=False) == 0.0


def test_a_reversed_ranking_on_four_pixels():
    fractions, by_uncertainty, oracle = sparsification_curves(-ERROR, ERROR, steps=4)
    assert fractions.tolist() == [0.0, 0.25, 0.5, 0.75]
    # Oracle removes 4, then 3, then 2: means of {1,2,3,4}, {1,2,3}, {1,2}, {1}.
    assert oracle.tolist() == [2.5, 2.0, 1.5, 1.0]
    # Reversed: removes 1, then 2, then 3.
    assert by_uncertainty.tolist() == [2.5, 3.0, 3.5, 4.0]
    # Gap 0, 1, 2, 3; trapezoids of width 1/4: 0.25 * (0/2 + 1 + 2 + 3/2) = 1.125.
    assert ause(-ERROR, ERROR, steps=4, normalise=False) == pytest.approx(1.125)
    # Normalised by the largest value of either curve, 4.
    assert ause(-ERROR, ERROR, steps=4) == pytest.approx(1.125 / 4)


def test_a_constant_uncertainty_is_a_random_ranking():
    """All pixels tied: the curve is the expected one over random orders, the mean error throughout."""
    _, by_uncertainty, _ = sparsification_curves(np.zeros(4), ERROR, steps=4)
    assert by_uncertainty.tolist() == [2.5, 2.5, 2.5, 2.5]
    # Gap 0, 0.5, 1, 1.5: 0.25 * (0 + 0.5 + 1 + 0.75) = 0.5625; normalised by 2.5: 0.225.
    assert ause(np.zeros(4), ERROR, steps=4, normalise=False) == pytest.approx(0.5625)
    assert ause(np.zeros(4), ERROR, steps=4) == pytest.approx(0.225)
    # The result does not depend on where the pixels lie.
    assert ause(np.zeros(4), ERROR[::-1], steps=4) == pytest.approx(0.225)


def test_ties_count_with_their_group_mean():
    # Uncertainty ranks {4} first, then {1, 3} tied, then {2}.
    uncertainty = np.array([0.5, 0.0, 0.5, 1.0])
    _, by_uncertainty, _ = sparsification_curves(uncertainty, ERROR, steps=4)
    # Kept first: 2, then the tied pair (each counts 2 on average), then 4.
    # Means kept: 4 pixels 2.5; 3 pixels (2 + 2 + 2)/3 = 2; 2 pixels (2 + 2)/2 = 2; 1 pixel 2.
    assert by_uncertainty == pytest.approx([2.5, 2.0, 2.0, 2.0])


def test_a_random_permutation_matches_its_expectation():
    """Errors uniform on [0, 1): oracle(t) = (1 - t)/2, a random ranking stays at 1/2 in
    expectation, so AUSE = sum of the trapezoids of t/2 over t = 0 .. 0.99 = 0.99^2 / 4."""
    n = 20_000
    error = (np.arange(n) + 0.5) / n
    uncertainty = np.random.default_rng(1).permutation(n).astype(float)
    expected = 0.99**2 / 4
    assert ause(uncertainty, error, normalise=False) == pytest.approx(expected, abs=0.01)
    # Normalised by the curves' largest value, about 1/2.
    assert ause(uncertainty, error) == pytest.approx(expected / 0.5, abs=0.02)
    # Better than random for an informative, noisy ranking; worse for the reversed one.
    noisy = error + np.random.default_rng(2).normal(0, 0.1, n)
    assert 0.0 < ause(noisy, error) < ause(uncertainty, error) < ause(-error, error)


def test_normalised_ause_ignores_the_scale_of_the_error():
    rng = np.random.default_rng(3)
    error, uncertainty = rng.random(50), rng.random(50)
    assert ause(uncertainty, 7.0 * error) == pytest.approx(ause(uncertainty, error))
    assert ause(uncertainty, np.zeros(50)) == 0.0


def test_bad_inputs_are_named():
    with pytest.raises(ValueError, match="uncertainty has 4 pixels"):
        ause(np.zeros(4), np.zeros(5))
    with pytest.raises(ValueError, match="error: 1 of 4 pixels are not finite"):
        ause(np.zeros(4), np.array([0.0, np.nan, 1.0, 2.0]))
    with pytest.raises(ValueError, match="steps 0"):
        ause(ERROR, ERROR, steps=0)


def test_mean_pool_averages_each_cell():
    image = np.arange(16.0).reshape(4, 4)
    assert mean_pool(image, 2, 2).tolist() == [[2.5, 4.5], [10.5, 12.5]]
    assert mean_pool(image, 4, 4).tolist() == image.tolist()
    # Sizes that do not divide: every cell gets pixels, and the mean is kept.
    odd = np.random.default_rng(4).random((7, 5, 3))
    pooled = mean_pool(odd, 3, 2)
    assert pooled.shape == (3, 2, 3) and np.isfinite(pooled).all()
    assert mean_pool(np.ones((7, 5)), 3, 2).tolist() == [[1.0, 1.0]] * 3
    with pytest.raises(ValueError, match="cannot shrink an image of 4x4 pixels to 8x2"):
        mean_pool(image, 8, 2)
