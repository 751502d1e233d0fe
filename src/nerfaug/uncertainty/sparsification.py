"""How well an uncertainty image ranks a view's errors: sparsification curves and their AUSE
(area under the sparsification error curve), the metric Bayes' Rays and FisherRF report.

Remove the pixels in order of decreasing uncertainty and track the mean error of those left; do
the same in order of decreasing true error (the oracle, the best any ranking can do); the
sparsification error is the first curve minus the second, and AUSE is its area over the fraction
removed. 0 is a perfect ranking; a ranking unrelated to the error gives the area between the
overall mean error and the oracle curve; a reversed ranking gives more (before normalising).

Conventions (as Bayes' Rays' evaluation): `steps` fractions 0, 1/steps, ..., (steps-1)/steps
removed; the area by the trapezoidal rule over those fractions; with `normalise`, both curves are
divided by the largest value of either first, so AUSE does not depend on the error's scale (the
divisor depends on the ranking too: a reversed ranking's curve peaks higher, which damps its
AUSE). `floor(fraction * n)` pixels are removed, so one is always left (their code keeps
`floor((1 - fraction) n)`, one pixel fewer at most, none when n < steps). Pixels of equal
uncertainty are taken in random order, and the curve is its expected value (each tied pixel
counts with its group's mean error), so a constant uncertainty image scores as a random ranking,
never by pixel order. Numpy only.
"""

from __future__ import annotations

import numpy as np

DEFAULT_STEPS = 100


def _as_flat(uncertainty, error) -> tuple[np.ndarray, np.ndarray]:
    u = np.asarray(uncertainty, dtype=np.float64).reshape(-1)
    e = np.asarray(error, dtype=np.float64).reshape(-1)
    if u.shape != e.shape:
        raise ValueError(
            f"uncertainty has {u.size} pixels ({np.shape(uncertainty)}), error {e.size} ({np.shape(error)})"
        )
    if u.size == 0:
        raise ValueError("uncertainty and error hold no pixels")
    for name, values in (("uncertainty", u), ("error", e)):
        bad = int(np.count_nonzero(~np.isfinite(values)))
        if bad:
            raise ValueError(f"{name}: {bad} of {values.size} pixels are not finite")
    return u, e


def _kept_means(errors_kept_first: np.ndarray, steps: int) -> np.ndarray:
    """Mean of the first n - floor(k n / steps) entries, for k = 0 .. steps-1."""
    n = errors_kept_first.size
    sums = np.concatenate([[0.0], np.cumsum(errors_kept_first)])
    kept = n - (np.arange(steps) * n) // steps  # integer arithmetic: no rounding of k/steps * n
    return sums[kept] / kept


def sparsification_curves(uncertainty, error, steps: int = DEFAULT_STEPS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sparsification curve of `uncertainty` and the oracle's, on the same fractions.

    Args:
        uncertainty: array of any shape, e.g. (H, W): higher = less trusted.
        error: array of the same number of elements, e.g. (H, W): the true per-pixel error.
        steps: how many fractions removed: 0, 1/steps, ..., (steps - 1)/steps.

    Returns:
        (fractions, by_uncertainty, oracle), each an array with shape (steps,): the fraction of
        pixels removed, and the mean error of the pixels left when the most uncertain
        (respectively the most erroneous) are removed first. Both start at the mean error.

    Example:
        >>> error = np.array([1.0, 2.0, 3.0, 4.0])
        >>> sparsification_curves(-error, error, steps=4)[1]  # the least erroneous removed first
        array([2.5, 3. , 3.5, 4. ])
    """
    u, e = _as_flat(uncertainty, error)
    if int(steps) < 1:
        raise ValueError(f"steps {steps}: must be >= 1")
    steps = int(steps)
    order = np.argsort(u, kind="stable")  # ascending: the pixels kept longest come first
    values, group = np.unique(u[order], return_inverse=True)
    # Ties in random order: a tied pixel's expected error is its group's mean error.
    group_mean = np.bincount(group, weights=e[order]) / np.bincount(group)
    by_uncertainty = _kept_means(group_mean[group], steps)
    oracle = _kept_means(np.sort(e), steps)
    fractions = np.arange(steps) / steps
    return fractions, by_uncertainty, oracle


def ause(uncertainty, error, steps: int = DEFAULT_STEPS, normalise: bool = True) -> float:
    """Area under the sparsification error curve of `uncertainty` against `error` (see the module
    docstring); 0 for a ranking as good as the error's own, larger is worse.

    Args:
        uncertainty: array of any shape, e.g. (H, W) ray entropy or FisherRF score per pixel.
        error: array with as many elements, e.g. (H, W) squared error per pixel.
        steps: fractions removed (`sparsification_curves`).
        normalise: divide both curves by their largest value first (Bayes' Rays' convention):
            AUSE in [0, 1) whatever the error's unit. An error that is 0 everywhere gives 0.

    Returns:
        float.

    Example:
        >>> error = np.array([1.0, 2.0, 3.0, 4.0])
        >>> ause(error, error)
        0.0
        >>> ause(-error, error, steps=4, normalise=False)  # 0.25 * (0/2 + 1 + 2 + 3/2)
        1.125
    """
    fractions, by_uncertainty, oracle = sparsification_curves(uncertainty, error, steps)
    if normalise:
        largest = max(by_uncertainty.max(), oracle.max())
        if largest <= 0:
            return 0.0
        by_uncertainty, oracle = by_uncertainty / largest, oracle / largest
    gap = by_uncertainty - oracle
    return float(np.sum((gap[1:] + gap[:-1]) / 2 * np.diff(fractions)))


def mean_pool(image, height: int, width: int) -> np.ndarray:
    """`image` shrunk to (height, width) by averaging: each pixel goes to the cell its centre lies
    in, so an uncertainty image of lower resolution can be compared with a full-size error image.

    Args:
        image: array with shape (H, W) or (H, W, C), H >= height, W >= width.
        height, width: the size to shrink to.

    Returns:
        float64 array with shape (height, width) or (height, width, C).

    Example:
        >>> mean_pool(np.arange(16.0).reshape(4, 4), 2, 2)
        array([[ 2.5,  4.5],
               [10.5, 12.5]])
    """
    image = np.asarray(image, dtype=np.float64)
    h, w = image.shape[:2]
    if not (1 <= height <= h and 1 <= width <= w):
        raise ValueError(f"cannot shrink an image of {h}x{w} pixels to {height}x{width}")
    rows = ((np.arange(h) + 0.5) * height / h).astype(int)
    columns = ((np.arange(w) + 0.5) * width / w).astype(int)
    cell = (rows[:, None] * width + columns[None, :]).reshape(-1)
    flat = image.reshape(h * w, -1)
    counts = np.bincount(cell, minlength=height * width)
    sums = np.stack([np.bincount(cell, weights=flat[:, c], minlength=height * width) for c in range(flat.shape[1])], 1)
    pooled = sums / counts[:, None]
    return pooled.reshape(height, width, *image.shape[2:])


__all__ = ["DEFAULT_STEPS", "ause", "mean_pool", "sparsification_curves"]
