"""Arguments of a session's steps, checked once for the library, the CLI and the service:
`RequestError` names the argument and its value (the CLI shows it as its option, `--n 0: ...`)."""

from __future__ import annotations


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
