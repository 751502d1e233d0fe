"""How big an experiment or a study is and about how long it takes on this device, printed by
`nerfaug run` and `nerfaug study` before they start: a rough model from the costs measured in
BENCHMARKS.md (seconds per training step, per evaluated view, per selection; one torch thread per
run), not a promise: a busy machine takes longer, a faster one less.
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Costs:
    """Seconds of one run's parts, one torch thread (BENCHMARKS.md).

    Attributes:
        step: one training step.
        view: evaluating one test view of 100x100 pixels (the cost grows with the pixels).
        select: choosing one run's views (scoring the candidates).
    """

    step: float
    view: float
    select: float


# The project's CPU machine, one thread per run: cpu engine ("NeRF engine: one CPU trial": ~28 ms per
# step at 2000 steps, 5.5 s for 50 views; "Main job": selection 5-13 s), nerfacto-cpu ("nerfacto-CPU
# preset": 70 s of CPU for 2000 steps, evaluation and selection 2.4x and 6x the cpu engine's), paper
# (5.9 s of CPU per step), test (the test suite's tiny engine).
CPU_COSTS = {
    "cpu": Costs(step=0.028, view=0.11, select=10.0),
    "nerfacto-cpu": Costs(step=0.035, view=0.26, select=30.0),
    "nerfacto-cpu-last-sample": Costs(step=0.035, view=0.26, select=30.0),
    "paper": Costs(step=5.9, view=3.0, select=600.0),
    "test": Costs(step=0.005, view=0.01, select=1.0),
}
# One H100 ("GPU: the paper preset on an H100": 0.026 s per step, 0.35 s per 400x400 view, 2.3 s
# of selection). Other engines were not measured on a GPU: taken as the paper preset's.
GPU_COSTS = {"paper": Costs(step=0.026, view=0.022, select=2.3)}
# One Cycles frame of a built-in scene at 100x100 pixels, 16 samples ("Built-in scenes": 0.15 s
# idle to 0.5 s under load), and Blender's start.
RENDER_VIEW_S = 0.3
RENDER_START_S = 2.0


def costs(engine: str, device: str) -> Costs:
    """The costs of `engine` (a preset, or a variant BASE+FIELD=VALUE: its base's) on `device`."""
    base = engine.split("+")[0]
    if device == "cuda":
        return GPU_COSTS.get(base, GPU_COSTS["paper"])
    return CPU_COSTS.get(base, CPU_COSTS["cpu"])


def run_seconds(engine: str, device: str, steps: int, n_test: int, resolution: int) -> float:
    """About how long one run takes: `steps` training steps, one selection, `n_test` test views of
    `resolution` pixels across evaluated."""
    c = costs(engine, device)
    return steps * c.step + n_test * c.view * (resolution / 100) ** 2 + c.select


def render_seconds(views: int, resolution: int) -> float:
    """About how long rendering one built-in scene's dataset takes (`views` frames)."""
    return RENDER_START_S + views * RENDER_VIEW_S * (resolution / 100) ** 2


def duration(seconds: float) -> str:
    """ "40 s", "12 min", "3.5 h", "2.1 days"."""
    if seconds < 90:
        return f"{max(1, round(seconds))} s"
    if seconds < 90 * 60:
        return f"{round(seconds / 60)} min"
    if seconds < 48 * 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def device_words(device: str, workers: int) -> str:
    """This device as the estimate says it, e.g. "cpu, 2 runs at a time on 2 cores"."""
    if device == "cuda":
        return f"cuda, {workers} run{'s' if workers > 1 else ''} at a time"
    cores = os.cpu_count() or 1
    return f"cpu, {workers} run{'s' if workers > 1 else ''} at a time on {cores} core{'s' if cores > 1 else ''}"


def estimate(
    runs: dict[str, int], device: str, steps: int, n_test: int, resolution: int, workers: int
) -> tuple[float, str]:
    """(seconds, one sentence) for `runs` (engine -> runs still to do) at `workers` runs at a time."""
    total = sum(n * run_seconds(engine, device, steps, n_test, resolution) for engine, n in runs.items())
    count = sum(runs.values())
    at_once = max(1, min(workers, count))
    # Runs spread over the workers: the work divided among them, but never less than one run.
    longest = max((run_seconds(e, device, steps, n_test, resolution) for e, n in runs.items() if n), default=0.0)
    seconds = max(total / at_once, longest) if count else 0.0
    return seconds, f"about {duration(seconds)} on this device ({device_words(device, at_once)})"


def size_line(
    what: str,
    runs: dict[str, int],
    finished: int,
    shape: str,
    resolution: int,
    steps: int,
    n_test: int,
    device: str,
    workers: int,
    render: tuple[int, int] | None = None,
) -> str:
    """The line printed before the work starts: how many runs, their size, and about how long.

    Args:
        what: the command, e.g. "nerfaug run".
        runs: engine -> runs to do (those already finished excluded).
        finished: runs already finished (skipped).
        shape: what multiplies to the run count, e.g. "1 scene x 4 methods x 5 trials".
        resolution, steps, n_test: each run's image size, training steps and test views.
        device, workers: where the runs go and how many at a time.
        render: (scenes, views per scene) of built-in scenes rendered first, if not yet cached.
    """
    seconds, when = estimate(runs, device, steps, n_test, resolution, workers)
    to_do = sum(runs.values())
    done = f", {finished} already finished" if finished else ""
    line = (
        f"{what}: {to_do + finished} runs ({shape}{done}), {resolution}x{resolution} pixels, {steps} steps each; "
        f"{to_do} to run: {when}"
    )
    if render is not None and render[0]:
        line += (
            f", plus about {duration(render[0] * render_seconds(render[1], resolution))} to render "
            f"{render[0]} built-in scene{'s' if render[0] > 1 else ''} the first time"
        )
    return line + ". An estimate from the costs measured in BENCHMARKS.md: a busy machine takes longer."


def per_cell(count: int, word: str) -> str:
    return f"{count} {word}{'s' if count != 1 else ''}"


__all__ = ["Costs", "estimate", "per_cell", "render_seconds", "run_seconds", "size_line"]
