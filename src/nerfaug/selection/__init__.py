"""Choosing which candidate views to add: candidates, estimators and selectors, and the registry of methods."""

from nerfaug.selection.batch import batch_aware_sample, batch_posterior
from nerfaug.selection.candidates import hemisphere_candidates, matching_poses, pool_candidates
from nerfaug.selection.config import AUTHORS_SETTINGS, SelectionConfig
from nerfaug.selection.estimators import fisherrf_candidates
from nerfaug.selection.interface import Estimate, Request
from nerfaug.selection.methods import (
    AUTHORS_VARIANTS,
    BATCH_AWARE,
    FAMILIES,
    MAIN_COMPARISON,
    METHODS,
    STUDY_METHODS,
    TABLE_I,
    TABLE_I_ROWS,
    TABLE_II,
    TABLE_II_ROWS,
    MethodSpec,
    get_method,
    method_label,
)
from nerfaug.selection.registry import ESTIMATORS, SELECTORS
from nerfaug.selection.select import Selection, candidate_scores, select_views
from nerfaug.selection.selectors import (
    greedy_farthest,
    rejection_sample,
    select_top_k,
    select_uniform,
)

__all__ = [
    "AUTHORS_SETTINGS",
    "AUTHORS_VARIANTS",
    "BATCH_AWARE",
    "ESTIMATORS",
    "FAMILIES",
    "MAIN_COMPARISON",
    "METHODS",
    "SELECTORS",
    "STUDY_METHODS",
    "TABLE_I",
    "TABLE_II",
    "TABLE_II_ROWS",
    "TABLE_I_ROWS",
    "Estimate",
    "MethodSpec",
    "Request",
    "Selection",
    "SelectionConfig",
    "batch_aware_sample",
    "batch_posterior",
    "candidate_scores",
    "fisherrf_candidates",
    "get_method",
    "greedy_farthest",
    "hemisphere_candidates",
    "matching_poses",
    "method_label",
    "pool_candidates",
    "rejection_sample",
    "select_top_k",
    "select_uniform",
    "select_views",
]
