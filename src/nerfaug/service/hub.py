"""The sessions a service holds: one `CaptureSession` per folder under the service root, one lock
per session (requests to a session run one at a time), the session folder's lock file held while
the service has it open (`nerfaug.capture.lock`: a `nerfaug train/add/propose` of it is refused
meanwhile), requests' work in bounded per-session queues (`nerfaug.service.work`), training in a
worker thread per session, and a record of each training job so that a restarted service resumes it.

    ROOT/
      <id>/                 a capture session (`nerfaug train/propose/add ROOT/<id>` open it too)
      .service/jobs/<id>.json   the session's training job: target step, state

Training (`CaptureSession.train_for`, the loop the commands run) holds the session's lock for a
chunk of steps at a time, so other requests to the session wait at most one chunk; the state a
client polls is a snapshot taken after each chunk (or, for a session not opened yet, read from its
files), never waiting for a lock or a worker.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path
from time import monotonic, time

from nerfaug.capture import lock as session_lock
from nerfaug.capture.folder import SessionFolder
from nerfaug.capture.requests import CHECKPOINT_EVERY_S, SESSION_ID, check_checkpoint_every, check_session_id
from nerfaug.capture.runfolder import SESSION_FILE
from nerfaug.capture.session import CaptureSession
from nerfaug.capture.state import SessionSummary
from nerfaug.data.formats import find_split
from nerfaug.jsonio import atomic_write_json, read_json
from nerfaug.service.errors import ServiceError, bad_input, status_of
from nerfaug.service.models import Job
from nerfaug.service.work import PER_SESSION, TOTAL, WORKERS, WorkQueues

JOBS_DIR = Path(".service") / "jobs"
MAX_TRAINING = 4  # sessions training at once (each a thread running torch)
# The job's file records the step it reached at most this often (seconds), so that a restart
# after a kill knows how many steps beyond the last save are redone.
RECORD_EVERY_S = 1.0
log = logging.getLogger("nerfaug.service")


class Slot:
    """One session's place in the hub: its lock, the open session, its job and its snapshot."""

    def __init__(self, session_id: str):
        self.id = session_id
        self.lock = threading.RLock()
        self.session = None
        self.job: Job | None = None
        self.thread: threading.Thread | None = None
        self.snapshot: SessionSummary | None = None
        self.folder_lock: session_lock.SessionLock | None = None  # the session folder's, while open here


class SessionHub:
    """The sessions under `root`; see the module docstring.

    Args:
        root: the service root folder (created if missing).
        device: torch device sessions train and render on.
        checkpoint_every: seconds of training between saves (and a save at each job's end).
        workers, per_session, total: the request queues' bounds (`WorkQueues`).
        max_training: sessions that may train at once (one more: 503).
    """

    def __init__(
        self,
        root: Path,
        device: str = "cpu",
        checkpoint_every: float = CHECKPOINT_EVERY_S,
        workers: int = WORKERS,
        per_session: int = PER_SESSION,
        total: int = TOTAL,
        max_training: int = MAX_TRAINING,
    ):
        self.checkpoint_every = check_checkpoint_every(checkpoint_every)  # before the root is made
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.device = device
        self.work = WorkQueues(workers, per_session, total)
        self.max_training = int(max_training)
        self._slots: dict[str, Slot] = {}
        self._slots_lock = threading.Lock()
        self._stopping = threading.Event()

    # -- sessions --

    def folder(self, session_id: str) -> Path:
        return self.root / check_session_id(session_id)

    def ids(self) -> list[str]:
        """Ids of the sessions under the root (folders holding a session.json)."""
        return sorted(
            p.name for p in self.root.iterdir() if SESSION_ID.fullmatch(p.name) and (p / SESSION_FILE).is_file()
        )

    def slot(self, session_id: str, must_exist: bool = True) -> Slot:
        folder = self.folder(session_id)
        with self._slots_lock:
            slot = self._slots.get(session_id)
            if slot is None:
                if must_exist and not (folder / SESSION_FILE).is_file():
                    raise ServiceError(404, f"session {session_id!r}: no such session under the service root")
                slot = self._slots[session_id] = Slot(session_id)
            return slot

    def opened(self, slot: Slot):
        """The slot's session, opened on first use (hold `slot.lock`); its folder's lock is taken
        first and kept (`SessionBusy`, a 409, while a `nerfaug` command is changing it)."""
        if slot.session is None:
            self._lock_folder(slot)
            try:
                slot.session = CaptureSession.open(self.root / slot.id, device=self.device)
            except BaseException:
                slot.folder_lock.release()
                slot.folder_lock = None
                raise
            self._snapshot(slot)
        return slot.session

    def _lock_folder(self, slot: Slot) -> None:
        if slot.folder_lock is None:
            slot.folder_lock = session_lock.acquire(self.root / slot.id, session_lock.SERVICE, wait=False)

    def created(self, session_id: str, create) -> dict:
        """Create a session with `create(folder)` (a function returning the `CaptureSession`)."""
        folder = self.folder(session_id)
        if folder.exists():
            raise ServiceError(409, f"session {session_id!r}: {folder.name} already exists under the service root")
        slot = self.slot(session_id, must_exist=False)
        with slot.lock:
            if slot.session is not None or (folder / SESSION_FILE).exists():
                raise ServiceError(409, f"session {session_id!r}: already exists")
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

    def submit(self, session_id: str, action):
        """`run(session_id, action)` queued behind the session's earlier requests (a Future);
        404 for an unknown session, 429/503 when the queues are full (`WorkQueues.submit`)."""
        self.slot(session_id)
        return self.work.submit(session_id, lambda: self.run(session_id, action))

    def submit_create(self, session_id: str, create):
        """`created(session_id, create)` in the session's queue (a Future)."""
        folder = self.folder(session_id)
        if folder.exists():
            raise ServiceError(409, f"session {session_id!r}: {folder.name} already exists under the service root")
        return self.work.submit(session_id, lambda: self.created(session_id, create))

    def submit_train(self, session_id: str, steps: int):
        """`train(session_id, steps)` in the session's queue (opening a session loads its model)."""
        self.slot(session_id)
        training = sum(
            1
            for s in list(self._slots.values())
            if s.id != session_id and s.job is not None and s.job.state == "running"
        )
        if training >= self.max_training:
            raise ServiceError(
                503,
                f"{training} sessions are training, the most this service runs at once; retry when one has finished",
                headers={"Retry-After": "30"},
            )
        return self.work.submit(session_id, lambda: self.train(session_id, steps))

    def dataset_path(self, relative: str, split: str | None = None) -> Path:
        """A dataset folder named relative to the root (links followed), refused when it leaves the
        root; given `split`, its listing file is found first, which refuses one that links outside
        the folder (`find_split`), so no file outside the root is read."""
        if not relative or Path(relative).is_absolute():
            raise bad_input(f"dataset {relative!r}: give a folder relative to the service root")
        path = (self.root / relative).resolve()
        if not path.is_relative_to(self.root.resolve()):
            raise bad_input(f"dataset {relative!r}: lies outside the service root")
        if not path.is_dir():
            raise ServiceError(404, f"dataset {relative!r}: no such folder under the service root")
        if split is not None:
            find_split(path, split)
        return path

    def run(self, session_id: str, action):
        """`action(session)` under the session's lock; the snapshot is refreshed after it."""
        slot = self.slot(session_id)
        with slot.lock:
            session = self.opened(slot)
            try:
                return action(session)
            finally:
                self._snapshot(slot)

    # -- state --

    def _snapshot(self, slot: Slot) -> None:
        if slot.session is not None:
            slot.snapshot = slot.session.summary()

    def has_snapshot(self, session_id: str) -> bool:
        """Whether the session's state is in memory (`state` then reads no file)."""
        slot = self._slots.get(session_id)
        return slot is not None and slot.snapshot is not None

    def state(self, session_id: str) -> dict:
        """The session's state, never waiting for a lock or a worker: the last snapshot (or, for a
        session not opened yet, what its files say: `SessionFolder.summary`) and the job."""
        slot = self.slot(session_id)
        summary = slot.snapshot or SessionFolder.open(self.folder(session_id)).summary()
        job = slot.job
        running = job is not None and job.state == "running"
        return {**summary.model_dump(), "running": running, "job": job and job.model_dump()}

    # -- training --

    def _job_file(self, session_id: str) -> Path:
        return self.root / JOBS_DIR / f"{session_id}.json"

    def _record(self, slot: Slot) -> None:
        atomic_write_json(self._job_file(slot.id), {"kind": "train", **slot.job.model_dump()})

    def train(self, session_id: str, steps: int) -> dict:
        """Start training `steps` more steps in a worker thread; 409 when a job is running."""
        slot = self.slot(session_id)
        with slot.lock:
            if slot.job is not None and slot.job.state == "running":
                raise ServiceError(
                    409, f"session {session_id!r}: training is already running (until step {slot.job.target})"
                )
            session = self.opened(slot)
            slot.job = Job(target=session.step + int(steps), start=session.step, step=session.step)
            self._record(slot)
            self._start(slot)
            return slot.job.model_dump()

    def _start(self, slot: Slot) -> None:
        slot.thread = threading.Thread(target=self._train_worker, args=(slot,), name=f"train-{slot.id}", daemon=True)
        slot.thread.start()

    def _train_worker(self, slot: Slot) -> None:
        job, recorded_at = slot.job, [monotonic()]

        def chunk_done(last: dict) -> None:
            job.step = slot.session.step
            if monotonic() - recorded_at[0] >= RECORD_EVERY_S:
                self._record(slot)
                recorded_at[0] = monotonic()
            self._snapshot(slot)

        try:
            with slot.lock:
                session = self.opened(slot)
            stop = self._stopping.is_set
            session.train_for(job.target - session.step, self.checkpoint_every, stop, hold=slot.lock, each=chunk_done)
            with slot.lock:
                self._snapshot(slot)
                if not stop():  # stopped by a shutdown: left running, resumed on restart
                    job.step, job.state, job.finished = session.step, "done", time()
                    self._record(slot)
        except Exception as error:  # noqa: BLE001 -- any failure is reported to the client polling the job
            job.state, job.finished, job.error = "failed", time(), status_of(error)[1]
            self._record(slot)

    def resume(self) -> list[str]:
        """Restart the training jobs a stopped or killed service left running; returns their ids."""
        resumed = []
        folder = self.root / JOBS_DIR
        for path in sorted(folder.glob("*.json")) if folder.is_dir() else []:
            session_id = path.stem
            try:
                record = read_json(path)
                if record.get("state") != "running" or not (self.root / session_id / SESSION_FILE).is_file():
                    continue
                slot = self.slot(session_id)
                with slot.lock:
                    session = self.opened(slot)
                    target = int(record["target"])
                    redone = max(0, int(record.get("step", session.step)) - session.step)
                    slot.job = Job(
                        target=target,
                        start=int(record.get("start", session.step)),
                        step=session.step,
                        resumed_from=session.step,
                        redone=redone,
                    )
                    self._record(slot)
                    self._start(slot)
                log.info(
                    "session %s: training resumed from step %d, its last save (%d steps after it are trained "
                    "again), until step %d",
                    session_id,
                    session.step,
                    redone,
                    target,
                )
                resumed.append(session_id)
            except Exception as error:  # noqa: BLE001 -- one bad session must not stop the others
                slot = self.slot(session_id, must_exist=False)
                slot.job = Job(target=0, start=0, step=0, state="failed", error=status_of(error)[1], finished=time())
        return resumed

    def shutdown(self, timeout: float = 30.0) -> None:
        """Stop the training workers at their next chunk (each saves its session first), drop the
        requests not started, and release the sessions' folders."""
        self._stopping.set()
        self.work.shutdown()
        for slot in list(self._slots.values()):
            if slot.thread is not None:
                slot.thread.join(timeout)
        for slot in list(self._slots.values()):
            if slot.folder_lock is not None:
                slot.folder_lock.release()
                slot.folder_lock = None
