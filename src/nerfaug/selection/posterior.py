"""The sharpness of the sampling posterior: how strongly the rejection sampler prefers high scores.

The sampler draws views with probability proportional to the scores w. Under the default
min-max normalisation U = H' + D' lies in [0, 2] and most candidates score a sizeable fraction of
the best, so the posterior is close to uniform (max U / mean U = 1.7 was measured on lego:
a mildly tilted uniform). A temperature T reshapes it to w^(1/T): T = 1 keeps it, T < 1
sharpens it (T -> 0 is next-best-view), T > 1 flattens it (T -> inf is uniform). Ratios of
scores are what the sampler uses, so this is the same as a softmax of log w / T.

How sharp is a posterior? Its Kish effective sample size, ESS = (sum w)^2 / sum w^2, counts the
candidates it effectively spreads over: C for uniform over C candidates, n for n equal peaks.
`temperature_for_ess` solves for the T that gives a target ESS, so a sharpness can be stated
without reference to the scores' scale: `SelectionConfig.sharpness` s in [0, 1] asks for
ESS = C^(1 - s) n^s, from uniform's C (s = 0) to next-best-view's n (s = 1); s = 1/2 is their
geometric mean, halfway on a log scale. This is decided from the candidates' own scores at
selection time, never from test views.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

# Bisection over the exponent 1/T in [1, _MAX_EXPONENT] (only sharpening is ever solved for).
_MAX_EXPONENT = 1e3
_BISECTIONS = 60


def kish_ess(weights: Tensor) -> float:
    """Kish's effective sample size (sum w)^2 / sum w^2 of non-negative weights (shape (n,));
    0 when they are all 0."""
    w = weights.detach().double().reshape(-1)
    total = float(w.sum())
    return total * total / float((w * w).sum()) if total > 0 else 0.0


def sharpen(scores: Tensor, exponent: float) -> Tensor:
    """scores ** exponent (exponent = 1/T > 0) divided by its maximum, so the best candidate scores
    1 and nothing overflows (only ratios matter to a sampler); zeros stay zero. Shape and dtype
    as `scores`; returned unchanged when the exponent is 1.

    Example:
        >>> sharpen(torch.tensor([0.0, 1.0, 2.0]), 2.0)
        tensor([0.0000, 0.2500, 1.0000])
    """
    if exponent <= 0:
        raise ValueError(f"the exponent 1/T must be positive, got {exponent}")
    if exponent == 1.0:
        return scores
    peak = scores.max()
    if peak <= 0:
        return scores
    return ((scores.double() / peak.double()) ** exponent).to(scores.dtype)


def exponent_for_ess(scores: Tensor, target_ess: float) -> float:
    """The exponent 1/T >= 1 whose posterior scores ** (1/T) has Kish ESS `target_ess`.

    ESS of w^g falls monotonically as g grows (the escort family's Renyi-2 entropy decreases),
    so a bisection finds it. Returns 1 when the scores are already at least that sharp, and the
    largest exponent tried when the target cannot be reached (ties at the maximum).

    Args:
        scores: Tensor with shape (n,), >= 0.
        target_ess: the ESS wanted, >= 1.
    """
    w = scores.detach().double().reshape(-1)
    w = w[w > 0]
    if w.numel() == 0 or kish_ess(w) <= target_ess:
        return 1.0
    log_w = torch.log(w / w.max())

    def ess(exponent: float) -> float:
        return kish_ess(torch.exp(exponent * log_w))

    low, high = 1.0, _MAX_EXPONENT
    if ess(high) > target_ess:
        return high
    for _ in range(_BISECTIONS):
        middle = math.sqrt(low * high)  # the exponent spans orders of magnitude
        if ess(middle) > target_ess:
            low = middle
        else:
            high = middle
    return high


def posterior_exponent(
    scores: Tensor, n: int, temperature: float, sharpness: float | None, eligible: Tensor | None = None
) -> float:
    """The exponent 1/T a sampler applies to `scores` (shape (C,)): 1 / `temperature`, or, when
    `sharpness` s is given, the one that makes the posterior's ESS C^(1 - s) n^s over the
    `eligible` candidates (all when None)."""
    if sharpness is None:
        return 1.0 / temperature
    pool = scores if eligible is None else scores[eligible]
    count = int((pool > 0).sum())
    if count <= n:
        return 1.0
    return exponent_for_ess(pool, count ** (1.0 - sharpness) * n**sharpness)
