"""The service holds cameras to the camera schema (`nerfaug.camera_schema`) as the CLI does: a
dataset whose lens no camera has (OPENCV k1 = -999, p1 = 500) and uploaded images' intrinsics no
lens makes are answered 422 in one line naming the file or field, and no session is made.

In process (FastAPI's test client over the app), on a dataset of two 16x12 photos."""

from __future__ import annotations

import json

import imageio.v3 as iio
import numpy as np
import pytest

pytest.importorskip("fastapi")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.hemisphere import half_hemisphere_poses  # noqa: E402
from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402

H, W = 12, 16


def png(seed: int) -> bytes:
    return iio.imwrite(
        "<bytes>", np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8), extension=".png"
    )


def distorted_dataset(root, **lens) -> None:
    (root / "images").mkdir(parents=True)
    poses = half_hemisphere_poses(2, radius=3.0).tolist()
    for i in range(2):
        (root / "images" / f"{i}.png").write_bytes(png(i))
    frames = [{"file_path": f"images/{i}.png", "transform_matrix": pose} for i, pose in enumerate(poses)]
    listing = {"camera_model": "OPENCV", "fl_x": 14.0, "cx": W / 2, "cy": H / 2, "w": W, "h": H, **lens}
    (root / "transforms.json").write_text(json.dumps(listing | {"frames": frames}))


@pytest.fixture
def client(tmp_path):
    with TestClient(create_app(SessionHub(tmp_path / "root"))) as client:
        yield client


@pytest.mark.parametrize("lens", [{"k1": -999}, {"p1": 500}])
def test_a_dataset_with_a_lens_no_camera_has_is_refused(tmp_path, client, lens):
    distorted_dataset(tmp_path / "root" / "bent", **lens)
    answer = client.post("/sessions/from-dataset", json={"id": "s", "dataset": "bent", "engine": "test"})
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    assert "transforms.json" in detail and "frames[0]" in detail and "photo pixels per pixel" in detail
    assert not (tmp_path / "root" / "s" / "session.json").exists()


@pytest.mark.parametrize(
    ("intrinsics", "says"),
    [
        ({"width": W, "height": H, "fx": 1e-30}, "field of view"),
        ({"width": W, "height": H, "fx": 14.0, "cy": -40.0}, "inside the image"),
        ({"width": 10**308, "height": H, "fx": 14.0}, "intrinsics.width"),
    ],
)
def test_uploaded_images_with_intrinsics_no_lens_makes_are_refused(tmp_path, client, intrinsics, says):
    settings = {"id": "u", "engine": "test", "intrinsics": intrinsics, "poses": half_hemisphere_poses(2).tolist()}
    files = [("images", (f"{i}.png", png(i), "image/png")) for i in range(2)]
    answer = client.post("/sessions/from-uploads", data={"settings": json.dumps(settings)}, files=files)
    assert answer.status_code == 422, answer.text
    assert says in answer.json()["detail"] and "\n" not in answer.json()["detail"]
    assert not (tmp_path / "root" / "u" / "session.json").exists()
