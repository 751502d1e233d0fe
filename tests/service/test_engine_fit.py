"""An engine's settings over HTTP: an infinite learning rate, or a run too large for this machine's
memory, refused with a 422 naming the engine and the setting, before any session folder is made
(they were a 201 and a training job that failed, or a 500 with the allocator's words)."""

from __future__ import annotations

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from fastapi.testclient import TestClient  # noqa: E402

from nerfaug.service.app import create_app  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    root = tmp_path_factory.mktemp("fit") / "root"
    hub = SessionHub(root)
    try:
        yield TestClient(create_app(hub)), root
    finally:
        hub.shutdown()


@pytest.mark.parametrize(
    "engine, says",
    [
        ("test+lr=inf", ["lr", "inf", "finite"]),
        ("test+far=inf", ["far", "inf", "finite"]),
        ("test+hidden_dim=1000000000", ["field.hidden_dim", "1000000000", "GiB", "memory"]),
        ("test+batch_size=1000000000", ["optimiser.batch_size", "1000000000", "memory"]),
        ("test+hash_levels=8", ["field.hash.levels", "not used by this engine"]),
    ],
)
def test_an_engine_that_cannot_train_here_is_a_422_naming_the_setting(served, engine, says):
    client, root = served
    before = sorted(p.name for p in root.iterdir()) if root.exists() else []
    answer = client.post("/sessions/from-dataset", json={"id": "s1", "dataset": "data", "engine": engine})
    assert answer.status_code == 422, answer.text
    text = answer.text
    assert "engine" in text and all(s in text for s in says), text
    after = sorted(p.name for p in root.iterdir()) if root.exists() else []
    assert after == before


def test_a_training_job_that_diverges_is_the_settings_fault_not_an_internal_error():
    from nerfaug.nerf.trainer import TrainingDiverged
    from nerfaug.service.errors import status_of

    status, text = status_of(TrainingDiverged(1, float("nan")))
    assert status == 422 and "internal error" not in text
    assert text.startswith("training diverged at step 1: loss = nan") and "engine settings" in text
