"""What estimators and selectors exchange: the `Request` both read, and the `Estimate` an
estimator hands its selector.

An estimator is `fn(request) -> Estimate`; a selector is `fn(request, estimate) -> (indices (n,),
estimate)`. Everything a selector reads from an estimate is a typed field, so a misspelt name is
an AttributeError at once, not a silently missing entry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import angles_from_pose
from nerfaug.selection.config import SelectionConfig


@dataclass
class Request:
    """Everything an estimator or a selector may use.

    Attributes:
        method: the method's name (for error messages).
        model: the NeRF (`NerfModel` interface), or None for methods that do not render.
        train_cameras: the current training views.
        candidates: the n_candidates views to choose from.
        n: how many to choose.
        generator: the random source (the same seed gives the same selection).
        config: the method's effective `SelectionConfig` (its own settings applied).
        excluded: bool Tensor with shape (n_candidates,), candidates that may not be chosen
            (e.g. too close to a view already kept, `selection.separation`); None for none.
        progress: called by an estimator that scores candidates one batch at a time with the
            number scored so far (to show progress); None for silence.
    """

    method: str
    model: nn.Module | None
    train_cameras: Cameras
    candidates: Cameras
    n: int
    generator: torch.Generator | None
    config: SelectionConfig
    excluded: Tensor | None = None
    progress: Callable[[int], None] | None = None

    def require_model(self) -> nn.Module:
        """The model; ValueError naming the method when there is none."""
        if self.model is None:
            raise ValueError(f"method {self.method!r} scores candidates with the model; got model=None")
        return self.model

    @cached_property
    def polar(self) -> Tensor:
        """Polar angle (radians from +z about the origin, the scene centre in the engine frame) of
        every candidate. Shape (n_candidates,), float64, CPU."""
        return angles_from_pose(self.candidates.camera_to_world.cpu())[1].double()

    @cached_property
    def eligible(self) -> Tensor | None:
        """Bool mask (n_candidates,) of the candidates that may be chosen: those at least
        `config.min_polar` from the pole and not `excluded`. None when every candidate may be."""
        allowed = None if self.config.min_polar is None else self.polar >= self.config.min_polar
        if self.excluded is None:
            return allowed
        free = ~self.excluded.cpu().bool().reshape(-1)
        return free if allowed is None else allowed & free


@dataclass(frozen=True)
class Terms:
    """The terms of U = a H + b D behind an estimate, kept so that a selector can recombine them
    (batch-aware sampling recomputes D as views are accepted).

    Attributes:
        weights: (a, b).
        entropy: Tensor with shape (n_candidates,), H as `combined_uncertainty` takes it (mean ray
            entropy in bits, or the authors' score); None when a = 0.
        distance: Tensor with shape (n_candidates,), float64, D against the training views, in
            radians^2; None when b = 0.
        rotations: Tensor with shape (n_candidates, 3, 3), float64, the rotations D compares;
            None when b = 0.
        metric: Tensor with shape (3, 3), the coverage term's M; None for the identity.
    """

    weights: tuple[float, float]
    entropy: Tensor | None = None
    distance: Tensor | None = None
    rotations: Tensor | None = None
    metric: Tensor | None = None


@dataclass(frozen=True)
class FisherGain:
    """FisherRF's expected information gain and what its greedy batch updates.

    Attributes:
        gain: Tensor with shape (n_candidates,), every candidate's information gain.
        h_train: Tensor with shape (P,), the Fisher diagonal over the training views.
        h_of: candidate index -> its Fisher diagonal H_cand, Tensor with shape (P,).
    """

    gain: Tensor
    h_train: Tensor
    h_of: Callable[[int], Tensor]


@dataclass(frozen=True)
class Estimate:
    """What an estimator gives a selector, and what a selector gives back with its choice.

    Attributes:
        scores: Tensor with shape (n_candidates,), on the CPU: the density or ranking.
        terms: the entropy and coverage terms behind `scores` ("combined", "entropy",
            "distance"); None otherwise.
        fisher: FisherRF's gain and diagonals ("fisher"); None otherwise.
        min_angle: Tensor with shape (n_candidates,), radians from each candidate to its nearest
            training view (the farthest-views selector's scores); None otherwise.
        uncertainty: Tensor with shape (n_candidates,), the scores before a sampler sharpened
            them to `scores`; None when they were not.
        exponent: the exponent 1/T that sharpened them; None when they were not.
        uniform_fill: how many of the chosen views a sampler drew uniformly because fewer
            candidates than asked for had a positive score (`selectors.sample_then_fill`).
    """

    scores: Tensor
    terms: Terms | None = None
    fisher: FisherGain | None = None
    min_angle: Tensor | None = None
    uncertainty: Tensor | None = None
    exponent: float | None = None
    uniform_fill: int = 0

    def components(self) -> dict[str, Tensor]:
        """The named terms behind `scores`, each a Tensor with shape (n_candidates,), as saved with
        the selection: "entropy" and "distance" (float32), "fisher", "min_angle", and
        "uncertainty" and "exponent" (1/T, repeated) when a sampler sharpened the scores."""
        named: dict[str, Tensor] = {}
        if self.terms is not None and self.terms.entropy is not None:
            named["entropy"] = self.terms.entropy.float()
        if self.terms is not None and self.terms.distance is not None:
            named["distance"] = self.terms.distance.float()
        if self.fisher is not None:
            named["fisher"] = self.fisher.gain
        if self.min_angle is not None:
            named["min_angle"] = self.min_angle
        if self.uncertainty is not None and self.exponent is not None:
            named["uncertainty"] = self.uncertainty
            named["exponent"] = torch.full_like(self.uncertainty, self.exponent)
        return named


Estimator = Callable[[Request], Estimate]
"""Scores the candidates: `fn(request) -> Estimate`."""

Selector = Callable[[Request, Estimate], "tuple[Tensor, Estimate]"]
"""Chooses `request.n` candidates: `fn(request, estimate) -> (indices (n,), estimate)`, the
estimate as the choice was made from it (e.g. sharpened)."""
