"""The registry of view-selection methods: an estimator (what scores the candidates) paired with a
selector (how k are chosen from the scores), so every row of the paper's Tables I and II is a
configuration.

Estimators: "combined" (the paper's U = a H + b D), "entropy" (H only), "distance" (D only),
"fisher" (FisherRF's expected information gain), "none" (no scores).
Selectors: "sampling" (the paper's rejection sampler), "top-k" (next best views), "greedy-fisher"
(FisherRF's greedy batch: update H_train after each pick), "uniform", "farthest".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.selection.selectors import (
    AUTHORS_THRESHOLD, MAX_DRAWS, SAMPLERS, greedy_farthest, rejection_sample, select_top_k,
    select_uniform,
)
from nerfaug.uncertainty.combined import NORMALISATIONS, combined_uncertainty
from nerfaug.uncertainty.entropy import ENTROPY_MODES, view_entropy
from nerfaug.uncertainty.fisher import (
    CACHE_FLOATS, DEFAULT_METHOD, FISHER_LAMBDA, FISHER_METHODS, fisher_diagonal, fisherrf_greedy,
    fisherrf_view_scores, sample_pixel_rays,
)
from nerfaug.uncertainty.so3 import coverage_distance, min_geodesic_angle

ESTIMATORS = ("combined", "entropy", "distance", "fisher", "none")
SELECTORS = ("sampling", "top-k", "greedy-fisher", "uniform", "farthest")


@dataclass(frozen=True)
class MethodSpec:
    """A named view-selection method: which scores, which selector, and what it reproduces."""

    name: str
    estimator: str
    selector: str
    description: str

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"unknown estimator {self.estimator!r}; valid: {', '.join(ESTIMATORS)}")
        if self.selector not in SELECTORS:
            raise ValueError(f"unknown selector {self.selector!r}; valid: {', '.join(SELECTORS)}")
        if self.selector == "greedy-fisher" and self.estimator != "fisher":
            raise ValueError("the greedy-fisher selector needs the fisher estimator")


METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in [
        MethodSpec("ours", "combined", "sampling",
                   "the paper's method: entropy + SO(3) coverage, rejection sampling"),
        MethodSpec("ours-nbv", "combined", "top-k",
                   "entropy + coverage, top-k (Table II 'ours, NBV')"),
        MethodSpec("uniform", "none", "uniform",
                   "Uniform (Mildenhall et al.): k candidates uniformly at random"),
        MethodSpec("entropy", "entropy", "top-k",
                   "Spatial Entropy (Lee et al. 2022): entropy only, top-k"),
        MethodSpec("entropy-sampling", "entropy", "sampling",
                   "entropy only, rejection sampling (Table I 'entropy only', Table II)"),
        MethodSpec("fisherrf", "fisher", "greedy-fisher",
                   "FisherRF (Jiang et al. 2024): greedy next best views by information gain"),
        MethodSpec("fisherrf-sampling", "fisher", "sampling",
                   "rejection sampling over FisherRF's information gain (Table II)"),
        MethodSpec("distance", "distance", "sampling",
                   "coverage term only, rejection sampling (Table I 'distance only')"),
        MethodSpec("distance-nbv", "distance", "top-k",
                   "coverage term only, top-k"),
        MethodSpec("furthest", "none", "farthest",
                   "maximally apart: greedy farthest views by geodesic angle (Fig. 2d)"),
    ]
}


@dataclass
class SelectionConfig:
    """Options of the estimators and selectors. Defaults follow the paper; `authors_variant()`
    switches to what the authors' code does.

    Attributes:
        entropy_resolution: width in pixels of the candidate renders the entropy is taken over.
        entropy_mode: `ray_entropy` mode: "escape" (default), "renormalise", "raw", "authors".
        normalisation: `combined_uncertainty` normalisation: "minmax" (default), "none", "authors".
        entropy_weight, distance_weight: a and b in U = a H + b D.
        metric: the SPD 3x3 matrix M of the coverage term as nested lists; None for identity.
        scale_m: the rejection sampler's M; None for the largest score.
        sampler: "paper" or "authors" (the code's in-order loop, accept if w > 15 nu).
        authors_threshold: the 15 of the authors' sampler.
        max_draws: proposals before the rejection sampler gives up.
        fisher_method: "random-sign" (default) or "exact"; see `nerfaug.uncertainty.fisher`.
        fisher_train_pixels: training pixels H_train is taken over (uniform subsample).
        fisher_train_chunk: rays per squared probe for H_train ("random-sign").
        fisher_train_probes: Rademacher probes per chunk for H_train ("random-sign"; each is
            three backward passes, one per colour channel).
        fisher_resolution: width in pixels of the candidate renders H_cand is taken over.
        fisher_probes: Rademacher probes per candidate ("random-sign"; likewise).
        fisher_lambda: lambda of the FisherRF score.
        fisher_cache_floats: memory bound (floats) on the candidates' Fisher diagonals kept for
            the greedy selection; beyond it they are recomputed when needed.
        chunk: rays per forward pass when rendering candidates (small chunks are faster on a CPU).
        background: colour composited behind rendered rays (FisherRF differentiates colours);
            None for the model's default.
    """

    entropy_resolution: int = 40
    entropy_mode: str = "escape"
    normalisation: str = "minmax"
    entropy_weight: float = 1.0
    distance_weight: float = 1.0
    metric: list[list[float]] | None = None
    scale_m: float | None = None
    sampler: str = "paper"
    authors_threshold: float = AUTHORS_THRESHOLD
    max_draws: int = MAX_DRAWS
    fisher_method: str = DEFAULT_METHOD
    fisher_train_pixels: int = 1024
    fisher_train_chunk: int = 128
    fisher_train_probes: int = 4
    fisher_resolution: int = 8
    fisher_probes: int = 1
    fisher_lambda: float = FISHER_LAMBDA
    fisher_cache_floats: int = CACHE_FLOATS
    chunk: int = 4096
    background: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        for name, value, valid in [
            ("entropy_mode", self.entropy_mode, ENTROPY_MODES),
            ("normalisation", self.normalisation, NORMALISATIONS),
            ("sampler", self.sampler, SAMPLERS),
            ("fisher_method", self.fisher_method, FISHER_METHODS),
        ]:
            if value not in valid:
                raise ValueError(f"SelectionConfig.{name}={value!r} is not one of {', '.join(valid)}")

    def authors_variant(self) -> "SelectionConfig":
        """This config with the authors' code's entropy, normalisation and sampler."""
        return replace(self, entropy_mode="authors", normalisation="authors", sampler="authors")

    def to_dict(self) -> dict:
        """Plain data (JSON-serialisable), for saving next to a selection."""
        return asdict(self)


@dataclass
class Selection:
    """The views a method chose, and the scores it chose them by.

    Attributes:
        indices: Tensor with shape (n,), candidate indices in the order chosen.
        scores: Tensor with shape (n_candidates,), the density or ranking the selector used
            (before any greedy update); ones for "uniform".
        components: name -> Tensor with shape (n_candidates,), the terms behind `scores`
            (e.g. "entropy", "distance" raw, before normalisation).
        method: the method's name.
    """

    indices: Tensor
    scores: Tensor
    components: dict[str, Tensor] = field(default_factory=dict)
    method: str = ""

    def to_dict(self) -> dict:
        """Plain lists and numbers (JSON-serialisable)."""
        return {
            "method": self.method,
            "indices": [int(i) for i in self.indices.tolist()],
            "scores": [float(s) for s in self.scores.tolist()],
            "components": {k: [float(x) for x in v.tolist()] for k, v in self.components.items()},
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Selection":
        return cls(
            torch.tensor(data["indices"], dtype=torch.long), torch.tensor(data["scores"]),
            {k: torch.tensor(v) for k, v in data.get("components", {}).items()}, data.get("method", ""),
        )


def get_method(name: str) -> MethodSpec:
    """The registered method `name`; ValueError listing the valid names otherwise."""
    if name not in METHODS:
        raise ValueError(f"unknown selection method {name!r}; valid methods: {', '.join(METHODS)}")
    return METHODS[name]


def _needs_model(model: nn.Module | None, spec: MethodSpec) -> nn.Module:
    if model is None:
        raise ValueError(f"method {spec.name!r} scores candidates with the model; got model=None")
    return model


def _background(config: SelectionConfig) -> Tensor | None:
    return None if config.background is None else torch.tensor(config.background, dtype=torch.float32)


def candidate_scores(
    method: str, model: nn.Module | None, train_cameras: Cameras, candidates: Cameras,
    config: SelectionConfig | None = None,
) -> tuple[Tensor, dict[str, Tensor]]:
    """The scores a method's estimator gives the candidates, and the terms behind them.

    For "combined", "entropy" and "distance" the components are the raw terms ("entropy" in
    bits, "distance" in radians^2) and the scores their combination (`combined_uncertainty`
    with weights (a, b), (1, 0) or (0, 1)). "none" gives ones. FisherRF needs its diagonals
    (`fisherrf_candidates`) and is scored in `select_views`.

    Returns:
        scores: Tensor with shape (n_candidates,), on the CPU.
        components: name -> Tensor with shape (n_candidates,), on the CPU.
    """
    spec = get_method(method)
    config = config or SelectionConfig()
    if spec.estimator == "none":
        return torch.ones(len(candidates)), {}
    weights = {
        "combined": (config.entropy_weight, config.distance_weight),
        "entropy": (1.0, 0.0),
        "distance": (0.0, 1.0),
    }
    if spec.estimator not in weights:
        raise ValueError(f"estimator {spec.estimator!r} has no closed-form scores; see select_views")
    a, b = weights[spec.estimator]
    components: dict[str, Tensor] = {}
    if a:
        components["entropy"] = view_entropy(
            _needs_model(model, spec), candidates, config.entropy_resolution, config.chunk,
            config.entropy_mode,
        ).cpu()
    if b:
        metric = None if config.metric is None else torch.tensor(config.metric, dtype=torch.float64)
        components["distance"] = coverage_distance(
            candidates.rotations.cpu().double(), train_cameras.rotations.cpu().double(), metric
        ).float()
    scores = combined_uncertainty(
        components.get("entropy"), components.get("distance"), a, b, config.normalisation
    )
    return scores, components


def fisherrf_candidates(
    model: nn.Module, train_cameras: Cameras, candidates: Cameras, config: SelectionConfig | None = None,
    generator: torch.Generator | None = None,
) -> tuple[Tensor, Tensor, Callable[[int], Tensor]]:
    """FisherRF's ingredients: H_train over `config.fisher_train_pixels` pixels drawn uniformly
    from the training views, every candidate's score at `config.fisher_resolution`, and H_cand
    on demand (kept within `config.fisher_cache_floats`, else recomputed) for the greedy selection.

    Returns:
        h_train: Tensor with shape (P,).
        scores: Tensor with shape (n_candidates,).
        h_of: candidate index -> H_cand, Tensor with shape (P,).
    """
    config = config or SelectionConfig()
    origins, directions = sample_pixel_rays(train_cameras, config.fisher_train_pixels, generator)
    background = _background(config)
    h_train = fisher_diagonal(
        model, origins, directions, config.fisher_method, config.fisher_train_probes, generator,
        config.fisher_train_chunk, background,
    )
    scores, h_of = fisherrf_view_scores(
        model, candidates, h_train, config.fisher_lambda, config.fisher_cache_floats,
        config.fisher_resolution, config.fisher_method, config.fisher_probes, generator,
        background=background,
    )
    return h_train, scores, h_of


def select_views(
    method: str,
    model: nn.Module | None,
    train_cameras: Cameras,
    candidates: Cameras,
    n: int,
    generator: torch.Generator | None = None,
    config: SelectionConfig | None = None,
) -> Selection:
    """Choose `n` of the candidate views with a registered method.

    Args:
        method: a name in `METHODS` ("ours", "ours-nbv", "uniform", "entropy", ...).
        model: the NeRF being trained (`NerfModel` interface); may be None for methods that do not
            score with it ("uniform", "distance", "distance-nbv", "furthest").
        train_cameras: the current training views.
        candidates: the n_candidates views to choose from.
        n: how many to choose.
        generator: random source for sampling, probes and pixel subsamples; the same seed gives
            the same selection.
        config: estimator and selector options; None for the defaults.

    Returns:
        Selection(indices (n,), scores (n_candidates,), components, method).
    """
    spec = get_method(method)
    config = config or SelectionConfig()
    if not 0 <= n <= len(candidates):
        raise ValueError(f"cannot choose {n} views out of {len(candidates)} candidates")
    if spec.estimator == "fisher":
        h_train, scores, h_of = fisherrf_candidates(
            _needs_model(model, spec), train_cameras, candidates, config, generator
        )
        scores = scores.cpu()
        components = {"fisher": scores}
    else:
        scores, components = candidate_scores(method, model, train_cameras, candidates, config)

    if spec.selector == "sampling":
        indices = rejection_sample(
            scores, n, generator, config.scale_m, config.max_draws, config.sampler, config.authors_threshold
        )
    elif spec.selector == "top-k":
        indices = select_top_k(scores, n)
    elif spec.selector == "greedy-fisher":
        indices, _ = fisherrf_greedy(h_train, h_of, n, config.fisher_lambda, scores)
    elif spec.selector == "uniform":
        indices = select_uniform(len(candidates), n, generator)
    else:  # "farthest"
        rotations = candidates.rotations.cpu().double()
        training = train_cameras.rotations.cpu().double()
        indices = greedy_farthest(rotations, training, n)
        if training.shape[0]:
            scores = min_geodesic_angle(rotations, training).float()
            components = {"min_angle": scores}  # radians to the nearest training view
    return Selection(indices.cpu(), scores.cpu(), components, spec.name)
