"""A refused request is answered in one line naming every field the client sent that was not
accepted (an unknown one with the field it may have meant) and every other problem, not the first
alone. In this process (FastAPI's test client over the app), on an empty root."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from fastapi.testclient import TestClient  # noqa: E402
from pydantic import BaseModel, ConfigDict, TypeAdapter, ValidationError  # noqa: E402

from nerfaug.capture.proposal_request import ProposalRequest  # noqa: E402
from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.errors import SHOWN_PROBLEMS, fields_of, problems_line  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402
from nerfaug.service.models import FromUploads  # noqa: E402

POSE = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 4.0], [0.0, 0.0, 0.0, 1.0]]
PNG = b"\x89PNG\r\n\x1a\n"  # never read: the settings are refused first
UNKNOWN = "unknown field: not one of this request's"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    hub = SessionHub(tmp_path_factory.mktemp("fields") / "root")
    try:
        yield TestClient(create_app(hub))
    finally:
        hub.shutdown()


def _refusal(answer) -> str:
    detail = answer.json()["detail"]
    assert answer.status_code == 422, (answer.status_code, detail)
    assert isinstance(detail, str) and "\n" not in detail, detail
    return detail


def test_a_misspelt_field_is_named_with_the_field_meant(client):
    """`{"step": 500}` names `step` and `steps`, not only the missing `steps`."""
    detail = _refusal(client.post("/sessions/s1/train", json={"step": 500}))
    assert detail == f"step: {UNKNOWN} (did you mean steps?); steps: Field required", detail


def test_every_problem_is_named_the_unknown_fields_first(client):
    body = {"n": 0, "mehtod": "uniform", "constraints": {"elevaton": [0, 60]}}
    detail = _refusal(client.post("/sessions/s1/proposals", json=body))
    parts = detail.split("; ")
    assert parts == [
        f"constraints.elevaton: {UNKNOWN} (did you mean elevation?)",
        f"mehtod: {UNKNOWN} (did you mean method?)",
        "n: must be >= 1 (got '0')",
    ], detail
    assert "more problem" not in detail


def test_a_field_like_none_is_answered_with_the_request_fields_once(client):
    """No field is close: the request's fields are listed, once for all the unknown fields."""
    detail = _refusal(client.post("/sessions/s1/train", json={"steps": 1, "zzz": 1, "qqq": 2}))
    assert detail == f"zzz: {UNKNOWN} (its fields: steps); qqq: {UNKNOWN}", detail


def test_past_the_shown_problems_their_count_and_fields_are_named(client):
    sent = [f"bogus{i}" for i in range(SHOWN_PROBLEMS + 3)]
    detail = _refusal(client.post("/sessions/s1/proposals", json={name: 1 for name in sent}))
    for name in sent[:SHOWN_PROBLEMS]:
        assert f"{name}: {UNKNOWN}" in detail, detail
    assert detail.endswith(f"; and 3 more problems ({', '.join(sent[SHOWN_PROBLEMS:])})"), detail


def test_the_settings_form_field_names_each_nested_field_with_its_prefix(client):
    settings = {"id": "u1", "poses": [POSE], "intrinsics": {"width": 8, "height": 8, "fxx": 10.0}, "sede": 3}
    answer = client.post(
        "/sessions/from-uploads",
        data={"settings": json.dumps(settings)},
        files=[("images", ("a.png", PNG, "image/png"))],
    )
    parts = _refusal(answer).split("; ")
    assert f"settings.intrinsics.fxx: {UNKNOWN} (did you mean fx?)" in parts, parts
    assert f"settings.sede: {UNKNOWN} (did you mean seed?)" in parts, parts
    assert "settings.intrinsics.fx: Field required" in parts, parts


def test_a_misspelt_form_field_is_named_with_the_field_meant(client):
    answer = client.post(
        "/sessions/s1/captures", data={"pose": json.dumps([POSE])}, files=[("images", ("a.png", PNG, "image/png"))]
    )
    assert _refusal(answer) == f"pose: {UNKNOWN} (did you mean poses?)"


def test_a_renamed_field_names_its_new_name_alone(client):
    detail = _refusal(client.post("/sessions/from-dataset", json={"id": "x", "dataset": "data", "preset": "test"}))
    assert detail == f"preset: {UNKNOWN}; renamed engine", detail


def test_fields_of_walks_nested_optional_and_list_types():
    assert fields_of(ProposalRequest)[:2] == ["n", "method"]
    assert "elevation" in fields_of(ProposalRequest, ("constraints",))
    assert fields_of(FromUploads, ("intrinsics",))[:2] == ["width", "height"]
    assert fields_of(ProposalRequest, ("n",)) is None  # an int holds no fields
    assert fields_of(None) is None

    class Inner(BaseModel):
        depth: int

    class Outer(BaseModel):
        items: list[Inner] | None = None

    assert fields_of(Outer, ("items", 3)) == ["depth"]


def test_without_a_request_class_the_unknown_field_is_named_alone():
    class Strict(BaseModel):
        model_config = ConfigDict(extra="forbid")
        steps: int

    with pytest.raises(ValidationError) as caught:
        TypeAdapter(Strict).validate_python({"step": 1, "steps": "x"})
    assert problems_line(caught.value.errors()) == (
        f"step: {UNKNOWN}; steps: Input should be a valid integer, unable to parse string as an integer (got 'x')"
    )
