"""`nerfaug uncertainty RUN --poses POSES --out DIR`: a figure and arrays per pose, in world units,
and an --out that is the user's is refused."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfaug.capture import CaptureSession
from nerfaug.cli import main
from nerfaug.hemisphere import pose_from_angles

from .test_constraints import tiny_dataset


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("uncertainty")
    # Twice NeRF-synthetic's scale: depths in world units are twice the engine's.
    session = CaptureSession.create(tiny_dataset(tmp / "data"), tmp / "run", preset="test", seed=2, radius=8.06)
    session.train(3)
    session.save()
    return tmp / "run"


def poses_file(path: Path, n: int = 2) -> Path:
    poses = pose_from_angles(torch.linspace(0.3, 2.0, n), torch.full((n,), 0.8), 8.06)
    frames = [{"file_path": f"./look_{i}", "transform_matrix": p.tolist()} for i, p in enumerate(poses)]
    path.write_text(json.dumps({"frames": frames}))
    return path


def test_the_command_writes_a_figure_and_arrays_per_pose(run, tmp_path, capsys):
    out = tmp_path / "images"
    args = ["uncertainty", str(run), "--poses", str(poses_file(tmp_path / "poses.json")), "--out", str(out)]
    main([*args, "--width", "6", "--fisher-width", "3", "--device", "cpu"])
    for name in ("look_0", "look_1"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
        assert np.load(out / f"{name}_rgb.npy").shape == (6, 6, 3)
        assert np.load(out / f"{name}_entropy.npy").shape == (6, 6)
        assert np.load(out / f"{name}_depth.npy").shape == (6, 6)
        assert np.load(out / f"{name}_fisher.npy").shape == (3, 3)
        assert np.load(out / f"{name}_pose.npy").shape == (4, 4)
    assert "look_1: mean entropy" in capsys.readouterr().out
    main([*args, "--width", "6", "--no-fisher", "--device", "cpu"])  # its own folder: written again


def test_depth_is_in_world_units(run):
    session = CaptureSession.open(run)
    pose = pose_from_angles(torch.tensor([1.0]), torch.tensor([0.7]), 8.06)
    maps = session.uncertainty_maps(pose, width=5, fisher=False)[0]
    assert maps.fisher is None
    engine = session.hemisphere.to_engine(pose)
    camera = session.template(5, 5)
    from nerfaug.selection.candidates import with_poses

    rendered = session.trainer.model.render_image(with_poses(camera, engine), 0)
    assert session.hemisphere.scale == pytest.approx(2.0, rel=1e-3)
    np.testing.assert_allclose(maps.depth, rendered["depth"].numpy() * session.hemisphere.scale, rtol=1e-4)


def test_a_users_folder_is_refused(run, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(SystemExit) as done:
        main(["uncertainty", str(run), "--poses", str(poses_file(tmp_path / "p.json")), "--out", str(mine)])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"nerfaug: {mine}: not empty") and "\n" not in err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
