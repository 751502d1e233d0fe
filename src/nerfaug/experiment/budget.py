"""How long a sweep may go on: whether another unit of work (a run, or a trial batch) fits before
a deadline, judged by the longest unit so far."""

from __future__ import annotations

import time


class Budget:
    """Whether another unit of work fits before a deadline: by the longest unit so far."""

    def __init__(self, deadline: float | None):
        self.deadline, self.longest, self.started = deadline, 0.0, {}

    def allows(self) -> bool:
        return self.deadline is None or time.monotonic() + self.longest <= self.deadline

    def start(self, unit_id) -> None:
        self.started[unit_id] = time.monotonic()

    def end(self, unit_id) -> None:
        self.longest = max(self.longest, time.monotonic() - self.started.pop(unit_id))
