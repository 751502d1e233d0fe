"""The folders a sweep or a study fills with data, and the marker that says nerfaug owns a folder,
are held to the containment rule too: a symbolic link planted in place of a results folder's
`datasets/`, its `datasets/cache/` (or an entry in it), a built-in scene's rendered folder, a
study's `datasets/` or `<engine>/` folder, or the `.nerfaug` marker, leading to a folder outside,
is refused in one line naming the link, and nothing outside is read into a run or written.

Each command runs on the analytic sphere of `test_study` (no Blender)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nerfaug.errors import PathRefused

from .test_study import sphere, toy_study  # noqa: F401 -- sphere: the module's dataset fixture

RUN = ["--preset", "tiny", "--methods", "uniform", "--trials", "1", "--workers", "1"]
RUN += ["--device", "cpu", "--no-report"]


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under `folder` (relative name -> bytes), links not followed: what must stay as it was."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and not p.is_symlink()
    }


@pytest.fixture
def outside(tmp_path) -> Path:
    """A user's folder outside every results folder, with files a link could lend a run."""
    folder = tmp_path / "outside"
    (folder / "cache").mkdir(parents=True)
    (folder / "cache" / "notes.txt").write_text("the user's own file\n")
    (folder / ".nerfaug").write_text(json.dumps({"kind": "results", "created": "2026-01-01T00:00:00+00:00"}))
    (folder / "sweep.json").write_text(json.dumps({"fingerprint": "elsewhere", "config": {}}))
    return folder


def results_folder(path: Path) -> Path:
    """An empty results folder of an earlier sitting (its marker only)."""
    from nerfaug import owned
    from nerfaug.experiment.store import RESULTS_KIND

    return owned.mark(path, RESULTS_KIND)


def link(path: Path, target: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(target, target_is_directory=target.is_dir())


def refused(capsys, command: list[str], named: Path) -> str:
    """Run `nerfaug command`; its refusal: exit 2, one line naming `named` and saying it leads outside."""
    from nerfaug.cli import main

    with pytest.raises(SystemExit) as ended:
        main(command)
    assert ended.value.code == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    said = [line for line in lines if str(named) in line]
    assert said and "leads outside" in said[-1], lines
    return said[-1]


@pytest.mark.parametrize("planted", ["datasets", "datasets/cache"])
def test_run_refuses_a_datasets_folder_linked_out(tmp_path, outside, sphere, capsys, planted):  # noqa: F811
    results = results_folder(tmp_path / "results")
    link(results / planted, outside)
    before = snapshot(outside)
    line = refused(capsys, ["run", "--data", str(sphere), "--out", str(results), *RUN], results / "datasets" / "cache")
    assert str(outside) not in line.split(":")[0]
    assert snapshot(outside) == before
    assert not (results / "runs").exists()  # refused before any run


def test_run_refuses_a_built_in_scenes_folder_linked_out_before_rendering(tmp_path, outside, capsys):
    results = results_folder(tmp_path / "results")
    (results / "datasets" / "cache").mkdir(parents=True)
    rendered = results / "datasets" / "lego-64px"
    link(rendered, outside)
    before = snapshot(outside)
    refused(capsys, ["run", "--scenes", "lego", "--resolution", "64", "--out", str(results), *RUN], rendered)
    assert snapshot(outside) == before
    assert not (results / "runs").exists()


def test_a_cache_entry_linked_out_is_neither_read_nor_replaced(tmp_path, outside, sphere):  # noqa: F811
    from nerfaug.scenes.cache import cache_path, folder_digest, load_split_cached

    cache = tmp_path / "results" / "datasets" / "cache"
    cache.mkdir(parents=True)
    digest = folder_digest(sphere)
    load_split_cached(sphere, "test", 1, outside, digest)  # a genuine entry, written outside
    entry = cache_path(outside, digest, "test", 1)
    link(cache_path(cache, digest, "test", 1), entry)
    before = snapshot(outside)
    with pytest.raises(PathRefused) as error:
        load_split_cached(sphere, "test", 1, cache, digest)
    text = str(error.value)
    assert "\n" not in text and text.startswith(f"{cache / entry.name}: ") and "leads outside" in text, text
    assert snapshot(outside) == before
    assert cache_path(cache, digest, "test", 1).is_symlink()  # not replaced by a file either


@pytest.mark.parametrize("planted", ["datasets", "datasets/24px"])
def test_study_refuses_its_datasets_folder_linked_out_before_rendering(tmp_path, outside, capsys, planted):
    study = tmp_path / "study"
    link(study / planted, outside)
    before = snapshot(outside)
    command = ["study", "--out", str(study), "--engines", "test", "--scenes", "lego", "--resolution", "24"]
    refused(capsys, [*command, "--trials", "1", "--device", "cpu"], study / "datasets" / "24px" / "lego")
    assert snapshot(outside) == before


def test_study_refuses_an_engine_folder_linked_out(tmp_path, outside, sphere, capsys):  # noqa: F811
    study = tmp_path / "study"
    link(study / "test", outside)
    before = snapshot(outside)
    refused(capsys, ["study", "--out", str(study), *toy_study(sphere)], study / "test")
    assert snapshot(outside) == before


def test_run_refuses_a_marker_linked_out(tmp_path, outside, sphere, capsys):  # noqa: F811
    """A marker linked to an outside results folder's would lend this folder its ownership."""
    results = tmp_path / "results"
    link(results / ".nerfaug", outside / ".nerfaug")
    before = snapshot(outside)
    refused(capsys, ["run", "--data", str(sphere), "--out", str(results), *RUN], results / ".nerfaug")
    assert snapshot(outside) == before
    assert sorted(p.name for p in results.iterdir()) == [".nerfaug"]


def test_an_owned_folders_marker_linked_out_is_refused_and_nothing_removed(tmp_path, outside):
    from nerfaug import owned

    folder = tmp_path / "export"
    folder.mkdir()
    (folder / "transforms.json").write_text("{}")
    link(folder / ".nerfaug", outside / ".nerfaug")
    with pytest.raises(PathRefused) as error:
        owned.remove_owned(folder, "results", "choose another folder", holds=["*"])
    assert str(error.value).startswith(f"{folder / '.nerfaug'}: ") and "leads outside" in str(error.value)
    assert (folder / "transforms.json").is_file() and (outside / ".nerfaug").is_file()
