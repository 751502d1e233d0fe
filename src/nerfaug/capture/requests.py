"""Arguments of a session's steps, checked once for the library, the CLI and the service:
`RequestError` names the argument and its value (the CLI shows it as its option, `--n 0: ...`)."""

from __future__ import annotations

import operator
import re


class RequestError(ValueError):
    """An argument of a request is out of range: names the argument and its value.

    Attributes:
        argument: the argument's name as the library spells it ("n_candidates").
        value: the value given.
        problem: what is wrong with it.
    """

    def __init__(self, argument: str, value, problem: str):
        self.argument, self.value, self.problem = argument, value, problem
        shown = repr(value) if isinstance(value, str) else value
        super().__init__(f"{argument} {shown}: {problem}")


def check_steps(steps: int) -> int:
    """`steps` (training steps to run) as an int; RequestError unless >= 0."""
    if int(steps) < 0:
        raise RequestError("steps", steps, "must be >= 0 (training steps to run)")
    return int(steps)


# A split's name: it becomes part of a file name (`transforms_{split}.json`), so no separators.
SPLIT_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
# Seeds reach torch's generators, which take a signed 64-bit integer.
SEED_MAX = 2**63 - 1
# A hemisphere radius, world units: beyond these a float32 engine frame loses the scene.
RADIUS_RANGE = (1e-6, 1e6)


def check_seed(seed, argument: str = "seed") -> int:
    """`seed` as an int; RequestError unless a whole number in 0..2^63-1 (what torch's generators take)."""
    try:
        value = None if isinstance(seed, bool) else operator.index(seed)
    except TypeError:
        value = None
    if value is None or not 0 <= value <= SEED_MAX:
        raise RequestError(argument, seed, "must be a whole number in 0..2^63-1 (9223372036854775807)")
    return value


def check_radius(radius, argument: str = "radius") -> float:
    """`radius` (a hemisphere's, world units) as a float; RequestError unless finite and in `RADIUS_RANGE`."""
    low, high = RADIUS_RANGE
    try:
        value = float(radius)
    except (TypeError, ValueError):
        value = float("nan")
    if not low <= value <= high:  # also refuses NaN
        raise RequestError(argument, radius, f"must be a distance in [{low:g}, {high:g}] (world units)")
    return value


def check_split(split, argument: str = "split") -> str:
    """`split` if it is a split's name (`SPLIT_NAME`: no path separators); RequestError otherwise."""
    if not isinstance(split, str) or not SPLIT_NAME.fullmatch(split):
        raise RequestError(argument, split, "must be a split's name: letters, digits, '.', '_', '-' (no separators)")
    return split
