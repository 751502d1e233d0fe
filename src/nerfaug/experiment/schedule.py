"""A run's schedule of views: `n_initial` views, then `rounds` rounds of `n_new` views, the first at
`add_at_step` and each next one `round_every` steps later, training on to `steps`. One round is the
paper's protocol (6 initial views, 6 added at step 200); the field's active-learning protocol
(FisherRF's) is few initial views and one view a round.

Light (no torch): the sweep's checks, the time estimate (`nerfaug.cli.run_size`) and the report
read it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol


class Schedule(Protocol):
    """The settings a schedule is made of, as an `ExperimentConfig` (`nerfaug.experiment.config`)
    holds them. Named here without importing it: it imports this module, to check its schedule
    with `check_schedule` whenever one is made."""

    steps: int
    add_at_step: int
    n_new: int
    rounds: int
    round_every: int
    pool: int
    batch: int


ExperimentConfig = Schedule  # what every function here is given

CURVE_VIEWS = 8
"""Test views a learning curve's points are measured on between rounds (spread over the test
views); the last point is the run's evaluation on all of them."""


ROUND_GROWTH = ("fixed", "per-view")
"""How the steps between two rounds are set: `round_every` each, or `round_every` per view in the
model after the earlier round."""


def round_steps(config: ExperimentConfig) -> list[int]:
    """The training step of each round: `add_at_step`, then every `round_every` steps ("fixed"), or
    `round_every` x the views in the model after the round before ("per-view").

    Example: 4 initial views, one a round from step 200, `round_every` 20, per view: rounds at
    200, 300 (+20 x 5 views), 420 (+20 x 6), ...
    """
    steps = [config.add_at_step]
    for done in range(1, config.rounds):
        views = config.n_initial + done * config.n_new if config.round_growth == "per-view" else 1
        steps.append(steps[-1] + config.round_every * views)
    return steps


def added_views(config: ExperimentConfig) -> int:
    """Views a run adds over all its rounds."""
    return config.rounds * config.n_new


def curve_evaluations(config: ExperimentConfig) -> int:
    """Test-view evaluations a run makes besides its last: before the first round and after each
    round but the last (none with one round)."""
    return config.rounds if config.rounds > 1 else 0


def schedule_words(settings: Mapping) -> str:
    """A schedule in words, from settings as a record keeps them (a dict with `n_initial`, `n_new`,
    `add_at_step` and, where more than one round, `rounds`, `round_every`, `round_growth`).

    Example:
        >>> schedule_words({"n_initial": 6, "n_new": 6, "add_at_step": 200})
        '6 initial views, 6 added at step 200'
        >>> schedule_words({"n_initial": 4, "n_new": 1, "add_at_step": 200, "rounds": 8, "round_every": 100})
        '4 initial views, then 8 rounds of 1 view, at step 200 and every 100 steps after'
        >>> schedule_words({"n_initial": 4, "n_new": 2, "add_at_step": 200, "rounds": 3, "round_every": 20,
        ...                 "round_growth": "per-view"})
        '4 initial views, then 3 rounds of 2 views, at step 200 and then 20 steps per view in the model between rounds'
    """
    get = settings.get
    start = f"{get('n_initial', '?')} initial views"
    rounds = get("rounds", 1)
    if rounds == 1:
        return f"{start}, {get('n_new', '?')} added at step {get('add_at_step', '?')}"
    views = f"{get('n_new', '?')} view{'' if get('n_new') == 1 else 's'}"
    if get("round_growth", "fixed") == "per-view":
        spacing = f"then {get('round_every', '?')} steps per view in the model between rounds"
    else:
        spacing = f"every {get('round_every', '?')} steps after"
    return f"{start}, then {rounds} rounds of {views}, at step {get('add_at_step', '?')} and {spacing}"


def _refuse(name: str, value, problem: str) -> None:
    raise ValueError(f"--{name.replace('_', '-')} {value!r}: {problem}")


def check_schedule(config: ExperimentConfig) -> None:
    """The schedule's settings against each other, the steps and a built-in scene's pool: one of
    `ExperimentConfig`'s rules between settings, run when a config is made (each setting's own
    bounds, e.g. --rounds >= 1, are in its annotation).

    Raises:
        ValueError: one line naming the option, its value and what would be accepted.
    """
    if config.steps <= config.add_at_step:
        _refuse(
            "steps",
            config.steps,
            f"must be greater than the step at which views are added ({config.add_at_step}), or the added views "
            "are never trained on",
        )
    last = round_steps(config)[-1]
    if config.steps <= last:
        _refuse(
            "rounds",
            config.rounds,
            f"the last round would come at step {last} (--add-at-step {config.add_at_step}, then "
            f"{config.rounds - 1} gaps of --round-every {config.round_every}"
            f"{' per view in the model' if config.round_growth == 'per-view' else ''}), not before the last step "
            f"(--steps {config.steps}); the views it adds would never be trained on",
        )
    if config.pool < config.n_new:
        _refuse("pool", config.pool, f"the pool must hold the {config.n_new} views to add")


def check_pool(config: ExperimentConfig, pool: int, where: str) -> None:
    """Whether a candidate pool of `pool` views holds every view the schedule adds; `where` names
    the pool (a dataset's listing, or "--pool")."""
    if pool < config.n_new:
        _refuse("n_new", config.n_new, f"the candidate pool of {where} holds only {pool} views")
    if pool < added_views(config):
        _refuse(
            "rounds",
            config.rounds,
            f"{config.rounds} rounds of --n-new {config.n_new} add {added_views(config)} views, more than the "
            f"{pool} candidates of {where}",
        )


__all__ = [
    "CURVE_VIEWS",
    "ROUND_GROWTH",
    "added_views",
    "check_pool",
    "check_schedule",
    "curve_evaluations",
    "round_steps",
]
