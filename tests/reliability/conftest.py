"""Inputs made once for every reliability case: a tiny dataset, a capture session on it, and a
finished results folder of it (each case copies what it changes)."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from cases import Bases  # noqa: E402
from harness import make_bases  # noqa: E402


@pytest.fixture(scope="session")
def bases(tmp_path_factory) -> Bases:
    return make_bases(tmp_path_factory.mktemp("bases"))
