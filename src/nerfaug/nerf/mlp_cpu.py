"""The fields' small ReLU MLPs forward and backward in one C pass (`mlp_cpu.c`), part of the
opt-in CPU engine version `cpu-fused-3` (`nerfaug.nerf.sampler_cpu`, NERFAUG_CPU_KERNELS=fused).

Why hand-written C: with the hash grids and the sampler in C loops, a `nerfacto-cpu` training step
on one core spends about a quarter of its time in the MLPs (widths 1-32 on 8-16 thousand samples,
6 -> 16 -> 1 for a proposal network): MKL is far from its speed at such widths (a 16384 x 16 by
16 x 6 product at under 5 GFLOP/s), and every layer's bias, ReLU and their gradients are further
passes over (samples x width) tensors that no longer fit in the core's caches (BENCHMARKS.md).
Here a block of 64 points goes through every layer while it stays in the first caches; the forward
keeps the hidden activations where a backward follows. Every product-and-add is a fused
multiply-add, by the instruction on AVX2 machines and by the C library's fmaf elsewhere, which
round alike, so a run computes the same bits on every machine (mlp_cpu.c says how the sums are
ordered). No library has such a kernel for the CPU (tiny-cuda-nn's fully fused MLP is CUDA-only;
oneDNN fuses one layer's ReLU but not the layers or the backward).

Chosen where the sampler loops are (`sampler_cpu.selected()`, which the fields ask before calling
`run`), for the MLPs of an engine with proposal networks (the engines `cpu-fused-3` is recorded
for), on float32 CPU tensors; elsewhere (float16 autocast, the GPU, other engines) `nn.Sequential`
runs. The parameters stay the `nn.Linear` layers' own, so checkpoints and optimisers see no
difference.
"""

from __future__ import annotations

import ctypes
import functools
from pathlib import Path

import torch
from torch import Tensor, nn

from nerfaug.nerf.hash_cpu import compiled

_SOURCE = Path(__file__).with_name("mlp_cpu.c")
_P, _I64, _INT = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int


@functools.cache
def _library() -> ctypes.CDLL | None:
    """The compiled loops, built on first use (None where no C compiler builds them)."""
    library = compiled(_SOURCE)
    if library is None:
        return None
    library.mlp_forward.argtypes = [_P, _I64, _INT, _P, _P, _P, _P, _P]
    library.mlp_backward.argtypes = [_P, _I64, _INT, _P, _P, _P, _P, _P, _P, _P, _P]
    library.mlp_forward.restype = library.mlp_backward.restype = _INT
    return library


def available() -> bool:
    """Whether the loops are built (a C compiler is present) or were built before."""
    return _library() is not None


def linear_layers(network: nn.Sequential) -> list[nn.Linear] | None:
    """The linear layers of `nerfaug.nerf.field.mlp`'s network (Linear, ReLU, ..., Linear), or None
    for a network of another form."""
    modules = list(network)
    linears = modules[0::2]
    if len(modules) % 2 == 0 or not all(isinstance(m, nn.Linear) for m in linears):
        return None
    if not all(isinstance(m, nn.ReLU) for m in modules[1::2]):
        return None
    return linears


def applies(x: Tensor, first: nn.Linear) -> bool:
    """Whether the C loops compute a network whose first layer is `first` on `x`: the loops
    built, `x` and the layer float32 on the CPU, and no float16/bfloat16 autocast."""
    if x.device.type != "cpu" or x.dtype != torch.float32 or torch.is_autocast_enabled("cpu"):
        return False
    weight = first.weight
    return weight.device.type == "cpu" and weight.dtype == torch.float32 and available()


def _pointers(tensors: list[Tensor]):
    return (ctypes.c_void_p * len(tensors))(*(t.data_ptr() for t in tensors))


def _check(code: int) -> None:
    if code:
        raise MemoryError("nerfaug's CPU MLP loop could not allocate its block buffers")


_BLOCK = 64
"""Points a block of the C loops (`BLOCK` in mlp_cpu.c)."""


class CpuMlp(torch.autograd.Function):
    """`nerfaug.nerf.field.mlp`'s network on x (n, dims[0]) -> (n, dims[-1]), weights and biases
    passed in layer order (w0, b0, w1, b1, ...) after `keep` (whether a backward will follow: the
    forward then keeps the hidden activations for it). Gradients reach x and every parameter."""

    @staticmethod
    def forward(ctx, x: Tensor, keep: bool, *parameters: Tensor) -> Tensor:
        x = x.detach().contiguous()
        parameters = tuple(p.detach().contiguous() for p in parameters)
        weights, biases = list(parameters[0::2]), list(parameters[1::2])
        dims = [x.shape[1], *(w.shape[0] for w in weights)]
        out = torch.empty(x.shape[0], dims[-1], dtype=torch.float32)
        blocks = -(-x.shape[0] // _BLOCK)
        hidden = torch.empty(blocks * sum(dims[1:-1]) * _BLOCK, dtype=torch.float32) if keep else None
        if x.shape[0]:
            _check(
                _library().mlp_forward(
                    x.data_ptr(),
                    x.shape[0],
                    len(weights),
                    (ctypes.c_int * len(dims))(*dims),
                    _pointers(weights),
                    _pointers(biases),
                    out.data_ptr(),
                    None if hidden is None else hidden.data_ptr(),
                )
            )
        ctx.save_for_backward(x, hidden, *parameters)
        ctx.dims = dims
        return out

    @staticmethod
    def backward(ctx, grad: Tensor):
        x, hidden, *parameters = ctx.saved_tensors
        weights, biases = parameters[0::2], parameters[1::2]
        grad_x = torch.empty_like(x) if ctx.needs_input_grad[0] else None
        grads = [torch.empty_like(p) for p in parameters]
        if x.shape[0]:
            _check(
                _library().mlp_backward(
                    x.data_ptr(),
                    x.shape[0],
                    len(weights),
                    (ctypes.c_int * len(ctx.dims))(*ctx.dims),
                    _pointers(list(weights)),
                    _pointers(list(biases)),
                    None if hidden is None else hidden.data_ptr(),
                    grad.contiguous().float().data_ptr(),
                    None if grad_x is None else grad_x.data_ptr(),
                    _pointers(grads[0::2]),
                    _pointers(grads[1::2]),
                )
            )
        else:
            for g in grads:
                g.zero_()
        needs = ctx.needs_input_grad[2:]
        return (grad_x, None, *(g if need else None for g, need in zip(grads, needs)))


def run(network: nn.Sequential, x: Tensor, fused: bool) -> Tensor:
    """`network(x)` for x (n, in) -> (n, out): through the C loops where `fused` (the caller's
    engine is one `cpu-fused-3` is recorded for, and `sampler_cpu.selected()`) and they apply,
    else PyTorch's layers. Where not `fused` nothing else is looked at, so that a compiled field
    (`--compile`) traces exactly PyTorch's layers."""
    if fused:
        linears = linear_layers(network)
        if linears is not None and applies(x, linears[0]):
            parameters = [p for layer in linears for p in (layer.weight, layer.bias)]
            keep = torch.is_grad_enabled() and (x.requires_grad or any(p.requires_grad for p in parameters))
            return CpuMlp.apply(x, keep, *parameters)
    return network(x)
