"""A results folder's own files (sweep.json, runs/<scene>, report.md, figures/) are held to the
containment rule: a symbolic link planted there that leads out is refused in one line naming the
file, before anything outside is read or written."""

import json
from pathlib import Path

import pytest

from nerfaug.errors import PathRefused
from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.store import RunKey, check_sweep, read_sweep
from nerfaug.experiment.sweep import run_sweep


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (relative name -> bytes): what must stay as it was."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def outside(tmp_path) -> Path:
    folder = tmp_path / "outside"
    (folder / "ours" / "trial_000").mkdir(parents=True)
    (folder / "ours" / "trial_000" / "result.json").write_text('{"not": "a run of this folder"}')
    (folder / "sweep.json").write_text(json.dumps({"fingerprint": "elsewhere", "config": {}}))
    return folder


def refused_line(error: pytest.ExceptionInfo, name: str) -> str:
    text = str(error.value)
    assert "\n" not in text and name in text and "outside" in text, text
    return text


def test_a_sweep_json_linked_out_is_refused_and_its_target_unchanged(tmp_path, outside):
    results = tmp_path / "results"
    results.mkdir()
    (results / "sweep.json").symlink_to(outside / "sweep.json")
    before = snapshot(outside)
    with pytest.raises(PathRefused) as error:
        read_sweep(results)
    refused_line(error, "sweep.json")
    with pytest.raises(PathRefused) as error:
        check_sweep(results, {"fingerprint": "new", "config": {}})
    refused_line(error, "sweep.json")
    assert snapshot(outside) == before
    assert (results / "sweep.json").is_symlink()  # not replaced by a file either

    from nerfaug.report.collect import collect_results

    with pytest.raises(PathRefused) as error:
        collect_results(results)
    refused_line(error, "sweep.json")


def test_a_scene_folder_linked_out_of_runs_is_refused_before_any_run(tmp_path, outside):
    results = tmp_path / "results"
    (results / "runs").mkdir(parents=True)
    (results / "runs" / "lego").symlink_to(outside, target_is_directory=True)
    before = snapshot(outside)
    with pytest.raises(PathRefused) as error:
        RunKey("lego", "ours", 0).folder(results)
    refused_line(error, "runs/lego/ours/trial_000")
    config = PROTOCOL_PRESETS.choose("tiny").replace(scenes=("lego",))
    with pytest.raises(PathRefused) as error:
        run_sweep(config, results, progress=False)
    refused_line(error, "runs/lego")
    assert snapshot(outside) == before
    assert sorted(p.name for p in results.iterdir()) == ["runs"]  # nothing written: no sweep.json, no dataset


def test_runs_linked_out_is_refused(tmp_path, outside):
    results = tmp_path / "results"
    results.mkdir()
    (results / "runs").symlink_to(outside, target_is_directory=True)
    with pytest.raises(PathRefused) as error:
        RunKey("lego", "ours", 0).folder(results)
    refused_line(error, "runs/lego")


def test_figures_linked_out_is_refused_and_nothing_drawn_there(tmp_path, outside):
    from nerfaug.cli.run_work import paper_tables
    from nerfaug.report import write_report

    results = tmp_path / "results"
    results.mkdir()
    (results / "sweep.json").write_text(json.dumps({"fingerprint": "f", "config": {}}))
    (results / "figures").symlink_to(outside, target_is_directory=True)
    before = snapshot(outside)
    with pytest.raises(PathRefused) as error:
        write_report(results, paper_tables())
    refused_line(error, "figures")
    assert snapshot(outside) == before
    assert not (results / "report.md").exists()


def test_a_report_linked_out_is_refused_before_anything_is_written(tmp_path, outside):
    from nerfaug.cli.run_work import paper_tables
    from nerfaug.report import write_report

    results = tmp_path / "results"
    results.mkdir()
    (results / "sweep.json").write_text(json.dumps({"fingerprint": "f", "config": {}}))
    (results / "report.md").symlink_to(outside / "sweep.json")
    before = snapshot(outside)
    with pytest.raises(PathRefused) as error:
        write_report(results, paper_tables())
    refused_line(error, "report.md")
    assert snapshot(outside) == before
    assert not (results / "figures").exists()
