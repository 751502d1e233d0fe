"""Help text of options whose default is None (or empty), for the config dataclasses tyro turns into the
`nerfaug` command: a shared leaf, so that library rooms (selection, capture) can say in their own
annotations what their unset options do."""

from __future__ import annotations

import tyro


def none_means(meaning: str, metavar: str):
    """`--help` for an option whose default is None: what None does, e.g. "(default: the
    identity)", and the metavar without "{None}|". For use in `Annotated[T | None, ...]`; tyro
    alone prints "(default: None)", which hides what the tool will do."""
    return tyro.conf.arg(metavar=metavar, help_behavior_hint=f"(default: {meaning})")


def empty_means(meaning: str, metavar: str):
    """`--help` for an option whose default is empty (no items): what that does, e.g. "(default:
    none)"; tyro alone prints "(default: )"."""
    return tyro.conf.arg(metavar=metavar, help_behavior_hint=f"(default: {meaning})")
