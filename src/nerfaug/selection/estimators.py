"""Estimators: what scores the candidates (each `fn(request) -> Estimate`, listed by name in
`selection.registry.ESTIMATORS`).

- "combined": the paper's U = a H + b D (`combined_uncertainty`), with the config's weights.
- "entropy": H only (weights (1, 0)); "distance": D only (weights (0, 1)).
- "fisher": FisherRF's expected information gain (`fisherrf_candidates`).
- "none": no scores (ones), for selectors that ignore them.

The entropy is taken over `scoring_cameras`: the candidates rendered `entropy_resolution` pixels
across, optionally with another field of view and only the central part of the image
(`scoring_fov`, `scoring_crop`), as the authors' code renders them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import angles_from_pose, pose_from_angles
from nerfaug.selection.config import DISTANCE_ROTATIONS, SelectionConfig
from nerfaug.selection.interface import Estimate, FisherGain, Request, Terms
from nerfaug.uncertainty.combined import combined_uncertainty
from nerfaug.uncertainty.entropy import authors_view_scores, mean_view_entropy
from nerfaug.uncertainty.fisher import fisher_diagonal, fisherrf_view_scores, stratified_pixel_rays
from nerfaug.uncertainty.rays import reduced_cameras
from nerfaug.uncertainty.so3 import coverage_distance


def scoring_cameras(candidates: Cameras, resolution: int, fov_deg: float | None = None, crop: float = 1.0) -> Cameras:
    """The cameras the entropy of `candidates` is rendered with.

    `resolution` pixels across (the height keeps the aspect ratio). With `fov_deg` the
    horizontal field of view is that many degrees instead of the candidates' own; with
    `crop` < 1 only the central `crop` fraction of that image (in width and height) is rendered,
    still `resolution` pixels across. The authors' code: fov 75, crop 0.5 (the central 400x400
    of an 800x800 render); that crop spans 2 atan(0.5 tan(37.5 deg)) = 42.0 degrees (NeRF-synthetic: 39.6).

    Returns:
        Cameras with the candidates' poses and principal points at the image centre.
    """
    if not 0 < crop <= 1:
        raise ValueError(f"scoring_crop must be in (0, 1], got {crop}")
    small = reduced_cameras(candidates, resolution)
    if fov_deg is None and crop == 1.0:
        return small
    if fov_deg is None:
        focal = small.fx
    else:
        if not 0 < fov_deg < 180:
            raise ValueError(f"scoring_fov must be in (0, 180) degrees, got {fov_deg}")
        focal = torch.full_like(small.fx, 0.5 * small.width / math.tan(math.radians(fov_deg) / 2))
    focal = focal / crop
    return Cameras(
        small.camera_to_world, focal, focal, small.width / 2.0, small.height / 2.0, small.width, small.height
    )


def candidate_entropy(request: Request) -> Tensor:
    """H per candidate (shape (n_candidates,), CPU) as `combined_uncertainty` takes it: the mean
    ray entropy in bits, or the authors' score (cube, min-max) in "authors" mode. Candidates
    farther than `entropy_max_polar` from the pole get mean entropy 0 first (the authors'
    entropy NBV)."""
    config = request.config
    cameras = scoring_cameras(request.candidates, config.entropy_resolution, config.scoring_fov, config.scoring_crop)
    means = mean_view_entropy(
        request.require_model(),
        cameras,
        config.entropy_resolution,
        config.chunk,
        config.entropy_mode,
        progress=request.progress,
    ).cpu()
    if config.entropy_max_polar is not None:
        means = torch.where(request.polar > config.entropy_max_polar, 0.0, means.double()).to(means.dtype)
    return authors_view_scores(means) if config.entropy_mode == "authors" else means


def distance_rotations(candidates: Cameras, how: str) -> Tensor:
    """The rotations the coverage term compares, float64 (n, 3, 3) on the CPU: the cameras' own
    ("pose"), or ("azimuth", the authors' NBV code) those of the same azimuth at polar angle 0,
    which makes D depend on the azimuth alone. Their Euler-'xyz' rotation (polar, 0, azimuth +
    pi/2) is exactly `pose_from_angles`' rotation, so only the zeroed polar angle differs."""
    if how not in DISTANCE_ROTATIONS:
        raise ValueError(f"distance_rotations must be one of {', '.join(DISTANCE_ROTATIONS)}, got {how!r}")
    if how == "pose":
        return candidates.rotations.cpu().double()
    azimuth, _, _ = angles_from_pose(candidates.camera_to_world.cpu())
    return pose_from_angles(azimuth, torch.zeros_like(azimuth))[:, :3, :3].double()


def _metric(request: Request) -> Tensor | None:
    metric = request.config.metric
    return None if metric is None else torch.tensor(metric, dtype=torch.float64)


def _terms(request: Request, a: float, b: float) -> Estimate:
    """U = a H + b D with the config's normalisation, with the terms a batch-aware selector needs
    to recompute D as views are accepted."""
    config = request.config
    terms = Terms((a, b))
    if a:
        terms = replace(terms, entropy=candidate_entropy(request))
    if b:
        rotations = distance_rotations(request.candidates, config.distance_rotations)
        training = request.train_cameras.rotations.cpu().double()
        distance = coverage_distance(rotations, training, _metric(request))
        terms = replace(terms, distance=distance, rotations=rotations, metric=_metric(request))
    scores = combined_uncertainty(terms.entropy, terms.distance, a, b, config.normalisation).float()
    return Estimate(scores, terms=terms)


def combined(request: Request) -> Estimate:
    """The paper's U = a H + b D with the config's weights (a, b)."""
    return _terms(request, request.config.entropy_weight, request.config.distance_weight)


def entropy_only(request: Request) -> Estimate:
    """H only (Table I "entropy only"; Lee et al.'s spatial entropy)."""
    return _terms(request, 1.0, 0.0)


def distance_only(request: Request) -> Estimate:
    """D only (Table I "distance only")."""
    return _terms(request, 0.0, 1.0)


def no_scores(request: Request) -> Estimate:
    """Ones: for selectors that ignore scores (uniform, farthest)."""
    return Estimate(torch.ones(len(request.candidates)))


def fisher(request: Request) -> Estimate:
    """FisherRF's information gain per candidate, with H_train and H_cand (on demand) for its
    greedy selector."""
    h_train, scores, h_of = fisherrf_candidates(
        request.require_model(),
        request.train_cameras,
        request.candidates,
        request.config,
        request.generator,
        progress=request.progress,
    )
    scores = scores.cpu()
    return Estimate(scores, fisher=FisherGain(scores, h_train, h_of))


def fisher_background(config: SelectionConfig) -> Tensor | None:
    """The colour FisherRF composites behind rendered rays (None: the model's own)."""
    return None if config.background is None else torch.tensor(config.background, dtype=torch.float32)


def fisher_train_rays(
    train_cameras: Cameras, config: SelectionConfig, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """The training rays H_train is taken over: about `config.fisher_train_pixels` pixels spread
    evenly over the training views (`stratified_pixel_rays`), with the weights that make their
    weighted sum estimate the sum over every pixel. Draws from `generator` once.

    Returns:
        origins, directions: Tensors with shape (n_rays, 3).
        weights: Tensor with shape (n_rays,).
    """
    return stratified_pixel_rays(train_cameras, config.fisher_train_pixels, generator)


def fisher_train_diagonal(
    model: nn.Module, train_cameras: Cameras, config: SelectionConfig, generator: torch.Generator | None = None
) -> Tensor:
    """H_train as `fisherrf_candidates` computes it: the Fisher diagonal over `fisher_train_rays`
    with the config's fisher_* settings. Draws from `generator` once for the pixels and once
    for the probes ("random-sign").

    Returns:
        Tensor with shape (P,).
    """
    # Stratified pixels with weights: H_train estimates the sum over every pixel of the training
    # images, the scale of each candidate's whole-image H_cand that the greedy batch adds to it.
    origins, directions, weights = fisher_train_rays(train_cameras, config, generator)
    return fisher_diagonal(
        model,
        origins,
        directions,
        config.fisher_method,
        config.fisher_train_probes,
        generator,
        config.fisher_train_chunk,
        fisher_background(config),
        weights=weights,
    )


def fisherrf_candidates(
    model: nn.Module,
    train_cameras: Cameras,
    candidates: Cameras,
    config: SelectionConfig,
    generator: torch.Generator | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[Tensor, Tensor, Callable[[int], Tensor]]:
    """FisherRF's ingredients: H_train over about `config.fisher_train_pixels` pixels spread
    evenly over the training views and weighted to estimate the sum over all their pixels, every
    candidate's score at `config.fisher_resolution`, and H_cand
    on demand (kept within `config.fisher_cache_floats`, else recomputed) for the greedy selection.
    `progress` is called with the number of candidates scored so far.

    Returns:
        h_train: Tensor with shape (P,).
        scores: Tensor with shape (n_candidates,).
        h_of: candidate index -> H_cand, Tensor with shape (P,).
    """
    h_train = fisher_train_diagonal(model, train_cameras, config, generator)
    background = fisher_background(config)
    scores, h_of = fisherrf_view_scores(
        model,
        candidates,
        h_train,
        config.fisher_lambda,
        config.fisher_cache_floats,
        config.fisher_resolution,
        config.fisher_method,
        config.fisher_probes,
        generator,
        background=background,
        progress=progress,
    )
    return h_train, scores, h_of
