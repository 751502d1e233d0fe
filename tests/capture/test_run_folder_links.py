"""Nothing inside a run folder leads out (`nerfaug.runfiles`): a symbolic link planted in a
capture session's folder in place of one of its files or folders, leading to an outside copy, is
refused by the command in one line naming the file (exit 2), and nothing outside is read or
written, nor anything of the session changed. Per file kind: the candidate pool, the proposals
folder, the TensorBoard log, session.json, the checkpoint, the lock, the dataset copy (and its
image folder, written by `add`), an earlier export's image folder; and an experiment run's files
(result, selection, metrics, history, view arrays, renders).

The session: 16 views of 8x8 pixels, a sparse start of 4 (so it has a pool), the "test" engine."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfaug.capture import CaptureSession
from nerfaug.cli import main
from nerfaug.errors import PathRefused
from nerfaug.experiment import runfolder, store
from nerfaug.hemisphere import sample_uniform_poses

from .test_sparse_start import all_round_dataset

COMMON = ["--engine", "test", "--seed", "1", "--device", "cpu", "--centre", "0", "0", "0"]


@pytest.fixture
def run(tmp_path) -> Path:
    data = all_round_dataset(tmp_path / "data")
    main(["train", str(data), "--out", str(tmp_path / "run"), "--initial", "4", "--steps", "2", *COMMON])
    return tmp_path / "run"


def files_of(folder: Path, leave_out: tuple[str, ...] = ()) -> dict[str, bytes | None]:
    """Every name under `folder` (links not followed) and the bytes of each file."""
    found = {}
    for path in sorted(folder.rglob("*")):
        name = path.relative_to(folder).as_posix()
        if name not in leave_out:
            found[name] = path.read_bytes() if path.is_file() and not path.is_symlink() else None
    return found


def plant(run: Path, name: str, outside: Path) -> Path:
    """Move the run's `name` (a file or folder; an empty folder when it has none) to `outside`, and
    put a link to it in its place: the user's outside copy, which nothing may touch. ".lock" links
    to a file of the user's (which taking the lock would truncate and rewrite), never moved."""
    target = outside / Path(name).name
    outside.mkdir(parents=True, exist_ok=True)
    if name == ".lock":
        target.write_text("the user's own file\n")
        (run / name).unlink(missing_ok=True)
    elif (run / name).exists():
        shutil.move(run / name, target)
    else:
        target.mkdir()
    (run / name).symlink_to(target, target_is_directory=target.is_dir())
    return target


def refused(capsys, argv: list[str], run: Path, name: str, outside: Path) -> str:
    """`nerfaug ARGV` refused: exit 2, one line naming RUN/NAME and where it must stay, never the outside."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    assert stopped.value.code == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1, error
    assert f"{run / name}" in error and f"leads outside {run}" in error, error
    assert str(outside) not in error, error
    return error


@pytest.mark.parametrize(
    ("name", "command"),
    [
        ("pool.json", "propose"),
        ("proposals", "propose"),
        ("tensorboard", "train-logged"),
        ("session.json", "train"),
        ("checkpoint.pt", "train"),
        (".lock", "train"),
        ("dataset", "propose"),
    ],
)
def test_a_link_out_of_the_run_folder_is_refused_naming_it_and_nothing_outside_is_touched(
    run, tmp_path, capsys, name, command
):
    outside = tmp_path / "outside"
    poses = tmp_path / "poses.json"
    plant(run, name, outside)
    before_outside, before_run = files_of(outside), files_of(run, leave_out=(".lock",))
    argv = {
        "propose": ["propose", str(run), "--n", "1", "--n-candidates", "5", "--allow-empty", "--out", str(poses)],
        "train": ["train", str(run), "--steps", "4", "--device", "cpu"],
        "train-logged": ["train", str(run), "--steps", "4", "--device", "cpu", "--logger", "tensorboard"],
    }[command]
    shown = "proposals/proposal_000.json" if name == "proposals" else name
    refused(capsys, argv, run, shown, outside)
    assert files_of(outside) == before_outside  # nothing outside read into the session, written or removed
    assert files_of(run, leave_out=(".lock",)) == before_run  # the session as it was
    assert not poses.exists()


def test_a_new_session_is_never_read_from_a_session_json_linked_in_from_outside(run, tmp_path, capsys):
    # A folder holding only a link to another session's session.json: `train DATA --out NEW` would
    # read it as NEW's session (its `created` carried over) and train from it.
    new, outside = tmp_path / "new", tmp_path / "outside"
    outside.mkdir()
    shutil.copy(run / "session.json", outside / "session.json")
    new.mkdir()
    (new / "session.json").symlink_to(outside / "session.json")
    before = files_of(outside)
    argv = ["train", str(tmp_path / "data"), "--out", str(new), "--steps", "2", *COMMON]
    refused(capsys, argv, new, "session.json", outside)
    assert files_of(outside) == before and sorted(p.name for p in new.iterdir()) == ["session.json"]


def test_captures_are_never_written_through_a_link_in_the_dataset_copy(run, tmp_path):
    session = CaptureSession.open(run)
    images = run / "dataset" / session.state.dataset.folder
    outside = tmp_path / "outside"
    plant(run, images.relative_to(run).as_posix(), outside)
    before = files_of(outside)
    shots = tmp_path / "shots"
    shots.mkdir()
    shutil.copy(tmp_path / "data" / "train" / "r_0.png", shots / "new_view.png")
    pose = sample_uniform_poses(1, torch.Generator().manual_seed(9), radius=4.03)
    with pytest.raises(PathRefused, match=r"new_view\.png: this path leads outside") as error:
        session.add_views(shots, pose)
    assert "\n" not in str(error.value) and str(outside) not in str(error.value)
    assert files_of(outside) == before
    assert len(json.loads((run / "dataset" / "transforms_train.json").read_text())["frames"]) == 4


def test_an_export_is_never_written_through_a_link_in_an_earlier_export(run, tmp_path, capsys):
    export, outside = tmp_path / "export", tmp_path / "outside"
    main(["export", str(run), "--out", str(export)])
    plant(export, "images", outside)  # an earlier export's images moved out, a link in their place
    before = {p.name: (p.stat().st_ino, p.read_bytes()) for p in outside.rglob("*.png")}
    assert len(before) == 4
    refused(capsys, ["export", str(run), "--out", str(export)], export, "images", outside)
    assert {p.name: (p.stat().st_ino, p.read_bytes()) for p in outside.rglob("*.png")} == before  # not even replaced


# --- an experiment run's folder ------------------------------------------------------------------


def experiment_run(folder: Path) -> Path:
    """A run folder with every file an experiment run writes that is read back."""
    store.write_result(folder, {key: {"psnr": 20.0} if key == "metrics" else "x" for key in store.RESULT_KEYS})
    runfolder.write_metrics(folder, {"psnr": 20.0})
    runfolder.write_history(folder, [{"step": 1, "loss": 0.5}])
    runfolder.write_config(folder, {"scene": "lego"}, {"steps": 1})
    runfolder.write_progress(folder, 1)
    runfolder.write_error(folder, "why")
    poses = np.tile(np.eye(4), (3, 1, 1))
    runfolder.write_selection(folder, {"method": "ours", "indices": [0], "scores": [1, 2, 3]}, ["a"], poses, poses)
    runfolder.write_view_uncertainty(
        folder, {k: np.zeros((2, 2, 3) if k == "render" else (2, 2)) for k in "render error entropy".split()}
    )
    (folder / "renders").mkdir()
    (folder / "renders" / "000_render.png").write_bytes(b"png")
    return folder


READERS = {
    "result.json": lambda f: store.read_result(f),
    "metrics.json": runfolder.read_metrics,
    "history.json": runfolder.read_history,
    "config.json": runfolder.read_config,
    "progress.json": runfolder.read_progress,
    "error.json": runfolder.read_error,
    "selection.json": runfolder.read_selection,
    "view_uncertainty": runfolder.read_view_uncertainty,
    "renders": runfolder.render_paths,
}
WRITERS = {
    "result.json": lambda f: store.write_result(f, {k: {"psnr": 1.0} for k in store.RESULT_KEYS}),
    "metrics.json": lambda f: runfolder.write_metrics(f, {"psnr": 1.0}),
    "history.json": lambda f: runfolder.write_history(f, []),
    "config.json": lambda f: runfolder.write_config(f, {}, {}),
    "progress.json": lambda f: runfolder.write_progress(f, 2),
    "error.json": lambda f: runfolder.write_error(f, "other"),
    "selection.json": lambda f: runfolder.write_selection(
        f, {"method": "m", "indices": [0], "scores": [1]}, ["a"], np.eye(4)[None], np.eye(4)[None]
    ),
    "view_uncertainty": lambda f: runfolder.write_view_uncertainty(f, {"entropy": np.ones((2, 2))}),
}


@pytest.mark.parametrize("name", sorted(READERS))
def test_an_experiment_runs_file_linked_outside_is_neither_read_nor_written(tmp_path, name):
    folder = experiment_run(tmp_path / "runs" / "lego" / "ours" / "trial_000")
    outside = tmp_path / "outside"
    assert READERS[name](folder) is not None  # read while it is the run's own
    plant(folder, name, outside)
    before = files_of(outside)
    with pytest.raises(PathRefused, match=f"{name}.*: this path leads outside {folder}, the folder"):
        READERS[name](folder)
    if name in WRITERS:
        with pytest.raises(PathRefused, match="leads outside"):
            WRITERS[name](folder)
    assert files_of(outside) == before
