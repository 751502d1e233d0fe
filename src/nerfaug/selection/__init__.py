"""Choosing which candidate views to add: candidates, estimators and selectors, and the registry of methods.

The names below are imported on first use, so that `nerfaug.selection.config` and
`nerfaug.selection.families` (what the options of `nerfaug run`, `study` and `propose` read) stay
free of torch: their `--help` answers without loading it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from nerfaug.registry import lazy_exports

_HOMES = {
    "batch_aware_sample": "nerfaug.selection.batch",
    "batch_posterior": "nerfaug.selection.batch",
    "hemisphere_candidates": "nerfaug.selection.candidates",
    "matching_poses": "nerfaug.selection.candidates",
    "pool_candidates": "nerfaug.selection.candidates",
    "AUTHORS_SETTINGS": "nerfaug.selection.config",
    "SelectionConfig": "nerfaug.selection.config",
    "fisherrf_candidates": "nerfaug.selection.estimators",
    "Estimate": "nerfaug.selection.interface",
    "Request": "nerfaug.selection.interface",
    "AUTHORS_VARIANTS": "nerfaug.selection.families",
    "BATCH_AWARE": "nerfaug.selection.families",
    "FAMILIES": "nerfaug.selection.families",
    "MAIN_COMPARISON": "nerfaug.selection.families",
    "STUDY_METHODS": "nerfaug.selection.families",
    "TABLE_I": "nerfaug.selection.families",
    "TABLE_I_ROWS": "nerfaug.selection.families",
    "TABLE_II": "nerfaug.selection.families",
    "TABLE_II_ROWS": "nerfaug.selection.families",
    "METHODS": "nerfaug.selection.methods",
    "MethodSpec": "nerfaug.selection.methods",
    "get_method": "nerfaug.selection.methods",
    "method_label": "nerfaug.selection.methods",
    "ESTIMATORS": "nerfaug.selection.registry",
    "SELECTORS": "nerfaug.selection.registry",
    "Selection": "nerfaug.selection.select",
    "candidate_scores": "nerfaug.selection.select",
    "select_views": "nerfaug.selection.select",
    "greedy_farthest": "nerfaug.selection.selectors",
    "rejection_sample": "nerfaug.selection.selectors",
    "select_top_k": "nerfaug.selection.selectors",
    "select_uniform": "nerfaug.selection.selectors",
}

if TYPE_CHECKING:
    from nerfaug.selection.batch import batch_aware_sample, batch_posterior
    from nerfaug.selection.candidates import hemisphere_candidates, matching_poses, pool_candidates
    from nerfaug.selection.config import AUTHORS_SETTINGS, SelectionConfig
    from nerfaug.selection.estimators import fisherrf_candidates
    from nerfaug.selection.families import (
        AUTHORS_VARIANTS,
        BATCH_AWARE,
        FAMILIES,
        MAIN_COMPARISON,
        STUDY_METHODS,
        TABLE_I,
        TABLE_I_ROWS,
        TABLE_II,
        TABLE_II_ROWS,
    )
    from nerfaug.selection.interface import Estimate, Request
    from nerfaug.selection.methods import METHODS, MethodSpec, get_method, method_label
    from nerfaug.selection.registry import ESTIMATORS, SELECTORS
    from nerfaug.selection.select import Selection, candidate_scores, select_views
    from nerfaug.selection.selectors import greedy_farthest, rejection_sample, select_top_k, select_uniform


__getattr__, __dir__ = lazy_exports(__name__, _HOMES, globals())


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
