"""Shared test settings: deterministic, small thread count (CI has 2 cores)."""

import os

import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")


def _test_threads() -> int:
    """Torch's intra-op thread count for the tests: 1 (CI has 2 cores; tests also run beside other
    processes), or NERFAUG_TEST_THREADS, with which `make test-rounding` runs the tests marked
    `rounding` under 2 threads too (a reduction split over threads sums in another order)."""
    text = os.environ.get("NERFAUG_TEST_THREADS", "1")
    if not text.isdigit() or int(text) < 1:
        raise pytest.UsageError(f"NERFAUG_TEST_THREADS: expected a whole number >= 1, got {text!r}")
    return int(text)


torch.set_num_threads(_test_threads())


@pytest.fixture
def generator() -> torch.Generator:
    return torch.Generator().manual_seed(0)


@pytest.fixture(autouse=True)
def _process_settings_do_not_leak():
    """The CLI's entry point flushes subnormal floats process-wide (`configure_process`); a test
    that calls it in-process must not change what the next test sees (hypothesis, for one,
    refuses to generate floats when subnormals are flushed)."""
    yield
    torch.set_flush_denormal(False)
