"""The two registries a view-selection method is made of: estimators (what scores the
candidates) and selectors (how n are chosen from the scores).

Both are small functions behind one narrow interface, registered by name with a decorator:

    @register_estimator("my-scores")
    def my_scores(request: Request) -> Scoring: ...

    @register_selector("my-picker")
    def my_picker(request: Request, scoring: Scoring) -> tuple[Tensor, Scoring]: ...

A new method is then one `MethodSpec` line in `nerfaug.selection.methods.METHODS` naming them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras

if TYPE_CHECKING:  # only for annotations: methods.py imports this module
    from nerfaug.selection.methods import SelectionConfig


@dataclass
class Request:
    """Everything an estimator or a selector may use.

    Attributes:
        method: the method's name (for error messages).
        model: the NeRF (`NerfModel` interface), or None for methods that do not render.
        train_cameras: the current training views.
        candidates: the n_candidates views to choose from.
        n: how many to choose.
        generator: the random source (the same seed gives the same selection).
        config: the method's effective `SelectionConfig` (its own settings applied).
    """

    method: str
    model: nn.Module | None
    train_cameras: Cameras
    candidates: Cameras
    n: int
    generator: torch.Generator | None
    config: SelectionConfig

    def require_model(self) -> nn.Module:
        """The model; ValueError naming the method when there is none."""
        if self.model is None:
            raise ValueError(f"method {self.method!r} scores candidates with the model; got model=None")
        return self.model

    @cached_property
    def polar(self) -> Tensor:
        """Polar angle (radians from +z about the origin, the scene centre in the engine frame) of
        every candidate. Shape (n_candidates,), float64, CPU."""
        from nerfaug.hemisphere import angles_from_pose

        return angles_from_pose(self.candidates.camera_to_world.cpu())[1].double()

    @cached_property
    def eligible(self) -> Tensor | None:
        """Bool mask (n_candidates,) of the candidates that may be chosen: those at least
        `config.min_polar` from the pole. None when every candidate may be."""
        if self.config.min_polar is None:
            return None
        return self.polar >= self.config.min_polar


@dataclass
class Scoring:
    """What an estimator gives the selector.

    Attributes:
        scores: Tensor with shape (n_candidates,), on the CPU: the density or ranking.
        components: name -> Tensor with shape (n_candidates,): the terms behind `scores`
            (saved with the selection).
        state: anything else a selector needs (not saved), e.g. FisherRF's H_train.
    """

    scores: Tensor
    components: dict[str, Tensor] = field(default_factory=dict)
    state: dict[str, Any] = field(default_factory=dict)


Estimator = Callable[[Request], Scoring]
Selector = Callable[[Request, Scoring], "tuple[Tensor, Scoring]"]

ESTIMATORS: dict[str, Estimator] = {}
SELECTORS: dict[str, Selector] = {}
# Selector name -> the estimators it works with (a selector absent here works with any).
SELECTOR_NEEDS: dict[str, tuple[str, ...]] = {}


def register_estimator(name: str) -> Callable[[Estimator], Estimator]:
    """Register `fn(request) -> Scoring` as the estimator `name`."""

    def register(fn: Estimator) -> Estimator:
        if name in ESTIMATORS:
            raise ValueError(f"estimator {name!r} is registered twice")
        ESTIMATORS[name] = fn
        return fn

    return register


def register_selector(name: str, needs: tuple[str, ...] | None = None) -> Callable[[Selector], Selector]:
    """Register `fn(request, scoring) -> (indices (n,), scoring)` as the selector `name`; `needs`
    lists the estimators whose `Scoring.state` it relies on."""

    def register(fn: Selector) -> Selector:
        if name in SELECTORS:
            raise ValueError(f"selector {name!r} is registered twice")
        SELECTORS[name] = fn
        if needs is not None:
            SELECTOR_NEEDS[name] = needs
        return fn

    return register
