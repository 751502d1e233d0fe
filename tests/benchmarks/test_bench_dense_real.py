"""benchmarks/bench_dense_real.py at toy size: the control really gives every image another
view's camera, and a scene the engine has not learnt fails the registration rule."""

import json
from pathlib import Path

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from nerfaug.cameras import Cameras
from nerfaug.data import Views
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_dense_real.py"


@settings(max_examples=20, deadline=None)
@given(count=st.integers(2, 9), seed=st.integers(0, 2**31 - 1))
def test_the_control_gives_every_image_another_views_camera(bench, count, seed):
    poses = sample_uniform_poses(count, torch.Generator().manual_seed(0))
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 4, 4)
    views = Views(cameras, torch.rand(count, 4, 4, 3), [f"v{i}" for i in range(count)])
    permuted = bench.permuted_cameras(views, seed)
    poses, moved = views.cameras.camera_to_world, permuted.cameras.camera_to_world
    assert torch.equal(permuted.images, views.images) and permuted.names == views.names
    # a permutation of the cameras, and a derangement: no image keeps its own
    assert sorted(map(tuple, moved.flatten(1).tolist())) == sorted(map(tuple, poses.flatten(1).tolist()))
    assert not any(torch.equal(moved[i], poses[i]) for i in range(count))


def test_an_untrained_engine_fails_the_rule_and_the_run_is_recorded(bench, dataset, tmp_path):
    out = tmp_path / "dense-real.json"
    args = ["--scenes", str(dataset), "--out", str(out), "--engine", "test", "--steps", "2", "--layouts", "1"]
    status = bench.main(args)
    (result,) = json.loads(out.read_text())
    assert status == 1 and result["registered"] is False and result["margin_db"] < bench.MARGIN_DB
    assert result["train_views"] == 3 + 8 and result["test_views"] == 4  # initial + pool, the test split
