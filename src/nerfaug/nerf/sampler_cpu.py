"""The proposal sampler's per-ray arithmetic fused into C loops for the CPU (`sampler_cpu.c`), an
opt-in engine version on top of the fused hash loop (`nerfaug.nerf.hash_cpu`).

With the hash grids in one C loop, most of a `nerfacto-cpu` training step on one core is hundreds
of small PyTorch operations on (rays x samples) tensors: volume-rendering weights (3 a step), the
inverse-CDF resampling (2), the interlevel loss (2 levels) and the distortion loss, forward and
backward, each operation a pass over memory and a dispatch. Each of those here is one C pass over
each ray, with its gradient written out by hand (tests/nerf/test_sampler_cpu.py checks both against
the PyTorch functions they replace).

Chosen by the environment variable `NERFAUG_CPU_KERNELS` ("hash", the default: the hash loop
alone, engine version hash-cpu-1; "fused": these loops and the MLP loop (`nerfaug.nerf.mlp_cpu`)
too, engine version cpu-fused-3, `nerfaug.nerf.config.CPU_FUSED_ENGINE_VERSION`), which a benchmark
may override by setting `MODE`.
They run only where the hash loop runs (`HashEncoding.cpu_loop_selected`), on float32 CPU
tensors, and where a C compiler built them; elsewhere the PyTorch functions run. Sums run in a
fixed order on one thread (running sums in double, as PyTorch's CPU cumsum), so a run is
deterministic given its seed, and no result depends on the CPU's vector width.
"""

from __future__ import annotations

import ctypes
import functools
import os
from pathlib import Path

import torch
from torch import Tensor

from nerfaug.nerf import mlp_cpu
from nerfaug.nerf.hash_cpu import compiled

_SOURCE = Path(__file__).with_name("sampler_cpu.c")
MODES = ("hash", "fused")
MODE = os.environ.get("NERFAUG_CPU_KERNELS") or "hash"
"""This process's choice (`NERFAUG_CPU_KERNELS`); a benchmark or test may set it."""

_P, _I, _F = ctypes.c_void_p, ctypes.c_int64, ctypes.c_float
_SIGNATURES = {
    "weights_forward": [_P, _P, _I, _I, _P, _P, _P],
    "weights_backward": [_P, _P, _I, _I, _P, _P, _P, _P, _P],
    "pdf_sample": [_P, _P, _I, _I, _P, _I, _F, _P, _P],
    "interlevel_forward": [_P, _P, _I, _I, _P, _P, _I, _F, _P, _P, _P],
    "interlevel_backward": [_P, _P, _I, _I, _P, _P, _I, _F, _P, _P, _P, _P, _P],
    "distortion_forward": [_P, _P, _I, _I, _F, _P, _P],
    "distortion_backward": [_P, _P, _I, _I, _F, _P, _P, _P],
}


@functools.cache
def _library() -> ctypes.CDLL | None:
    """The compiled loops, built on first use (None where no C compiler builds them)."""
    library = compiled(_SOURCE)
    if library is None:
        return None
    for name, argtypes in _SIGNATURES.items():
        function = getattr(library, name)
        function.argtypes, function.restype = argtypes, None
    return library


def available() -> bool:
    """Whether the loops are built (a C compiler is present) or were built before."""
    return _library() is not None


def selected() -> bool:
    """Whether this process trains with the fused sampler and MLP loops: `MODE` "fused", the hash
    loop selected (`HashEncoding.cpu_loop_selected`) and these loops and `mlp_cpu`'s built.

    Raises:
        ValueError: `MODE` (NERFAUG_CPU_KERNELS) is neither "hash" nor "fused".
    """
    if MODE not in MODES:
        raise ValueError(f"NERFAUG_CPU_KERNELS must be one of {', '.join(MODES)}, got {MODE!r}")
    if MODE != "fused":
        return False
    from nerfaug.nerf.encoding import HashEncoding

    return HashEncoding.cpu_loop_selected() and available() and mlp_cpu.available()


def applies(*tensors: Tensor) -> bool:
    """Whether the loops compute on these tensors: `selected()` and all of them float32 on the CPU."""
    return selected() and all(t.device.type == "cpu" and t.dtype == torch.float32 for t in tensors)


def _ptr(tensor: Tensor | None):
    return None if tensor is None else tensor.data_ptr()


def _call(name: str, *args) -> None:
    getattr(_library(), name)(*(_ptr(a) if isinstance(a, Tensor) else a for a in args))


class FusedWeights(torch.autograd.Function):
    """`volrend.render_weights`: densities (R, n) and interval lengths (R, n) -> weights and
    transmittance (R, n). Gradients reach the densities only."""

    @staticmethod
    def forward(ctx, sigmas: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
        sigmas, deltas = sigmas.detach().contiguous(), deltas.detach().contiguous()
        weights, transmittance, decay = (torch.empty_like(sigmas) for _ in range(3))
        rays, n = sigmas.shape
        _call("weights_forward", sigmas, deltas, rays, n, weights, transmittance, decay)
        ctx.save_for_backward(sigmas, deltas, transmittance, decay)
        return weights, transmittance

    @staticmethod
    def backward(ctx, grad_weights: Tensor | None, grad_transmittance: Tensor | None):
        sigmas, deltas, transmittance, decay = ctx.saved_tensors
        if grad_weights is None:
            grad_weights = torch.zeros_like(sigmas)
        grad_weights = grad_weights.contiguous().float()
        if grad_transmittance is not None:
            grad_transmittance = grad_transmittance.contiguous().float()
        grad_sigmas = torch.empty_like(sigmas)
        rays, n = sigmas.shape
        _call(
            "weights_backward",
            *(sigmas, deltas, rays, n, transmittance, decay),
            *(grad_weights, grad_transmittance, grad_sigmas),
        )
        return grad_sigmas, None


def render_weights(sigmas: Tensor, deltas: Tensor) -> tuple[Tensor, Tensor]:
    """`nerfaug.nerf.volrend.render_weights` in one pass a ray (shapes as there): deltas must not
    need gradients. Materialises the outputs (no views) for R * n > 0."""
    if sigmas.numel() == 0:
        return torch.zeros_like(sigmas), torch.ones_like(sigmas)
    return FusedWeights.apply(sigmas, deltas)


def sample_pdf(edges: Tensor, weights: Tensor, u: Tensor, padding: float) -> Tensor:
    """`nerfaug.nerf.sampling.sample_pdf`'s inversion at positions `u` (R, s) in [0, 1], drawn as
    there: edges (R, bins + 1), weights (R, bins) >= 0 -> new edges (R, s), no gradient."""
    edges, weights = edges.detach().contiguous(), weights.detach().contiguous()
    u = u.contiguous()
    rays, bins = weights.shape
    out = torch.empty(rays, u.shape[1], dtype=torch.float32)
    scratch = torch.empty(bins + 1, dtype=torch.float32)
    if rays:
        _call("pdf_sample", edges, weights, rays, bins, u, u.shape[1], float(padding), scratch, out)
    return out


class FusedInterlevel(torch.autograd.Function):
    """One proposal level's interlevel penalty of every final sample (R, n) (as
    `proposal._interlevel_terms`); gradients reach the proposal weights only."""

    @staticmethod
    def forward(ctx, edges: Tensor, weights: Tensor, p_edges: Tensor, p_weights: Tensor, eps: float) -> Tensor:
        tensors = [t.detach().contiguous() for t in (edges, weights, p_edges, p_weights)]
        rays, n = tensors[1].shape
        m = tensors[3].shape[1]
        terms = torch.empty(rays, n, dtype=torch.float32)
        scratch, bins = torch.empty(m + 1, dtype=torch.float32), torch.empty(2 * n, dtype=torch.int64)
        if rays:
            _call("interlevel_forward", *tensors[:2], rays, n, *tensors[2:], m, eps, scratch, bins, terms)
        ctx.save_for_backward(*tensors)
        ctx.eps = eps
        return terms

    @staticmethod
    def backward(ctx, grad: Tensor):
        edges, weights, p_edges, p_weights = ctx.saved_tensors
        rays, n = weights.shape
        m = p_weights.shape[1]
        grad_p = torch.empty_like(p_weights)
        scratch, bins = torch.empty(m + 1, dtype=torch.float32), torch.empty(2 * n, dtype=torch.int64)
        accumulated = torch.empty(m + 1, dtype=torch.float64)
        if rays:
            _call(
                "interlevel_backward",
                *(edges, weights, rays, n, p_edges, p_weights, m, ctx.eps),
                *(grad.contiguous().float(), scratch, bins, accumulated, grad_p),
            )
        return None, None, None, grad_p, None


class FusedDistortion(torch.autograd.Function):
    """`proposal.distortion_per_ray`: edges (R, n + 1) without gradient, weights (R, n) -> (R,)."""

    @staticmethod
    def forward(ctx, edges: Tensor, weights: Tensor, eps: float) -> Tensor:
        edges, weights = edges.detach().contiguous(), weights.detach().contiguous()
        rays, n = weights.shape
        out = torch.empty(rays, dtype=torch.float32)
        scratch = torch.empty(2 * n, dtype=torch.float32)
        if rays:
            _call("distortion_forward", edges, weights, rays, n, eps, scratch, out)
        ctx.save_for_backward(edges, weights)
        ctx.eps = eps
        return out

    @staticmethod
    def backward(ctx, grad: Tensor):
        edges, weights = ctx.saved_tensors
        rays, n = weights.shape
        grad_weights = torch.empty_like(weights)
        scratch = torch.empty(2 * n, dtype=torch.float32)
        if rays:
            _call(
                "distortion_backward",
                edges,
                weights,
                rays,
                n,
                ctx.eps,
                grad.contiguous().float(),
                scratch,
                grad_weights,
            )
        return None, grad_weights, None
