"""Shared test settings: deterministic, small thread count (CI has 2 cores)."""

import os

import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")
torch.set_num_threads(1)  # CI has 2 cores; tests also run beside other processes


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
