"""The CPU engine versions a benchmark compares, and how a process chooses one: each arm's hash
kernel (`HashEncoding.default_kernel`, as NERFAUG_HASH_KERNEL sets it) and sampler loops
(`sampler_cpu.MODE`, as NERFAUG_CPU_KERNELS sets it)."""

from __future__ import annotations

import contextlib
import os

from nerfaug.nerf import sampler_cpu
from nerfaug.nerf.encoding import HashEncoding

ARMS = {"reference": ("torch", "hash"), "hash-cpu-1": ("auto", "hash"), "cpu-fused-3": ("auto", "fused")}
"""Each engine version's (hash kernel, sampler loops); the reference records no version."""

_VARIABLES = ("NERFAUG_HASH_KERNEL", "NERFAUG_CPU_KERNELS")


def select(arm: str) -> None:
    """Make `arm` this process's engine, and that of any process a run starts."""
    kernel, mode = ARMS[arm]
    HashEncoding.default_kernel, sampler_cpu.MODE = kernel, mode
    os.environ.update(zip(_VARIABLES, (kernel, mode)))


@contextlib.contextmanager
def choice_kept():
    """The process's own choice of kernels and its environment back afterwards (a test calls a
    benchmark's `main`; a later test's processes must not inherit the last arm)."""
    chosen = (HashEncoding.default_kernel, sampler_cpu.MODE)
    environment = {name: os.environ.get(name) for name in _VARIABLES}
    try:
        yield
    finally:
        HashEncoding.default_kernel, sampler_cpu.MODE = chosen
        for name, value in environment.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
