"""The devices a command or a protocol may name (`--device`): one type with its meaning, read by
every command's options and by the experiments' protocol; `nerfaug.device` turns a name into a
torch device. Light (no torch), so that every `--help` reads it."""

from __future__ import annotations

from typing import Annotated, Literal

import tyro

Device = Annotated[
    Literal["auto", "cpu", "cuda"],
    tyro.conf.arg(help_behavior_hint="(default: auto: cuda when this machine has a GPU, else cpu)"),
]
"""auto (cuda when this machine has a GPU, else cpu), cpu or cuda; each option's help says what
computes there."""
