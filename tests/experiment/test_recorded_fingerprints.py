"""The committed study tables still read, and every run in them keeps its fingerprint: the settings
that change a run's numbers (the engine's complete settings among them, by their flat names)
hash today as they did when the run was made, so a study resumes from these tables and a
change of a setting's structure (the engine's nesting) moves no result."""

import contextlib
import json
from pathlib import Path

import pytest

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.store import fingerprint, run_fingerprint
from nerfaug.nerf.encoding import HashEncoding
from nerfaug.selection.config import SelectionConfig
from nerfaug.selection.methods import get_method

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
TABLES = ["study-table.json", "real-study-table.json"]


def plan_config(plan: dict, engine: str, engine_version: str | None) -> ExperimentConfig:
    """The protocol a table's plan records, for one engine (on the CPU, where these ran)."""
    settings = dict(plan["config"])
    settings["selection"] = SelectionConfig(**settings["selection"])
    settings["scenes"], settings["methods"] = tuple(settings["scenes"]), tuple(settings["methods"])
    config = ExperimentConfig(**{**settings, "engine": engine, "device": "cpu"})
    return config.replace(batch=2) if engine_version else config  # trial batches: their own engine version


@contextlib.contextmanager
def reference_hash_kernel():
    """The hash grids on the PyTorch path (NERFAUG_HASH_KERNEL=torch), as every committed run
    alone trained: with the fused CPU loop a run is another engine version."""
    default = HashEncoding.default_kernel
    HashEncoding.default_kernel = "torch"
    try:
        yield
    finally:
        HashEncoding.default_kernel = default


@pytest.mark.parametrize("name", TABLES)
def test_every_committed_run_keeps_its_fingerprint(name):
    table = json.loads((RESULTS / name).read_text())
    sweeps: dict[tuple, str] = {}
    for run in table["runs"]:
        key = (run["engine"], run.get("engine_version"))
        if key not in sweeps:
            with reference_hash_kernel():
                sweeps[key] = fingerprint(plan_config(table["plan"], *key).fingerprinted())
        assert run_fingerprint(sweeps[key], get_method(run["method"]).definition()) == run["fingerprint"], run
    assert len(table["runs"]) >= 720
