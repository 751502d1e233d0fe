"""The service's sessions refuse a save period the capture core refuses, when the service is made
(not at each training job's start)."""

import pytest

pytest.importorskip("fastapi")

from nerfaug.capture.requests import RequestError  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402


def test_a_save_period_not_above_zero_is_refused_when_the_hub_is_made(tmp_path):
    with pytest.raises(RequestError, match=r"^checkpoint_every 0: must be > 0$"):
        SessionHub(tmp_path / "root", checkpoint_every=0)
    assert not (tmp_path / "root").exists()
    assert SessionHub(tmp_path / "root", checkpoint_every=0.5).checkpoint_every == 0.5
