"""benchmarks/gpu_study.py and gpu_study.sh on the CPU, through the code a GPU slot runs: packs
that unpack to the same files (and are refused when they do not); the plan's order (ours against
uniform on the first scene before anything else); batches sized by a model of the machine's
times; the shell script's CPU mode exactly as CI runs it (a toy scene it makes itself), which
brings back what finished, or a record of why nothing did; the merge, which records the runs and
writes the page, and refuses a cell of mixed engine versions."""

import json
import os
import re
import subprocess
import sys
import tarfile
from pathlib import Path

import pytest

from nerfaug.experiment.budget import TimeModel
from nerfaug.experiment.study import gpu_study_order

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "gpu_study.py"


def archived(archive: Path, name: str) -> list[dict]:
    with tarfile.open(archive) as tar:
        return [json.load(tar.extractfile(m)) for m in tar.getmembers() if m.name.endswith(name) and m.isfile()]


def call(out: Path, budget: int) -> subprocess.CompletedProcess:
    """benchmarks/gpu_study.sh in its CPU mode, as CI runs it (this interpreter as PYTHON)."""
    env = os.environ | {"DEVICE": "cpu", "BUDGET_S": str(budget), "OUT": str(out), "PYTHON": sys.executable}
    return subprocess.run(
        ["bash", str(ROOT / "benchmarks" / "gpu_study.sh")],
        env=env,
        capture_output=True,
        text=True,
        timeout=budget + 90,
    )


def test_the_deciding_comparison_runs_first():
    methods = ("uniform", "ours", "ours-batch-sharp", "fisherrf", "entropy-sampling", "furthest")
    order = gpu_study_order(["mic", "lego"], methods, 10)
    assert len(order) == 120 and len(set(order)) == 120
    first = order[:20]  # ours and uniform on the first scene, 10 seed pairs, before any other cell
    assert {k.scene for k in first} == {"mic"} and {k.method for k in first} == {"uniform", "ours"}
    assert [(k.trial, k.method) for k in first[:4]] == [(0, "uniform"), (0, "ours"), (1, "uniform"), (1, "ours")]
    # Then the scene's other methods, trial by trial, then the next scene in the same order.
    assert {k.scene for k in order[:60]} == {"mic"} and order[20].method == "ours-batch-sharp"
    assert [(k.scene, k.method, k.trial) for k in order[60:62]] == [("lego", "uniform", 0), ("lego", "ours", 0)]


def test_study_runs_on_the_gpu_keep_the_papers_plan_and_skip_what_does_not_come_back(bench):
    from nerfaug.experiment.config import STUDY_PRESETS

    gpu = STUDY_PRESETS["gpu"]
    assert (gpu.engine, gpu.resolution, gpu.steps, gpu.n_test) == ("paper", 400, 10_000, 200)
    args = bench.parser().parse_args(["run"])
    assert (args.device, args.engine, args.resolution, args.steps, args.preset) == ("cuda", "paper", 400, 10_000, "gpu")
    # Neither the uncertainty images nor the hemisphere map: a call brings back the records only.
    assert not gpu.view_uncertainty and not gpu.hemisphere_map


def test_batches_are_sized_by_the_measured_times_and_learn_from_finished_ones():
    # 2 s a step alone, 3 s for four at once (a GPU serving several runs): 10 steps, 5 views of 1 s.
    model = TimeModel(steps=10, n_test=5, step_s={1: 2.0, 4: 3.0}, view_s=1.0, overhead_s=1.0, default_select_s=4.0)
    assert (
        model.step_seconds(1) == 2.0
        and model.step_seconds(4) == 3.0
        and model.step_seconds(2) == pytest.approx(2 + 1 / 3)
    )
    assert model.predict(["ours"]) == pytest.approx(20 + 5 + 1 + 4)
    four = 30 + 4 * 10
    assert model.fits(["uniform", "ours"] * 2, four * 1.15, 4) == 4
    assert model.fits(["uniform", "ours"] * 2, four * 1.15 - 1, 4) == 3  # one run fewer when four do not fit
    assert model.fits(["uniform"] * 8, 10**6, 3) == 3  # never beyond what memory holds
    assert model.fits(["uniform"], 30, 4) == 0  # not even one: the call says so instead of starting it
    # A finished batch of two: each run's share of 12 s of training, 10 s evaluating, 0.5 s selecting.
    results = [
        {"method": m, "batch_size": 2, "timing": {"train_before": 1.0, "train_after": 5.0, "evaluation": 10.0,
                                                   "selection": 0.5}}
        for m in ("uniform", "ours")
    ]  # fmt: skip
    model.learn(results, wall_s=40.0)
    assert model.step_s[2] == pytest.approx(1.2) and model.view_s == pytest.approx(2.0)
    assert model.select_s == {"uniform": 0.5, "ours": 0.5} and model.overhead_s == pytest.approx((40 - 12 - 21) / 2)


def test_packs_unpack_to_their_files_and_a_changed_one_is_refused(bench, dataset, tmp_path):
    manifest = bench.pack(dataset, tmp_path / "packs" / "sphere.tar")
    assert manifest["scene"] == "sphere" and manifest["files"] > 10
    found = bench.unpack(tmp_path / "packs", tmp_path / "data")
    assert list(found) == ["sphere"]
    assert bench.folder_digest(found["sphere"]) == bench.folder_digest(dataset) == manifest["digest"]
    with pytest.raises(SystemExit, match="over --max-mib"):
        bench.pack(dataset, tmp_path / "big.tar", max_mib=0.001)
    # A pack whose files changed after packing is refused by the digest it carries.
    with tarfile.open(tmp_path / "packs" / "sphere.tar") as tar:
        tar.extractall(tmp_path / "edit", filter="data")
    image = next((tmp_path / "edit" / "sphere" / "test").glob("*.png"))
    image.write_bytes(image.read_bytes()[:-1] + b"\0")
    (tmp_path / "bad").mkdir()
    with tarfile.open(tmp_path / "bad" / "sphere.tar", "w") as tar:
        tar.add(tmp_path / "edit" / "sphere", arcname="sphere")
    with pytest.raises(SystemExit, match="do not match the digest"):
        bench.unpack(tmp_path / "bad", tmp_path / "data2")


def test_a_cell_of_mixed_engine_versions_is_refused(bench):
    table = [{"engine": "paper", "scene": "mic", "engine_version": "2"}]
    bench.check_versions(table, [{"engine": "paper", "scene": "lego", "engine_version": None}], "a.tgz")  # other cell
    bench.check_versions(table, [{"engine": "paper", "scene": "mic", "engine_version": "2"}], "a.tgz")
    with pytest.raises(SystemExit, match="paper/mic would hold runs of engine versions 2, 3"):
        bench.check_versions(table, [{"engine": "paper", "scene": "mic", "engine_version": "3"}], "a.tgz")
    with pytest.raises(SystemExit, match="the reference engine"):
        bench.check_versions(table, [{"engine": "paper", "scene": "mic"}], "a.tgz")


@pytest.mark.slow
def test_the_cpu_mode_brings_back_finished_runs_in_the_plans_order_and_the_merge_writes_the_page(bench, tmp_path):
    done = call(tmp_path / "out", 120)
    assert done.returncode == 0, done.stdout + done.stderr
    archive = tmp_path / "out" / "gpu-study.tar.gz"
    runs = archived(archive, "/result.json")
    (record,) = archived(archive, "gpu-call.json")
    assert record["finished"] == len(runs) >= 1, record
    assert record["measured"]["step_s"] and record["batches"][0]["predicted_s"] > 0
    # The plan's order: what finished is the head of it (uniform and ours, trial by trial, first).
    methods = ("uniform", "ours", "ours-batch-sharp", "fisherrf", "entropy-sampling", "furthest")
    head = gpu_study_order(["sphere"], methods, 10)[: len(runs)]
    assert {(r["method"], r["trial"]) for r in runs} == {(k.method, k.trial) for k in head}
    # Trained in batches, each run as it would be alone: the reference engine, no version recorded.
    assert all("engine_version" not in r for r in runs)
    # Merged here: the table records the runs, the page lists them.
    table, page = tmp_path / "T.json", tmp_path / "P.md"
    bench.main(["merge", str(archive), "--work", str(tmp_path / "m"), "--table", str(table), "--page", str(page)])
    recorded = json.loads(table.read_text())["runs"]
    assert len(recorded) == len(runs) and {r.get("engine_version", "") for r in recorded} == {""}
    text = page.read_text()
    assert f"runs in the table: {len(runs)}" in text
    # Every pre-registered hypothesis of the GPU plan, each with a computed verdict: a toy table
    # is far from complete, so each is partial (a partial table decides nothing).
    for name in ("G1", "G2", "G3", "G4"):
        assert re.search(rf"\b{name}\b.*partial: \d+ of \d+ runs", text), name


@pytest.mark.slow
def test_a_budget_too_small_for_one_run_brings_back_why(bench, tmp_path):
    done = call(tmp_path / "out", 20)
    assert done.returncode == 0, done.stdout + done.stderr
    archive = tmp_path / "out" / "gpu-study.tar.gz"
    (record,) = archived(archive, "gpu-call.json")
    assert record["finished"] == 0 and archived(archive, "/result.json") == []
    assert "s were left" in record["stopped"] or "nothing measured" in record["stopped"], record
    assert record["runs_left_in_plan"] == 60
    # The merge says so and records nothing.
    bench.main(["merge", str(archive), "--work", str(tmp_path / "m"), "--table", str(tmp_path / "T.json"),
                "--page", str(tmp_path / "P.md")])  # fmt: skip
    assert not (tmp_path / "T.json").exists()
