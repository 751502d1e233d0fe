"""The two registries a view-selection method is made of: estimators (what scores the
candidates) and selectors (how n are chosen from the scores), by name.

Both are small functions behind one narrow interface (`selection.interface`): an estimator is
`fn(request) -> Estimate`, a selector `fn(request, estimate) -> (indices (n,), estimate)`. Adding
one is its function (in `estimators.py`, `selectors.py` or a module of its own) and one line
here; a new method is then one `MethodSpec` line in `selection.methods.METHODS` naming them.
An unknown name is a ValueError that lists the known ones.
"""

from __future__ import annotations

from nerfaug.registry import lookup
from nerfaug.selection import estimators, selectors
from nerfaug.selection.batch import batch_sample_views
from nerfaug.selection.interface import Estimator, Selector

ESTIMATORS: dict[str, Estimator] = {
    "combined": estimators.combined,
    "entropy": estimators.entropy_only,
    "distance": estimators.distance_only,
    "none": estimators.no_scores,
    "fisher": estimators.fisher,
}
"""Estimators: name -> `fn(request) -> Estimate`."""

SELECTORS: dict[str, Selector] = {
    "sampling": selectors.sample_views,
    "top-k": selectors.top_k_views,
    "uniform": selectors.uniform_views,
    "farthest": selectors.farthest_views,
    "greedy-fisher": selectors.greedy_fisher_views,
    "batch-sampling": batch_sample_views,
}
"""Selectors: name -> `fn(request, estimate) -> (indices (n,), estimate)`."""

SELECTOR_NEEDS: dict[str, tuple[str, ...]] = {
    "greedy-fisher": ("fisher",),
    "batch-sampling": ("combined", "distance"),
}
"""Selector -> the estimators whose `Estimate` fields it reads (a selector absent here works with
any estimator)."""


def get_estimator(name: str) -> Estimator:
    """The estimator `name`; ValueError listing the valid names otherwise.

    Example:
        >>> get_estimator("bayes")
        Traceback (most recent call last):
        ...
        ValueError: unknown estimator 'bayes'; choose one of: combined, entropy, distance, none, fisher
    """
    return lookup(ESTIMATORS, "estimator", name)


def get_selector(name: str, estimator: str | None = None) -> Selector:
    """The selector `name`; ValueError listing the valid names otherwise, or naming the estimators
    it needs when `estimator` is not one of them.

    Example:
        >>> get_selector("greedy-fisher", "combined")
        Traceback (most recent call last):
        ...
        ValueError: the greedy-fisher selector needs the estimator fisher
    """
    selector = lookup(SELECTORS, "selector", name)
    needs = SELECTOR_NEEDS.get(name)
    if estimator is not None and needs is not None and estimator not in needs:
        raise ValueError(f"the {name} selector needs the estimator {' or '.join(needs)}")
    return selector
