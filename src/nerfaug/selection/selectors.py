"""Selectors: how k views are chosen from candidates, given their scores or their poses.

- `select_uniform`: k distinct candidates uniformly at random (the "Uniform" baseline).
- `select_top_k`: the k highest scores, next-best-view style ("NBV").
- `rejection_sample`: the paper's sampler (Sec. III-C): draw a candidate uniformly, accept it with
  probability w / M, never draw an accepted candidate again; or the authors' code's variant.
- `sample_then_fill`: the paper's sampler where fewer than k scores are positive (its limit).
- `greedy_farthest`: "maximally apart", each pick the candidate farthest (geodesic angle) from
  the training views and the views picked so far.

Below them, the selectors `selection.registry.SELECTORS` lists (`sample_views`, `top_k_views`,
...): each `fn(request, estimate) -> (indices (n,), estimate)` over one of the functions above.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import torch
from torch import Tensor

from nerfaug.registry import check_name
from nerfaug.selection.config import AUTHORS_THRESHOLD, MAX_DRAWS, REJECTION_SAMPLERS
from nerfaug.selection.interface import Estimate, Request
from nerfaug.selection.posterior import posterior_exponent, sharpen
from nerfaug.uncertainty.fisher import fisherrf_greedy
from nerfaug.uncertainty.so3 import min_geodesic_angle


class UniformFill(UserWarning):
    """A sampler found fewer candidates with a positive score than views to choose and drew the
    rest uniformly (`sample_then_fill`)."""


class DirectDraw(UserWarning):
    """The paper's rejection sampler reached `max_draws` and drew its remaining views directly from
    the distribution it samples (`rejection_sample`): the same distribution, without the loop."""


# The authors' sampler draws nu ~ U[0.05, 1] per visit (accept if w > AUTHORS_THRESHOLD * nu).
AUTHORS_NU_RANGE = (0.05, 1.0)
# Random numbers are drawn in blocks (same stream for a seed, far fewer calls).
_BLOCK = 1024


def _check_k(n_candidates: int, k: int) -> None:
    if not 0 <= k <= n_candidates:
        raise ValueError(f"cannot choose {k} views out of {n_candidates} candidates")


def _check_eligible(eligible: Tensor | None, n_candidates: int, k: int) -> Tensor:
    """The (n_candidates,) bool mask of candidates that may be chosen (all when None)."""
    if eligible is None:
        return torch.ones(n_candidates, dtype=torch.bool)
    eligible = torch.as_tensor(eligible, dtype=torch.bool).cpu().reshape(-1)
    if eligible.numel() != n_candidates:
        raise ValueError(f"eligible has {eligible.numel()} entries for {n_candidates} candidates")
    if int(eligible.sum()) < k:
        raise ValueError(
            f"cannot choose {k} views: only {int(eligible.sum())} of {n_candidates} candidates are eligible"
        )
    return eligible


def select_uniform(
    n_candidates: int, k: int, generator: torch.Generator | None = None, eligible: Tensor | None = None
) -> Tensor:
    """k distinct candidate indices uniformly at random (among the `eligible` ones). Shape (k,)."""
    _check_k(n_candidates, k)
    if eligible is None:
        return torch.randperm(n_candidates, generator=generator)[:k]
    allowed = torch.nonzero(_check_eligible(eligible, n_candidates, k)).reshape(-1)
    return allowed[torch.randperm(allowed.numel(), generator=generator)[:k]]


def select_top_k(scores: Tensor, k: int, eligible: Tensor | None = None) -> Tensor:
    """Indices of the k highest scores (among the `eligible` candidates), best first; ties go to
    the lower index. Shape (k,)."""
    _check_k(scores.shape[0], k)
    scores = scores.detach().cpu().double()
    if eligible is not None:
        scores = torch.where(_check_eligible(eligible, scores.shape[0], k), scores, -math.inf)
    return torch.argsort(scores, descending=True, stable=True)[:k]


def _check_scores(scores: Tensor) -> Tensor:
    scores = scores.detach().cpu().double().reshape(-1)
    if not torch.isfinite(scores).all():
        raise ValueError("scores must be finite to sample from them")
    if (scores < 0).any():
        raise ValueError(f"scores are an unnormalised density and must be >= 0; the smallest is {scores.min():.6g}")
    return scores


def _require_acceptable(accept_prob: Tensor, k: int, why: str) -> None:
    acceptable = int((accept_prob > 0).sum())
    if acceptable < k:
        raise ValueError(
            f"rejection sampling cannot choose {k} distinct views: only {acceptable} of "
            f"{accept_prob.numel()} candidates can ever be accepted ({why})"
        )


def rejection_sample(
    scores: Tensor,
    k: int,
    generator: torch.Generator | None = None,
    scale_m: float | None = None,
    max_draws: int = MAX_DRAWS,
    variant: str = "paper",
    threshold: float = AUTHORS_THRESHOLD,
    eligible: Tensor | None = None,
) -> Tensor:
    """Choose k distinct candidates with the paper's rejection sampler.

    "paper" (default): repeat until k are accepted: draw a candidate uniformly among those not yet
    accepted, draw u ~ U[0, 1), accept it if u < w / M (the paper writes u <= w / M; the two
    differ on a probability-zero event, and "<" never accepts a zero score). For k = 1 the chosen
    index has probability w_i / sum_j w_j; for k > 1 each draw is from the density restricted to
    the candidates not chosen yet.

    Each acceptance picks candidate i with probability a_i / sum_j a_j over the candidates left
    (a = min(w / M, 1), the acceptance probability), whatever M is. When acceptances are so rare
    that `max_draws` proposals are spent (a few candidates with nearly all the score, the rest
    tiny), the remaining views are drawn from exactly that distribution by torch.multinomial
    without replacement, with a `DirectDraw` warning: the same distribution without an unbounded
    loop. Until then the draws, and so the choice for a seed, are the loop's.

    M defaults to max(w), the smallest valid scale (fewest rejections). A given M below max(w)
    makes w / M exceed 1 for some candidates: a warning names the smallest valid M and those
    acceptance probabilities are clipped to 1 (the result then no longer follows the scores).

    "authors": the authors' code: go through the candidates in order (again from the start while
    fewer than k are accepted), skip accepted ones, draw nu ~ U[0.05, 1] and accept if
    w > threshold * nu (threshold 15). Their scores are in [0, 1] with max 1; other scores are
    divided by their max first (the max over all candidates, eligible or not, as their code
    normalises before its loop). Only candidates with w > 0.75 can then be accepted, each with
    probability (w / 15 - 0.05) / 0.95 per visit. Their code also rejects candidates within
    0.4 rad of the pole: pass those as not `eligible` (`SelectionConfig.min_polar`).

    Args:
        scores: Tensor with shape (n_candidates,), w >= 0 (an unnormalised density).
        k: number of views to choose.
        generator: random source; the same seed gives the same choice.
        scale_m: M; None for max(w). Ignored by "authors".
        max_draws: proposals after which the remaining views are drawn directly ("paper"), or
            the sampler gives up with a RuntimeError ("authors", whose sweep has no such
            distribution).
        variant: "paper" or "authors".
        threshold: the authors' factor 15 ("authors" only).
        eligible: bool Tensor with shape (n_candidates,): candidates that may be accepted
            (an ineligible one is never accepted; "paper" takes M over the eligible ones); None
            for all.

    Returns:
        Tensor with shape (k,), candidate indices in the order accepted.

    Raises:
        ValueError: fewer than k candidates can ever be accepted (e.g. all scores 0), or bad input.
        RuntimeError: `max_draws` proposals were not enough ("authors").
    """
    check_name("sampler variant", variant, REJECTION_SAMPLERS)
    w = _check_scores(scores)
    _check_k(w.numel(), k)
    allowed = _check_eligible(eligible, w.numel(), k)
    if variant == "authors":
        return _authors_sample(w, k, generator, max_draws, threshold, allowed)

    w = torch.where(allowed, w, 0.0)
    peak = float(w.max()) if w.numel() else 0.0
    if scale_m is None:
        scale_m = peak
    elif scale_m <= 0:
        raise ValueError(f"the scale M must be positive, got {scale_m}")
    elif peak > scale_m:
        warnings.warn(
            f"rejection sampling scale M={scale_m:.6g} is below the largest score {peak:.6g}: "
            f"w / M exceeds 1 for {int((w > scale_m).sum())} candidates and is clipped to 1, so "
            f"the samples do not follow the scores; a valid M is any M >= {peak:.6g}",
            stacklevel=2,
        )
    accept_prob = (w / scale_m).clamp(max=1.0) if scale_m > 0 else torch.zeros_like(w)
    _require_acceptable(accept_prob, k, "a candidate with score 0 is never accepted")

    probs = accept_prob.tolist()
    remaining = list(range(w.numel()))
    chosen: list[int] = []
    draws = 0
    while len(chosen) < k:
        picks = torch.rand(_BLOCK, generator=generator, dtype=torch.float64)
        us = torch.rand(_BLOCK, generator=generator, dtype=torch.float64)
        for pick, u in zip(picks.tolist(), us.tolist()):
            if draws >= max_draws:
                return _draw_directly(accept_prob, chosen, remaining, k, max_draws, generator)
            draws += 1
            candidate = remaining[min(int(pick * len(remaining)), len(remaining) - 1)]
            if u < probs[candidate]:
                chosen.append(candidate)
                remaining.remove(candidate)
                if len(chosen) == k:
                    break
    return torch.tensor(chosen, dtype=torch.long)


def _draw_directly(
    accept_prob: Tensor, chosen: list[int], remaining: list[int], k: int, max_draws: int, generator
) -> Tensor:
    """`chosen` and k - len(chosen) more of `remaining`, drawn in order with probability
    proportional to `accept_prob` among those left: the distribution of the rejection loop's next
    acceptances (see `rejection_sample`), for when the loop spent `max_draws`."""
    left = torch.tensor(remaining, dtype=torch.long)
    weights = accept_prob[left]
    warnings.warn(
        f"rejection sampling accepted {len(chosen)} of {k} views in {max_draws} draws (the remaining "
        f"candidates' mean acceptance probability is {float(weights.mean()):.3g}), so the other "
        f"{k - len(chosen)} are drawn directly from the same distribution (score-weighted, without "
        "replacement)",
        DirectDraw,
        stacklevel=3,
    )
    rest = left[torch.multinomial(weights, k - len(chosen), replacement=False, generator=generator)]
    return torch.cat([torch.tensor(chosen, dtype=torch.long), rest])


def _authors_sample(w: Tensor, k: int, generator, max_draws: int, threshold: float, allowed: Tensor) -> Tensor:
    low, high = AUTHORS_NU_RANGE
    peak = float(w.max())
    if peak > 0:  # their rule assumes scores in [0, 1] with max 1 (as their normalisation gives)
        w = w / peak
    # Their loop draws nu for an ineligible candidate too and then skips it: same as w = 0.
    w = torch.where(allowed, w, 0.0)
    accept_prob = ((w / threshold - low) / (high - low)).clamp(0.0, 1.0)
    _require_acceptable(
        accept_prob, k, f"the authors' rule accepts only w > {threshold} * {low} = {threshold * low:.6g}"
    )
    n = w.numel()
    scores = w.tolist()
    accepted = [False] * n
    chosen: list[int] = []
    draws = 0
    while len(chosen) < k:
        nus = (low + (high - low) * torch.rand(n, generator=generator, dtype=torch.float64)).tolist()
        for i in range(n):
            if accepted[i]:
                continue
            if draws >= max_draws:
                raise RuntimeError(
                    f"the authors' sampler gave up after {max_draws} draws with {len(chosen)} of {k} accepted"
                )
            draws += 1
            if scores[i] > threshold * nus[i]:
                accepted[i] = True
                chosen.append(i)
                if len(chosen) == k:
                    break
    return torch.tensor(chosen, dtype=torch.long)


def sample_then_fill(
    scores: Tensor, k: int, generator: torch.Generator | None = None, eligible: Tensor | None = None
) -> Tensor:
    """k distinct candidates when fewer than k eligible ones have a positive score: all the
    positive ones, in an order drawn as the paper's sampler draws (each next one with probability
    proportional to its score among those left), then uniformly among the other eligible ones.

    This is the limit of the paper's sampler on scores + eps as eps -> 0: a zero-score candidate
    is then accepted only once no positive one is left, and among equal scores every draw is
    uniform. (torch.multinomial without replacement draws that order directly, with no rejection
    loop that tiny positive scores could make arbitrarily long.)

    Args:
        scores: Tensor with shape (n_candidates,), w >= 0, fewer than k of them positive.
        k: number of views to choose.
        generator: random source.
        eligible: bool Tensor with shape (n_candidates,); None for all.

    Returns:
        Tensor with shape (k,), candidate indices: the positive ones first.
    """
    w = _check_scores(scores)
    _check_k(w.numel(), k)
    allowed = _check_eligible(eligible, w.numel(), k)
    positive = (w > 0) & allowed
    first = torch.nonzero(positive).reshape(-1)
    if first.numel() >= k:
        raise ValueError(f"{first.numel()} candidates have a positive score: sample {k} of them with rejection_sample")
    if first.numel():
        first = first[torch.multinomial(w[first], first.numel(), replacement=False, generator=generator)]
    rest = select_uniform(w.numel(), k - first.numel(), generator, allowed & ~positive)
    return torch.cat([first, rest])


def greedy_farthest(
    candidate_rotations: Tensor, training_rotations: Tensor, k: int, eligible: Tensor | None = None
) -> Tensor:
    """ "Maximally apart": k times, pick the candidate whose smallest geodesic angle to the training
    views and the views already picked is largest.

    Args:
        candidate_rotations: Tensor with shape (n_candidates, 3, 3).
        training_rotations: Tensor with shape (n_training, 3, 3); with none, the first pick is
            candidate 0.
        k: number of views.
        eligible: bool Tensor with shape (n_candidates,), candidates that may be picked; None for all.

    Returns:
        Tensor with shape (k,), in the order picked.
    """
    n = candidate_rotations.shape[0]
    _check_k(n, k)
    allowed = _check_eligible(eligible, n, k)
    nearest = torch.full((n,), math.inf, dtype=candidate_rotations.dtype)
    if training_rotations.shape[0] > 0:
        nearest = min_geodesic_angle(candidate_rotations.cpu(), training_rotations.cpu())
    chosen: list[int] = []
    for _ in range(k):
        gap = torch.where(allowed, nearest, -math.inf)
        gap[chosen] = -math.inf
        best = int(torch.argmax(gap))
        chosen.append(best)
        to_best = min_geodesic_angle(candidate_rotations.cpu(), candidate_rotations[best : best + 1].cpu())
        nearest = torch.minimum(nearest, to_best)
    return torch.tensor(chosen, dtype=torch.long)


# The selectors listed in `selection.registry.SELECTORS`: adapters from a `Request` and the
# estimator's `Estimate` to the functions above. Every one honours `Request.eligible`.


def sampling_density(request: Request, estimate: Estimate) -> Estimate:
    """The scores a sampler draws from: `estimate.scores ** (1/T)` (see `posterior`). When T is not
    1 the result's scores are that density, with the scores before as `uncertainty` and 1/T as
    `exponent`."""
    config = request.config
    exponent = posterior_exponent(estimate.scores, request.n, config.temperature, config.sharpness, request.eligible)
    if exponent == 1.0:
        return estimate
    return replace(estimate, scores=sharpen(estimate.scores, exponent), uncertainty=estimate.scores, exponent=exponent)


def sample_views(request: Request, estimate: Estimate) -> tuple[Tensor, Estimate]:
    """The paper's rejection sampler (or the authors' sweep, `config.sampler`).

    When fewer than n eligible candidates have a positive density (a NeRF that renders nothing
    gives FisherRF's gain 0 everywhere), the paper's sampler cannot choose n: then every
    positive one is taken and the rest are drawn uniformly from the other eligible candidates,
    with a warning, and the estimate's `uniform_fill` counts them (see `sample_then_fill`).
    """
    config = request.config
    estimate = sampling_density(request, estimate)
    if config.sampler == "paper":
        allowed = _check_eligible(request.eligible, estimate.scores.shape[0], request.n)
        positive = int(((_check_scores(estimate.scores) > 0) & allowed).sum())
        if positive < request.n:
            warnings.warn(
                f"method {request.method!r}: only {positive} of {int(allowed.sum())} eligible candidates "
                f"have a positive score, so {request.n - positive} of the {request.n} views are drawn "
                "uniformly from the others (the model gives them no information to choose by)",
                UniformFill,
                stacklevel=2,
            )
            indices = sample_then_fill(estimate.scores, request.n, request.generator, allowed)
            return indices, replace(estimate, uniform_fill=request.n - positive)
    indices = rejection_sample(
        estimate.scores,
        request.n,
        request.generator,
        config.scale_m,
        config.max_draws,
        config.sampler,
        config.authors_threshold,
        request.eligible,
    )
    return indices, estimate


def top_k_views(request: Request, estimate: Estimate) -> tuple[Tensor, Estimate]:
    """Next best views: the n highest scores."""
    return select_top_k(estimate.scores, request.n, request.eligible), estimate


def uniform_views(request: Request, estimate: Estimate) -> tuple[Tensor, Estimate]:
    """n candidates uniformly at random."""
    return select_uniform(len(request.candidates), request.n, request.generator, request.eligible), estimate


def farthest_views(request: Request, estimate: Estimate) -> tuple[Tensor, Estimate]:
    """Greedy farthest views; scored by the angle (radians) to the nearest training view."""
    rotations = request.candidates.rotations.cpu().double()
    training = request.train_cameras.rotations.cpu().double()
    indices = greedy_farthest(rotations, training, request.n, request.eligible)
    if training.shape[0]:
        angle = min_geodesic_angle(rotations, training).float()
        estimate = Estimate(angle, min_angle=angle)
    return indices, estimate


def greedy_fisher_views(request: Request, estimate: Estimate) -> tuple[Tensor, Estimate]:
    """FisherRF's greedy batch: add each pick's H_cand into H_train and rescore."""
    gain = estimate.fisher
    if gain is None:
        raise ValueError(f"method {request.method!r}: the greedy-fisher selector needs the fisher estimator")
    scores = estimate.scores
    if request.eligible is not None:
        _check_eligible(request.eligible, scores.shape[0], request.n)
        scores = torch.where(request.eligible, scores.double(), -math.inf)
    indices, _ = fisherrf_greedy(gain.h_train, gain.h_of, request.n, request.config.fisher_lambda, scores)
    return indices, estimate
