"""The figures every benchmark record starts with: when, on which machine, how loaded, which torch,
with which settings. A ratio is only comparable with another measured on the same machine at the
same load, so each record carries them."""

from __future__ import annotations

import datetime
import os
import platform
from pathlib import Path

import torch


def at_start() -> dict:
    """The date, machine and load average when a benchmark starts."""
    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "host": platform.node(),
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "load_average_at_start": os.getloadavg(),
        "torch": torch.__version__,
    }


def at_end(start: dict, settings: dict) -> dict:
    """`start` with the load average now and the benchmark's settings (paths as text)."""
    return {
        **start,
        "load_average_at_end": os.getloadavg(),
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in settings.items()},
    }
