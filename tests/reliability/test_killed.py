"""A command killed (SIGKILL: no handler, no cleanup runs) at the worst moment, then the next
command on the same folder: what the killed one wrote is recorded or undone, and what the next
one says is true. The kill is simulated in this process: the write after the chosen point raises
an exception no code of nerfaug catches, and the cleanup a kill skips is switched off."""

import json

import pytest
from harness import copy, run_cli, write_images

from nerfaug.capture import CaptureSession
from nerfaug.capture import session as capture_session


class Killed(BaseException):
    """What SIGKILL would be, were it an exception: nothing catches it."""


def _kill_at_first_save(monkeypatch) -> None:
    save = CaptureSession.save
    calls = []

    def killed_save(self):
        if not calls:
            calls.append(1)
            raise Killed
        return save(self)

    monkeypatch.setattr(CaptureSession, "save", killed_save)


def test_an_add_killed_once_its_listing_is_written_is_recorded_at_the_next_open(bases, tmp_path, monkeypatch):
    run = copy(bases.session, tmp_path / "run")
    test = json.loads((bases.dataset / "transforms_test.json").read_text())
    names = ["capture_000_00", "capture_000_01"]
    frames = [{"file_path": f"./{n}", "transform_matrix": f["transform_matrix"]} for n, f in zip(names, test["frames"])]
    (tmp_path / "poses.json").write_text(json.dumps({"camera_angle_x": test["camera_angle_x"], "frames": frames}))
    images = write_images(tmp_path / "captures", names)
    _kill_at_first_save(monkeypatch)  # add writes the images and the listing, then saves: killed there
    killed = run_cli(
        ["add", run, "--images", images, "--poses", tmp_path / "poses.json", "--steps", "0", "--device", "cpu"]
    )
    assert killed.escaped is not None and "Killed" in killed.escaped
    assert json.loads((run / "session.json").read_text())["additions"] == []  # as the kill left it

    again = run_cli(["train", run, "--steps", "5", "--device", "cpu"])
    assert again.code == 0, again.err
    state = json.loads((run / "session.json").read_text())
    assert [a["names"] for a in state["additions"]] == [names]
    assert "stopped before saving" in state["additions"][0]["warnings"][0]
    assert state["views_in_model"] == 10 + len(names)
    assert len(CaptureSession.open(run).trainer.train_views) == 10 + len(names)


def _sparse_start(bases, run) -> list:
    """`nerfaug train`'s arguments for a 2-step sparse start of 3 views into `run`."""
    options = ["--engine", "test", "--steps", "2", "--initial", "3", "--device", "cpu"]
    return ["train", bases.dataset, "--out", run, *options]


def test_a_sparse_start_killed_while_creating_is_not_called_a_session_that_lost_its_file(bases, tmp_path, monkeypatch):
    run = tmp_path / "run"
    argv = _sparse_start(bases, run)
    _kill_at_first_save(monkeypatch)
    monkeypatch.setattr(capture_session, "remove_unfinished", lambda *args: None)  # a kill runs no cleanup
    killed = run_cli(argv)
    assert killed.escaped is not None and "Killed" in killed.escaped
    assert run.is_dir() and not (run / "session.json").exists()
    monkeypatch.undo()

    again = run_cli(argv)
    said = again.err + again.out
    assert "restore" not in said, said  # there never was a session.json to restore
    assert again.code == 0, said  # what the stopped creation left is nerfaug's alone: made anew
    assert json.loads((run / "session.json").read_text())["step"] == 2


@pytest.mark.parametrize("own", ["notes.txt", "dataset/notes.txt"])
def test_a_users_file_in_a_folder_left_by_a_stopped_creation_is_never_removed(bases, tmp_path, monkeypatch, own):
    run = tmp_path / "run"
    argv = _sparse_start(bases, run)
    _kill_at_first_save(monkeypatch)
    monkeypatch.setattr(capture_session, "remove_unfinished", lambda *args: None)
    run_cli(argv)
    monkeypatch.undo()
    (run / own).write_text("mine")

    again = run_cli(argv)
    assert again.code == 2, again.err
    lines = again.error_lines()
    assert len(lines) == 1 and own.split("/")[-1] in lines[0] and "restore" not in lines[0], again.err
    assert (run / own).read_text() == "mine"
