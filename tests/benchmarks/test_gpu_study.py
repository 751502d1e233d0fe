"""benchmarks/gpu_study.py on the CPU at toy size, through the code a GPU slot runs: packs that
unpack to the same files (and are refused when they do not), calls that each run the next trial
batches the table lacks within their budget and bring them back, and the merge that records them
in the table and writes the page."""

import json
import tarfile
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow]
SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "gpu_study.py"
# A small engine that batches (the paper engine's structure: hash grid, proposal sampler).
TOY = [
    "--device", "cpu", "--engine", "nerfacto-cpu+batch_size=64+num_samples=8+proposal_samples=16,8",
    "--preset", "tiny", "--resolution", "24", "--steps", "30", "--trials", "2", "--methods", "uniform", "ours",
    "--batch", "2", "--threads", "1", "--quiet", "--layouts", "1",
]  # fmt: skip


def archived_results(archive: Path) -> list[dict]:
    with tarfile.open(archive) as tar:
        return [
            json.load(tar.extractfile(m)) for m in tar.getmembers() if m.name.endswith("/result.json") and m.isfile()
        ]


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


def test_calls_run_the_next_batches_within_their_budget_and_the_merge_makes_the_page(bench, dataset, tmp_path):
    bench.pack(dataset, tmp_path / "packs" / "sphere.tar")
    table = tmp_path / "committed-table.json"
    common = ["--packs", str(tmp_path / "packs"), "--table", str(table), *TOY]
    # A budget shorter than one batch: the call runs one trial batch (the first always starts) and stops.
    first = bench.main(
        ["run", "--work", str(tmp_path / "w1"), "--budget-s", "0.5", "--archive", str(tmp_path / "a1.tgz"), *common]
    )
    assert first["units"] == 1 and first["runs_left_in_plan"] == 2 and first["table_runs"] == 2
    runs = archived_results(tmp_path / "a1.tgz")
    assert sorted((r["method"], r["trial"]) for r in runs) == [("ours", 0), ("uniform", 0)]  # a whole trial
    assert {r["engine_version"] for r in runs} == {"batched-1"} and {r["batch_size"] for r in runs} == {2}
    assert all(isinstance(r["health"]["empty"], bool) for r in runs)  # each run says whether it learned
    # What came back is committed; the next call (a bare machine) runs only what the table lacks.
    bench.main(["merge", str(tmp_path / "a1.tgz"), "--work", str(tmp_path / "m1"), "--table", str(table),
                "--page", str(tmp_path / "page.md")])  # fmt: skip
    second = bench.main(
        ["run", "--work", str(tmp_path / "w2"), "--budget-s", "600", "--archive", str(tmp_path / "a2.tgz"), *common]
    )
    assert second["runs_left_in_plan"] == 0 and second["table_runs"] == 4
    assert sorted((r["method"], r["trial"]) for r in archived_results(tmp_path / "a2.tgz")) == [
        ("ours", 1),
        ("uniform", 1),
    ]
    bench.main(["merge", str(tmp_path / "a2.tgz"), "--work", str(tmp_path / "m2"), "--table", str(table),
                "--page", str(tmp_path / "page.md")])  # fmt: skip
    recorded = json.loads(table.read_text())
    assert len(recorded["runs"]) == 4 and {r["engine_version"] for r in recorded["runs"]} == {"batched-1"}
    page = (tmp_path / "page.md").read_text()
    assert "runs in the table: 4" in page and "batched-1" in page
