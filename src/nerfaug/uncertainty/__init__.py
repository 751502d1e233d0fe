"""Uncertainty of candidate views: ray entropy (in-distribution), SO(3) coverage
(out-of-distribution), their combination (the paper's U), FisherRF's information gain, and how
well an uncertainty image ranks a view's errors (AUSE, `sparsification`)."""

from nerfaug.uncertainty.combined import NORMALISATIONS, combined_uncertainty
from nerfaug.uncertainty.entropy import ENTROPY_MODES, minmax_normalise, ray_entropy, view_entropy
from nerfaug.uncertainty.fisher import (
    FISHER_LAMBDA,
    FISHER_METHODS,
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
