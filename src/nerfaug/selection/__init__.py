"""Choosing which candidate views to add: candidates, selectors, and the registry of methods."""

from nerfaug.selection.candidates import hemisphere_candidates, matching_poses, pool_candidates
from nerfaug.selection.methods import (
    METHODS, MethodSpec, Selection, SelectionConfig, candidate_scores, fisherrf_candidates,
    get_method, select_views,
)
from nerfaug.selection.selectors import (
    greedy_farthest, rejection_sample, select_top_k, select_uniform,
)

__all__ = [
    "METHODS", "MethodSpec", "Selection", "SelectionConfig", "candidate_scores",
    "fisherrf_candidates", "get_method", "greedy_farthest", "hemisphere_candidates",
    "matching_poses", "pool_candidates", "rejection_sample", "select_top_k", "select_uniform",
    "select_views",
]
