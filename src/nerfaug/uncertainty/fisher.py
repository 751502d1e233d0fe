"""FisherRF (Jiang, Lei, Daniilidis, ECCV 2024): diagonal Fisher information of the model's
parameters from rendered colours, and greedy batch selection by expected information gain.

With a Gaussian pixel likelihood the Fisher information of the parameters theta is J^T J, with
J = d(rendered colours) / d(theta) (one row per pixel and colour channel). FisherRF keeps its
diagonal, diag(J^T J)_k = sum over pixels and channels of (d c / d theta_k)^2, over every
trainable parameter of the model (field and proposal networks alike), flattened in
`model.named_parameters()` order. A candidate's score is

    sum_k H_cand[k] / (H_train[k] + lambda),        lambda = 1e-6 (the authors' release),

with H_train over (a pixel subsample of) the training views and H_cand over the candidate's
pixels at reduced resolution; no ground truth is needed, only rendered colours. Batch selection
is greedy: pick the best candidate, add its H_cand into H_train, rescore.

Two estimators of the diagonal:

- "random-sign" (default): Rademacher probes v (entries +-1 over the rays), one colour channel c
  at a time: E[(J_c^T v)^2] = sum over rays of (d c_ray / d theta)^2 because E[v_i v_j] = delta_ij,
  so the sum over channels is unbiased for diag(J^T J). A probe costs three backward passes.
  Probing the channels separately matters: the three channels of a ray have nearly the same
  gradient (same geometry), so a probe mixing them has large cross terms; measured on
  `NerfModel` at step 200, one per-channel probe per candidate gives nearly the same candidate
  scores for different seeds (correlation 0.99) where four mixed probes, at a similar cost,
  did not (0.78). Squares
  are taken per chunk of rays (per view for candidates); with one ray per chunk the estimate is
  exact.
- "exact": per-ray Jacobians, squared and summed. Through `torch.func` (`functional_call` +
  `vmap(jacrev)`) when the model's forward is vmap-able; otherwise (`nonzero`, data-dependent
  shapes, `.item()`...) one ray at a time with three backward passes: the same numbers, slower,
  and a warning says so.

Why "random-sign" is the default: `NerfModel` skips empty samples with `nonzero`, which vmap
cannot batch, so "exact" falls back to 3 backward passes per ray, 192 for an 8x8 candidate
render, where one probe needs 3. With P in the millions (K-planes, hash grids) each backward
pass writes a dense P-vector, so the number of passes is the cost. "exact" is there to validate
the estimator (tests) and for small models.

The model is put in eval mode (deterministic rendering) while the diagonal is computed.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import torch
from torch import Tensor, nn
from torch.func import functional_call, jacrev, vmap

from nerfaug.cameras import Cameras, generate_rays
from nerfaug.registry import check_name
from nerfaug.uncertainty.choices import CACHE_FLOATS, DEFAULT_METHOD, FISHER_LAMBDA, FISHER_METHODS
from nerfaug.uncertainty.rays import model_device

# Bound on the per-chunk Jacobian (rays x 3 x parameters floats) held by the vmap estimator.
_JACOBIAN_BUDGET_FLOATS = 2**25


def trainable_parameters(model: nn.Module) -> dict[str, Tensor]:
    """The parameters the Fisher diagonal is taken over: every one with requires_grad, by name."""
    params = {name: p for name, p in model.named_parameters() if p.requires_grad}
    if not params:
        raise ValueError("the model has no trainable parameters to take the Fisher information of")
    return params


def n_trainable(model: nn.Module) -> int:
    """P, the length of the flattened Fisher diagonal."""
    return sum(p.numel() for p in trainable_parameters(model).values())


@contextmanager
def _eval_mode(model: nn.Module) -> Iterator[None]:
    was_training = model.training
    model.eval()
    try:
        yield
    finally:
        model.train(was_training)


def _flat(grads) -> Tensor:
    return torch.cat([g.reshape(-1) for g in grads])


def _exact_vmap(model, params, origins, directions, groups, n_groups, background, weights) -> Tensor:
    """Per-ray Jacobians with torch.func, squared, weighted, summed into their group. (n_groups, P)."""
    frozen = {k: v.detach() for k, v in params.items()}

    def rgb_of_ray(p, origin, direction):
        out = functional_call(model, p, (origin[None], direction[None]), {"background": background})
        return out.rgb[0]

    per_ray = vmap(jacrev(rgb_of_ray), in_dims=(None, 0, 0))
    n_params = sum(p.numel() for p in params.values())
    chunk = max(1, _JACOBIAN_BUDGET_FLOATS // (3 * n_params))
    total = torch.zeros(n_groups, n_params, device=origins.device)
    for start in range(0, origins.shape[0], chunk):
        jac = per_ray(frozen, origins[start : start + chunk], directions[start : start + chunk])
        squared = torch.cat([(j**2).sum(dim=1).flatten(1) for j in jac.values()], dim=1)
        total.index_add_(0, groups[start : start + chunk], squared * weights[start : start + chunk, None])
    return total


def _exact_loop(model, params, origins, directions, groups, n_groups, background, weights) -> Tensor:
    """The same as `_exact_vmap`, one ray and one channel per backward pass."""
    n_params = sum(p.numel() for p in params.values())
    total = torch.zeros(n_groups, n_params, device=origins.device)
    for r in range(origins.shape[0]):
        rgb = model(origins[r : r + 1], directions[r : r + 1], background=background).rgb[0]
        for c in range(3):
            grads = torch.autograd.grad(rgb[c], list(params.values()), retain_graph=c < 2, allow_unused=True)
            grads = [torch.zeros_like(p) if g is None else g for g, p in zip(grads, params.values())]
            total[groups[r]] += weights[r] * _flat(grads) ** 2
    return total


def _group_seeds(generator: torch.Generator | None, n_groups: int) -> list[int]:
    """One probe seed per group, from one draw of `generator`: a group's probes do not depend on
    which other groups are computed with it, so one view's estimate can be recomputed alone."""
    base = int(torch.randint(2**62, (1,), generator=generator))
    return [base + g for g in range(n_groups)]


def _probe_squares(rgb: Tensor, params: dict[str, Tensor], signs: Tensor) -> Tensor:
    """(P,): sum over probes and colour channels c of (J_c^T v)^2, J_c = d rgb[:, c] / d theta.

    Args:
        rgb: Tensor with shape (n_rays, 3), rendered with a graph to the parameters.
        signs: Tensor with shape (n_probes, n_rays), entries +-1.

    One backward pass per probe and channel: autograd's `is_grads_batched` (vmap over the
    backward) was measured slower than this loop on `NerfModel` on a CPU."""
    values = list(params.values())
    total = None
    for v in signs:
        for channel in range(3):
            probe = torch.zeros_like(rgb)
            probe[:, channel] = v
            grads = torch.autograd.grad(rgb, values, grad_outputs=probe, retain_graph=True, allow_unused=True)
            squares = _flat([torch.zeros_like(p) if g is None else g for g, p in zip(grads, values)]) ** 2
            total = squares if total is None else total + squares
    return total


def _random_sign(
    model, params, origins, directions, groups, n_groups, background, weights, n_probes, generators, chunk
):
    """Rademacher estimate of sum_i w_i (d c_i / d theta)^2 per group; squares taken per chunk of
    at most `chunk` rays of one group; group g's probes drawn from generators[g].

    The weight folds into the probe, v_i sqrt(w_i): E[(sum_i v_i sqrt(w_i) J_i)^2] = sum_i w_i J_i^2."""
    n_params = sum(p.numel() for p in params.values())
    total = torch.zeros(n_groups, n_params, device=origins.device)
    order = torch.argsort(groups, stable=True)
    bounds = torch.searchsorted(groups[order], torch.arange(n_groups + 1, device=groups.device)).tolist()
    for g in range(n_groups):
        rays = order[bounds[g] : bounds[g + 1]]
        for start in range(0, rays.numel(), chunk):
            idx = rays[start : start + chunk]
            rgb = model(origins[idx], directions[idx], background=background).rgb
            signs = torch.randint(0, 2, (n_probes, rgb.shape[0]), generator=generators[g], dtype=torch.int8)
            probes = (signs.to(rgb.dtype) * 2.0 - 1.0).to(rgb.device) * weights[idx].sqrt()
            total[g] += _probe_squares(rgb, params, probes)
    return total / n_probes


def fisher_diagonal_groups(
    model: nn.Module,
    origins: Tensor,
    directions: Tensor,
    groups: Tensor,
    n_groups: int,
    method: str = DEFAULT_METHOD,
    n_probes: int = 1,
    generator: torch.Generator | None = None,
    chunk: int = 1024,
    background: Tensor | None = None,
    weights: Tensor | None = None,
) -> Tensor:
    """Diagonal Fisher information of the model's trainable parameters, one per group of rays.

    Args:
        model: a module with `forward(origins, directions, background=None) -> RenderOutput`.
        origins, directions: Tensors with shape (n_rays, 3).
        groups: Tensor with shape (n_rays,), integer group (e.g. view) of each ray in [0, n_groups).
        n_groups: number of groups.
        method: "random-sign" (default) or "exact"; see the module docstring.
        n_probes: Rademacher probes per chunk, each three backward passes ("random-sign" only).
        generator: seeds the probes ("random-sign" only; drawn from once); each group draws from
            its own generator, so a group's estimate does not depend on the others.
        chunk: most rays per forward pass and per squared probe ("random-sign"; "exact" sizes
            its own chunks).
        background: passed to the model's forward, Tensor with shape (3,) or None.
        weights: Tensor with shape (n_rays,), each ray's weight w_i (the pixels it stands for, see
            `stratified_pixels`); None for ones.

    Returns:
        Tensor with shape (n_groups, P), sum over each group's rays of w_i (d c_i / d theta)^2 summed
        over the colour channels, P = number of trainable parameters, on the model's device.
    """
    generators = (
        [torch.Generator().manual_seed(s) for s in _group_seeds(generator, n_groups)]
        if (method == "random-sign")
        else []
    )
    return _fisher_groups(
        model, origins, directions, groups, n_groups, method, n_probes, generators, chunk, background, weights
    )


def _fisher_groups(
    model, origins, directions, groups, n_groups, method, n_probes, generators, chunk, background, weights
) -> Tensor:
    check_name("Fisher method", method, FISHER_METHODS)
    if n_probes < 1:
        raise ValueError(f"n_probes must be at least 1, got {n_probes}")
    device = model_device(model)
    origins, directions = origins.to(device), directions.to(device)
    groups = torch.as_tensor(groups, device=device).long()
    weights = (torch.ones(origins.shape[0]) if weights is None else torch.as_tensor(weights)).float().to(device)
    if background is not None:
        background = torch.as_tensor(background, dtype=torch.float32, device=device)
    params = trainable_parameters(model)
    with _eval_mode(model):
        if method == "random-sign":
            return _random_sign(
                model,
                params,
                origins,
                directions,
                groups,
                n_groups,
                background,
                weights,
                n_probes,
                generators,
                chunk,
            )
        try:
            return _exact_vmap(model, params, origins, directions, groups, n_groups, background, weights)
        except (RuntimeError, NotImplementedError, ValueError) as error:
            warnings.warn(
                f"the model's forward does not run under torch.func.vmap ({type(error).__name__}: "
                f"{str(error).splitlines()[0] if str(error) else ''}); computing the exact Fisher "
                "diagonal one ray at a time, which is slower (method='random-sign' is faster)",
                stacklevel=3,
            )
            return _exact_loop(model, params, origins, directions, groups, n_groups, background, weights)


def fisher_diagonal(
    model: nn.Module,
    origins: Tensor,
    directions: Tensor,
    method: str = DEFAULT_METHOD,
    n_probes: int = 4,
    generator: torch.Generator | None = None,
    chunk: int = 128,
    background: Tensor | None = None,
    weights: Tensor | None = None,
) -> Tensor:
    """sum_i w_i (d c_i / d theta)^2 over all the given rays i: diag(J^T W J), J = d(rendered
    rgb)/d(trainable parameters); with `weights` from `stratified_pixels`, an unbiased estimate of
    the diagonal over every pixel of the images.

    Args:
        model, method, n_probes, generator, background: as in `fisher_diagonal_groups`.
        origins, directions: Tensors with shape (n_rays, 3).
        chunk: rays per squared probe ("random-sign"): the rays are split into consecutive
            chunks, each estimated on its own, which removes the cross terms between chunks.
        weights: Tensor with shape (n_rays,), or None for ones.

    Returns:
        Tensor with shape (P,), trainable parameters flattened in `named_parameters()` order.
    """
    if origins.shape[0] == 0:
        return torch.zeros(n_trainable(model), device=model_device(model))
    weights = torch.ones(origins.shape[0]) if weights is None else torch.as_tensor(weights)
    one_group = torch.zeros(origins.shape[0], dtype=torch.long)
    if method != "random-sign":
        return _fisher_groups(
            model, origins, directions, one_group, 1, method, n_probes, [], chunk, background, weights
        )[0]
    starts = range(0, origins.shape[0], chunk)
    seeds = _group_seeds(generator, len(starts))
    # One chunk at a time, so that only one P-vector is held whatever the number of chunks.
    return sum(
        _fisher_groups(
            model,
            origins[s : s + chunk],
            directions[s : s + chunk],
            one_group[s : s + chunk],
            1,
            method,
            n_probes,
            [torch.Generator().manual_seed(seed)],
            chunk,
            background,
            weights[s : s + chunk],
        )[0]
        for s, seed in zip(starts, seeds)
    )


def sample_pixel_rays(
    cameras: Cameras, n_pixels: int, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor]:
    """Rays through `n_pixels` pixels drawn uniformly (with replacement) over all the cameras.

    Unweighted; `stratified_pixel_rays` gives an estimate of the whole images' sum with less noise.

    Returns:
        origins, directions: Tensors with shape (n_pixels, 3).
    """
    u = torch.rand(n_pixels, 3, generator=generator, dtype=torch.float64)
    views = (u[:, 0] * len(cameras)).long().clamp_max(len(cameras) - 1)
    xs = (u[:, 1] * cameras.width).long().clamp_max(cameras.width - 1)
    ys = (u[:, 2] * cameras.height).long().clamp_max(cameras.height - 1)
    return generate_rays(cameras, views, xs, ys)


def pixel_grid(n_pixels: int, width: int, height: int) -> tuple[int, int]:
    """(columns, rows) of blocks, about `n_pixels` of them with the image's aspect ratio, at most
    one block per pixel (then the grid is the whole image)."""
    if n_pixels < 1:
        raise ValueError(f"the number of pixels per view must be at least 1, got {n_pixels}")
    columns = min(width, max(1, round(math.sqrt(n_pixels * width / height))))
    rows = min(height, max(1, round(n_pixels / columns)))
    return columns, rows


def stratified_pixels(
    n_views: int, width: int, height: int, columns: int, rows: int, generators: list[torch.Generator]
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """One pixel drawn uniformly in each block of a `columns` x `rows` grid over each view, weighted
    by its block's area: sum_i w_i f(pixel_i) is an unbiased estimate of the sum of f over every
    pixel of the views (E[area * f(uniform pixel of the block)] = the block's sum), with less
    variance than uniform draws because the pixels are spread over the image. With one block per
    pixel it is that sum, exactly.

    Args:
        n_views: views (a pixel set per view, view after view, blocks row-major).
        width, height: image size in pixels.
        columns, rows: the grid, at most width x height.
        generators: one per view; view v's pixels are drawn from generators[v] only.

    Returns:
        views, xs, ys: Tensors with shape (n_views * columns * rows,), integer pixel coordinates.
        weights: Tensor with shape (n_views * columns * rows,), block areas (sum width * height per view).
    """
    if not (1 <= columns <= width and 1 <= rows <= height):
        raise ValueError(f"a {columns} x {rows} pixel grid does not fit a {width} x {height} image")
    x_edges = torch.arange(columns + 1) * width // columns
    y_edges = torch.arange(rows + 1) * height // rows
    y0, x0 = torch.meshgrid(y_edges[:-1], x_edges[:-1], indexing="ij")
    y_size, x_size = torch.meshgrid(y_edges.diff(), x_edges.diff(), indexing="ij")
    x0, y0, x_size, y_size = x0.reshape(-1), y0.reshape(-1), x_size.reshape(-1), y_size.reshape(-1)
    xs, ys = [], []
    for v in range(n_views):
        u = torch.rand(2, x0.numel(), generator=generators[v], dtype=torch.float64)
        xs.append(x0 + (u[0] * x_size).long().minimum(x_size - 1))
        ys.append(y0 + (u[1] * y_size).long().minimum(y_size - 1))
    views = torch.arange(n_views).repeat_interleave(x0.numel())
    weights = (x_size * y_size).double().repeat(n_views)
    return views, torch.cat(xs), torch.cat(ys), weights


def stratified_pixel_rays(
    cameras: Cameras, n_pixels: int, generator: torch.Generator | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """Rays through about `n_pixels` pixels spread evenly over the views (`stratified_pixels`,
    n_pixels / n_views per view), with weights that make a weighted sum over them an unbiased
    estimate of the sum over every pixel of every view.

    Returns:
        origins, directions: Tensors with shape (n_rays, 3).
        weights: Tensor with shape (n_rays,), float32; they sum to n_views * width * height.
    """
    columns, rows = pixel_grid(max(1, n_pixels // len(cameras)), cameras.width, cameras.height)
    generators = [torch.Generator().manual_seed(s) for s in _group_seeds(generator, len(cameras))]
    views, xs, ys, weights = stratified_pixels(len(cameras), cameras.width, cameras.height, columns, rows, generators)
    origins, directions = generate_rays(cameras, views, xs, ys)
    return origins, directions, weights.float()


def fisher_views(
    model: nn.Module,
    cameras: Cameras,
    resolution: int = 16,
    method: str = DEFAULT_METHOD,
    n_probes: int = 1,
    generator: torch.Generator | None = None,
    chunk: int = 1024,
    background: Tensor | None = None,
) -> Tensor:
    """H_cand of every view: an unbiased estimate of the Fisher diagonal over all its pixels.

    The pixels are a stratified subsample (`stratified_pixels`) of the views at their own
    resolution, `resolution` blocks across, rather than a rendering at reduced resolution: a tiny
    rendering aliases (its rays sample the scene at a few fixed places, which decide the score),
    and its sum is not on the scale of the training images' sum, which the score's lambda and the
    greedy update (H_train + H_cand) need. Holds n_views x P floats; `fisherrf_view_scores`
    scores many views of a large model without.

    Args:
        cameras: the n_views candidate views.
        resolution: blocks across each view (rows follow the aspect ratio); the view's width or
            more gives the whole image, exactly.
        method, n_probes, generator, chunk, background: as in `fisher_diagonal_groups`; each view
            is one group and draws its pixels and probes from its own seed.

    Returns:
        Tensor with shape (n_views, P).
    """
    return _views_fisher(
        model, cameras, resolution, method, n_probes, _group_seeds(generator, len(cameras)), chunk, background
    )


def _views_fisher(model, cameras, resolution, method, n_probes, seeds, chunk, background) -> Tensor:
    if resolution < 1:
        raise ValueError(f"resolution must be at least 1 pixel, got {resolution}")
    columns = min(resolution, cameras.width)
    rows = min(cameras.height, max(1, round(resolution * cameras.height / cameras.width)))
    generators = [torch.Generator().manual_seed(seed) for seed in seeds]
    views, xs, ys, weights = stratified_pixels(len(cameras), cameras.width, cameras.height, columns, rows, generators)
    origins, directions = generate_rays(cameras, views, xs, ys)
    # Each view's probes continue from the generator its pixels came from.
    return _fisher_groups(
        model,
        origins,
        directions,
        views,
        len(cameras),
        method,
        n_probes,
        generators,
        chunk,
        background,
        weights.float(),
    )


def fisherrf_scores(h_train: Tensor, h_candidates: Tensor, lam: float = FISHER_LAMBDA) -> Tensor:
    """Expected information gain of each candidate: sum_k H_cand[k] / (H_train[k] + lambda).

    Args:
        h_train: Tensor with shape (P,).
        h_candidates: Tensor with shape (n_candidates, P) or (P,).
        lam: lambda, the prior precision that keeps parameters no training ray touches finite.

    Returns:
        Tensor with shape (n_candidates,) (or a scalar for one candidate).
    """
    return h_candidates @ (1.0 / (h_train + lam))


def fisherrf_view_scores(
    model: nn.Module,
    cameras: Cameras,
    h_train: Tensor,
    lam: float = FISHER_LAMBDA,
    cache_floats: int = CACHE_FLOATS,
    resolution: int = 8,
    method: str = DEFAULT_METHOD,
    n_probes: int = 1,
    generator: torch.Generator | None = None,
    chunk: int = 1024,
    background: Tensor | None = None,
    views_per_batch: int = 32,
    progress: Callable[[int], None] | None = None,
) -> tuple[Tensor, Callable[[int], Tensor]]:
    """FisherRF scores of many views, holding at most `cache_floats` floats of H_cand.

    All n_views x P floats are kept when they fit (small models); otherwise the best-scoring
    views' H_cand are kept and the others recomputed when the greedy selection asks for them.

    Args:
        model, cameras, resolution, method, n_probes, chunk, background: as in `fisher_views`.
        h_train: Tensor with shape (P,).
        lam: as in `fisherrf_scores`.
        cache_floats: memory bound on the kept H_cand, in floats (default 2^28, 1 GiB).
        generator: seeds the probes; drawn from once.
        views_per_batch: views whose H_cand are computed together.
        progress: called after each batch with the number of views scored so far.

    Returns:
        scores: Tensor with shape (n_views,).
        h_of: view index -> its H_cand (P,), kept or recomputed (the same numbers: each view's
            probes come from its own seed).
    """
    seeds = _group_seeds(generator, len(cameras))
    keep = max(1, cache_floats // max(1, h_train.numel()))

    def compute(indices: list[int]) -> Tensor:
        return _views_fisher(
            model,
            cameras[indices],
            resolution,
            method,
            n_probes,
            [seeds[i] for i in indices],
            chunk,
            background,
        )

    inverse = 1.0 / (h_train + lam)
    scores = torch.empty(len(cameras), device=h_train.device)
    kept: dict[int, Tensor] = {}
    for first in range(0, len(cameras), views_per_batch):
        batch = list(range(first, min(len(cameras), first + views_per_batch)))
        h = compute(batch)
        scores[batch] = h @ inverse
        kept.update(zip(batch, h))
        if len(kept) > keep:
            kept = {i: kept[i] for i in sorted(kept, key=lambda i: float(scores[i]), reverse=True)[:keep]}
        if progress is not None:
            progress(batch[-1] + 1)

    def h_of(index: int) -> Tensor:
        return kept[index] if index in kept else compute([index])[0]

    return scores, h_of


def fisherrf_greedy(
    h_train: Tensor,
    h_candidates: Tensor | Callable[[int], Tensor],
    k: int,
    lam: float = FISHER_LAMBDA,
    scores: Tensor | None = None,
) -> tuple[Tensor, Tensor]:
    """FisherRF's batch selection: take the best candidate, add its H_cand to H_train, rescore.

    Evaluated lazily (same picks, fewer rescorings): adding to H_train only lowers every score,
    so a candidate whose fresh score beats every other candidate's last (higher or equal) score is
    the best one; only candidates reaching the top are rescored.

    Args:
        h_train: Tensor with shape (P,).
        h_candidates: Tensor with shape (n_candidates, P), or a function giving candidate i's
            H_cand (P,) on demand (then `scores` is required).
        k: views to pick, at most n_candidates.
        lam: as in `fisherrf_scores`.
        scores: Tensor with shape (n_candidates,), the scores against `h_train`; computed from a
            tensor `h_candidates` when None.

    Returns:
        indices: Tensor with shape (k,), in the order picked.
        scores: Tensor with shape (n_candidates,), the scores before the first pick.
    """
    if scores is None:
        if callable(h_candidates):
            raise ValueError("scores are required when h_candidates is a function")
        scores = fisherrf_scores(h_train, h_candidates, lam)
    h_of = h_candidates if callable(h_candidates) else h_candidates.__getitem__
    n = scores.shape[0]
    if not 0 <= k <= n:
        raise ValueError(f"cannot pick {k} views out of {n} candidates")
    bounds = scores.detach().double().cpu().clone()
    fresh = torch.ones(n, dtype=torch.bool)
    h = h_train.clone()
    chosen: list[int] = []
    while len(chosen) < k:
        best = int(torch.argmax(bounds))
        if fresh[best]:
            chosen.append(best)
            bounds[best] = -torch.inf
            h += h_of(best)
            fresh[:] = False
            continue
        bounds[best] = float(fisherrf_scores(h, h_of(best), lam))
        fresh[best] = True
    return torch.tensor(chosen, dtype=torch.long), scores
