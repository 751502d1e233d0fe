"""How long a sweep may go on: whether another unit of work (a run, or a batch) fits before
a deadline, judged by the longest unit so far (`Budget`), or by a model of this machine's times
(`TimeModel`: how many runs the next batch may hold)."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field


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


@dataclass
class TimeModel:
    """How long a batch of given runs takes on this machine, from a measurement of the
    machine itself (a few training steps at the study's size, one test view rendered) and then
    from the batches that finished: what a GPU slot's scheduler sizes its next batch by.

    A batch of n runs costs `steps` x (seconds a step of a batch of n runs) for training, plus per
    run its evaluation (`n_test` views), its method's selection and an overhead (set-up, the
    oracle, the run's files and figures)."""

    steps: int
    n_test: int
    step_s: dict[int, float]
    """seconds a training step takes with n runs in the batch, as measured (n -> seconds)."""
    view_s: float
    """seconds to render and score one test view of one run."""
    overhead_s: float
    """seconds per run outside training, evaluation and selection."""
    select_s: dict[str, float] = field(default_factory=dict)
    """seconds a method's selection took (learned from finished runs)."""
    default_select_s: float = 10.0
    """a method's selection before any of its runs finished."""

    def step_seconds(self, n: int) -> float:
        """Seconds a step of a batch of `n` runs: linear between the sizes measured, from the
        nearest two beyond them; proportional to n from a single measured size (the cautious
        guess: no sharing gain assumed)."""
        points = sorted(self.step_s.items())
        if len(points) == 1:
            ((m, s),) = points
            return s * max(1.0, n / m)
        if n <= points[0][0]:
            (n0, s0), (n1, s1) = points[0], points[1]
        else:
            below = [p for p in points if p[0] <= n]
            above = [p for p in points if p[0] > n]
            (n0, s0), (n1, s1) = (below[-1], above[0]) if above else (points[-2], points[-1])
        return max(min(s0, s1), s0 + (s1 - s0) * (n - n0) / (n1 - n0))

    def predict(self, methods: list[str]) -> float:
        """Seconds a batch of runs of `methods` (one entry per run) takes."""
        per_run = sum(
            self.n_test * self.view_s + self.overhead_s + self.select_s.get(m, self.default_select_s) for m in methods
        )
        return self.steps * self.step_seconds(len(methods)) + per_run

    def fits(self, methods: list[str], left_s: float, most: int, margin: float = 1.15) -> int:
        """The most runs of the head of `methods` (at most `most`) whose batch, its prediction
        times `margin`, ends within `left_s` seconds; 0 when not even one does."""
        n = min(most, len(methods))
        while n > 0 and margin * self.predict(methods[:n]) > left_s:
            n -= 1
        return n

    def learn(self, results: list[dict], wall_s: float) -> None:
        """Update from a finished batch: its `results` (result.json records, with their "timing":
        each run's share of the batch's training, its evaluation and selection) and its wall time
        (records and archive included)."""
        if not results:
            return
        n = max(r.get("batch_size", len(results)) for r in results)
        timing = [r["timing"] for r in results]
        train = sum(t.get("train_before", 0.0) + t.get("train_after", 0.0) for t in timing)
        self.step_s[n] = train / self.steps * n / len(results)
        self.view_s = max(t.get("evaluation", 0.0) for t in timing) / self.n_test
        for r in results:
            self.select_s[r["method"]] = max(self.select_s.get(r["method"], 0.0), r["timing"].get("selection", 0.0))
        rest = (
            wall_s - train * n / len(results) - sum(t.get("evaluation", 0.0) + t.get("selection", 0.0) for t in timing)
        )
        self.overhead_s = max(0.0, rest) / len(results)

    def to_dict(self) -> dict:
        return asdict(self)
