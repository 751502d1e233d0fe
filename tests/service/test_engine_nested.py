"""An engine setting over HTTP has the name it has on the command line and in session.json: the
engine is `{"preset": NAME, GROUP: {SETTING: VALUE}}`, read once at the edge, and the value reaches
the field the session builds. A setting the engine does not read is refused before a folder is made."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.capture import CaptureSession  # noqa: E402
from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402

from .test_serve import tiny_dataset  # noqa: E402


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    root = tmp_path_factory.mktemp("nested") / "root"
    tiny_dataset(root / "data")
    hub = SessionHub(root)
    try:
        yield TestClient(create_app(hub)), root
    finally:
        hub.shutdown()


def test_a_nested_engine_setting_reaches_the_field_and_is_recorded_by_that_name(served):
    client, root = served
    engine = {"preset": "test", "field": {"hidden_dim": 48}}
    created = client.post("/sessions/from-dataset", json={"id": "wide", "dataset": "data", "engine": engine})
    assert created.status_code == 201, created.text
    assert json.loads((root / "wide" / "session.json").read_text())["engine"] == engine
    session = CaptureSession.open(root / "wide")
    assert session.trainer.model.field.density_mlp[0].out_features == 48


def test_an_engine_cannot_carry_a_setting_it_does_not_use(served):
    client, root = served
    engine = {"preset": "cpu", "field": {"hash": {"levels": 8}}}  # a K-planes engine given a hash grid's setting
    refused = client.post("/sessions/from-dataset", json={"id": "carry", "dataset": "data", "engine": engine})
    assert refused.status_code == 422
    detail = refused.json()["detail"]
    assert "field.hash.levels 8: not used by this engine: its field.encoding is 'kplanes'" in detail, detail
    assert not (root / "carry").exists()
