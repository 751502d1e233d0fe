"""What the service says in the user's words: a request log of one line per request (method, path,
status, milliseconds), and answers holding no path of the server's own (paths under the root are
given relative to it, as the client names them).

In process (FastAPI's test client over the app), on a tiny dataset of four 8x8 views."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pytest
import torch

pytest.importorskip("fastapi")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.cameras import Cameras  # noqa: E402
from nerfaug.data import Views, write_blender_split  # noqa: E402
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses  # noqa: E402
from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.errors import public_text  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402


def tiny_dataset(root: Path, n: int = 4, split: str = "train", seed: int = 0) -> None:
    generator = torch.Generator().manual_seed(seed)
    poses = sample_uniform_poses(n, generator)
    images = (torch.rand(n, 8, 8, 3, generator=generator) * 255).round() / 255
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 8, 8)
    write_blender_split(root, split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(n)]))


@pytest.fixture
def client(tmp_path):
    tiny_dataset(tmp_path / "root" / "data")
    tiny_dataset(tmp_path / "root" / "held-out", n=2, split="test", seed=5)
    with TestClient(create_app(SessionHub(tmp_path / "root"))) as client:
        yield client


def test_every_request_is_logged_in_one_line_with_its_status_and_time(client, caplog):
    with caplog.at_level(logging.INFO, logger="nerfaug.service.app"):
        assert client.get("/health").status_code == 200
        assert client.get("/sessions/nobody").status_code == 404
    lines = [r.getMessage() for r in caplog.records if r.name == "nerfaug.service.app"]
    assert len(lines) == 2, lines
    assert re.fullmatch(r"GET /health 200 \d+ ms", lines[0]) and re.fullmatch(
        r"GET /sessions/nobody 404 \d+ ms", lines[1]
    )


def test_the_evaluate_answer_names_no_path_of_the_server(client, tmp_path, monkeypatch):
    missing = tmp_path / "elsewhere" / "alexnet.pth"  # LPIPS unavailable: its reason names where it looked
    monkeypatch.setenv("NERFAUG_ALEXNET_WEIGHTS", str(missing))
    body = {"id": "s", "dataset": "data", "engine": "test", "seed": 1}
    assert client.post("/sessions/from-dataset", json=body).status_code == 201
    answer = client.post("/sessions/s/evaluate", json={"dataset": "held-out", "lpips": False})
    assert answer.status_code == 200, answer.text
    status = answer.json()["lpips_status"]
    assert "alexnet.pth" in status  # the file it looked for, by name
    assert str(tmp_path) not in answer.text and not re.search(r"(?<![\w.:/])/(root|home|tmp|usr|work)\b", answer.text)


def test_public_text_makes_paths_relative_to_the_root_and_hides_the_others():
    root = Path("/srv/sessions")
    text = "from /srv/sessions/s1/dataset/transforms.json, weights /opt/venv/lpips/alexnet.ckpt, see https://x.org/a/b"
    shown = public_text(text, root)
    assert shown == "from s1/dataset/transforms.json, weights alexnet.ckpt, see https://x.org/a/b"
    assert public_text("leads outside /srv/sessions, the folder", root) == "leads outside the service root, the folder"


def test_the_service_scores_the_views_a_sparse_start_kept_apart(tmp_path):
    """A session started sparse from a set without a test split is scored on the views it kept apart,
    as `nerfaug eval` scores it, by default and when the split it started from is named."""
    from nerfaug.capture import CaptureSession, SessionSettings
    from nerfaug.capture.requests import SparseStart

    root = tmp_path / "root"
    tiny_dataset(root / "data", n=12)  # a train split only: 3 views kept apart
    settings = SessionSettings(engine="test", seed=1)
    kept = CaptureSession.create(root / "data", root / "s", settings, start=SparseStart(initial=3)).state.start
    with TestClient(create_app(SessionHub(root))) as client:
        answer = client.post("/sessions/s/evaluate", json={"dataset": "data", "lpips": False})
        assert answer.status_code == 200, answer.text
        scored = answer.json()
        assert sorted(v["name"] for v in scored["per_view"]) == sorted(kept["held_out"]) and scored["views"] == 3
        assert scored["trained_on"] == 0 and scored["split"] == "train" and scored["note"] is None
        assert scored["scored"] == "the 3 views of data kept apart for testing when the session started"
        whole = client.post("/sessions/s/evaluate", json={"dataset": "data", "split": "train", "lpips": False})
        assert whole.json()["views"] == 3  # the split it started from: still the views kept apart
