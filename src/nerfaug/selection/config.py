"""`SelectionConfig`: the options of the estimators and selectors, and the settings the authors'
code uses where the paper is silent (`AUTHORS_SETTINGS`).

The names a choice field may take are listed here, next to the field: `REJECTION_SAMPLERS`
(`sampler`: the rejection sampler's variants; the engine's ray samplers are
`nerfaug.nerf.SAMPLERS`) and `DISTANCE_ROTATIONS` (`distance_rotations`); the uncertainty measures'
modes are `nerfaug.uncertainty.choices`'.

Each field's bounds are in its annotation, checked by pydantic in one place, `checked()` (a
`nerfaug.schema.Schema`): a proposal's request checks its settings with it (`ProposalRequest`), an
experiment's config when it is made (`experiment.config.ExperimentConfig`). tyro builds the options without
checking them, so a refused value is one line naming its option.

Nothing here imports torch, nor numpy until a metric is checked: `nerfaug run`, `study` and
`propose` offer these options, and their `--help` loads neither.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from types import MappingProxyType
from typing import Annotated, Literal

import tyro
from pydantic import AfterValidator, Field
from tyro.constructors import PrimitiveConstructorSpec

from nerfaug.schema import SCHEMA, Schema, validated
from nerfaug.uncertainty.choices import (
    CACHE_FLOATS,
    DEFAULT_METHOD,
    ENTROPY_MODES,
    FISHER_LAMBDA,
    FISHER_METHODS,
    NORMALISATIONS,
)

# The rejection sampler's variants (`selectors.rejection_sample`): the paper's, and the authors'
# code's in-order sweep.
REJECTION_SAMPLERS = ("paper", "authors")
# The authors' code accepts candidate i when w_i > AUTHORS_THRESHOLD * nu, nu ~ U[0.05, 1].
AUTHORS_THRESHOLD = 15.0
# Proposals before a rejection sampler gives up.
MAX_DRAWS = 1_000_000
# The rotations the coverage term compares (`estimators.distance_rotations`).
DISTANCE_ROTATIONS = ("pose", "azimuth")


def _unset_means(meaning: str, metavar: str):
    """`--help` of an option whose default is None: what None does, e.g. "(default: the
    identity)", and the metavar without "{None}|" (tyro alone prints "(default: None)")."""
    return tyro.conf.arg(metavar=metavar, help_behavior_hint=f"(default: {meaning})")


def _metric_from_words(words: list[str]) -> list[list[float]]:
    values = [float(word) for word in words]
    return [values[0:3], values[3:6], values[6:9]]


# `--selection.metric` takes the 3x3 matrix as nine numbers, row by row; tyro's own parse of
# nested lists cannot split them into rows.
METRIC_ON_THE_COMMAND_LINE = PrimitiveConstructorSpec(
    nargs=9,
    metavar="M11 M12 M13 M21 M22 M23 M31 M32 M33",
    instance_from_str=_metric_from_words,
    is_instance=lambda value: value is None or isinstance(value, list),
    str_from_instance=lambda value: ["None"] if value is None else [str(v) for row in value for v in row],
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


def _metric(metric: list[list[float]]) -> list[list[float]]:
    """`metric` if it can be the coverage term's M: a symmetric positive-definite 3x3 matrix of
    finite numbers (pydantic checked that it holds numbers, and that they are finite)."""
    import numpy as np  # here: `--help` reads this module (above)

    if len(metric) != 3 or any(len(row) != 3 for row in metric):
        raise ValueError("must be a 3x3 matrix of numbers")
    matrix = np.array(metric, dtype=float)
    if not np.allclose(matrix, matrix.T):
        raise ValueError("must be symmetric")
    if np.linalg.eigvalsh(matrix).min() <= 0:
        raise ValueError("must be positive definite")
    return metric


# The settings whose value sets the work of a selection, and their largest values: a proposal's
# request (over HTTP too) is refused beyond these before any work starts.
MAX_RESOLUTION = 256
MAX_RAYS_PER_CHUNK = 65_536
# Strict numbers: true/false, or a number written as a string, is no setting's value.
Weight = Annotated[float, Field(strict=True, ge=0)]
Positive = Annotated[float, Field(strict=True, gt=0)]
Angle = Annotated[float, Field(strict=True)]
# Whole numbers >= 1: pixels across, rays, random probes.
Resolution = Annotated[int, Field(strict=True, ge=1, le=MAX_RESOLUTION)]
Rays = Annotated[int, Field(strict=True, ge=1, le=MAX_RAYS_PER_CHUNK)]
Probes = Annotated[int, Field(strict=True, ge=1, le=64)]


@dataclass
class SelectionConfig(Schema):
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
        entropy_resolution: width in pixels of each candidate's render the entropy is measured on.
        entropy_mode: how a ray's entropy counts the chance that it sees background: "escape" (as
            one more outcome), "renormalise", "raw" (the paper's formula as written), "authors"
            (their code); docs/methods.md.
        normalisation: how the entropy and coverage terms are scaled before they are added:
            "minmax" (each to [0, 1] over the candidates), "none" (the paper's equation as
            written), "authors" (their code).
        entropy_weight: weight of the entropy term (how unsure the NeRF is about a view) in a
            candidate's score.
        distance_weight: weight of the coverage term (how far a view is from those trained on)
            in a candidate's score.
        metric: the symmetric positive-definite 3x3 matrix that weighs rotations in the coverage
            term (on the command line nine numbers, row by row).
        scale_m: the bound the rejection sampler divides scores by.
        sampler: the rejection sampler: "paper" (random draws, accepted in proportion to the
            score) or "authors" (their code: candidates in order, accepted above a random
            threshold).
        authors_threshold: the "authors" sampler accepts a candidate whose score exceeds this
            times a random number in [0.05, 1].
        max_draws: draws after which the paper's rejection sampler draws its remaining views
            directly from the distribution it samples (the authors' sampler gives up with an error).
        fisher_method: how FisherRF's information is estimated: "random-sign" (random probes,
            unbiased, fast) or "exact" (slow; for checking); docs/methods.md.
        fisher_train_pixels: training pixels FisherRF's estimate of what the training views
            already give is taken over (a random, unbiased subsample; docs/methods.md says how
            the default was chosen).
        fisher_train_chunk: rays per random probe in that estimate ("random-sign").
        fisher_train_probes: random probes per chunk of rays in that estimate ("random-sign";
            each costs three backward passes).
        fisher_resolution: pixels across each candidate's image FisherRF scores (a random,
            unbiased subsample; the image's width or more takes every pixel).
        fisher_probes: random probes per candidate ("random-sign"; each costs three backward
            passes).
        fisher_lambda: FisherRF's regulariser, added to the training views' information.
        fisher_cache_floats: memory bound (floats) on the candidates' FisherRF information kept
            while views are chosen one by one; beyond it, it is computed again when needed.
        chunk: rays per forward pass when rendering candidates (small chunks are faster on a CPU).
        background: colour behind rendered rays (FisherRF differentiates colours).
        scoring_fov: horizontal field of view, degrees, of the candidate renders the entropy is
            measured on (the authors' code: 75).
        scoring_crop: the central fraction (width and height) of that view the entropy is
            measured on, rendered `--selection.entropy-resolution` pixels across (the authors'
            code: 0.5).
        min_polar: candidates within this angle of the pole (straight above; radians, 90 degrees
            minus the elevation) are never chosen (the authors' sampler: 0.4).
        entropy_max_polar: candidates farther than this angle from the pole (radians) get entropy
            0 (the authors' entropy method: 0.75).
        distance_rotations: the rotations the coverage term compares: "pose" (the cameras' whole
            rotations) or "azimuth" (the turn about the up axis alone, as the authors' code).
        temperature: T of the sampler, scores ** (1/T): 1 keeps the scores, < 1 sharpens
            towards the best-scored view, > 1 flattens towards uniform. Samplers only.
        sharpness: in [0, 1]: the temperature is chosen per selection so that 0 keeps the
            scores, 1 takes the best-scored views, and 0.5 lies halfway (docs/methods.md).
            Replaces `--selection.temperature`.
        batch_entropy_sigma: for the batch-aware methods: once a view is accepted, the entropy
            of candidates near it is lowered, within about this angle (radians; docs/methods.md).
    """

    __pydantic_config__ = SCHEMA

    entropy_resolution: Resolution = 40
    entropy_mode: Literal[ENTROPY_MODES] = "escape"
    normalisation: Literal[NORMALISATIONS] = "minmax"
    entropy_weight: Weight = 1.0
    distance_weight: Weight = 1.0
    metric: Annotated[
        Annotated[list[list[float]], AfterValidator(_metric)] | None,
        METRIC_ON_THE_COMMAND_LINE,
        _unset_means("the identity", "M11 M12 M13 M21 M22 M23 M31 M32 M33"),
    ] = None
    scale_m: Annotated[Positive | None, _unset_means("the largest score", "FLOAT")] = None
    sampler: Literal[REJECTION_SAMPLERS] = "paper"
    authors_threshold: Weight = AUTHORS_THRESHOLD
    max_draws: Annotated[int, Field(strict=True, ge=1, le=10 * MAX_DRAWS)] = MAX_DRAWS
    fisher_method: Literal[FISHER_METHODS] = DEFAULT_METHOD
    fisher_train_pixels: Rays = 4096
    fisher_train_chunk: Annotated[int, Field(strict=True, ge=1, le=4096)] = 128
    fisher_train_probes: Probes = 4
    fisher_resolution: Resolution = 45
    fisher_probes: Probes = 1
    fisher_lambda: Positive = FISHER_LAMBDA
    fisher_cache_floats: Annotated[int, Field(strict=True, ge=1, le=CACHE_FLOATS)] = CACHE_FLOATS
    chunk: Rays = 4096
    background: Annotated[tuple[float, float, float] | None, _unset_means("the model's", "R G B")] = None
    scoring_fov: Annotated[
        Annotated[float, Field(strict=True, gt=0, lt=180)] | None, _unset_means("the candidates' own", "DEGREES")
    ] = None
    scoring_crop: Annotated[float, Field(strict=True, gt=0, le=1)] = 1.0
    min_polar: Annotated[Angle | None, _unset_means("no limit", "RADIANS")] = None
    entropy_max_polar: Annotated[Angle | None, _unset_means("no limit", "RADIANS")] = None
    distance_rotations: Literal[DISTANCE_ROTATIONS] = "pose"
    temperature: Positive = 1.0
    sharpness: Annotated[
        Annotated[float, Field(strict=True, ge=0, le=1)] | None,
        _unset_means("unset: --selection.temperature applies", "FLOAT"),
    ] = None
    batch_entropy_sigma: Annotated[Positive | None, _unset_means("no discount", "RADIANS")] = None

    def authors_variant(self) -> SelectionConfig:
        """This config with the authors' code's settings (`AUTHORS_SETTINGS`): entropy,
        normalisation, sampler, polar limit and scoring view."""
        return replace(self, **AUTHORS_SETTINGS)

    def to_dict(self) -> dict:
        """Plain data (JSON-serialisable), for saving next to a selection."""
        return asdict(self)

    def changes(self) -> dict:
        """The fields that differ from `SelectionConfig()`'s defaults."""
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
        """The inverse of `to_dict`, checked (`checked()`).

        Raises:
            RequestError: naming the first unknown or refused field and its value.
        """
        return validated(cls, data)
