"""A field a client sends that no request of the route has (a JSON body's key, a form field, a query
parameter) is refused with a 422 naming it, over every route, before the request is queued: never
accepted and ignored. In this process (FastAPI's test client over the app), on an empty root."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402

POSE = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]
PNG = b"\x89PNG\r\n\x1a\n"  # never read: the unknown field is refused first


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    hub = SessionHub(tmp_path_factory.mktemp("unknown") / "root")
    try:
        yield TestClient(create_app(hub))
    finally:
        hub.shutdown()


def _json(path, body):
    return lambda c: c.post(path, json=body)


SETTINGS = {"id": "u1", "poses": [POSE], "intrinsics": {"width": 8, "height": 8, "fx": 10.0}}
UNKNOWN = {
    "train": (_json("/sessions/s1/train", {"steps": 1, "x": 1}), "x"),
    "proposals": (_json("/sessions/s1/proposals", {"n": 1, "x": 1}), "x"),
    "proposal constraints": (_json("/sessions/s1/proposals", {"n": 1, "constraints": {"x": 1}}), "constraints.x"),
    "uncertainty": (_json("/sessions/s1/uncertainty", {"pose": POSE, "x": 1}), "x"),
    "evaluate": (_json("/sessions/s1/evaluate", {"dataset": "data", "x": 1}), "x"),
    "from-dataset": (_json("/sessions/from-dataset", {"id": "d1", "dataset": "data", "x": 1}), "x"),
    "from-uploads settings": (
        lambda c: c.post(
            "/sessions/from-uploads",
            data={"settings": json.dumps({**SETTINGS, "x": 1})},
            files=[("images", ("a.png", PNG, "image/png"))],
        ),
        "settings.x",
    ),
    "from-uploads intrinsics": (
        lambda c: c.post(
            "/sessions/from-uploads",
            data={"settings": json.dumps({**SETTINGS, "intrinsics": {**SETTINGS["intrinsics"], "x": 1}})},
            files=[("images", ("a.png", PNG, "image/png"))],
        ),
        "settings.intrinsics.x",
    ),
    "from-uploads form field": (
        lambda c: c.post(
            "/sessions/from-uploads",
            data={"settings": json.dumps(SETTINGS), "x": "1"},
            files=[("images", ("a.png", PNG, "image/png"))],
        ),
        "x",
    ),
    "captures form field": (
        lambda c: c.post(
            "/sessions/s1/captures",
            data={"poses": json.dumps([POSE]), "x": "1"},
            files=[("images", ("a.png", PNG, "image/png"))],
        ),
        "x",
    ),
    "health query": (lambda c: c.get("/health", params={"x": "1"}), "x"),
    "sessions query": (lambda c: c.get("/sessions", params={"x": "1"}), "x"),
    "state query": (lambda c: c.get("/sessions/s1", params={"x": "1"}), "x"),
    "train query": (lambda c: c.post("/sessions/s1/train", json={"steps": 1}, params={"x": "1"}), "x"),
}


@pytest.mark.parametrize("name", sorted(UNKNOWN))
def test_an_unknown_field_is_refused_naming_it(client, name):
    send, field = UNKNOWN[name]
    answer = send(client)
    detail = answer.json()["detail"]
    assert answer.status_code == 422, (answer.status_code, detail)
    assert isinstance(detail, str) and detail.startswith(f"{field}: unknown field") and "\n" not in detail, detail


def test_the_known_fields_alone_pass_this_check(client):
    """Without the unknown field, the same requests go on to what they ask (here: no session s1)."""
    assert client.post("/sessions/s1/train", json={"steps": 1}).status_code == 404
    assert client.get("/health").status_code == 200
    answer = client.post(
        "/sessions/s1/captures", data={"poses": json.dumps([POSE])}, files=[("images", ("a.png", PNG, "image/png"))]
    )
    assert answer.status_code == 404, answer.text
