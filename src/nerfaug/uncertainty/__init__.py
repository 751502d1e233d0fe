"""Uncertainty of candidate views: ray entropy (in-distribution), SO(3) coverage
(out-of-distribution), their combination (the paper's U), FisherRF's information gain, and how
well an uncertainty image ranks a view's errors (AUSE, `sparsification`).

The names below are imported on first use, so that `nerfaug.uncertainty.choices` (the modes
`SelectionConfig` offers) stays free of torch: `nerfaug propose --help` answers without loading it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from nerfaug.registry import lazy_exports

_HOMES = {
    "NORMALISATIONS": "nerfaug.uncertainty.choices",
    "ENTROPY_MODES": "nerfaug.uncertainty.choices",
    "FISHER_LAMBDA": "nerfaug.uncertainty.choices",
    "FISHER_METHODS": "nerfaug.uncertainty.choices",
    "combined_uncertainty": "nerfaug.uncertainty.combined",
    "minmax_normalise": "nerfaug.uncertainty.entropy",
    "ray_entropy": "nerfaug.uncertainty.entropy",
    "view_entropy": "nerfaug.uncertainty.entropy",
    "fisher_diagonal": "nerfaug.uncertainty.fisher",
    "fisher_diagonal_groups": "nerfaug.uncertainty.fisher",
    "fisher_views": "nerfaug.uncertainty.fisher",
    "fisherrf_greedy": "nerfaug.uncertainty.fisher",
    "fisherrf_scores": "nerfaug.uncertainty.fisher",
    "fisherrf_view_scores": "nerfaug.uncertainty.fisher",
    "sample_pixel_rays": "nerfaug.uncertainty.fisher",
    "coverage_distance": "nerfaug.uncertainty.so3",
    "min_geodesic_angle": "nerfaug.uncertainty.so3",
    "so3_geodesic_sq": "nerfaug.uncertainty.so3",
    "so3_log": "nerfaug.uncertainty.so3",
    "ause": "nerfaug.uncertainty.sparsification",
    "sparsification_curves": "nerfaug.uncertainty.sparsification",
}

if TYPE_CHECKING:
    from nerfaug.uncertainty.choices import ENTROPY_MODES, FISHER_LAMBDA, FISHER_METHODS, NORMALISATIONS
    from nerfaug.uncertainty.combined import combined_uncertainty
    from nerfaug.uncertainty.entropy import minmax_normalise, ray_entropy, view_entropy
    from nerfaug.uncertainty.fisher import (
        fisher_diagonal,
        fisher_diagonal_groups,
        fisher_views,
        fisherrf_greedy,
        fisherrf_scores,
        fisherrf_view_scores,
        sample_pixel_rays,
    )
    from nerfaug.uncertainty.so3 import coverage_distance, min_geodesic_angle, so3_geodesic_sq, so3_log
    from nerfaug.uncertainty.sparsification import ause, sparsification_curves


__getattr__, __dir__ = lazy_exports(__name__, _HOMES, globals())


__all__ = [
    "ENTROPY_MODES",
    "FISHER_LAMBDA",
    "FISHER_METHODS",
    "NORMALISATIONS",
    "ause",
    "combined_uncertainty",
    "coverage_distance",
    "fisher_diagonal",
    "fisher_diagonal_groups",
    "fisher_views",
    "fisherrf_greedy",
    "fisherrf_scores",
    "fisherrf_view_scores",
    "min_geodesic_angle",
    "minmax_normalise",
    "ray_entropy",
    "sample_pixel_rays",
    "so3_geodesic_sq",
    "so3_log",
    "sparsification_curves",
    "view_entropy",
]
