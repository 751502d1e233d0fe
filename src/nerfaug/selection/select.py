"""`select_views`: choose n of the candidate views with a registered method, and the `Selection`
it returns (the chosen indices, with the scores and terms they were chosen by)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.selection.config import SelectionConfig
from nerfaug.selection.interface import Request
from nerfaug.selection.methods import get_method
from nerfaug.selection.registry import get_estimator, get_selector
from nerfaug.selection.separation import separated_views


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
        uniform_fill: how many of the chosen views were drawn uniformly because fewer candidates
            than asked for had a positive score (0: all chosen by the method's scores).
        config: the settings it chose with: the caller's, with the method's own applied over
            them (what a run or a proposal records; not part of `to_dict`).
    """

    indices: Tensor
    scores: Tensor
    components: dict[str, Tensor] = field(default_factory=dict)
    method: str = ""
    uniform_fill: int = 0
    config: SelectionConfig | None = None

    def to_dict(self) -> dict:
        """Plain lists and numbers (JSON-serialisable)."""
        return {
            "method": self.method,
            "indices": [int(i) for i in self.indices.tolist()],
            "scores": [float(s) for s in self.scores.tolist()],
            "components": {k: [float(x) for x in v.tolist()] for k, v in self.components.items()},
        } | ({"uniform_fill": self.uniform_fill} if self.uniform_fill else {})

    def score_label(self, config: SelectionConfig | None = None) -> str:
        """What `scores` are, with their unit (`MethodSpec.score_label`; a hemisphere map's colour
        bar), given the caller's settings."""
        exponent = self.components.get("exponent")
        exponent = float(exponent[0]) if exponent is not None and len(exponent) else None
        return get_method(self.method).score_label(config, exponent)

    @classmethod
    def from_dict(cls, data: dict) -> Selection:
        return cls(
            torch.tensor(data["indices"], dtype=torch.long),
            torch.tensor(data["scores"]),
            {k: torch.tensor(v) for k, v in data.get("components", {}).items()},
            data.get("method", ""),
            int(data.get("uniform_fill", 0)),
        )


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
    estimate = get_estimator(spec.estimator)(request)
    return estimate.scores.cpu(), estimate.components()


def select_views(
    method: str,
    model: nn.Module | None,
    train_cameras: Cameras,
    candidates: Cameras,
    n: int,
    generator: torch.Generator | None = None,
    config: SelectionConfig | None = None,
    min_separation: float = 0.0,
    progress: Callable[[int], None] | None = None,
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
        config: estimator and selector options, checked (`SelectionConfig.checked()`); None for
            the defaults. The method's own settings (`MethodSpec.settings`) are applied over it,
            here and nowhere else on the way to the selector.
        min_separation: radians; > 0 keeps every two chosen views at least this far apart about
            the origin (`selection.separation`); 0, the default, chooses as the method does.
        progress: called with the number of candidates scored so far, after each batch the
            estimator scores (estimators that render); None for silence.

    Returns:
        Selection(indices (n,), scores (n_candidates,), components, method).
    """
    spec = get_method(method)
    if not 0 <= n <= len(candidates):
        raise ValueError(f"cannot choose {n} views out of {len(candidates)} candidates")
    config = spec.effective_config(config)
    request = Request(spec.name, model, train_cameras, candidates, n, generator, config, progress=progress)
    estimate = get_estimator(spec.estimator)(request)
    selector = get_selector(spec.selector, spec.estimator)
    if min_separation > 0:
        indices, estimate = separated_views(request, estimate, selector, min_separation)
    else:
        indices, estimate = selector(request, estimate)
    components = {k: v.detach().cpu() for k, v in estimate.components().items()}
    scores = estimate.scores.detach().cpu()
    return Selection(indices.cpu(), scores, components, spec.name, estimate.uniform_fill, config)
