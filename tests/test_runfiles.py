"""`nerfaug.runfiles`, the one way into a run folder: names inside it (a link within it too) are
opened; a name that leads out (a link, `..`, an absolute name, a link loop) is refused in one line
naming the file, for reading and writing alike, and nothing outside is read, made or written."""

from __future__ import annotations

import os

import pytest

from nerfaug import runfiles
from nerfaug.errors import PathRefused


@pytest.fixture
def run(tmp_path):
    (tmp_path / "run" / "sub").mkdir(parents=True)
    (tmp_path / "run" / "a.json").write_text('{"a": 1}')
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "b.json").write_text('{"b": 2}')
    return tmp_path / "run"


def test_names_inside_the_run_folder_are_read_and_written(run):
    (run / "same.json").symlink_to(run / "a.json")  # a link that stays inside is followed
    assert runfiles.read_json(run, "same.json") == {"a": 1}
    written = runfiles.write_json(run, "sub/c.json", {"c": 3})
    assert written == (run / "sub" / "c.json").resolve() and runfiles.read_json(run, "sub/c.json") == {"c": 3}
    assert runfiles.folder(run, "new/deeper").is_dir()
    with runfiles.open_lock(run, ".lock") as handle:
        handle.write("held")
    assert runfiles.read_text(run, ".lock") == "held"


@pytest.mark.parametrize("kind", ["file link", "folder link", "dotdot", "absolute", "loop"])
def test_a_name_leading_out_is_refused_for_every_use_and_nothing_outside_changes(run, tmp_path, kind):
    outside = tmp_path / "outside"
    name = {"file link": "b.json", "folder link": "sub2/b.json", "dotdot": "../outside/b.json"}.get(kind, "b.json")
    if kind == "file link":
        (run / "b.json").symlink_to(outside / "b.json")
    elif kind == "folder link":
        (run / "sub2").symlink_to(outside, target_is_directory=True)
    elif kind == "absolute":
        name = str(outside / "b.json")
    elif kind == "loop":
        (run / "b.json").symlink_to(run / "b.json")
    uses = [
        lambda: runfiles.read_json(run, name),
        lambda: runfiles.read_bytes(run, name),
        lambda: runfiles.write_json(run, name, {"x": 0}),
        lambda: runfiles.write_bytes(run, name, b"x"),
        lambda: runfiles.open_lock(run, name),
        lambda: runfiles.folder(run, name),
    ]
    for use in uses:
        with pytest.raises(PathRefused) as refused:
            use()
        message = str(refused.value)
        assert message.startswith(f"{run / name}: this path ") and "\n" not in message
        assert (
            "cannot be followed" if kind == "loop" else f"leads outside {run}, the folder it must stay in"
        ) in message
        if kind.endswith("link"):
            assert str(outside) not in message  # where a link leads is never told
    assert sorted(os.listdir(outside)) == ["b.json"] and (outside / "b.json").read_text() == '{"b": 2}'
    assert not runfiles.is_file(run, name) and runfiles.is_file(run, "a.json")
