"""The service's hub refuses a request it could not run before queueing it, in HTTP's words: a
training job beyond the pool's bound (`nerfaug.capture.pool`, tested there) is a 503 with
Retry-After, an unknown session a 404, an id taken a 409."""

import pytest

pytest.importorskip("fastapi")

from nerfaug.capture.runfolder import SESSION_FILE  # noqa: E402
from nerfaug.service.errors import headers_of, status_of  # noqa: E402
from nerfaug.service.hub import SessionHub  # noqa: E402


def refusal(call) -> tuple[int, str, dict | None]:
    with pytest.raises(Exception) as caught:
        call()
    return (*status_of(caught.value), headers_of(caught.value))


def test_requests_that_could_not_run_are_refused_before_they_are_queued(tmp_path):
    (tmp_path / "root" / "s").mkdir(parents=True)
    (tmp_path / "root" / "s" / SESSION_FILE).write_text("{}")  # never opened: each is refused first
    hub = SessionHub(tmp_path / "root", max_training=0)
    try:
        status, message, headers = refusal(lambda: hub.submit_train("s", 1))
        assert (status, headers) == (503, {"Retry-After": "30"}) and message.startswith("0 sessions are training")
        assert refusal(lambda: hub.submit("nope", print))[:2] == (
            404,
            "session 'nope': no such session under the service root",
        )
        assert refusal(lambda: hub.submit_create("s", print))[0] == 409
        assert hub.work.pending() == 0
    finally:
        hub.shutdown()


def test_a_session_linked_out_of_the_root_is_neither_listed_nor_served_nor_made(tmp_path):
    (tmp_path / "outside" / "s").mkdir(parents=True)
    (tmp_path / "outside" / "s" / SESSION_FILE).write_text("{}")
    (tmp_path / "root").mkdir()
    (tmp_path / "root" / "s").symlink_to(tmp_path / "outside" / "s", target_is_directory=True)
    (tmp_path / "root" / "t").symlink_to(tmp_path / "outside" / "t", target_is_directory=True)
    hub = SessionHub(tmp_path / "root")
    try:
        assert hub.ids() == []
        for call in (lambda: hub.state("s"), lambda: hub.submit("s", print), lambda: hub.submit_train("s", 1)):
            status, message, _ = refusal(call)
            assert status == 422 and "session 's' leads outside" in message and "outside/s" not in message
        assert refusal(lambda: hub.submit_create("t", print))[0] == 422
        assert hub.work.pending() == 0 and sorted(p.name for p in (tmp_path / "outside").iterdir()) == ["s"]
    finally:
        hub.shutdown()


def test_the_services_engine_settings_change_the_engine_of_each_session_it_creates(tmp_path):
    from nerfaug.service.models import FromDataset

    hub = SessionHub(tmp_path, engine_settings={"field": {"hidden_dim": 48}})
    plain = SessionHub(tmp_path)
    fitting_occupancy = SessionHub(
        tmp_path, engine_settings={"field": {"planes": {"resolutions": (32,)}}}
    )  # K-planes engines only
    try:
        request = FromDataset(id="s", dataset="data", engine="cpu")
        assert hub.settings_of(request).engine.record() == {"preset": "cpu", "field": {"hidden_dim": 48}}
        nerfacto = hub.settings_of(FromDataset(id="s", dataset="data")).engine
        assert nerfacto.record() == {"preset": "nerfacto-cpu", "field": {"hidden_dim": 48}}
        assert plain.settings_of(request) is request
        status, message, _ = refusal(lambda: fitting_occupancy.settings_of(FromDataset(id="s", dataset="data")))
        assert status == 422 and message.startswith("engine: refuses this service's engine settings: field.planes")
        assert fitting_occupancy.settings_of(request).engine.config.field.encoding.resolutions == (32,)
    finally:
        hub.shutdown()
        plain.shutdown()
        fitting_occupancy.shutdown()
