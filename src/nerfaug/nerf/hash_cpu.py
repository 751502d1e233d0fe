"""The hash encoding's interpolation fused into one C loop for the CPU (`hash_cpu.c`).

On one CPU core a `nerfacto-cpu` training step is bound by memory traffic: the PyTorch path
writes and reads back rows, weights and gathered features as (levels x 8 x points) tensors (tens
of MB a step, past every cache). The C loop walks each point's 8 vertices per level and keeps them
in registers: the same rows and weights as `HashEncoding.corners`, the features summed (forward)
or the output gradient scattered into the table (backward).

Why hand-written C: no maintained library has a CPU hash-grid kernel (tiny-cuda-nn, nerfacc and
Instant-NGP are CUDA-only; torch.compile's inductor code for the PyTorch composition still
materialises the corner tensors and was 1.4-1.55x on the encoding, BENCHMARKS.md "Engine
variants"). It is plain C without torch headers, so it builds in about a second with the system C
compiler (`cc`, or `$CC`) and no download, once per source version, into the user's cache; it is
called through ctypes on the tensors' memory.

Where no compiler is present (or the build fails) `available()` is False and the encoding keeps the
PyTorch path; the engine version records which arithmetic a run used
(`nerfaug.nerf.config.engine_version`). The sums run in a fixed order on one thread, so a run is
deterministic given its seed; they are not the PyTorch path's sums bit for bit (another order).
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import torch
from torch import Tensor

_SOURCE = Path(__file__).with_name("hash_cpu.c")
# No -march=native and no -ffast-math: the same float32 operations in the same order on every
# x86-64 or ARM machine; -ffp-contract=off keeps a*b+c two roundings (no fused multiply-add).
_FLAGS = ("-O3", "-shared", "-fPIC", "-ffp-contract=off", "-fno-fast-math", "-std=c99")


def _cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "nerfaug"


def compiled(source: Path) -> ctypes.CDLL | None:
    """The C file `source` built with `_FLAGS` into the user's cache, once per source version and
    compiler, and loaded (None where no C compiler builds it). Each caller keeps its library
    (`_library`); also builds `nerfaug.nerf.sampler_cpu`'s loops."""
    text = source.read_bytes()
    compiler = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        return None
    digest = hashlib.sha256(text + " ".join((compiler, *_FLAGS)).encode()).hexdigest()[:16]
    target = _cache_dir() / f"{source.stem}-{digest}.so"
    if not target.exists():
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            # Built beside the target and renamed: processes of a sweep building at once each
            # write their own file, and the rename is atomic.
            with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
                built = Path(scratch) / f"{source.stem}.so"
                subprocess.run(
                    [compiler, *_FLAGS, "-o", str(built), str(source), "-lm"],
                    check=True,
                    capture_output=True,
                    timeout=120,
                )
                os.replace(built, target)
        except (OSError, subprocess.SubprocessError):
            return None
    return ctypes.CDLL(str(target))


@functools.cache
def _library() -> ctypes.CDLL | None:
    """The compiled kernel, built on first use (None where no C compiler builds it)."""
    library = compiled(_SOURCE)
    if library is None:
        return None
    pointer, i64, i32 = ctypes.c_void_p, ctypes.c_int64, ctypes.c_int
    # The *_reference loops take one point at a time: what the eight-point loops are tested against.
    for name in ("hash_forward", "hash_backward", "hash_forward_reference", "hash_backward_reference"):
        function = getattr(library, name)
        function.argtypes = [pointer, i64, pointer, i32, i32, pointer, pointer, i32, i64, pointer]
        function.restype = None
    return library


def available() -> bool:
    """Whether the fused CPU kernel is built (a C compiler is present) or was built before."""
    return _library() is not None


def supports(x: Tensor, table: Tensor) -> bool:
    """Whether the kernel takes these points and table: float32 CPU tensors, points without
    gradients of their own (the kernel computes none for them)."""
    return (
        x.device.type == "cpu"
        and table.device.type == "cpu"
        and x.dtype == torch.float32
        and table.dtype == torch.float32
        and not x.requires_grad
        and available()
    )


def _call(name: str, x: Tensor, tensor: Tensor, out: Tensor, encoding) -> None:
    levels, features = encoding.num_levels, encoding.features_per_level
    getattr(_library(), name)(
        x.data_ptr(),
        x.shape[0],
        tensor.data_ptr(),
        features,
        levels,
        encoding.resolutions.data_ptr(),
        encoding.factors.data_ptr(),
        encoding.dense_levels,
        encoding.table_size,
        out.data_ptr(),
    )


class CpuHashInterpolation(torch.autograd.Function):
    """`HashEncoding`'s features of points (n, 3) -> (n, levels * features) through the C loop;
    points outside [0, 1]^3 are clamped onto it. Gradients reach the table only."""

    @staticmethod
    def forward(ctx, x: Tensor, table: Tensor, encoding) -> Tensor:
        x = x.detach().contiguous()
        table = table.detach().contiguous()
        out = torch.empty(x.shape[0], encoding.output_dim, dtype=torch.float32)
        if x.shape[0]:
            _call("hash_forward", x, table, out, encoding)
        ctx.save_for_backward(x)
        ctx.encoding = encoding
        return out

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[None, Tensor, None]:
        (x,) = ctx.saved_tensors
        encoding = ctx.encoding
        grad_table = torch.zeros_like(encoding.table)
        if x.shape[0]:
            _call("hash_backward", x, grad.contiguous().float(), grad_table, encoding)
        return None, grad_table, None
