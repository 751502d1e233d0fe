"""Shared test settings: deterministic, small thread count (CI has 2 cores)."""

import os

import pytest
import torch

os.environ.setdefault("MPLBACKEND", "Agg")
torch.set_num_threads(1)  # CI has 2 cores; tests also run beside other processes


@pytest.fixture
def generator() -> torch.Generator:
    return torch.Generator().manual_seed(0)
