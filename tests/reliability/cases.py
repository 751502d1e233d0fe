"""The bad inputs' registry and what their areas share; the cases themselves are in
`cases_datasets.py`, `cases_capture.py`, `cases_sessions.py`, `cases_settings.py` and
`cases_experiments.py` (`all_cases()`
collects them).

Each case builds what it needs in a fresh folder and says what `nerfaug` must answer.
A case is a function (tmp, bases) -> Case. `bases` holds inputs made once (a dataset, a capture
session, a finished results folder); a case copies what it changes, and lists in `inputs` every
folder the command must leave byte for byte unchanged.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from harness import Case, copy

TINY = [
    "--preset",
    "tiny",
    "--methods",
    "uniform",
    "--trials",
    "1",
    "--resolution",
    "8",
    "--steps",
    "21",
    "--no-report",
    "--device",
    "cpu",
]


@dataclass
class Bases:
    dataset: Path  # Blender format, 10 train (8x8), 3 test, 3 initial views
    session: Path  # a capture session on `dataset`, trained 3 steps (preset test)
    results: Path  # a finished `nerfaug run` of `dataset` (TINY)


CASES: dict = {}


def case(function):
    CASES[function.__name__] = function
    return function


def edit_json(path: Path, change) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def copy_dataset(tmp: Path, bases: Bases, name: str = "data") -> Path:
    return copy(bases.dataset, tmp / name)


def train_on(data: Path, tmp: Path, *extra) -> Case:
    return Case(
        ["train", data, "--out", tmp / "run", "--engine", "test", "--steps", "1", "--device", "cpu", *extra], [data]
    )


def all_cases() -> dict:
    """Every registered case by name (importing the area modules registers them)."""
    import cases_capture  # noqa: F401
    import cases_datasets  # noqa: F401
    import cases_experiments  # noqa: F401
    import cases_sessions  # noqa: F401
    import cases_settings  # noqa: F401

    return CASES
