"""What the user gave on the command line, for `nerfaug train` on a session folder: the options
given are compared with the session's settings, even at their default value."""

from __future__ import annotations

from collections.abc import Sequence
from contextvars import ContextVar

COMMAND_LINE: ContextVar[tuple[str, ...] | None] = ContextVar("command_line", default=None)
"""The arguments `nerfaug.cli.main` is parsing (None outside it), for `given_options`."""


def given_options(names: Sequence[str], argv: Sequence[str]) -> set[str]:
    """Which of the options `names` (written as on the command line, e.g. "estimate-up") `argv`
    gives, whatever their value: `--name`, `--name=value`, `--name_with_underscores`, `--no-name`
    (`--prefix.no-name` for a dotted name).

    Example:
        >>> sorted(given_options(["seed", "estimate-up", "up"], ["train", "run", "--seed=0", "--no-estimate-up"]))
        ['estimate-up', 'seed']
    """
    spellings = {}  # every way an option may be written (- or _ between words, negated) -> its name
    for name in names:
        base, dot, last = name.replace("_", "-").rpartition(".")
        spellings[f"{base}{dot}{last}"] = spellings[f"{base}{dot}no-{last}"] = name
    words = (word.partition("=")[0].removeprefix("--").replace("_", "-") for word in argv if word.startswith("--"))
    return {spellings[word] for word in words if word in spellings}
