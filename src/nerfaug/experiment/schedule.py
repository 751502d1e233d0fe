"""A run's schedule of views: `n_initial` views, then `rounds` rounds of `n_new` views, the first at
`add_at_step` and each next one `round_every` steps later, training on to `steps`. One round is the
paper's protocol (6 initial views, 6 added at step 200); the field's active-learning protocol
(FisherRF's) is few initial views and one view a round.

Light (no torch): the sweep's checks, the time estimate (`nerfaug.cli.run_size`) and the report
read it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from nerfaug.experiment.config import ExperimentConfig

CURVE_VIEWS = 8
"""Test views a learning curve's points are measured on between rounds (spread over the test
views); the last point is the run's evaluation on all of them."""


def round_steps(config: ExperimentConfig) -> list[int]:
    """The training step of each round: `add_at_step`, then every `round_every` steps."""
    return [config.add_at_step + r * config.round_every for r in range(config.rounds)]


def added_views(config: ExperimentConfig) -> int:
    """Views a run adds over all its rounds."""
    return config.rounds * config.n_new


def curve_evaluations(config: ExperimentConfig) -> int:
    """Test-view evaluations a run makes besides its last: before the first round and after each
    round but the last (none with one round)."""
    return config.rounds if config.rounds > 1 else 0


def _refuse(name: str, value, problem: str) -> None:
    raise ValueError(f"--{name.replace('_', '-')} {value!r}: {problem}")


def check_schedule(config: ExperimentConfig) -> None:
    """The schedule's settings against each other, the steps and a built-in scene's pool.

    Raises:
        ValueError: one line naming the option, its value and what would be accepted.
    """
    for name in ("rounds", "round_every"):
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            _refuse(name, value, "must be an integer >= 1")
    if config.add_at_step < 0:
        _refuse("add_at_step", config.add_at_step, "must be >= 0")
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
            f"the last round would come at step {last} (--add-at-step {config.add_at_step} + "
            f"{config.rounds - 1} x --round-every {config.round_every}), not before the last step (--steps "
            f"{config.steps}); the views it adds would never be trained on",
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


__all__ = ["CURVE_VIEWS", "added_views", "check_pool", "check_schedule", "curve_evaluations", "round_steps"]
