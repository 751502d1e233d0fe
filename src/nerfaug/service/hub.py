"""The service's sessions: a `SessionPool` (`nerfaug.capture.pool`: the sessions under the service
root, their locks, training jobs resumed on restart, state from snapshots) whose requests wait in
bounded per-session queues (`nerfaug.service.work`: 429/503 when full), each refused before it is
queued when it could not run (an unknown session, an id taken, too many sessions training).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from nerfaug.capture.pool import MAX_TRAINING, SessionPool
from nerfaug.capture.requests import CHECKPOINT_EVERY_S, RequestError
from nerfaug.nerf.engine import Engine
from nerfaug.service.errors import public_answer
from nerfaug.service.work import PER_SESSION, TOTAL, WORKERS, WorkQueues


class SessionHub(SessionPool):
    """The sessions under `root` (`SessionPool`), their requests queued (`WorkQueues`).

    Args:
        root, device, checkpoint_every, max_training: the pool's (`SessionPool`).
        workers, per_session, total: the request queues' bounds (`WorkQueues`).
        engine_settings: engine settings (nested by component) changed in every session created
            (`nerfaug serve --engine.field.hidden-dim 32`).
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
        engine_settings: dict | None = None,
    ):
        # A failed job's error as a request's would be answered: never what a file holds, nor a server path.
        super().__init__(root, device, checkpoint_every, max_training, describe=lambda e: public_answer(e, root)[1])
        self.work = WorkQueues(workers, per_session, total)
        self.engine_settings = dict(engine_settings or {})

    def settings_of(self, request):
        """A creation request (`SessionSettings`) whose engine carries the service's engine settings."""
        if not self.engine_settings:
            return request
        try:
            engine = Engine.read(request.engine).with_settings(self.engine_settings)
        except ValueError as error:  # e.g. proposal settings for an engine without proposal networks
            raise RequestError("engine", request.engine, f"refuses this service's engine settings: {error}") from None
        return replace(request, engine=engine).checked()

    def submit(self, session_id: str, action: Callable):
        """`run(session_id, action)` queued behind the session's earlier requests (a Future)."""
        self.require(session_id)
        return self.work.submit(session_id, lambda: self.run(session_id, action))

    def submit_create(self, session_id: str, create: Callable):
        """`create(session_id, create)` in the session's queue (a Future)."""
        self.refuse_existing(session_id)
        return self.work.submit(session_id, lambda: self.create(session_id, create))

    def submit_train(self, session_id: str, steps: int):
        """`train(session_id, steps)` in the session's queue (opening a session loads its model)."""
        self.require(session_id)
        self.refuse_training_beyond(session_id)
        return self.work.submit(session_id, lambda: self.train(session_id, steps))

    def shutdown(self, timeout: float = 30.0) -> None:
        """Drop the requests not started, then stop the pool (`SessionPool.shutdown`)."""
        self.work.shutdown()
        super().shutdown(timeout)
