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


@pytest.mark.parametrize("name", TABLES)
def test_a_table_re_derives_its_runs_fingerprints_from_its_plan_alone(name, monkeypatch):
    """`rederived_fingerprints` (what `nerfaug study --one-shot-table` counts a run by) gives every
    committed run its recorded fingerprint, from the table's plan and the run's recorded engine
    version, whatever this machine's engine version is; a changed setting of the plan gives none."""
    from nerfaug.experiment.study import rederived_fingerprints

    table = json.loads((RESULTS / name).read_text())
    key = {id(r): (r["engine"], r.get("engine_version") or None, r["method"]) for r in table["runs"]}
    keys = set(key.values())
    monkeypatch.setattr(ExperimentConfig, "engine_version", lambda self: "a later arithmetic")
    now = rederived_fingerprints(table["plan"], keys)
    assert all(now[key[id(r)]] == r["fingerprint"] for r in table["runs"])
    plan = table["plan"] | {"config": table["plan"]["config"] | {"n_test": 49}}
    assert not set(rederived_fingerprints(plan, keys).values()) & {r["fingerprint"] for r in table["runs"]}
