"""Whether two sets of paired values are equivalent within a margin: the test by which a new engine
version is accepted (paired seeds, a TOST bound), beside `nerfaug.statistics`' tests of a
difference."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from scipy import stats


def paired_equivalence(x: Iterable[float], y: Iterable[float], bound: float, alpha: float = 0.05) -> dict:
    """Two one-sided tests (TOST, Schuirmann 1987) that paired values x and y are equivalent: the
    mean of d = x - y lies inside (-bound, bound). Each side is a one-sided one-sample t-test
    (`scipy.stats.ttest_1samp`): H0 mean <= -bound against mean > -bound, and H0 mean >= bound
    against mean < bound; equivalence is shown when both reject at `alpha` (p = the larger of the
    two), which is the (1 - 2 alpha) confidence interval of the mean lying inside the bounds.

    Args:
        x, y: one value per pair, in the same order (at least two pairs, no NaN).
        bound: the equivalence margin, > 0, in the values' unit.

    Returns:
        dict with n_pairs, mean (of d), low, high (its 1 - 2 alpha confidence interval), p_lower,
        p_upper, p_value (their maximum), bound, alpha, equivalent (p_value < alpha), and
        max_abs_difference (the largest |d|).

    Example:
        >>> paired_equivalence([1.0, 2.0, 3.0, 4.0], [1.05, 1.95, 3.02, 3.99], bound=0.2)["equivalent"]
        True
    """
    x, y = np.asarray(list(x), dtype=np.float64), np.asarray(list(y), dtype=np.float64)
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise ValueError("paired values must be finite numbers")
    if x.size != y.size:
        raise ValueError(f"paired samples differ in length: {x.size} and {y.size}")
    if x.size < 2:
        raise ValueError(f"an equivalence test needs at least two pairs, got {x.size}")
    if not bound > 0:
        raise ValueError(f"the equivalence bound must be > 0, got {bound}")
    d = x - y
    p_lower = float(stats.ttest_1samp(d, -bound, alternative="greater").pvalue)
    p_upper = float(stats.ttest_1samp(d, bound, alternative="less").pvalue)
    sem = float(np.std(d, ddof=1) / math.sqrt(d.size))
    half = float(stats.t.ppf(1.0 - alpha, d.size - 1)) * sem
    mean = float(d.mean())
    p = max(p_lower, p_upper)
    return {
        "n_pairs": int(d.size),
        "mean": mean,
        "low": mean - half,
        "high": mean + half,
        "p_lower": p_lower,
        "p_upper": p_upper,
        "p_value": p,
        "bound": float(bound),
        "alpha": float(alpha),
        "equivalent": bool(p < alpha),
        "max_abs_difference": float(np.abs(d).max()),
    }
