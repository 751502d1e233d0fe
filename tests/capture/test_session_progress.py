"""Long calls of the Python API say how far they are: training through a callback (and a bar or
lines when the session was opened with progress=True), and a proposal's scoring of candidates."""

import pytest

from nerfaug.capture import CaptureSession, ProposalRequest, SessionSettings
from nerfaug.selection import SelectionConfig

from .test_constraints import tiny_dataset


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("progress")
    settings = SessionSettings(engine="test", seed=3, radius=4.03)
    session = CaptureSession.create(tiny_dataset(tmp / "data"), tmp / "run", settings)
    session.save()
    return tmp / "run"


def test_train_calls_back_every_ten_steps_and_at_the_last(session_dir):
    session = CaptureSession.open(session_dir)
    seen = []
    last = session.train(25, callback=seen.append)
    assert [entry["step"] for entry in seen] == [10, 20, 25]
    assert seen[-1] == last and all({"loss", "psnr"} <= set(entry) for entry in seen)


def test_a_session_opened_with_progress_shows_training_and_scoring(session_dir, capsys):
    session = CaptureSession.open(session_dir, progress=True)
    session.train(20)
    session.propose(
        ProposalRequest(allow_empty=True, n=2, n_candidates=40, selection=SelectionConfig(entropy_resolution=4)),
        map=False,
    )
    err = capsys.readouterr().err  # not a terminal here: plain lines
    assert "training: 20/20" in err
    assert "scoring candidates (ours): 40/40" in err
    quiet = CaptureSession.open(session_dir)
    quiet.train(10)
    quiet.propose(
        ProposalRequest(allow_empty=True, n=2, n_candidates=40, selection=SelectionConfig(entropy_resolution=4)),
        map=False,
    )
    assert capsys.readouterr().err == ""
