"""A pool of sessions under one root (`nerfaug.capture.pool`), in this process: a job left running
is resumed by a pool made again on the root (from its record, with the steps beyond the last save
counted as redone), a folder the pool holds is refused to a second pool and to a command, at most
`max_training` sessions train at once and a session one job at a time, and what the pool refuses
(an unknown session, an id taken, a dataset outside the root, a save period not above zero).

Sessions are tiny (4 views of 8x8 pixels, the "test" engine); every wait is bounded."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, SessionSettings
from nerfaug.capture.lock import SessionBusy, acquire
from nerfaug.capture.pool import JOBS_DIR, JobRunning, SessionPool, TrainingFull
from nerfaug.capture.requests import RequestError
from nerfaug.data import Views, write_blender_split
from nerfaug.errors import FolderRefused, PathRefused
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

SIZE = 8


@pytest.fixture
def root(tmp_path) -> Path:
    """A pool's root holding a tiny dataset in `data/`."""
    generator = torch.Generator().manual_seed(0)
    poses = sample_uniform_poses(4, generator)
    images = torch.rand(4, SIZE, SIZE, 3, generator=generator)
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    write_blender_split(
        tmp_path / "root" / "data", "train", Views(cameras, images, [f"./train/r_{i}" for i in range(4)])
    )
    return tmp_path / "root"


def new_session(pool: SessionPool, session_id: str):
    data = pool.dataset_path("data", "train")
    return pool.create(session_id, lambda folder: CaptureSession.create(data, folder, SessionSettings(engine="test")))


def ended(pool: SessionPool, session_id: str, timeout: float = 120.0):
    """The session's state once its job is no longer running (bounded in count and time)."""
    deadline = time.monotonic() + timeout
    for _ in range(int(timeout * 20)):
        state = pool.state(session_id)
        if not state.running or time.monotonic() > deadline:
            return state
        time.sleep(0.05)
    return state


def test_a_recreated_pool_resumes_a_recorded_job_from_the_last_save(root):
    first = SessionPool(root)
    assert new_session(first, "s").step == 0
    first.shutdown()
    # As a killed pool leaves it: its job running, 3 steps recorded beyond the save at step 0.
    record = {"kind": "train", "target": 5, "start": 0, "step": 3, "state": "running"}
    (root / JOBS_DIR).mkdir(parents=True)
    (root / JOBS_DIR / "s.json").write_text(json.dumps(record))
    (root / JOBS_DIR / "done.json").write_text(json.dumps({**record, "state": "done"}))
    (root / JOBS_DIR / "gone.json").write_text(json.dumps(record))  # no such session: skipped
    second = SessionPool(root)
    try:
        assert second.resume() == ["s"]
        state = ended(second, "s")
    finally:
        second.shutdown()
    assert state.step == 5 and state.job.state == "done" and state.job.target == 5
    assert (state.job.resumed_from, state.job.redone, state.job.progress) == (0, 3, 1.0)
    assert json.loads((root / "s" / "session.json").read_text())["step"] == 5
    assert json.loads((root / JOBS_DIR / "s.json").read_text())["state"] == "done"


def test_a_job_stopped_by_a_shutdown_is_resumed_by_the_next_pool(root):
    first = SessionPool(root, checkpoint_every=0.05)
    new_session(first, "s")
    target = first.train("s", 100_000).target
    first.shutdown()  # stops the job at its next chunk, saved; its record stays "running"
    saved = json.loads((root / "s" / "session.json").read_text())["step"]
    assert json.loads((root / JOBS_DIR / "s.json").read_text())["state"] == "running"
    second = SessionPool(root)
    try:
        assert second.resume() == ["s"]
        state = second.state("s")
        assert state.running and state.job.target == target and state.job.resumed_from == saved
    finally:
        second.shutdown()


def test_a_folder_the_pool_holds_is_refused_to_a_second_pool_and_to_a_command(root):
    first = SessionPool(root)
    new_session(first, "s")
    second = SessionPool(root)
    with pytest.raises(SessionBusy, match="HTTP API"):
        second.run("s", lambda session: session.step)
    with pytest.raises(SessionBusy, match="HTTP API"):
        acquire(root / "s", "nerfaug train", wait=False)
    first.shutdown()  # releases the folder
    try:
        assert second.run("s", lambda session: session.step) == 0
    finally:
        second.shutdown()


def test_at_most_max_training_sessions_train_and_each_one_job_at_a_time(root):
    pool = SessionPool(root, max_training=1)
    try:
        for session_id in ("a", "b"):
            new_session(pool, session_id)
        pool.refuse_training_beyond("b")  # nothing trains yet
        pool.train("a", 100_000)
        with pytest.raises(TrainingFull, match="^1 sessions are training"):
            pool.refuse_training_beyond("b")
        with pytest.raises(TrainingFull):  # the pool keeps its bound whoever asks
            pool.train("b", 1)
        assert pool.state("b").job is None
        pool.refuse_training_beyond("a")  # its own job is not counted
        with pytest.raises(JobRunning, match="'a': training is already running"):
            pool.train("a", 1)
    finally:
        pool.shutdown()


def test_what_the_pool_refuses(root, tmp_path):
    with pytest.raises(RequestError, match=r"^checkpoint_every 0: must be > 0$"):
        SessionPool(tmp_path / "other", checkpoint_every=0)
    assert not (tmp_path / "other").exists()  # refused before the root is made
    pool = SessionPool(root)
    with pytest.raises(FileNotFoundError, match="session 'nope'"):
        pool.state("nope")
    with pytest.raises(RequestError, match="session id"):
        pool.require("../data")
    with pytest.raises(FolderRefused, match="data already exists"):
        pool.refuse_existing("data")
    for outside in ("/etc", "../", "data/../.."):
        with pytest.raises(ValueError, match="relative to the service root|leads outside"):
            pool.dataset_path(outside)
    with pytest.raises(FileNotFoundError, match="'missing'"):
        pool.dataset_path("missing")

    def fails(folder):
        raise ValueError("no session")

    with pytest.raises(ValueError, match="no session"):
        pool.create("x", fails)
    with pytest.raises(FileNotFoundError):  # a failed creation leaves no session behind
        pool.require("x")
    assert pool.ids() == []


def test_a_request_waits_for_at_most_the_chunk_under_way_while_the_session_trains(root):
    """Requests to a training session are served between the job's chunks: each waits at most for
    the chunk under way and one that began as it arrived (CHUNK_STEPS steps each). A plain lock
    lets the worker take it back after every chunk, so a request could wait thousands of steps."""
    from nerfaug.capture.session import CHUNK_STEPS

    pool = SessionPool(root, checkpoint_every=3600.0)
    try:
        new_session(pool, "s")
        pool.train("s", 5000)
        waited = []
        for _ in range(20):
            before = pool.state("s").step  # the step after the last finished chunk
            waited.append(pool.run("s", lambda session: session.step) - before)
        running = pool.state("s").running
    finally:
        pool.shutdown()
    assert running, "the job ended before the requests were made: the test measured nothing"
    assert max(waited) <= 2 * CHUNK_STEPS, waited


def test_a_waiting_request_goes_before_the_workers_next_chunk():
    """The turn itself, without timing: a worker that ends a chunk while a request waits cannot
    take the next chunk before it (a plain lock would let it, and usually does)."""
    import threading

    from nerfaug.capture.pool import _Turns

    turns, order = _Turns(), []

    def ask() -> None:
        with turns:
            order.append("request")

    turns.chunk.__enter__()  # the worker is in a chunk
    request = threading.Thread(target=ask)
    request.start()
    for _ in range(2000):  # until the request waits (bounded: 10 s)
        if turns.waiting:
            break
        time.sleep(0.005)
    assert turns.waiting == 1
    turns.chunk.__exit__()
    with turns.chunk:  # the worker's next chunk
        order.append("chunk")
    request.join(10)
    assert order == ["request", "chunk"] and turns.waiting == 0


def test_a_session_folder_linked_outside_the_root_is_neither_listed_nor_served_nor_written(root, tmp_path):
    """A session id that is a link inside the root to a folder outside it: not listed, and every
    request naming it (state, a request, training, a new session there) refused in one line before
    anything there is read or written. A link to a folder inside the root is a session as any."""
    outside = tmp_path / "outside"
    CaptureSession.create(root / "data", outside / "s", SessionSettings(engine="test"))
    before = sorted((p.relative_to(outside).as_posix(), p.stat().st_mtime_ns) for p in outside.rglob("*"))
    (root / "linked").symlink_to(outside / "s", target_is_directory=True)
    (root / "dangling").symlink_to(outside / "new", target_is_directory=True)
    pool = SessionPool(root)
    try:
        assert pool.ids() == []
        refusals = [
            lambda: pool.state("linked"),
            lambda: pool.require("linked"),
            lambda: pool.run("linked", lambda session: session.save()),
            lambda: pool.train("linked", 1),
            lambda: pool.refuse_existing("dangling"),
            lambda: new_session(pool, "dangling"),
        ]
        for call in refusals:
            with pytest.raises(PathRefused) as info:
                call()
            message = str(info.value)
            assert "leads outside" in message and str(root) in message and "\n" not in message
            assert str(outside) not in message
        assert not (outside / "new").exists()
        assert sorted((p.relative_to(outside).as_posix(), p.stat().st_mtime_ns) for p in outside.rglob("*")) == before
        new_session(pool, "real")
        (root / "alias").symlink_to(root / "real", target_is_directory=True)
        assert pool.ids() == ["alias", "real"] and pool.state("alias").step == 0
    finally:
        pool.shutdown()
