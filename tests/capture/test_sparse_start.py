"""A sparse start from any dataset (`nerfaug train DATA --initial N --layout K`): N views on one
half of the object, as the paper's experiments start; the others the candidate pool `propose`
chooses from by their own names, so that `add` takes the chosen images from the dataset."""

import json
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, SessionSettings
from nerfaug.capture.requests import RequestError, SparseStart
from nerfaug.cli import main
from nerfaug.data import write_blender_split
from nerfaug.data.views import Views
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, angles_from_pose, sample_uniform_poses

from ..data.test_captured_formats import llff_fixture

SIZE = 8
VIEWS = 16


def all_round_dataset(root: Path) -> Path:
    """A Blender dataset of `VIEWS` views uniform over the hemisphere, all the way round."""
    generator = torch.Generator().manual_seed(3)
    poses = sample_uniform_poses(VIEWS, generator)
    images = (torch.rand(VIEWS, SIZE, SIZE, 3, generator=generator) * 255).round() / 255
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    write_blender_split(root, "train", Views(cameras, images, [f"./train/r_{i}" for i in range(VIEWS)]))
    return root


def azimuths_deg(run: Path) -> torch.Tensor:
    frames = json.loads((run / "dataset" / "transforms_train.json").read_text())["frames"]
    azimuth, _, _ = angles_from_pose(torch.tensor([f["transform_matrix"] for f in frames]))
    return torch.rad2deg(azimuth) % 360


def test_train_starts_from_a_few_views_on_one_half_and_proposes_from_the_rest(tmp_path, capsys):
    data = all_round_dataset(tmp_path / "data")
    run = tmp_path / "run"
    common = ["--steps", "2", "--engine", "test", "--seed", "1", "--device", "cpu", "--centre", "0", "0", "0"]
    main(["train", str(data), "--out", str(run), "--initial", "4", *common])
    assert capsys.readouterr().out.startswith("training on 4 of the 16 views of split 'train'")
    state = json.loads((run / "session.json").read_text())
    pool = json.loads((run / state["pool"]).read_text())["frames"]
    started, kept = state["start"]["names"], state["start"]["held_out"]
    # No test split: a quarter of the views is kept apart for testing, neither initial nor candidates.
    assert state["start"] == {"initial": 4, "layout": 0, "of": 16, "names": started, "held_out": kept}
    assert len(started) == 4 and len(kept) == 4 and len(pool) == 8
    named = [Path(n).stem for n in started + kept] + [Path(f["file_path"]).stem for f in pool]
    assert sorted(named) == sorted(f"r_{i}" for i in range(VIEWS))
    # One half: every initial view within 180 degrees of azimuth, counted from the half's start (90).
    assert bool((((azimuths_deg(run) - 90) % 360) < 180 + 1e-3).all())

    poses = tmp_path / "poses.json"
    main(["propose", str(run), "--n", "2", "--n-candidates", "5", "--allow-empty", "--out", str(poses)])
    chosen = [Path(f["file_path"]).stem for f in json.loads(poses.read_text())["frames"]]
    assert set(chosen) <= {Path(f["file_path"]).stem for f in pool}  # the pool's views, by their names
    assert CaptureSession.open(run).proposals[-1].candidates == "pool"
    main(["add", str(run), "--images", str(data / "train"), "--poses", str(poses), "--steps", "0"])
    session = CaptureSession.open(run)
    assert len(session.cameras) == 6
    again = session.propose(session_request(n=6), map=False)  # the 6 pool views not yet added
    assert sorted(again.names) == sorted(set(Path(f["file_path"]).stem for f in pool) - set(chosen))


def session_request(**fields):
    from nerfaug.capture import ProposalRequest

    return ProposalRequest(allow_empty=True, min_separation=0.0, **fields)


def test_layouts_turn_the_half_and_refusals_name_the_option(tmp_path, capsys):
    data = all_round_dataset(tmp_path / "data")
    settings = SessionSettings(engine="test", centre=(0.0, 0.0, 0.0))
    first = CaptureSession.create(data, tmp_path / "a", settings, start=SparseStart(initial=3, layout=0))
    other = CaptureSession.create(data, tmp_path / "b", settings, start=SparseStart(initial=3, layout=1))
    assert set(first.state.start["names"]) != set(other.state.start["names"])
    for argv, says in (
        (["--initial", "40"], "nerfaug: --initial 40: only "),
        (["--layout", "3", "--initial", "2"], "nerfaug: --layout 3: must be < 3"),
        (["--initial", "0"], "nerfaug: --initial 0: must be >= 1"),
    ):
        with pytest.raises(SystemExit) as done:
            main(["train", str(data), "--out", str(tmp_path / "c"), "--engine", "test", "--steps", "0", *argv])
        assert done.value.code == 2
        said = capsys.readouterr()
        assert said.err.strip().startswith(says) and "training on" not in said.out
        assert not (tmp_path / "c").exists()


def test_a_captured_set_starts_sparse_too(tmp_path):
    data = llff_fixture(tmp_path / "llff", n=12, masks=False)
    session = CaptureSession.create(
        data, tmp_path / "run", SessionSettings(engine="test", estimate_up=True), start=SparseStart(initial=3)
    )
    assert len(session.cameras) == 3
    pool = json.loads((tmp_path / "run" / "pool.json").read_text())["frames"]
    # 3 of the 12 kept apart for testing (no test split), 3 initial: 6 candidates.
    assert len(session.state.start["held_out"]) == 3
    assert len(pool) == 6 and all(Path(f["file_path"]).stem.startswith("IMG_") for f in pool)
    with pytest.raises(
        RequestError,
        match=r"initial 12: only \d views lie in the half .*\(azimuths [\d.]+ to [\d.]+ degrees\); 12 are needed "
        r"\(of 12 views of .*poses_bounds.npy, 3 of them held out for testing\)",
    ):
        CaptureSession.create(data, tmp_path / "all", SessionSettings(engine="test"), start=SparseStart(initial=12))
