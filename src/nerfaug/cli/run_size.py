"""How big an experiment or a study is and about how long it takes on this device, printed by
`nerfaug run` and `nerfaug study` before they start: a rough model from the per-run costs measured
in BENCHMARKS.md ("Per-run costs the time estimate reads"; one torch thread per run), divided by
the engine version's measured speed (`VERSION_SPEED`), with each dataset scene's own candidates,
test views and image size (`SceneSize`); not a promise: a busy machine takes longer, a faster one
less.

It imports no torch: the callers name each run's scoring (the method's estimator in
`nerfaug.selection.methods.METHODS`), so this module needs no method registry.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from nerfaug.experiment.schedule import CURVE_VIEWS, curve_evaluations

if TYPE_CHECKING:
    from nerfaug.experiment.config import ExperimentConfig


@dataclass(frozen=True)
class Costs:
    """Seconds of one run's parts, one torch thread.

    Attributes:
        step: one training step (the mean over a run's steps, the early slow ones included).
        view: evaluating one test view of 100x100 pixels: its render, PSNR, SSIM and LPIPS (the
            cost grows with the pixels).
        figures: the first test view's uncertainty figures (`view_uncertainty`), FisherRF's
            estimate of what the training views know most of it.
        finish: setting the run up, the health check (renders of its training views) and
            writing its folder.
        scoring: estimator -> scoring 100 candidate views (the cost grows with the pool); the
            estimators absent ("none", "distance") read camera poses only and cost nothing here.
    """

    step: float
    view: float
    figures: float
    finish: float
    scoring: Mapping[str, float]


# The project's 2-core CPU VM, one thread per run ("Per-run costs the time estimate reads"). cpu
# engine: the 20 runs of the idle demo (70 ms a step over 800 steps, 4 s for 20 views, 9.7 s of
# figures; selection from 100 candidates 2.4 s for ours and entropy, 27 s for FisherRF).
# nerfacto-cpu: "Trial batches on the CPU" (130 s for 2000 steps, 31.6 s for 50 views) and single
# runs on the shared machine (selection, figures). Setup, health check and files: a single run's
# wall less its recorded phases, 1.1-1.9 s. The paper engine: 5.9 s a step ("nerfacto-CPU
# preset"), the rest guesses from that step, not measured. test: the test suite's tiny engine.
NERFACTO_CPU = Costs(0.065, 0.60, 8.0, 1.5, {"combined": 7.4, "entropy": 7.4, "fisher": 28.0})
CPU_COSTS = {
    "cpu": Costs(0.070, 0.20, 9.7, 1.5, {"combined": 2.4, "entropy": 2.4, "fisher": 27.0}),
    "nerfacto-cpu": NERFACTO_CPU,
    "nerfacto-cpu-last-sample": NERFACTO_CPU,
    "paper": Costs(5.9, 3.0, 60.0, 10.0, {"combined": 80.0, "entropy": 80.0, "fisher": 600.0}),
    "test": Costs(0.005, 0.01, 0.5, 0.2, {"combined": 1.0, "entropy": 1.0, "fisher": 1.0}),
}
# How much faster than the reference engine (whose runs the costs above were measured on) an engine
# version's arithmetic runs, a whole run's CPU seconds: nerfacto-cpu's runs of the study protocol
# alternating with the reference's on a quiet machine ("`cpu-fused-3` at 1.93x the reference's
# runs per core-hour"), taken for every part of a run but its setup and files, and for every
# engine with hash grids (nerfacto-cpu is the one measured).
VERSION_SPEED = {"hash-cpu-1": 1.61, "cpu-fused-3": 1.93}
# One H100 ("GPU: the paper preset on an H100": 0.026 s a step, 0.35 s a 400x400 view, 17.7 s of
# figures, 4.2 s besides the phases, ours' selection from 500 candidates 2.3 s; FisherRF's not
# measured there, taken as 11x ours' as on the CPU). Other engines were not measured on a GPU:
# taken as the paper preset's.
GPU_COSTS = {"paper": Costs(0.026, 0.022, 17.7, 4.2, {"combined": 0.46, "entropy": 0.46, "fisher": 5.0})}
# Runs sharing one GPU: 4 at once did 1.7x the work of one alone ("GPU: the paper preset on an H100").
GPU_SHARED_THROUGHPUT = 1.7
# One Cycles frame of a built-in scene at 100x100 pixels, 16 samples (the idle demo rendered 126
# in 28 s, "The demo's time estimate against its time"), and Blender's start.
RENDER_VIEW_S = 0.2
RENDER_START_S = 2.0


@dataclass(frozen=True)
class SceneSize:
    """What a dataset scene's runs cost by where it differs from the config's (a built-in scene
    follows the config: --pool candidates, --n-test test views, --resolution square images).

    Attributes:
        name: the scene's name in results.
        pool: the candidate views each round scores.
        test: the test views evaluated.
        pixels: an image's width x height at the size the runs use.
    """

    name: str
    pool: int
    test: int
    pixels: int


def scene_sizes(checked: Mapping[str, Mapping]) -> dict[str, SceneSize]:
    """name -> size of each dataset scene `nerfaug.experiment.sweep.check_config` checked (its
    record of one: "pool", "test", "width", "height"); built-in scenes are left out."""
    return {
        name: SceneSize(name, int(s["pool"]), int(s["test"]), int(s["width"]) * int(s["height"]))
        for name, s in checked.items()
        if "pool" in s
    }


class RunKind(NamedTuple):
    """What a run's cost depends on besides the protocol: its engine (in words, as `costs` reads
    it), its method's scoring estimator ("none" for uniform), the engine version it runs
    (`ExperimentConfig.engine_version`: None for the reference engine) and its scene's size (None:
    the config's). A plain (engine, scoring) pair reads as one of the reference engine on a scene
    of the config's size."""

    engine: str
    scoring: str
    version: str | None = None
    scene: SceneSize | None = None


def costs(engine: str, device: str) -> Costs:
    """The costs of `engine` (an `Engine` in words, "cpu --engine.field.hidden-dim 48": its preset's) on `device`."""
    base = engine.split()[0]
    if device == "cuda":
        return GPU_COSTS.get(base, GPU_COSTS["paper"])
    return CPU_COSTS.get(base, CPU_COSTS["cpu"])


def run_seconds(
    engine: str, scoring: str, config: ExperimentConfig, version: str | None = None, scene: SceneSize | None = None
) -> float:
    """About how long one run of `config` takes with `engine` at engine version `version` (None:
    the reference), its method scoring the candidates with the estimator `scoring` ("none" for
    uniform), on a scene of size `scene` (None: the config's pool, test views and resolution):
    training, selection, evaluation, the uncertainty figures when `config.view_uncertainty`, and
    the rest. With rounds (`experiment.schedule`): a selection each round (each over the whole
    pool: the views taken are few) and the learning curve's test views before each but the last."""
    c = costs(engine, config.device)
    if scene is None:
        pool, test, pixels = config.pool, config.n_test, config.resolution**2
    else:
        pool, test, pixels = scene.pool, scene.test, scene.pixels
    view = c.view * pixels / 100**2
    work = (
        config.steps * c.step
        + c.scoring.get(scoring, 0.0) * pool / 100 * config.rounds
        + test * view
        + curve_evaluations(config) * min(CURVE_VIEWS, test) * view
        + (c.figures if config.view_uncertainty else 0.0)
    )
    return work / VERSION_SPEED.get(version, 1.0) + c.finish


def runs_in_parallel(at_once: int, device: str) -> float:
    """How many runs' work `at_once` runs do together. On a CPU, one run per core: two one-thread
    runs side by side on the 2-core VM each cost what one alone does ("Per-run costs the time
    estimate reads"), and runs beyond the cores wait for one."""
    if device == "cuda":
        return min(at_once, GPU_SHARED_THROUGHPUT)
    return min(at_once, os.cpu_count() or 1)


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


def estimate(runs: Mapping[tuple, int], config: ExperimentConfig, workers: int) -> tuple[float, str]:
    """(seconds, one sentence) for `runs` (`RunKind`, or an (engine, scoring estimator) pair ->
    runs still to do) of `config`, `workers` runs at a time."""
    each = {}
    for kind, n in runs.items():
        if n:
            engine, scoring, version, scene = RunKind(*kind)
            each[kind] = run_seconds(engine, scoring, config, version, scene)
    count = sum(runs.values())
    at_once = max(1, min(workers, count))
    total = sum(n * each[kind] for kind, n in runs.items() if n)
    # The work spread over the runs in parallel, but never less than the longest run.
    seconds = max(total / runs_in_parallel(at_once, config.device), max(each.values())) if count else 0.0
    return seconds, f"about {duration(seconds)} on this device ({device_words(config.device, at_once)})"


def assumed(runs: Mapping[tuple, int], device: str) -> str:
    """What the estimate of `runs` on `device` took from their kinds beyond the config, in words:
    an engine version's speed, each dataset scene's candidates where a method scores them ("" when
    nothing)."""
    kinds = [RunKind(*kind) for kind, n in runs.items() if n]
    versions = sorted({k.version for k in kinds if k.version in VERSION_SPEED})
    said = [f"engine version {v} at {VERSION_SPEED[v]:.2f}x the reference engine's speed" for v in versions]
    scenes = {k.scene.name: k.scene for k in kinds if k.scene is not None}
    if scenes and any(k.scoring in costs(k.engine, device).scoring for k in kinds):
        pools = ", ".join(f"{name} {scene.pool}" for name, scene in scenes.items())
        said.append(f"candidates scored a round: {pools}")
    return "; ".join(said)


def size_line(
    what: str,
    runs: Mapping[tuple, int],
    finished: int,
    shape: str,
    config: ExperimentConfig,
    workers: int,
    render: tuple[int, int] | None = None,
) -> str:
    """The line printed before the work starts: how many runs, their size, and about how long.

    Args:
        what: the command, e.g. "nerfaug run".
        runs: `RunKind` (or an (engine, the method's scoring estimator) pair) -> runs to do (those
            already finished excluded).
        finished: runs already finished (skipped).
        shape: what multiplies to the run count, e.g. "1 scene x 4 methods x 5 trials".
        config: the protocol every run follows (its image size, steps, test views, pool, device).
        workers: how many runs at a time.
        render: (scenes, views per scene) of built-in scenes rendered first, if not yet cached.
    """
    seconds, when = estimate(runs, config, workers)
    to_do = sum(runs.values())
    done = f", {finished} already finished" if finished else ""
    side = config.resolution
    names = sorted({kind[0] for kind in runs}) or [str(config.engine)]  # said: `nerfaug train`'s default differs
    engines = " and ".join(names)
    # The schedule, where it is not the paper's one round.
    rounds = ""
    if config.rounds > 1:
        rounds = f", {config.n_initial} initial views + {config.rounds} rounds of {config.n_new}"
    line = (
        f"{what}: {to_do + finished} runs ({shape}{done}), {side}x{side} pixels, {config.steps} steps each{rounds} "
        f"with the {engines} engine{'s' if len(names) > 1 else ''}; {to_do} to run: {when}"
    )
    if render is not None and render[0]:
        line += (
            f", plus about {duration(render[0] * render_seconds(render[1], side))} to render "
            f"{render[0]} built-in scene{'s' if render[0] > 1 else ''} the first time"
        )
    said = assumed(runs, config.device)
    said = f" ({said})" if said else ""
    return line + f". An estimate from the costs measured in BENCHMARKS.md{said}: a busy machine takes longer."


def per_cell(count: int, word: str) -> str:
    return f"{count} {word}{'s' if count != 1 else ''}"


__all__ = [
    "VERSION_SPEED",
    "Costs",
    "RunKind",
    "SceneSize",
    "assumed",
    "estimate",
    "per_cell",
    "render_seconds",
    "run_seconds",
    "scene_sizes",
    "size_line",
]
