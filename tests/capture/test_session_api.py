"""The session's API beyond proposing: the one training loop (`train_for`: chunks, a save every
`checkpoint_every` seconds and at the end, a clean stop), a session made from image files as
captured (`from_files`, `add_files`: what the service's uploads become), and `summary()`, the same
whether the model is loaded or only the folder is read."""

import itertools
import json
import signal
import subprocess
import sys

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.capture import CaptureSession, Intrinsics, SessionFolder, SessionSettings
from nerfaug.capture import session as capture_session
from nerfaug.capture.images import ImageFile
from nerfaug.capture.requests import RequestError
from nerfaug.data import DatasetError, load_dataset
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

from .test_constraints import SIZE, tiny_dataset

SETTINGS = SessionSettings(engine="test", seed=3, radius=4.03)


@pytest.fixture
def session(tmp_path) -> CaptureSession:
    return CaptureSession.create(tiny_dataset(tmp_path / "data"), tmp_path / "run", SETTINGS)


def saved_step(session) -> int:
    return json.loads((session.run_dir / "session.json").read_text())["step"]


def test_train_for_saves_every_period_and_at_the_end(session, monkeypatch):
    # A clock that advances one second per reading: once at the start, once after each 10-step
    # chunk and once after each save, so with a 2 s period the session saves every 20 steps.
    monkeypatch.setattr(capture_session, "monotonic", itertools.count().__next__)
    saves = []
    save = CaptureSession.save
    monkeypatch.setattr(CaptureSession, "save", lambda self: saves.append(self.step) or save(self))
    last = session.train_for(45, checkpoint_every=2.0)
    assert saves == [20, 40, 45]
    assert last["step"] == 45 == session.step == saved_step(session) == session.saved_step


def test_train_for_stops_at_a_chunk_boundary_and_saves(session):
    chunks = []
    last = session.train_for(100, checkpoint_every=1e9, stop=lambda: len(chunks) >= 2, each=chunks.append)
    assert [entry["step"] for entry in chunks] == [10, 20]
    assert last == chunks[-1] and session.step == 20 == saved_step(session)


@pytest.mark.parametrize("seconds", [0, -1.0, float("nan")])
def test_train_for_refuses_a_period_not_above_zero_before_training(session, seconds):
    with pytest.raises(RequestError, match=r"^checkpoint_every .*: must be > 0$"):
        session.train_for(10, checkpoint_every=seconds)
    assert session.step == 0


def png(seed: int) -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    return iio.imwrite("<bytes>", pixels, extension=".png")


def test_a_session_from_image_files_and_their_poses(tmp_path):
    poses = sample_uniform_poses(5, torch.Generator().manual_seed(4), radius=4.03)
    files = [ImageFile(f"shot_{i}", ".png", png(i)) for i in range(5)]
    fx = 0.5 * SIZE / np.tan(0.5 * BLENDER_CAMERA_ANGLE_X)
    k = Intrinsics(width=SIZE, height=SIZE, fx=fx)
    with pytest.raises(ValueError, match="^poses: 3 poses for 4 images; give one pose per image$"):
        CaptureSession.from_files(files[:4], poses[:3], k, tmp_path / "refused", SETTINGS)
    assert not (tmp_path / "refused").exists()
    session = CaptureSession.from_files(files[:4], poses[:4], k, tmp_path / "run", SETTINGS)
    assert session.state.intrinsics.fx == pytest.approx(fx) and session.summary().views == 4
    assert session.add_files(files[4:], poses[4:]) == ["shot_4"]
    stored = session.dataset_dir / session.state.dataset.folder / "shot_4.png"
    assert stored.read_bytes() == files[4].data  # byte for byte
    grown = load_dataset(session.dataset_dir)
    assert torch.allclose(grown.cameras.camera_to_world, poses, atol=1e-6)
    # Two files of one name: the second would replace the first, so both calls refuse them.
    twice = [files[0], ImageFile("shot_0", ".jpg", files[1].data)]
    with pytest.raises(DatasetError, match=r"^images\[1\] \(shot_0.jpg\): the same name as images\[0\]$"):
        CaptureSession.from_files(twice, poses[:2], k, tmp_path / "twice", SETTINGS)
    assert not (tmp_path / "twice").exists()
    renamed = [ImageFile(f"again_{f.name}", f.suffix, f.data) for f in twice]
    with pytest.raises(DatasetError, match="the same name as images"):
        session.add_files(renamed, poses[:2])
    # A name that is not a view's would be written outside the folder the files are staged in.
    with pytest.raises(DatasetError, match=r"^images\[0\] \(\.\./outside\.png\): a file name may hold only"):
        session.add_files([ImageFile("../outside", ".png", files[1].data)], poses[:1])
    with pytest.raises(DatasetError, match=r"^images\[0\] \(shot_9\.txt\): the file name must end in one of"):
        session.add_files([ImageFile("shot_9", ".txt", files[1].data)], poses[:1])
    assert session.summary().views == 5 and len(load_dataset(session.dataset_dir)) == 5


def png_of(shape: tuple[int, ...]) -> bytes:
    return iio.imwrite("<bytes>", np.zeros(shape, np.uint8), extension=".png")


@pytest.mark.parametrize(
    ("data", "problem"),
    [
        (b"\x89PNG\r\n\x1a\n" + bytes(30), "cannot read image (its bytes do not decode as .png)"),
        (png_of((SIZE, SIZE)), "an image must have shape (H, W, 3) or (H, W, 4), channels last (RGB or RGBA)"),
        (png_of((SIZE, 2 * SIZE, 3)), f"image is {2 * SIZE}x{SIZE} pixels but the dataset's camera is {SIZE}x{SIZE}"),
    ],
)
def test_image_files_are_decoded_and_checked_before_a_session_is_made_or_grows(session, tmp_path, data, problem):
    poses = sample_uniform_poses(2, torch.Generator().manual_seed(4), radius=4.03)
    fx = 0.5 * SIZE / np.tan(0.5 * BLENDER_CAMERA_ANGLE_X)
    files = [ImageFile("good", ".png", png(0)), ImageFile("bad", ".png", data)]
    with pytest.raises(DatasetError) as refused:
        CaptureSession.from_files(files, poses, Intrinsics(width=SIZE, height=SIZE, fx=fx), tmp_path / "new", SETTINGS)
    assert str(refused.value).startswith(f"images[1] (bad.png): {problem}")
    assert not (tmp_path / "new").exists()
    views = session.summary().views
    with pytest.raises(DatasetError, match=r"^images\[1\] \(bad.png\): "):
        session.add_files(files, poses)
    assert session.summary().views == views and not any(session.dataset_dir.rglob("good.png"))


def test_the_summary_is_the_same_with_and_without_the_model(session):
    session.train(3)
    session.save()
    loaded, folder = session.summary(), SessionFolder.open(session.run_dir).summary()
    assert loaded.last_losses and [h["step"] for h in loaded.last_losses] == [1, 2, 3]
    assert folder.last_losses == []
    assert loaded.model_dump(exclude={"last_losses"}) == folder.model_dump(exclude={"last_losses"})
    assert (loaded.id, loaded.step, loaded.views) == ("run", 3, 4)


def test_a_session_names_what_asks_for_another_session(session, tmp_path):
    """`SessionState.differences`: the dataset first, then the settings given, then the split; a
    dataset but no split compares the split a new session on it would train on."""
    state, data = session.state, tmp_path / "data"
    assert state.differences(state.settings()) == []  # every setting: its own
    assert state.differences(state.settings(), split=state.source.split, data=data) == []
    other = SessionSettings(engine="cpu", seed=4, radius=4.03)
    assert state.differences(other, {"engine"}) == [("engine", "cpu", "test")]
    elsewhere = tiny_dataset(tmp_path / "elsewhere")
    found = state.differences(other, {"seed"}, split="initial", data=elsewhere)
    assert found == [("data", str(elsewhere), state.source.data_dir), ("seed", "4", "3"), ("split", "initial", "train")]


KILLED_ADD = """
import os, signal, sys

replace = os.replace


def killed_before_the_image_lands(source, target, *args, **kwargs):
    if str(target).endswith(".png"):
        os.kill(os.getpid(), signal.SIGKILL)
    return replace(source, target, *args, **kwargs)


os.replace = killed_before_the_image_lands
from nerfaug.cli import main

main(["add", sys.argv[1], "--images", sys.argv[2], "--poses", sys.argv[3], "--steps", "0", "--device", "cpu"])
"""


def test_an_add_killed_mid_write_leaves_a_temporary_image_the_next_add_removes(session, tmp_path):
    """`nerfaug add` SIGKILLed while its image is a temporary file beside its final name: the
    next addition removes that file (named as nerfaug's atomic writes name theirs), and only such
    files: a user's files that look alike stay."""
    (tmp_path / "shots").mkdir()
    (tmp_path / "shots" / "new_a.png").write_bytes(png(7))
    pose = sample_uniform_poses(1, torch.Generator().manual_seed(9))[0].tolist()
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"frames": [{"file_path": "new_a", "transform_matrix": pose}]}))
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_ADD, str(session.run_dir), str(tmp_path / "shots"), str(poses)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    images = session.run_dir / "dataset" / "train"
    left = [p.name for p in images.iterdir() if p.name.endswith(".tmp")]
    assert len(left) == 1 and left[0].startswith(".new_a.png."), sorted(p.name for p in images.iterdir())
    for name in ("notes.tmp", ".notes.tmp", ".new_a.png.tmp"):  # not nerfaug's temporary files
        (images / name).write_text("mine")
    reopened = CaptureSession.open(session.run_dir)
    assert reopened.add_views(tmp_path / "shots", poses) == ["new_a"]
    assert sorted(p.name for p in images.iterdir() if p.name.endswith(".tmp")) == [
        ".new_a.png.tmp",
        ".notes.tmp",
        "notes.tmp",
    ]


def test_an_image_linked_out_of_the_captures_folder_is_refused_before_it_is_read(session, tmp_path):
    (tmp_path / "shots").mkdir()
    (tmp_path / "elsewhere.png").write_bytes(png(8))
    (tmp_path / "shots" / "new_b.png").symlink_to(tmp_path / "elsewhere.png")
    pose = sample_uniform_poses(1, torch.Generator().manual_seed(10))
    with pytest.raises(DatasetError, match=r"shots/new_b\.png: image leads outside .*shots, the folder it must"):
        session.add_views(tmp_path / "shots", pose)
    assert len(session.frames()) == 4
