"""Where `nerfaug serve` does its long work (proposals, captures, uncertainty images, evaluation,
opening and creating sessions): a dedicated pool of worker threads, apart from the event loop
that answers `/health` and session states, with a bounded queue per session.

A session's requests run one at a time, in arrival order; a session takes at most one worker, so
a slow session never holds workers that other sessions' requests could use. A request beyond a
session's queue is answered 429, one beyond the whole service's 503, both with Retry-After.
"""

from __future__ import annotations

import math
import statistics
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from time import monotonic

from nerfaug.service.errors import ServiceError

WORKERS = 2  # threads doing sessions' work at once (each runs torch on the service's threads)
PER_SESSION = 4  # requests of one session queued or running
TOTAL = 64  # requests of all sessions queued or running


class WorkQueues:
    """Bounded per-session queues over one worker pool; see the module docstring.

    Args:
        workers: worker threads.
        per_session: requests one session may have queued or running (more: 429).
        total: requests all sessions may have queued or running (more: 503).
    """

    def __init__(self, workers: int = WORKERS, per_session: int = PER_SESSION, total: int = TOTAL):
        if workers < 1 or per_session < 1 or total < 1:
            raise ValueError(f"workers {workers}, per_session {per_session}, total {total}: each must be >= 1")
        self.workers, self.per_session, self.total = workers, per_session, total
        self._pool = ThreadPoolExecutor(workers, thread_name_prefix="nerfaug-work")
        self._lock = threading.Lock()
        self._queues: dict[str, deque] = {}
        self._running: set[str] = set()
        self._pending = 0
        self._seconds: deque[float] = deque(maxlen=32)  # recent requests' durations

    def pending(self, key: str | None = None) -> int:
        """Requests queued or running (of session `key`, or of all)."""
        with self._lock:
            if key is None:
                return self._pending
            return len(self._queues.get(key, ())) + (key in self._running)

    def retry_after(self, waiting: int) -> int:
        """Seconds a client should wait before asking again: the recent median duration times the
        requests ahead of it, 1 to 60."""
        typical = statistics.median(self._seconds) if self._seconds else 1.0
        return max(1, min(60, math.ceil(typical * max(1, waiting))))

    def submit(self, key: str, work: Callable[[], object]) -> Future:
        """Queue `work()` behind session `key`'s earlier requests; its future holds the result.

        Raises:
            ServiceError: 429 when the session's queue is full, 503 when the service's is.
        """
        with self._lock:
            waiting = len(self._queues.get(key, ())) + (key in self._running)
            if waiting >= self.per_session:
                raise ServiceError(
                    429,
                    f"session {key!r}: {waiting} requests are queued or running, the most one session takes; "
                    "retry later",
                    headers={"Retry-After": str(self.retry_after(waiting))},
                )
            if self._pending >= self.total:
                raise ServiceError(
                    503,
                    f"the service has {self._pending} requests queued or running, the most it takes; retry later",
                    headers={"Retry-After": str(self.retry_after(self._pending // self.workers))},
                )
            future: Future = Future()
            self._queues.setdefault(key, deque()).append((future, work))
            self._pending += 1
            if key not in self._running:
                self._running.add(key)
                self._pool.submit(self._run_next, key)
        return future

    def _run_next(self, key: str) -> None:
        with self._lock:
            future, work = self._queues[key].popleft()
        if future.set_running_or_notify_cancel():  # False: the client gave up while it waited
            start = monotonic()
            try:
                future.set_result(work())
            except BaseException as error:  # noqa: BLE001 -- handed to the request that waits for it
                future.set_exception(error)
            finally:
                self._seconds.append(monotonic() - start)
        with self._lock:
            self._pending -= 1
            if self._queues[key]:
                self._pool.submit(self._run_next, key)  # behind other sessions' requests: fair turns
            else:
                del self._queues[key]
                self._running.discard(key)

    def shutdown(self) -> None:
        """Stop taking work; requests not started are dropped."""
        self._pool.shutdown(wait=False, cancel_futures=True)
