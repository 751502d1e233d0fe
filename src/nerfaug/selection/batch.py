"""Batch-aware sampling (beyond the paper).

The paper scores the candidates once and draws all n views from that one posterior, so the
coverage term D ignores the views accepted earlier in the same batch: two near-identical
unseen views can both be accepted, though once one is trained on the other is no longer far
from the training set. Here the posterior is updated after every acceptance:

- Coverage: D is recomputed against the training views plus the views accepted so far,
  D_j(g) = D_0(g) + sum over accepted a of 1/2 ||log(g_a^-1 g)||_M^2 (exactly the paper's D with
  the accepted views added to the training set), and re-normalised as the config says.
- Entropy (optional, `SelectionConfig.batch_entropy_sigma`): the entropy of a candidate near an
  accepted view is discounted by prod over accepted a of (1 - exp(-theta_a^2 / (2 sigma^2))),
  theta_a the geodesic angle to a. This is the "local penalisation" of batch Bayesian
  optimisation (Gonzalez et al., 2016): the entropy was measured before any of the batch was
  seen, and a view next to an accepted one looks at nearly the same rays, whose uncertainty that
  view will resolve; sigma is the angle over which two views still share most of their rays.
- The next view is then drawn with the paper's rejection sampler from the updated posterior
  (M = its maximum over the remaining candidates), raised to the exponent 1/T (`posterior`),
  which is fixed once from the initial posterior so that every draw of the batch is equally
  sharp.

With n = 1 this is the plain sampler. Entropy terms are rendered once: the update only reuses
the rotations, so a batch costs the same model evaluations as the plain sampler.
"""

from __future__ import annotations

import torch
from torch import Tensor

from nerfaug.selection.config import MAX_DRAWS
from nerfaug.selection.interface import Estimate, Request
from nerfaug.selection.posterior import sharpen
from nerfaug.selection.selectors import rejection_sample, sampling_density
from nerfaug.uncertainty.combined import combined_uncertainty
from nerfaug.uncertainty.so3 import so3_geodesic_sq


def batch_posterior(
    entropy: Tensor | None,
    base_distance: Tensor | None,
    pairwise: Tensor | None,
    accepted: list[int],
    weights: tuple[float, float],
    normalisation: str,
    angle_sq: Tensor | None = None,
    entropy_sigma: float | None = None,
) -> Tensor:
    """The posterior U after the views `accepted` joined the training set.

    Args:
        entropy: Tensor with shape (C,), the entropy term as `combined_uncertainty` takes it;
            None when its weight is 0.
        base_distance: Tensor with shape (C,), D against the training views; None when b = 0.
        pairwise: Tensor with shape (C, C), f(g_i, g_j) = 1/2 ||log(g_i^-1 g_j)||_M^2.
        accepted: candidate indices accepted so far.
        weights: (a, b).
        normalisation: as in `combined_uncertainty`.
        angle_sq: Tensor with shape (C, C), squared geodesic angles (for the entropy discount).
        entropy_sigma: radians; None for no entropy discount.

    Returns:
        Tensor with shape (C,), float64.
    """
    distance = base_distance
    if distance is not None and accepted:
        distance = base_distance + pairwise[:, accepted].sum(dim=1)
    if entropy is not None and entropy_sigma is not None and accepted:
        keep = (1.0 - torch.exp(-angle_sq[:, accepted] / (2.0 * entropy_sigma**2))).prod(dim=1)
        entropy = entropy.double() * keep
    a, b = weights
    return combined_uncertainty(entropy, distance, a, b, normalisation).double()


def batch_aware_sample(
    entropy: Tensor | None,
    base_distance: Tensor | None,
    rotations: Tensor,
    k: int,
    generator: torch.Generator | None = None,
    weights: tuple[float, float] = (1.0, 1.0),
    normalisation: str = "minmax",
    metric: Tensor | None = None,
    exponent: float = 1.0,
    entropy_sigma: float | None = None,
    eligible: Tensor | None = None,
    max_draws: int = MAX_DRAWS,
) -> Tensor:
    """Choose k candidates one at a time, updating the posterior after each acceptance.

    Args:
        entropy: Tensor with shape (C,) or None (see `batch_posterior`).
        base_distance: Tensor with shape (C,), D against the training views, or None.
        rotations: Tensor with shape (C, 3, 3), the candidates' rotations D is taken over.
        k: views to choose.
        generator: random source; the same seed gives the same choice.
        weights, normalisation: as in `combined_uncertainty`.
        metric: Tensor with shape (3, 3), the coverage term's M; None for the identity.
        exponent: 1/T applied to every posterior (see `posterior`).
        entropy_sigma: radians, the entropy discount's width; None for none.
        eligible: bool Tensor with shape (C,): candidates that may be chosen; None for all.
        max_draws: proposals per acceptance before giving up.

    Returns:
        Tensor with shape (k,), candidate indices in the order accepted.
    """
    n = rotations.shape[0]
    if not 0 <= k <= n:
        raise ValueError(f"cannot choose {k} views out of {n} candidates")
    rotations = rotations.cpu().double()
    pairwise = angle_sq = None
    if base_distance is not None:
        pairwise = 0.5 * so3_geodesic_sq(rotations[:, None], rotations[None], metric)
    if entropy_sigma is not None:
        if entropy_sigma <= 0:
            raise ValueError(f"batch_entropy_sigma must be positive, got {entropy_sigma}")
        angle_sq = so3_geodesic_sq(rotations[:, None], rotations[None])
    allowed = torch.ones(n, dtype=torch.bool) if eligible is None else eligible.clone().bool()
    chosen: list[int] = []
    for _ in range(k):
        posterior = batch_posterior(
            entropy, base_distance, pairwise, chosen, weights, normalisation, angle_sq, entropy_sigma
        )
        density = sharpen(posterior.clamp_min(0.0), exponent)
        pick = int(rejection_sample(density, 1, generator, None, max_draws, "paper", eligible=allowed)[0])
        chosen.append(pick)
        allowed[pick] = False
    return torch.tensor(chosen, dtype=torch.long)


def batch_sample_views(request: Request, estimate: Estimate) -> tuple[Tensor, Estimate]:
    """Rejection sampling with the coverage term (and optionally the entropy) updated after each
    acceptance; the saved scores are the first draw's posterior."""
    config = request.config
    if config.sampler != "paper":
        raise ValueError(
            f"method {request.method!r} samples one view at a time with the paper's sampler; "
            f"SelectionConfig.sampler={config.sampler!r} is not supported (use 'paper')"
        )
    terms = estimate.terms
    if terms is None:
        raise ValueError(f"method {request.method!r}: batch-aware sampling needs the entropy and coverage terms")
    shaped = sampling_density(request, estimate)
    indices = batch_aware_sample(
        terms.entropy,
        terms.distance,
        request.candidates.rotations.cpu() if terms.rotations is None else terms.rotations,
        request.n,
        request.generator,
        terms.weights,
        config.normalisation,
        terms.metric,
        1.0 if shaped.exponent is None else shaped.exponent,
        config.batch_entropy_sigma,
        request.eligible,
        config.max_draws,
    )
    return indices, shaped
