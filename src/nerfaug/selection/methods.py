"""The registry of view-selection methods: an estimator (what scores the candidates) paired with a
selector (how n are chosen from the scores), plus the settings the method fixes, so every row of
the paper's Tables I and II, the authors' code's variants and the batch-aware variants are
configurations of one `select_views`.

Estimators (`selection.estimators`): "combined" (the paper's U = a H + b D), "entropy" (H only),
"distance" (D only), "fisher" (FisherRF's expected information gain), "none" (no scores).
Selectors (`selection.selectors`, `selection.batch`): "sampling" (the paper's rejection sampler),
"top-k" (next best views), "greedy-fisher" (FisherRF's greedy batch: update H_train after each
pick), "uniform", "farthest", "batch-sampling" (the posterior updated after each acceptance).

Adding a method: register an estimator or selector function if a new one is needed
(`selection.registry`), then add one `MethodSpec` line to `METHODS` (and to a family below if it
belongs in a table).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace
from types import MappingProxyType

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.selection.batch import batch_aware_sample  # noqa: F401 (importing registers "batch-sampling")
from nerfaug.selection.estimators import (  # importing it registers the estimators
    DISTANCE_ROTATIONS,
)
from nerfaug.selection.registry import ESTIMATORS, SELECTOR_NEEDS, SELECTORS, Request
from nerfaug.selection.selectors import AUTHORS_THRESHOLD, MAX_DRAWS, SAMPLERS
from nerfaug.uncertainty.combined import NORMALISATIONS
from nerfaug.uncertainty.entropy import ENTROPY_MODES
from nerfaug.uncertainty.fisher import (
    CACHE_FLOATS,
    DEFAULT_METHOD,
    FISHER_LAMBDA,
    FISHER_METHODS,
)

# What the authors' code (Agaggar/nerfstudio-low-data) does where the paper is silent, as
# `SelectionConfig` settings; `SelectionConfig.authors_variant()` applies them. See the
# SelectionConfig docstring for what the project cannot copy exactly.
AUTHORS_SETTINGS = MappingProxyType(
    {
        "entropy_mode": "authors",  # p = w / max(w) over the view's rays, -10 sum p log2(p + 1e-9)
        "normalisation": "authors",  # per-view H cubed + min-max; D min-max; (H' + D') / max
        "sampler": "authors",  # in-order sweep, nu ~ U(0.05, 1), accept if w > 15 nu
        "min_polar": 0.4,  # candidates within 0.4 rad of the pole are never accepted
        "scoring_fov": 75.0,  # their scoring renders: 75-degree field of view ...
        "scoring_crop": 0.5,  # ... of which only the central 400x400 of 800x800 is used
    }
)
# The authors' entropy NBV baseline: top-k of minmax(H^3) + minmax(D), H zeroed beyond 0.75 rad
# from the pole, D over azimuth-only rotations (their code zeroes the candidates' polar angle).
AUTHORS_NBV_SETTINGS = MappingProxyType(
    {
        **{k: v for k, v in AUTHORS_SETTINGS.items() if k not in ("sampler", "min_polar")},
        "entropy_max_polar": 0.75,
        "distance_rotations": "azimuth",
    }
)
# Batch-aware sampling (`selection.batch`). The entropy discount's width: a view within about
# half a field of view of an accepted one sees mostly the same rays (NeRF-synthetic's field of
# view is 0.69 rad, so 0.35). Chosen from the camera geometry, not from any result.
BATCH_ENTROPY_SIGMA = 0.35
# The sharp variant's posterior: effective sample size at the geometric mean of uniform's (all
# candidates) and next-best-view's (n), halfway between the two on a log scale; see
# `selection.posterior`. The plain posterior is nearly flat (measured on lego: max U / mean U = 1.7).
BATCH_SHARPNESS = 0.5


@dataclass(frozen=True)
class MethodSpec:
    """A named view-selection method: which scores, which selector, the settings it fixes, and
    what it reproduces.

    Attributes:
        name: the method's name (`nerfaug methods`, `--methods`).
        estimator: a name in `ESTIMATORS`.
        selector: a name in `SELECTORS`.
        description: one line: what it is and where it comes from.
        label: the display name in reports and tables.
        settings: `SelectionConfig` fields this method fixes, applied over the caller's config.
    """

    name: str
    estimator: str
    selector: str
    description: str
    label: str = ""
    settings: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.estimator not in ESTIMATORS:
            raise ValueError(f"unknown estimator {self.estimator!r}; valid: {', '.join(ESTIMATORS)}")
        if self.selector not in SELECTORS:
            raise ValueError(f"unknown selector {self.selector!r}; valid: {', '.join(SELECTORS)}")
        needs = SELECTOR_NEEDS.get(self.selector)
        if needs is not None and self.estimator not in needs:
            raise ValueError(f"the {self.selector} selector needs the estimator {' or '.join(needs)}")
        unknown = set(self.settings) - {f.name for f in fields(SelectionConfig)}
        if unknown:
            raise ValueError(f"method {self.name!r}: unknown SelectionConfig settings {sorted(unknown)}")
        if not self.label:
            object.__setattr__(self, "label", self.name)
        object.__setattr__(self, "settings", dict(self.settings))

    def effective_config(self, config: SelectionConfig | None = None) -> SelectionConfig:
        """`config` (defaults when None) with this method's settings applied."""
        config = config or SelectionConfig()
        return replace(config, **self.settings) if self.settings else config

    def definition(self) -> dict:
        """Plain data that identifies what the method computes (for results fingerprints)."""
        return {"estimator": self.estimator, "selector": self.selector, "settings": dict(self.settings)}


@dataclass
class SelectionConfig:
    """Options of the estimators and selectors. Defaults follow the paper; `authors_variant()`
    switches to what the authors' code does (`AUTHORS_SETTINGS`; the method "ours-authors").

    What the authors' variant cannot copy exactly, and why:
    - Scoring renders: theirs are 800x800 with a 75-degree field of view, of which the central
      400x400 are used (160k rays per candidate, 80M for 500 candidates: hours on a CPU). Here the
      same field of view and crop (`scoring_fov` 75, `scoring_crop` 0.5) are rendered
      `entropy_resolution` pixels across (40 by default): the same part of the scene, fewer rays.
    - Their black background and bounding-box crop do not enter: the entropy is taken from the
      volume-rendering weights alone (no colour), inside the engine's own scene bounds.
    - Their entropy normalises by the maximum weight over a whole rendered chunk; here over each
      view's rays (a chunk's extent depended on their renderer's batching, not on the method).
    - Their distance has no 1/2 and is min-max normalised: min-max removes any constant factor,
      so D here (with the 1/2) gives the same normalised term.
    - Their polar test reads the pre-rendered poses' angles; here the polar angle is measured
      about the origin, the scene centre in the engine's frame (experiments and capture sessions
      alike).

    Attributes:
        entropy_resolution: width in pixels of the candidate renders the entropy is taken over.
        entropy_mode: `ray_entropy` mode: "escape" (default), "renormalise", "raw", "authors".
        normalisation: `combined_uncertainty` normalisation: "minmax" (default), "none", "authors".
        entropy_weight: a in U = a H + b D (the entropy term's weight).
        distance_weight: b in U = a H + b D (the coverage term's weight).
        metric: the SPD 3x3 matrix M of the coverage term as nested lists; None for identity.
        scale_m: the rejection sampler's M; None for the largest score.
        sampler: "paper" or "authors" (the code's in-order loop, accept if w > 15 nu).
        authors_threshold: the 15 of the authors' sampler.
        max_draws: proposals before the rejection sampler gives up.
        fisher_method: "random-sign" (default) or "exact"; see `nerfaug.uncertainty.fisher`.
        fisher_train_pixels: training pixels H_train is taken over (a stratified, weighted
            subsample of the training views, `fisher_train_rays`). With fisher_resolution 45, 4096
            was chosen as the cheapest setting whose candidate ranking, at step 200 on lego
            100x100, stays put when either side's pixels double (mean Spearman >= 0.9 and top-6
            overlap >= 4/6 for each of 4 seeds), measured with unweighted uniform training pixels;
            with this estimator the means hold but one seed of 4 keeps 2/6 when the training
            pixels double (benchmarks/bench_fisher.py; BENCHMARKS.md, "FisherRF stability").
        fisher_train_chunk: rays per squared probe for H_train ("random-sign").
        fisher_train_probes: Rademacher probes per chunk for H_train ("random-sign"; each is
            three backward passes, one per colour channel).
        fisher_resolution: pixels across each candidate H_cand is taken over (a stratified,
            weighted subsample of its image, `fisher_views`: unbiased for the whole image; the
            image's width or more takes every pixel).
        fisher_probes: Rademacher probes per candidate ("random-sign"; likewise).
        fisher_lambda: lambda of the FisherRF score.
        fisher_cache_floats: memory bound (floats) on the candidates' Fisher diagonals kept for
            the greedy selection; beyond it they are recomputed when needed.
        chunk: rays per forward pass when rendering candidates (small chunks are faster on a CPU).
        background: colour composited behind rendered rays (FisherRF differentiates colours);
            None for the model's default.
        scoring_fov: horizontal field of view, degrees, of the entropy's candidate renders; None
            for the candidates' own (the authors' code: 75).
        scoring_crop: the central fraction (width and height) of that view the entropy is taken
            over, rendered `entropy_resolution` pixels across (the authors' code: 0.5).
        min_polar: candidates closer than this to the pole (polar angle from +z, radians) are
            never chosen, by any selector; None for no limit (the authors' sampler: 0.4).
        entropy_max_polar: candidates farther than this from the pole (radians) get entropy 0
            before normalisation; None for no limit (the authors' entropy NBV: 0.75).
        distance_rotations: the rotations the coverage term compares: "pose" (the cameras') or the
            azimuth's alone, "azimuth" (polar angle set to 0, as the authors' NBV code does).
        temperature: T of the sampling posterior, scores ** (1/T): 1 keeps the scores, < 1
            sharpens towards next-best-view, > 1 flattens towards uniform. Samplers only.
        sharpness: if set, in [0, 1]: T is solved per selection so the posterior's effective
            sample size is C^(1 - s) n^s (C candidates, n views): 0 keeps it, 1 is next-best-view,
            and 0.5 the geometric mean (see `nerfaug.selection.posterior`). Overrides `temperature`.
        batch_entropy_sigma: for batch-aware sampling: the entropy of a candidate theta radians
            from an accepted view is multiplied by 1 - exp(-theta^2 / (2 sigma^2)); None for no
            entropy discount (see `nerfaug.selection.batch`).
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
    fisher_train_pixels: int = 4096
    fisher_train_chunk: int = 128
    fisher_train_probes: int = 4
    fisher_resolution: int = 45
    fisher_probes: int = 1
    fisher_lambda: float = FISHER_LAMBDA
    fisher_cache_floats: int = CACHE_FLOATS
    chunk: int = 4096
    background: tuple[float, float, float] | None = None
    scoring_fov: float | None = None
    scoring_crop: float = 1.0
    min_polar: float | None = None
    entropy_max_polar: float | None = None
    distance_rotations: str = "pose"
    temperature: float = 1.0
    sharpness: float | None = None
    batch_entropy_sigma: float | None = None

    def __post_init__(self) -> None:
        for name, value, valid in [
            ("entropy_mode", self.entropy_mode, ENTROPY_MODES),
            ("normalisation", self.normalisation, NORMALISATIONS),
            ("sampler", self.sampler, SAMPLERS),
            ("fisher_method", self.fisher_method, FISHER_METHODS),
            ("distance_rotations", self.distance_rotations, DISTANCE_ROTATIONS),
        ]:
            if value not in valid:
                raise ValueError(f"SelectionConfig.{name}={value!r} is not one of {', '.join(valid)}")
        for name, ok, rule in [
            ("entropy_resolution", self.entropy_resolution >= 1, ">= 1"),
            ("scoring_crop", 0 < self.scoring_crop <= 1, "in (0, 1]"),
            ("scoring_fov", self.scoring_fov is None or 0 < self.scoring_fov < 180, "in (0, 180) degrees"),
            ("temperature", self.temperature > 0, "> 0"),
            ("sharpness", self.sharpness is None or 0 <= self.sharpness <= 1, "in [0, 1]"),
            ("batch_entropy_sigma", self.batch_entropy_sigma is None or self.batch_entropy_sigma > 0, "> 0"),
            ("entropy_weight", self.entropy_weight >= 0, ">= 0"),
            ("distance_weight", self.distance_weight >= 0, ">= 0"),
            ("authors_threshold", self.authors_threshold >= 0, ">= 0"),
            ("scale_m", self.scale_m is None or self.scale_m > 0, "> 0"),
            *[
                (name, getattr(self, name) >= 1, ">= 1")
                for name in (
                    "max_draws",
                    "chunk",
                    "fisher_train_pixels",
                    "fisher_train_chunk",
                    "fisher_train_probes",
                    "fisher_resolution",
                    "fisher_probes",
                    "fisher_cache_floats",
                )
            ],
            ("fisher_lambda", self.fisher_lambda > 0, "> 0"),
        ]:
            if not ok:
                raise ValueError(f"SelectionConfig.{name}={getattr(self, name)!r} must be {rule}")

    def authors_variant(self) -> SelectionConfig:
        """This config with the authors' code's settings (`AUTHORS_SETTINGS`): entropy,
        normalisation, sampler, polar limit and scoring view."""
        return replace(self, **AUTHORS_SETTINGS)

    def to_dict(self) -> dict:
        """Plain data (JSON-serialisable), for saving next to a selection."""
        return asdict(self)

    def changes(self) -> dict:
        """The fields that differ from `SelectionConfig()`'s defaults: what a user set with
        `--selection.*` options, to apply over a preset's selection settings."""
        default = SelectionConfig().to_dict()
        return {k: getattr(self, k) for k, v in self.to_dict().items() if v != default[k]}

    def flags(self) -> list[str]:
        """The `--selection.*` options that give this config (its changes from the defaults)."""
        words = []
        for name, value in self.changes().items():
            values = value if isinstance(value, (list, tuple)) else [value]
            flat = [v for item in values for v in (item if isinstance(item, (list, tuple)) else [item])]
            words += [f"--selection.{name.replace('_', '-')}", *map(str, flat)]
        return words

    @classmethod
    def from_dict(cls, data: dict) -> SelectionConfig:
        """The inverse of `to_dict`; unknown keys are refused with their names."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown SelectionConfig fields {unknown}; valid: {', '.join(sorted(known))}")
        values = dict(data)
        if values.get("background") is not None:
            values["background"] = tuple(values["background"])
        return cls(**values)


def _line(name: str, estimator: str, selector: str, description: str, label: str = "", **settings) -> MethodSpec:
    return MethodSpec(name, estimator, selector, description, label, settings)


METHODS: dict[str, MethodSpec] = {
    spec.name: spec
    for spec in [
        _line(
            "ours",
            "combined",
            "sampling",
            "the paper's method with each term min-max normalised over the candidates before the sum "
            "(U = H' + D'), rejection sampling",
            "Ours (min-max H + D)",
        ),
        _line(
            "ours-paper-sum",
            "combined",
            "sampling",
            "the paper's method as its text writes it: the raw sum U = H + D (entropy in bits, coverage "
            "in rad^2, no normalisation), rejection sampling",
            "Ours (raw sum H + D, as written)",
            normalisation="none",
        ),
        _line("ours-nbv", "combined", "top-k", "entropy + coverage, top-k (Table II 'ours, NBV')", "Ours (NBV)"),
        _line(
            "ours-authors",
            "combined",
            "sampling",
            "ours as the authors' code computes it: their entropy, normalisation, in-order sampler "
            "with M = 15, polar >= 0.4 rad, 75-degree central-crop scoring views",
            "Ours (authors' code)",
            **AUTHORS_SETTINGS,
        ),
        _line(
            "ours-batch",
            "combined",
            "batch-sampling",
            "beyond the paper: ours with the coverage term updated after each accepted view",
            "Ours (batch-aware)",
        ),
        _line(
            "ours-batch-local",
            "combined",
            "batch-sampling",
            "beyond the paper: batch-aware ours, also discounting the entropy near accepted views "
            "(Gaussian local penalty, sigma 0.35 rad)",
            "Ours (batch-aware, local)",
            batch_entropy_sigma=BATCH_ENTROPY_SIGMA,
        ),
        _line(
            "ours-batch-sharp",
            "combined",
            "batch-sampling",
            "beyond the paper: ours-batch-local with a sharper posterior (ESS at the geometric mean "
            "of uniform's and NBV's)",
            "Ours (batch-aware, sharp)",
            batch_entropy_sigma=BATCH_ENTROPY_SIGMA,
            sharpness=BATCH_SHARPNESS,
        ),
        _line("uniform", "none", "uniform", "Uniform (Mildenhall et al.): k candidates uniformly at random", "Uniform"),
        _line("entropy", "entropy", "top-k", "Spatial Entropy (Lee et al. 2022): entropy only, top-k", "Entropy (NBV)"),
        _line(
            "entropy-sampling",
            "entropy",
            "sampling",
            "entropy only, rejection sampling (Table I 'entropy only', Table II)",
            "Entropy (sampling)",
        ),
        _line(
            "entropy-authors-nbv",
            "combined",
            "top-k",
            "the authors' code's entropy NBV: top-k of minmax(H^3) + minmax(D), H zeroed beyond "
            "0.75 rad polar, D from azimuth",
            "Entropy NBV (authors' code)",
            **AUTHORS_NBV_SETTINGS,
        ),
        _line(
            "fisherrf",
            "fisher",
            "greedy-fisher",
            "FisherRF (Jiang et al. 2024): greedy next best views by information gain",
            "FisherRF",
        ),
        _line(
            "fisherrf-sampling",
            "fisher",
            "sampling",
            "rejection sampling over FisherRF's information gain (Table II)",
            "FisherRF (sampling)",
        ),
        _line(
            "distance",
            "distance",
            "sampling",
            "coverage term only, rejection sampling (Table I 'distance only')",
            "Distance only",
        ),
        _line("distance-nbv", "distance", "top-k", "coverage term only, top-k", "Distance (NBV)"),
        _line(
            "distance-authors-nbv",
            "distance",
            "top-k",
            "the authors' code's 'max distance': top-k of D over azimuth-only rotations",
            "Max distance (authors' code)",
            distance_rotations="azimuth",
        ),
        _line(
            "furthest",
            "none",
            "farthest",
            "maximally apart: greedy farthest views by geodesic angle (Fig. 2d)",
            "Furthest",
        ),
    ]
}

# Method families: the one source of truth for the tables, the comparisons and the study.
# Table I (terms), as (row label, method).
TABLE_I_ROWS = (("Combined (ours)", "ours"), ("Entropy only", "entropy-sampling"), ("Distance only", "distance"))
# Table II (NBV vs sampling), as (family, variant, method), in the paper's order.
TABLE_II_ROWS = (
    ("Ours", "NBV", "ours-nbv"),
    ("Ours", "Sampling", "ours"),
    ("FisherRF", "NBV", "fisherrf"),
    ("FisherRF", "Sampling", "fisherrf-sampling"),
    ("Entropy", "NBV", "entropy"),
    ("Entropy", "Sampling", "entropy-sampling"),
)
TABLE_I = tuple(m for _, m in TABLE_I_ROWS)
TABLE_II = ("ours", "ours-nbv", "fisherrf", "fisherrf-sampling", "entropy", "entropy-sampling")
# The paper's main comparison (Sec. IV): ours first, then the three baselines.
MAIN_COMPARISON = ("ours", "uniform", "entropy", "fisherrf")
# The authors' code's variants beside the paper's definition.
AUTHORS_VARIANTS = ("ours", "ours-authors", "entropy-authors-nbv", "distance-authors-nbv")
# Beyond the paper: batch-aware sampling beside plain sampling.
BATCH_AWARE = ("ours", "ours-batch", "ours-batch-local", "ours-batch-sharp")
# The study: ours (min-max and the raw sum as written), its authors' variant, the batch-aware variant and the baselines.
STUDY_METHODS = (
    "ours",
    "ours-paper-sum",
    "ours-authors",
    "ours-batch-sharp",
    "uniform",
    "entropy",
    "fisherrf",
    "furthest",
)
FAMILIES: dict[str, tuple[str, ...]] = {
    "table-i": TABLE_I,
    "table-ii": TABLE_II,
    "main": MAIN_COMPARISON,
    "authors": AUTHORS_VARIANTS,
    "batch": BATCH_AWARE,
    "study": STUDY_METHODS,
}


def method_label(name: str) -> str:
    """The display label of a method (its name when it is not registered)."""
    return METHODS[name].label if name in METHODS else name


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
    def from_dict(cls, data: dict) -> Selection:
        return cls(
            torch.tensor(data["indices"], dtype=torch.long),
            torch.tensor(data["scores"]),
            {k: torch.tensor(v) for k, v in data.get("components", {}).items()},
            data.get("method", ""),
        )


def get_method(name: str) -> MethodSpec:
    """The registered method `name`; ValueError listing the valid names otherwise."""
    if name not in METHODS:
        raise ValueError(f"unknown selection method {name!r}; valid methods: {', '.join(METHODS)}")
    return METHODS[name]


def candidate_scores(
    method: str,
    model: nn.Module | None,
    train_cameras: Cameras,
    candidates: Cameras,
    config: SelectionConfig | None = None,
) -> tuple[Tensor, dict[str, Tensor]]:
    """The scores a method's estimator gives the candidates, and the terms behind them (with
    the method's own settings applied to `config`).

    For "combined", "entropy" and "distance" the components are the raw terms ("entropy" in
    bits, or the authors' score, "distance" in radians^2) and the scores their combination
    (`combined_uncertainty` with weights (a, b), (1, 0) or (0, 1)). "none" gives ones.
    FisherRF's need the model's Fisher diagonals (random probes: pass a generator to
    `select_views` for reproducible ones).

    Returns:
        scores: Tensor with shape (n_candidates,), on the CPU.
        components: name -> Tensor with shape (n_candidates,), on the CPU.
    """
    spec = get_method(method)
    request = Request(spec.name, model, train_cameras, candidates, 0, None, spec.effective_config(config))
    scoring = ESTIMATORS[spec.estimator](request)
    return scoring.scores.cpu(), dict(scoring.components)


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
        config: estimator and selector options; None for the defaults. The method's own
            settings (`MethodSpec.settings`) are applied over it.

    Returns:
        Selection(indices (n,), scores (n_candidates,), components, method).
    """
    spec = get_method(method)
    if not 0 <= n <= len(candidates):
        raise ValueError(f"cannot choose {n} views out of {len(candidates)} candidates")
    request = Request(spec.name, model, train_cameras, candidates, n, generator, spec.effective_config(config))
    scoring = ESTIMATORS[spec.estimator](request)
    indices, scoring = SELECTORS[spec.selector](request, scoring)
    components = {k: v.detach().cpu() for k, v in scoring.components.items()}
    return Selection(indices.cpu(), scoring.scores.detach().cpu(), components, spec.name)
