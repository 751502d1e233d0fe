"""Over HTTP, nothing inside a session's folder leads out either (`nerfaug.runfiles`): a link
planted in a session's folder in place of its candidate pool, proposals folder, session.json,
checkpoint, lock, dataset copy or its image folder, leading to an outside copy, is answered 422 in
one line naming the file from the service root (`s/pool.json`), never where the link leads; nothing
outside is read into an answer or written, and the session stays as it was.

In process (FastAPI's test client over the app), on a session of 4 of 16 views of 8x8 pixels (a
sparse start, so it has a pool), the "test" engine."""

from __future__ import annotations

import json
import shutil

import pytest

pytest.importorskip("fastapi")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.capture import CaptureSession, SessionSettings  # noqa: E402
from nerfaug.capture.requests import SparseStart  # noqa: E402
from nerfaug.hemisphere import sample_uniform_poses  # noqa: E402
from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402

from ..capture.test_run_folder_links import files_of, plant  # noqa: E402
from ..capture.test_sparse_start import all_round_dataset  # noqa: E402

PROPOSE = {"n": 1, "n_candidates": 5, "allow_empty": True, "min_separation": 0.0}


@pytest.fixture
def root(tmp_path):
    data = all_round_dataset(tmp_path / "data")
    settings = SessionSettings(engine="test", seed=1, centre=(0.0, 0.0, 0.0))
    CaptureSession.create(data, tmp_path / "root" / "s", settings, start=SparseStart(initial=4))
    return tmp_path / "root"


def captures(data_dir):
    import torch

    pose = sample_uniform_poses(1, torch.Generator().manual_seed(9), radius=4.03).tolist()
    image = (data_dir / "train" / "r_0.png").read_bytes()
    return {"data": {"poses": json.dumps(pose)}, "files": [("images", ("new_view.png", image, "image/png"))]}


@pytest.mark.parametrize(
    ("name", "request_"),
    [
        ("pool.json", "propose"),
        ("proposals", "propose"),
        ("session.json", "state"),
        ("session.json", "propose"),
        ("checkpoint.pt", "train"),
        (".lock", "train"),
        ("dataset", "state"),
        ("dataset/train", "captures"),
    ],
)
def test_a_link_out_of_a_sessions_folder_is_answered_422_naming_it(root, tmp_path, name, request_):
    outside, run = tmp_path / "outside", root / "s"
    with TestClient(create_app(SessionHub(root))) as client:
        if request_ == "captures":  # the session open and its model loaded: the link is met by the write
            assert client.post("/sessions/s/proposals", json=PROPOSE).status_code == 200
        plant(run, name, outside)
        before_outside, before_run = files_of(outside), files_of(run, leave_out=(".lock",))
        answer = {
            "propose": lambda: client.post("/sessions/s/proposals", json=PROPOSE),
            "state": lambda: client.get("/sessions/s"),
            "train": lambda: client.post("/sessions/s/train", json={"steps": 3}),
            "captures": lambda: client.post("/sessions/s/captures", **captures(tmp_path / "data")),
        }[request_]()
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    shown = {"proposals": "proposals/proposal_000.json", "dataset/train": "dataset/train/new_view.png"}
    # Named from the service root, as the client names the session: never the server's own layout.
    assert detail.startswith(f"s/{shown.get(name, name)}: ") and "leads outside s" in detail, detail
    assert "\n" not in detail and str(outside) not in detail
    assert files_of(outside) == before_outside
    assert files_of(run, leave_out=(".lock",)) == before_run


def test_the_session_answers_again_once_its_own_file_is_back(root, tmp_path):
    outside, run = tmp_path / "outside", root / "s"
    plant(run, "pool.json", outside)
    with TestClient(create_app(SessionHub(root))) as client:
        assert client.post("/sessions/s/proposals", json=PROPOSE).status_code == 422
        (run / "pool.json").unlink()
        shutil.copy(outside / "pool.json", run / "pool.json")
        answer = client.post("/sessions/s/proposals", json=PROPOSE)
    assert answer.status_code == 200, answer.text
    assert (run / "proposals" / "proposal_000.json").is_file() and (run / "proposals" / "proposal_000.png").is_file()
