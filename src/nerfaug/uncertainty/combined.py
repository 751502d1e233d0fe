"""The paper's total uncertainty of a candidate view, U = a H + b D (Sec. III-B, Eq. 1).

H is the mean ray entropy of the view (bits, `entropy.view_entropy`) and D the coverage term
(radians^2, `so3.coverage_distance`). The paper adds them raw (a = b = 1). The two live on
different scales: with 6 training views D spans roughly 0 to 30 over the hemisphere while a view's
mean entropy spans a bit or two, so the raw sum is close to "distance only" and the entropy
term barely moves the sampling distribution. Normalisations:

- "minmax" (default): each term min-max normalised to [0, 1] over the candidates, then
  U = a H' + b D'. Both terms then span the same range and a, b mean relative importance.
  A term that is constant over the candidates carries no information and becomes 0.
- "none": U = a H + b D on the raw values, the paper's equation as written.
- "authors": the authors' code: min-max normalise each term, U = a H' + b D', then divide by
  max U so the best candidate scores 1 (with their entropy scores, see `view_entropy(mode=
  "authors")`).

Only ratios of scores matter to the rejection sampler (accept with probability w / M), so the
overall scale of U is free; the relative scale of the two terms is what the choice decides.
Entropy-only and distance-only are the weights (1, 0) and (0, 1).
"""

from __future__ import annotations

from torch import Tensor

from nerfaug.registry import check_name
from nerfaug.uncertainty.choices import NORMALISATIONS
from nerfaug.uncertainty.entropy import minmax_normalise


def combined_uncertainty(
    entropy: Tensor | None,
    distance: Tensor | None,
    entropy_weight: float = 1.0,
    distance_weight: float = 1.0,
    normalisation: str = "minmax",
) -> Tensor:
    """U = a H + b D over candidate views, each term normalised as `normalisation` says.

    Args:
        entropy: Tensor with shape (n_candidates,), H per candidate; None when a = 0.
        distance: Tensor with shape (n_candidates,), D per candidate; None when b = 0.
        entropy_weight, distance_weight: a and b, >= 0.
        normalisation: "minmax" (default), "none" or "authors"; see the module docstring.

    Returns:
        Tensor with shape (n_candidates,), >= 0 when the terms are.

    Example:
        >>> import torch
        >>> combined_uncertainty(torch.tensor([1.0, 2.0, 3.0]), torch.tensor([0.0, 10.0, 5.0]))
        tensor([0.0000, 1.5000, 1.5000])

        (minmax: H' = [0, 0.5, 1] and D' = [0, 1, 0.5], so U = H' + D'.)
    """
    check_name("normalisation", normalisation, NORMALISATIONS)
    if entropy_weight < 0 or distance_weight < 0:
        raise ValueError(f"weights must be >= 0, got a={entropy_weight}, b={distance_weight}")
    terms = [(t, w) for t, w in ((entropy, entropy_weight), (distance, distance_weight)) if w != 0]
    if any(t is None for t, _ in terms):
        raise ValueError("a term with a non-zero weight was not given")
    if not terms:
        raise ValueError("both weights are zero: the uncertainty would be identically zero")
    if normalisation != "none":
        terms = [(minmax_normalise(t), w) for t, w in terms]
    total = sum(w * t for t, w in terms)
    if normalisation == "authors":
        peak = total.max()
        total = total / peak if peak > 0 else total
    return total
