"""A pool of capture sessions under one root folder, trained in the background: what `nerfaug
serve` holds (its routes, queues and status codes are `nerfaug.service`'s), usable without it.

One `CaptureSession` per folder under the root, opened on first use; one lock per session (its
requests run one at a time); the session folder's lock file held while the pool has it open
(`nerfaug.capture.lock`: a `nerfaug train/add/propose` of it is refused meanwhile); training in a
worker thread per session, at most `max_training` at once; and a record of each training job, so
that a pool made again on the same root (a restarted service) resumes it (`resume`).

    ROOT/
      <id>/                     a capture session (`nerfaug train/propose/add ROOT/<id>` open it too)
      .service/jobs/<id>.json   the session's training job: target step, state

Training (`CaptureSession.train_for`, the loop the commands run) holds the session's lock for a
chunk of steps at a time and takes its next chunk only when no request is waiting (`_Turns`), so
other requests to the session wait at most about one chunk; the state
(`state`) is a snapshot taken after each chunk (or, for a session not opened yet, read from its
files), never waiting for a lock or a worker.

Refusals: an unknown session or dataset `FileNotFoundError`; a session id that exists already
`FolderRefused`; a second training job of a session `JobRunning`; one training job more than
`max_training` `TrainingFull`; a session folder, dataset or job record leading outside the root
(a link) `PathRefused` (`nerfaug.containment.inside`: the folders are used resolved).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from pathlib import Path
from time import monotonic, time
from typing import Literal

from pydantic import BaseModel, Field, computed_field

from nerfaug import runfiles
from nerfaug.capture import lock as session_lock
from nerfaug.capture.folder import SessionFolder
from nerfaug.capture.requests import CHECKPOINT_EVERY_S, SESSION_ID, check_checkpoint_every, check_session_id
from nerfaug.capture.runfolder import SESSION_FILE
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.state import SessionSummary
from nerfaug.containment import inside, is_inside
from nerfaug.data.formats import find_split
from nerfaug.errors import FolderRefused, NerfaugError

JOBS_DIR = Path(".service") / "jobs"
MAX_TRAINING = 4  # sessions training at once (each a thread running torch)
# The job's file records the step it reached at most this often (seconds), so that a restart
# after a kill knows how many steps beyond the last save are redone.
RECORD_EVERY_S = 1.0
log = logging.getLogger(__name__)


class JobRunning(session_lock.SessionBusy):
    """The session is training already: one job at a time."""


class TrainingFull(NerfaugError):
    """As many sessions are training as the pool trains at once; ask again in `retry_after` seconds."""

    exit_code = 1
    retry_after = 30


class Job(BaseModel):
    """A training job: from `start` to `target` steps; `state` is running, done or failed. A job a
    restarted service resumed has `resumed_from` and `redone`."""

    target: int
    start: int
    step: int
    state: Literal["running", "done", "failed"] = "running"
    error: str | None = None
    started: float = Field(default_factory=time)
    finished: float | None = None
    resumed_from: int | None = Field(
        None, description="a job a restarted service resumed: the step of the session's last save it went on from"
    )
    redone: int = Field(0, description="steps trained after that save before the service stopped, trained again")

    @computed_field
    @property
    def progress(self) -> float:
        """The share of the job's steps done."""
        return 1.0 if self.target <= self.start else round((self.step - self.start) / (self.target - self.start), 4)


class SessionStatus(SessionSummary):
    """The session's state, and its training job."""

    running: bool
    job: Job | None


def one_line(error: BaseException) -> str:
    """An error's message on one line (its type's name when it has none)."""
    return " ".join(str(error).split()) or type(error).__name__


class _Turns:
    """A session's lock with requests served before the training worker's next chunk.

    `threading.RLock` is not fair: a training worker that releases the lock after a chunk and takes
    it again at once can keep a request waiting for thousands of chunks (a capture waited over a
    minute on a busy 2-core machine). So requests count themselves while they wait, and the worker
    takes its next chunk only when none is waiting: a request waits at most for the chunk under way
    (and one that began as it arrived). `with turns:` is a request's turn, `with turns.chunk:` the
    worker's."""

    def __init__(self):
        self.lock = threading.RLock()
        self._waiting = 0
        self._changed = threading.Condition(threading.Lock())
        self.chunk = _ChunkTurn(self)

    def __enter__(self):
        with self._changed:
            self._waiting += 1
        try:
            self.lock.acquire()
        finally:
            with self._changed:
                self._waiting -= 1
                self._changed.notify_all()
        return self

    def __exit__(self, *exc) -> None:
        self.lock.release()

    @property
    def waiting(self) -> int:
        """Requests waiting for the lock now."""
        with self._changed:
            return self._waiting

    def wait_for_requests(self) -> None:
        """Return once no request is waiting for the lock."""
        with self._changed:
            self._changed.wait_for(lambda: self._waiting == 0)


class _ChunkTurn:
    """The training worker's turn: after every waiting request (`_Turns`)."""

    def __init__(self, turns: _Turns):
        self.turns = turns

    def __enter__(self):
        self.turns.wait_for_requests()
        self.turns.lock.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.turns.lock.release()


class _Slot:
    """One session's place in the pool: its lock, the open session, its job and its snapshot."""

    def __init__(self, session_id: str):
        self.id = session_id
        self.lock = _Turns()
        self.session: CaptureSession | None = None
        self.job: Job | None = None
        self.thread: threading.Thread | None = None
        self.snapshot: SessionSummary | None = None
        self.folder_lock: session_lock.SessionLock | None = None  # the session folder's, while open here

    @property
    def training(self) -> bool:
        return self.job is not None and self.job.state == "running"


class SessionPool:
    """The sessions under `root`; see the module docstring.

    Args:
        root: the root folder (created if missing).
        device: torch device sessions train and render on.
        checkpoint_every: seconds of training between saves (and a save at each job's end).
        max_training: sessions that may train at once (one more: `TrainingFull`).
        describe: a failed job's error as the line its record keeps (a service passes one that
            never repeats what a file on the server holds).
    """

    def __init__(
        self,
        root: Path,
        device: str = "cpu",
        checkpoint_every: float = CHECKPOINT_EVERY_S,
        max_training: int = MAX_TRAINING,
        describe: Callable[[BaseException], str] = one_line,
    ):
        self.checkpoint_every = check_checkpoint_every(checkpoint_every)  # before the root is made
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.device = device
        self.max_training = int(max_training)
        self.describe = describe
        self._slots: dict[str, _Slot] = {}
        self._slots_lock = threading.Lock()
        self._stopping = threading.Event()

    # -- sessions --

    def folder(self, session_id: str) -> Path:
        """The session's folder, resolved: `RequestError` for an id that is not a `SessionId`,
        `PathRefused` for one whose folder leads outside the root (a link)."""
        return inside(self.root, self.root / check_session_id(session_id), f"session {session_id!r}")

    def ids(self) -> list[str]:
        """Ids of the sessions under the root (folders inside it holding a session.json)."""
        return sorted(
            p.name
            for p in self.root.iterdir()
            if SESSION_ID.fullmatch(p.name) and is_inside(self.root, p) and runfiles.exists(p, SESSION_FILE)
        )

    def require(self, session_id: str) -> None:
        """Refuse (`FileNotFoundError`) an id no session under the root has."""
        self._slot(session_id)

    def refuse_existing(self, session_id: str) -> None:
        """Refuse (`FolderRefused`) a new session's id whose folder exists."""
        folder = self.folder(session_id)
        if folder.exists():
            raise FolderRefused(f"session {session_id!r}: {folder.name} already exists under the service root")

    def _slot(self, session_id: str, must_exist: bool = True) -> _Slot:
        folder = self.folder(session_id)
        with self._slots_lock:
            slot = self._slots.get(session_id)
            if slot is None:
                if must_exist and not runfiles.exists(folder, SESSION_FILE):
                    raise FileNotFoundError(f"session {session_id!r}: no such session under the service root")
                slot = self._slots[session_id] = _Slot(session_id)
            return slot

    def _opened(self, slot: _Slot) -> CaptureSession:
        """The slot's session, opened on first use (hold `slot.lock`); its folder's lock is taken
        first and kept (`SessionBusy` while a `nerfaug` command is changing it)."""
        if slot.session is None:
            self._lock_folder(slot)
            try:
                slot.session = CaptureSession.open(self.folder(slot.id), device=self.device)
            except BaseException:
                slot.folder_lock.release()
                slot.folder_lock = None
                raise
            self._snapshot(slot)
        return slot.session

    def _lock_folder(self, slot: _Slot) -> None:
        if slot.folder_lock is None:
            slot.folder_lock = session_lock.acquire(self.folder(slot.id), session_lock.SERVICE, wait=False)

    def create(self, session_id: str, create: Callable[[Path], CaptureSession]) -> SessionStatus:
        """Create a session with `create(folder)` (a function returning the `CaptureSession`)."""
        self.refuse_existing(session_id)
        folder = self.folder(session_id)
        slot = self._slot(session_id, must_exist=False)
        with slot.lock:
            if slot.session is not None or runfiles.exists(folder, SESSION_FILE):
                raise FolderRefused(f"session {session_id!r}: already exists")
            try:
                slot.session = create(folder)
            except BaseException:
                with self._slots_lock:
                    self._slots.pop(session_id, None)
                raise
            self._lock_folder(slot)  # nobody else knows the new folder yet: free
            slot.session.save()
            self._snapshot(slot)
        return self.state(session_id)

    def run(self, session_id: str, action: Callable[[CaptureSession], object]):
        """`action(session)` under the session's lock; the snapshot is refreshed after it."""
        slot = self._slot(session_id)
        with slot.lock:
            session = self._opened(slot)
            try:
                return action(session)
            finally:
                self._snapshot(slot)

    def dataset_path(self, relative: str, split: str | None = None) -> Path:
        """A dataset folder named relative to the root (links followed), refused when it leaves the
        root; given `split`, its listing file is found first, which refuses one that links outside
        the folder (`find_split`), so no file outside the root is read."""
        if not relative or Path(relative).is_absolute():
            raise ValueError(f"dataset {relative!r}: give a folder relative to the service root")
        path = inside(self.root, self.root / relative, f"dataset {relative!r}")
        if not path.is_dir():
            raise FileNotFoundError(f"dataset {relative!r}: no such folder under the service root")
        if split is not None:
            find_split(path, split)
        return path

    # -- state --

    def _snapshot(self, slot: _Slot) -> None:
        if slot.session is not None:
            slot.snapshot = slot.session.summary()

    def has_snapshot(self, session_id: str) -> bool:
        """Whether the session's state is in memory (`state` then reads no file)."""
        slot = self._slots.get(session_id)
        return slot is not None and slot.snapshot is not None

    def state(self, session_id: str) -> SessionStatus:
        """The session's state, never waiting for a lock or a worker: the last snapshot (or, for a
        session not opened yet, what its files say: `SessionFolder.summary`) and the job."""
        slot = self._slot(session_id)
        summary = slot.snapshot or SessionFolder.open(self.folder(session_id)).summary()
        job = slot.job
        return SessionStatus(**summary.model_dump(), running=slot.training, job=job and job.model_copy())

    # -- training --

    def refuse_training_beyond(self, session_id: str) -> None:
        """Refuse (`TrainingFull`) a job of this session while `max_training` others are training."""
        with self._slots_lock:
            self._refuse_training_beyond(session_id)

    def _refuse_training_beyond(self, session_id: str) -> None:
        training = sum(1 for s in self._slots.values() if s.id != session_id and s.training)
        if training >= self.max_training:
            raise TrainingFull(
                f"{training} sessions are training, the most this service runs at once; retry when one has finished"
            )

    def train(self, session_id: str, steps: int) -> Job:
        """Start training `steps` more steps in a worker thread; `JobRunning` when a job is
        running, `TrainingFull` when `max_training` other sessions are training."""
        slot = self._slot(session_id)
        with slot.lock:
            if slot.training:
                raise JobRunning(f"session {session_id!r}: training is already running (until step {slot.job.target})")
            session = self._opened(slot)
            with self._slots_lock:  # counted and started at once: two sessions never pass the bound together
                self._refuse_training_beyond(session_id)
                slot.job = Job(target=session.step + int(steps), start=session.step, step=session.step)
            self._record(slot)
            self._start(slot)
            return slot.job.model_copy()

    def _record(self, slot: _Slot) -> None:
        runfiles.write_json(self.root, JOBS_DIR / f"{slot.id}.json", {"kind": "train", **slot.job.model_dump()})

    def _start(self, slot: _Slot) -> None:
        slot.thread = threading.Thread(target=self._train_worker, args=(slot,), name=f"train-{slot.id}", daemon=True)
        slot.thread.start()

    def _train_worker(self, slot: _Slot) -> None:
        job, recorded_at = slot.job, [monotonic()]

        def chunk_done(last: dict) -> None:
            job.step = slot.session.step
            if monotonic() - recorded_at[0] >= RECORD_EVERY_S:
                self._record(slot)
                recorded_at[0] = monotonic()
            self._snapshot(slot)

        try:
            with slot.lock:
                session = self._opened(slot)
            stop = self._stopping.is_set
            session.train_for(
                job.target - session.step, self.checkpoint_every, stop, hold=slot.lock.chunk, each=chunk_done
            )
            with slot.lock:
                self._snapshot(slot)
                if not stop():  # stopped by a shutdown: left running, resumed on restart
                    job.step, job.state, job.finished = session.step, "done", time()
                    self._record(slot)
        except Exception as error:  # noqa: BLE001 -- any failure is reported to whoever polls the job
            job.state, job.finished, job.error = "failed", time(), self.describe(error)
            self._record(slot)

    def resume(self) -> list[str]:
        """Restart the training jobs a stopped or killed pool (service) left running; returns their ids."""
        resumed = []
        folder = runfiles.path_in(self.root, JOBS_DIR)
        for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
            session_id = path.stem
            try:
                if self._resume(session_id, runfiles.read_json(folder, path.name)):
                    resumed.append(session_id)
            except Exception as error:  # noqa: BLE001 -- one bad session must not stop the others
                slot = self._slot(session_id, must_exist=False)
                slot.job = Job(target=0, start=0, step=0, state="failed", error=self.describe(error), finished=time())
        return resumed

    def _resume(self, session_id: str, record: dict) -> bool:
        """Restart the job `record` (a job file's content) when it was left running; whether it was."""
        if record.get("state") != "running" or not runfiles.exists(self.folder(session_id), SESSION_FILE):
            return False
        slot = self._slot(session_id)
        with slot.lock:
            session = self._opened(slot)
            target = int(record["target"])
            redone = max(0, int(record.get("step", session.step)) - session.step)
            start = int(record.get("start", session.step))
            slot.job = Job(target=target, start=start, step=session.step, resumed_from=session.step, redone=redone)
            self._record(slot)
            self._start(slot)
        log.info(
            "session %s: training resumed from step %d, its last save (%d steps after it are trained again), "
            "until step %d",
            session_id,
            session.step,
            redone,
            target,
        )
        return True

    def shutdown(self, timeout: float = 30.0) -> None:
        """Stop the training workers at their next chunk (each saves its session first) and release
        the sessions' folders."""
        self._stopping.set()
        for slot in list(self._slots.values()):
            if slot.thread is not None:
                slot.thread.join(timeout)
        for slot in list(self._slots.values()):
            if slot.folder_lock is not None:
                slot.folder_lock.release()
                slot.folder_lock = None
