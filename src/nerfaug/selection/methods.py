"""The registry of view-selection methods: an estimator (what scores the candidates) paired with a
selector (how n are chosen from the scores), plus the settings the method fixes, so every row of
the paper's Tables I and II, the authors' code's variants and the batch-aware variants are
configurations of one `select_views`. The method families (the tables, the comparisons and the
study) name them in `selection.families`.

Estimators (`selection.estimators`): "combined" (the paper's U = a H + b D), "entropy" (H only),
"distance" (D only), "fisher" (FisherRF's expected information gain), "none" (no scores).
Selectors (`selection.selectors`, `selection.batch`): "sampling" (the paper's rejection sampler),
"top-k" (next best views), "greedy-fisher" (FisherRF's greedy batch: update H_train after each
pick), "uniform", "farthest", "batch-sampling" (the posterior updated after each acceptance).

Adding a method: write an estimator or selector function and list it in `selection.registry` if
a new one is needed, then add one `MethodSpec` line to `METHODS` (and to a family below if it
belongs in a table).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType

from nerfaug.registry import lookup
from nerfaug.selection.config import AUTHORS_SETTINGS, SelectionConfig
from nerfaug.selection.registry import get_estimator, get_selector

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
        estimator: a name in `selection.registry.ESTIMATORS`.
        selector: a name in `selection.registry.SELECTORS`.
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
        get_estimator(self.estimator)
        get_selector(self.selector, self.estimator)
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

    def score_label(self, config: SelectionConfig | None = None, exponent: float | None = None) -> str:
        """What this method's candidate scores are, with their unit: the colour bar of its map.

        Args:
            config: the caller's settings (this method's own are applied over them).
            exponent: 1/T when a sampler sharpened the scores (`Estimate.exponent`); None otherwise.

        Example:
            >>> print(METHODS["entropy"].score_label())
            uncertainty U = H′ (no unit; ′: min-max scaled)
            H: mean ray entropy (bits)
        """
        config = self.effective_config(config)
        if self.estimator == "none":
            return "no score (the selector ignores scores)"
        label = (
            "FisherRF information gain (no unit)"
            if self.estimator == "fisher"
            else _uncertainty_label(self.estimator, config)
        )
        if exponent is not None and exponent != 1.0:
            label += f"\nraised to the power {exponent:.3g} (the sampler's 1/T)"
        return label


def _uncertainty_label(estimator: str, config: SelectionConfig) -> str:
    """U = a H + b D of the estimators "combined", "entropy" and "distance" as `combined_uncertainty`
    computes it with `config`: its terms, their units and their normalisation, a line each."""
    weights = {
        "combined": (config.entropy_weight, config.distance_weight),
        "entropy": (1.0, 0.0),
        "distance": (0.0, 1.0),
    }[estimator]
    authors_entropy = config.entropy_mode == "authors"
    terms = [
        (weight, symbol, meaning, unit)
        for weight, symbol, meaning, unit in (
            (weights[0], "H", "the authors' entropy score" if authors_entropy else "mean ray entropy", "bits"),
            (weights[1], "D", "SO(3) distance to the training views", "rad²"),
        )
        if weight
    ]
    scaled = config.normalisation != "none"
    prime = "′" if scaled else ""
    formula = " + ".join(f"{symbol}{prime}" if w == 1 else f"{w:g}·{symbol}{prime}" for w, symbol, _, _ in terms)
    units = [u for _, symbol, _, u in terms if not (symbol == "H" and authors_entropy)]
    if not scaled:
        unit = f" ({' + '.join(units)})" if units else ""
    elif config.normalisation == "authors":
        unit = " (no unit; ′: min-max scaled, U / max U)"
    else:
        unit = " (no unit; ′: min-max scaled)"
    meanings = [
        f"{symbol}: {meaning}" + ("" if symbol == "H" and authors_entropy else f" ({u})")
        for _, symbol, meaning, u in terms
    ]
    return "\n".join([f"uncertainty U = {formula}{unit}", *meanings])


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


def method_label(name: str) -> str:
    """The display label of a method (its name when it is not registered)."""
    return METHODS[name].label if name in METHODS else name


def get_method(name: str) -> MethodSpec:
    """The registered method `name`; ValueError listing the valid names otherwise."""
    return lookup(METHODS, "selection method", name)
