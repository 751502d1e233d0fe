"""A simulated capture (`nerfaug.capture.simulate.render_proposals`): its numbers are refused
before anything is read, a camera Blender cannot render (non-square pixels, an off-centre
principal point) is refused naming session.json's field, and Blender is asked for the session's
image size and field of view, one PNG per proposed pose."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, SessionSettings, simulate
from nerfaug.capture.requests import RequestError
from nerfaug.data import Views, write_blender_split
from nerfaug.errors import DatasetError
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

SIZE = 8


@pytest.fixture
def session(tmp_path) -> Path:
    """A tiny session (4 random 8x8 views, the "test" engine, untrained) and its folder."""
    generator = torch.Generator().manual_seed(0)
    poses = sample_uniform_poses(4, generator)
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    images = torch.rand(4, SIZE, SIZE, 3, generator=generator)
    write_blender_split(tmp_path / "data", "train", Views(cameras, images, [f"./train/r_{i}" for i in range(4)]))
    CaptureSession.create(tmp_path / "data", tmp_path / "run", SessionSettings(engine="test")).save()
    return tmp_path / "run"


def poses_file(path: Path, n: int = 2) -> Path:
    poses = sample_uniform_poses(n, torch.Generator().manual_seed(1))
    frames = [{"file_path": f"./new/p_{i}", "transform_matrix": poses[i].tolist()} for i in range(n)]
    path.write_text(json.dumps({"frames": frames}))
    return path


@pytest.mark.parametrize(("name", "value"), [("samples", 0), ("seed", -1), ("threads", 0)])
def test_numbers_are_refused_before_the_session_is_read(tmp_path, name, value):
    settings = {"samples": 16, "seed": 0, "threads": 2, name: value}
    with pytest.raises(RequestError) as refused:
        simulate.render_proposals(tmp_path / "no-run", tmp_path / "no.json", "lego", tmp_path / "out", **settings)
    assert refused.value.argument == name and refused.value.value == value


@pytest.mark.parametrize(("field", "factor"), [("fy", 1.5), ("cx", 0.8), ("cy", 1.2)])
def test_a_camera_blender_cannot_render_is_refused_naming_the_field(session, tmp_path, monkeypatch, field, factor):
    state = json.loads((session / "session.json").read_text())
    state["intrinsics"][field] = state["intrinsics"][field] * factor
    (session / "session.json").write_text(json.dumps(state))
    monkeypatch.setattr(simulate, "render_poses", lambda *a, **k: pytest.fail("rendered"))
    with pytest.raises(
        DatasetError, match=r"session\.json, field 'intrinsics': Blender renders square pixels"
    ) as refused:
        simulate.render_proposals(session, poses_file(tmp_path / "p.json"), "lego", tmp_path / "out")
    assert refused.value.value[field] == pytest.approx(state["intrinsics"][field])
    assert not (tmp_path / "out").exists()


def test_blender_gets_the_sessions_camera_and_one_path_per_pose(session, tmp_path, monkeypatch):
    asked = {}

    def fake_render(scene, matrices, paths, width, height, camera_angle_x, samples, seed, threads):
        asked.update(scene=scene, n=len(matrices), paths=paths, size=(width, height), angle=camera_angle_x)

    monkeypatch.setattr(simulate, "render_poses", fake_render)
    paths = simulate.render_proposals(session, poses_file(tmp_path / "p.json", 3), "lego", tmp_path / "out")
    assert paths == [tmp_path / "out" / f"p_{i}.png" for i in range(3)] == asked["paths"]
    assert asked["size"] == (SIZE, SIZE) and asked["n"] == 3
    assert math.isclose(asked["angle"], BLENDER_CAMERA_ANGLE_X, rel_tol=1e-6)
