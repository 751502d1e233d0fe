"""An HTTP answer never shows the server's own layout: a path under the service root is named
relative to it (a session's file as `s/session.json`), the root itself as "the service root",
any other absolute path by its file name alone; so too in a failed training job's record.

In process (FastAPI's test client over the app), on a session of the "test" engine."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest.importorskip("fastapi")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.capture import CaptureSession, SessionSettings  # noqa: E402
from nerfaug.capture.requests import SparseStart  # noqa: E402
from nerfaug.errors import DatasetError, PathRefused  # noqa: E402
from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402

from ..capture.test_run_folder_links import plant  # noqa: E402
from ..capture.test_sparse_start import all_round_dataset  # noqa: E402

PROPOSE = {"n": 1, "n_candidates": 5, "allow_empty": True, "min_separation": 0.0}
# An absolute path as a message would show one (not a URL's "//", nor the second half of "a/b").
ABSOLUTE = re.compile(r"(?<![\w.:/])/(tmp|root|home|work|usr|srv|var|private)\b")


@pytest.fixture
def root(tmp_path) -> Path:
    data = all_round_dataset(tmp_path / "data")
    settings = SessionSettings(engine="test", seed=1, centre=(0.0, 0.0, 0.0))
    CaptureSession.create(data, tmp_path / "root" / "s", settings, start=SparseStart(initial=4))
    (tmp_path / "root" / "broken").mkdir()
    (tmp_path / "root" / "broken" / "transforms_train.json").write_text("{not json")
    (tmp_path / "outside").mkdir()
    return tmp_path / "root"


def detail(answer, status: int, tmp_path: Path) -> str:
    assert answer.status_code == status, answer.text
    text = answer.json()["detail"]
    assert str(tmp_path) not in text and not ABSOLUTE.search(text), text
    return text


def test_a_bad_session_name_and_a_session_linked_out_name_no_server_path(root, tmp_path):
    (root / "away").symlink_to(tmp_path / "outside", target_is_directory=True)
    (tmp_path / "data").rename(root / "data")  # a dataset the client may name
    with TestClient(create_app(SessionHub(root))) as client:
        assert "session id" in detail(client.get("/sessions/a%20b"), 422, tmp_path)
        assert detail(client.get("/sessions/nope"), 404, tmp_path).startswith("session 'nope'")
        refused = detail(client.get("/sessions/away"), 422, tmp_path)
        created = client.post("/sessions/from-dataset", json={"id": "away", "dataset": "data", "engine": "test"})
        refused_again = detail(created, 422, tmp_path)
    assert refused == "away: session 'away' leads outside the service root, the folder it must stay in"
    assert refused_again == refused
    assert list((tmp_path / "outside").iterdir()) == []


def test_a_dataset_error_names_the_file_under_the_root(root, tmp_path):
    (tmp_path / "data").rename(root / "data")  # a dataset the client may name
    with TestClient(create_app(SessionHub(root))) as client:
        created = client.post("/sessions/from-dataset", json={"id": "t", "dataset": "broken", "engine": "test"})
        text = detail(created, 422, tmp_path)
        assert text.startswith("broken/transforms_train.json: invalid JSON"), text
        (root / "s" / "session.json").write_text("{not json")  # a dataset error inside a session
        text = detail(client.get("/sessions/s"), 409, tmp_path)  # the session's folder is inconsistent
    assert text.startswith("s/session.json: "), text


def test_a_refused_link_inside_a_session_is_named_from_the_session(root, tmp_path):
    plant(root / "s", "pool.json", tmp_path / "elsewhere")
    with TestClient(create_app(SessionHub(root))) as client:
        text = detail(client.post("/sessions/s/proposals", json=PROPOSE), 422, tmp_path)
    assert text.startswith("s/pool.json: this path leads outside s, the folder it must stay in"), text


def test_a_root_given_relative_is_not_named_either(root, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (root / "away").symlink_to(tmp_path / "outside", target_is_directory=True)
    with TestClient(create_app(SessionHub(Path("root")))) as client:
        text = detail(client.get("/sessions/away"), 422, tmp_path)
    assert text == "away: session 'away' leads outside the service root, the folder it must stay in"


def test_a_failed_jobs_record_names_no_server_path(root, tmp_path):
    hub = SessionHub(root)
    error = PathRefused(root / "s" / "checkpoint.pt", f"this path leads outside {root / 's'}")
    assert hub.describe(error) == "s/checkpoint.pt: this path leads outside s"
    weights = DatasetError(tmp_path / "venv" / "lpips" / "alexnet.pth", "missing")
    assert hub.describe(weights) == "alexnet.pth: missing"


def test_a_path_the_client_sent_is_shown_as_sent(root, tmp_path):
    with TestClient(create_app(SessionHub(root))) as client:
        answer = client.post("/sessions/from-dataset", json={"id": "t", "dataset": "/etc", "engine": "test"})
    assert answer.status_code == 422 and answer.json()["detail"].startswith("dataset '/etc': "), answer.text
