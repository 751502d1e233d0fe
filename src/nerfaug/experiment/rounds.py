"""A run's rounds of selection (`experiment.schedule`): which candidates each round may still
choose, and what the run's record keeps of them: each round's step, chosen views, scoring and
oracle times, and the test metrics after it (a learning curve).

A point of the curve between rounds is measured on `CURVE_VIEWS` test views spread over the test
views (the same ones in every run of a scene, so methods compare on the same views); the last
round's point is the run's evaluation on all its test views. A run of one round keeps no such
record: its result is what it was before rounds existed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from nerfaug.data import Views
from nerfaug.data.views import spread_over_frames
from nerfaug.evaluation import evaluate_views
from nerfaug.experiment.schedule import CURVE_VIEWS


def curve_views(test: Views) -> Views:
    """The test views a curve's points between rounds are measured on: at most `CURVE_VIEWS`,
    spread over `test`."""
    return test.subset(spread_over_frames(CURVE_VIEWS, len(test)))


@dataclass
class Rounds:
    """The rounds of one run as they are played: the candidates left, every view chosen, and the
    record of each round.

    Attributes:
        pool_size: candidates in the run's pool.
        views: views the model trains on now (the initial ones, then each round's added).
        chosen: pool indices chosen so far, in the order chosen.
        first: the first round's `Selection` (scored over the whole pool: the run's selection.json
            and hemisphere map show its scores, with every chosen view).
        played: one dict per round: {"round", "step", "chosen", "names", "views", "selection_s",
            "oracle_s", and, once measured, "metrics", "test_views", "metrics_step"}.
        start: the curve's first point, before the first round: {"step", "views", "test_views", "metrics"}.
    """

    pool_size: int
    views: int
    chosen: list[int] = field(default_factory=list)
    first: object = None
    played: list[dict] = field(default_factory=list)
    start: dict | None = None

    def remaining(self) -> list[int]:
        """Pool indices not chosen yet, in pool order: the next round's candidates."""
        taken = set(self.chosen)
        return [i for i in range(self.pool_size) if i not in taken]

    def measure(self, model, test: Views, step: int, lpips, timing: dict) -> None:
        """The curve's point at `step`, before the next round: the start, or the last round's
        metrics. Times it into `timing["curve"]`."""
        begin = time.perf_counter()
        subset = curve_views(test)
        evaluation = evaluate_views(
            lambda cameras, index: model.render_image(cameras, index)["rgb"], subset, lpips=lpips, progress=False
        )
        point = {"step": step, "views": self.views, "test_views": len(subset), "metrics": evaluation.mean}
        if self.played:
            self.played[-1].update({k: point[k] for k in ("metrics", "test_views")} | {"metrics_step": step})
        else:
            self.start = point
        timing["curve"] = timing.get("curve", 0.0) + time.perf_counter() - begin

    def add(self, step: int, selection, chosen: list[int], names: list[str], spent: dict) -> None:
        """Record a round at `step` that chose pool indices `chosen` (named `names`); `spent`: its
        {"selection", "oracle"} seconds."""
        if self.first is None:
            self.first = selection
        self.chosen += chosen
        self.views += len(chosen)
        self.played.append(
            {
                "round": len(self.played) + 1,
                "step": step,
                "chosen": chosen,
                "names": names,
                "views": self.views,
                "selection_s": spent["selection"],
                "oracle_s": spent["oracle"],
            }
            | ({"uniform_fill": selection.uniform_fill} if selection.uniform_fill else {})
        )

    def record(self, metrics: dict, test_views: int, steps: int) -> dict:
        """What a run's result keeps: {"rounds": [...], "before_rounds": {...}}, the last round's
        metrics those of the run's evaluation (`metrics` on all `test_views`, at step `steps`);
        empty for a run of one round, whose record is as it always was."""
        if len(self.played) <= 1:
            return {}
        self.played[-1].update({"metrics": metrics, "test_views": test_views, "metrics_step": steps})
        return {"rounds": self.played, "before_rounds": self.start}


__all__ = ["Rounds", "curve_views"]
