"""What the user gave on the command line, shared by the commands that apply options over a
preset's settings (`run`, `study`): an option given applies even at its default value; one not
given leaves the preset's."""

from __future__ import annotations

from collections.abc import Sequence
from contextvars import ContextVar
from dataclasses import fields

COMMAND_LINE: ContextVar[tuple[str, ...] | None] = ContextVar("command_line", default=None)
"""The arguments `nerfaug.cli.main` is parsing (None outside it), for `given_fields`."""


def given_fields(options, prefix: str, argv: Sequence[str] | None) -> dict:
    """The fields of the dataclass `options` that `argv` gives as `--PREFIX.FIELD` options, with
    their values in `options`: what to apply over a preset's settings. A field given applies even
    at its default value; one not given leaves the preset's. Without a command line (`argv`
    None: the command was called from Python), the fields that differ from the defaults.

    Example:
        >>> from nerfaug.selection import SelectionConfig
        >>> argv = ["run", "--selection.temperature", "1.0", "--selection.entropy_resolution=20"]
        >>> given_fields(SelectionConfig(entropy_resolution=20), "selection", argv)
        {'entropy_resolution': 20, 'temperature': 1.0}
    """
    names = [f.name for f in fields(options)]
    if argv is None:
        defaults = type(options)()
        return {name: getattr(options, name) for name in names if getattr(options, name) != getattr(defaults, name)}
    given = given_options([f"{prefix}.{name}" for name in names], argv)
    return {name: getattr(options, name) for name in names if f"{prefix}.{name}" in given}


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
