"""Which torch device computes, and in which precision: one place that turns `--device
auto|cpu|cuda` (`nerfaug.device_choice.Device`) into a `torch.device`, describes it for the
records, and says when mixed precision applies.

    >>> resolve_device("cpu")
    device(type='cpu')
    >>> autocast_dtype(torch.device("cpu"), "auto") is None  # the CPU always computes in float32
    True
"""

from __future__ import annotations

from typing import Literal

import torch

Precision = Literal["auto", "fp32", "fp16", "bf16"]
"""Training precision: auto (float32 everywhere: half precision does not train this engine, see
`autocast_dtype`), or forced."""
PRECISIONS = ("auto", "fp32", "fp16", "bf16")


def resolve_device(device: str | torch.device | None = "auto") -> torch.device:
    """The torch device `device` names; "auto" (or None) is cuda when available, else cpu.

    Args:
        device: "auto", "cpu", "cuda", "cuda:1", ... or a torch.device.

    Raises:
        ValueError: one line naming the device when it is not a device or is not available here.
    """
    if device is None or (isinstance(device, str) and device.strip().lower() == "auto"):
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        resolved = torch.device(device.strip().lower() if isinstance(device, str) else device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(f"device {device!r} is not a torch device (use auto, cpu or cuda): {error}") from None
    if resolved.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(
                f"device {str(device)!r}: no CUDA GPU is available to torch {torch.__version__} on this "
                "machine (use --device cpu, or auto to take a GPU only when there is one)"
            )
        if resolved.index is not None and resolved.index >= torch.cuda.device_count():
            raise ValueError(f"device {str(device)!r}: only {torch.cuda.device_count()} CUDA device(s) here")
    return resolved


def device_kind(device: str | torch.device | None = "auto") -> str:
    """ "cpu" or "cuda" (the device type, no index): what decides a run's numbers. "auto" is
    resolved here; a named device is not checked for availability (a driver may describe runs
    that execute on other machines)."""
    if device is None or (isinstance(device, str) and device.strip().lower() == "auto"):
        return resolve_device("auto").type
    try:
        return torch.device(device.strip().lower() if isinstance(device, str) else device).type
    except (RuntimeError, TypeError) as error:
        raise ValueError(f"device {device!r} is not a torch device (use auto, cpu or cuda): {error}") from None


def describe_device(device: str | torch.device | None = "auto") -> str:
    """A one-line description for the records, e.g. "cpu" or "cuda:0 (NVIDIA H100 80GB HBM3)"."""
    resolved = resolve_device(device)
    if resolved.type != "cuda":
        return resolved.type
    index = resolved.index if resolved.index is not None else torch.cuda.current_device()
    return f"cuda:{index} ({torch.cuda.get_device_name(index)})"


def autocast_dtype(device: torch.device, precision: str = "auto") -> torch.dtype | None:
    """The autocast dtype of a training step on `device`, or None for plain float32.

    "auto" is float32 (None) on every device. Nerfacto trains under float16 mixed precision, but
    this engine (pure PyTorch, no fused MLPs) does not learn under it: measured on an H200, the
    paper preset at 100 px (12 views, 1000 steps, 4 seeds) fitted its training views to 12.8-21.4
    dB under fp16 autocast against 30.8-31.5 dB in float32, at about the same step time, and a
    400 px trial rendered a grey, colourless lego (BENCHMARKS.md, "GPU: the paper preset on an
    H200"). "fp16"/"bf16" stay available on cuda; on a CPU they are refused: CPU autocast would
    change the CPU's numbers for no speed gain here.

    Raises:
        ValueError: an unknown precision, or half precision asked for on a non-cuda device.
    """
    if precision not in PRECISIONS:
        raise ValueError(f"precision {precision!r} is not one of {', '.join(PRECISIONS)}")
    if precision == "fp32":
        return None
    if precision == "auto":
        return None
    if device.type != "cuda":
        raise ValueError(f"precision {precision!r} needs a cuda device; {device} trains in fp32 (use auto or fp32)")
    return torch.float16 if precision == "fp16" else torch.bfloat16


def peak_memory_mib(device: torch.device) -> float | None:
    """Peak memory torch allocated on a cuda device since the last reset, in MiB; None elsewhere."""
    if device.type != "cuda":
        return None
    return torch.cuda.max_memory_allocated(device) / 2**20


def synchronize(device: torch.device) -> None:
    """Wait for queued kernels on `device` (so wall-clock timings are honest); no-op on a CPU."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def configure_process(threads: int | None = None) -> None:
    """Process-wide torch settings, made once at an entry point (the CLI, a sweep worker, a
    benchmark), never inside a library object.

    Flushes subnormal floats to zero: vanishing transmittances and saturated activations make
    them, and they slow x86 CPUs by an order of magnitude (measured: 12x per training step);
    flushing changes no result measurably. A no-op where unsupported.

    Args:
        threads: torch's intra-op thread count; None leaves it as it is.
    """
    torch.set_flush_denormal(True)
    if threads is not None:
        torch.set_num_threads(threads)
