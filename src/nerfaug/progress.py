"""Progress of long work: a live bar in a terminal, plain lines where output is not one (a pipe, tee, CI).

A live bar redraws itself in place, which only a terminal can show: written to a file or a pipe it
would appear once, when the work is over. So where the output is not a terminal, `progress_bar`
returns a `LineProgress` instead, which prints one line each time a task passes another tenth of
its total (or every `every` units), with the time elapsed and an estimate of the time left.

    with progress_bar(fields="psnr {psnr:.2f} dB") as bar:
        task = bar.add_task("training", total=1000, psnr=float("nan"))
        for step in range(1, 1001):
            bar.update(task, completed=step, psnr=...)
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import TypeVar

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
)
from rich.text import Text

# A task prints a line each time it passes another tenth of its total, unless told `every`.
LINES_PER_TASK = 10
T = TypeVar("T")


def is_live(console: Console) -> bool:
    """Whether `console` can show a live bar (a terminal that understands cursor movement)."""
    return console.is_terminal and not console.is_dumb_terminal


def duration(seconds: float) -> str:
    """Seconds as H:MM:SS, e.g. `duration(3725) == "1:02:05"`; "?" when unknown."""
    if not math.isfinite(seconds) or seconds < 0:
        return "?"
    minutes, secs = divmod(int(round(seconds)), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"


def _fields_text(template: str, fields: dict) -> str:
    """`template` filled from a task's fields; "" when the task lacks one (tasks of one bar differ)."""
    try:
        return template.format(**fields) if template else ""
    except (KeyError, ValueError, TypeError):
        return ""


class _FieldsColumn(ProgressColumn):
    def __init__(self, template: str):
        super().__init__()
        self.template = template

    def render(self, task) -> Text:
        return Text(_fields_text(self.template, task.fields))


@dataclass
class _Task:
    description: str
    total: float | None
    every: float
    fields: dict
    completed: float = 0.0
    started: float = field(default_factory=time.monotonic)
    printed: float = 0.0  # the `completed` of the last line printed


class RemainingAtMeanRate(ProgressColumn):
    """The time left at the mean rate since the task started (the rest goes as fast as what is
    done), as `LineProgress` says it. Rich's own column divides by the rate of the last 30 s,
    which swings when the units end in bursts (a sweep's runs, ending together on parallel workers)."""

    def render(self, task) -> Text:
        if task.total is None or not task.completed or not task.elapsed:
            return Text("-:--:--", style="progress.remaining")
        left = task.elapsed * max(task.total - task.completed, 0) / task.completed
        return Text(duration(left), style="progress.remaining")


class LineProgress:
    """The part of `rich.progress.Progress` nerfaug uses, shown as plain lines.

    A line reads `DESCRIPTION: COMPLETED/TOTAL FIELDS, H:MM:SS elapsed, ETA H:MM:SS`; the ETA
    assumes the rest goes as fast as what is done.
    """

    def __init__(self, console: Console | None = None, fields: str = "", enabled: bool = True):
        self.console, self.fields, self.enabled = console, fields, enabled
        self.tasks: dict[int, _Task] = {}
        self._next = 0

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc) -> None:
        pass

    def add_task(self, description: str, total: float | None = None, every: float | None = None, **fields) -> int:
        """A task; it prints a line every `every` units of progress (default: each tenth of `total`)."""
        if every is None:
            every = math.ceil(total / LINES_PER_TASK) if total else 1
        self._next += 1
        self.tasks[self._next] = _Task(description, total, max(every, 1e-12), fields)
        return self._next

    def update(
        self,
        task_id: int,
        *,
        completed: float | None = None,
        advance: float | None = None,
        description: str | None = None,
        total: float | None = None,
        **fields,
    ) -> None:
        task = self.tasks[task_id]
        task.fields.update(fields)
        if description is not None:
            task.description = description
        if total is not None:
            task.total = total
        if completed is not None:
            task.completed = completed
        if advance is not None:
            task.completed += advance
        passed = task.completed // task.every > task.printed // task.every
        finished = task.total is not None and task.completed >= task.total > task.printed
        if task.completed > task.printed and (passed or finished):
            task.printed = task.completed
            self._line(task)

    def advance(self, task_id: int, advance: float = 1) -> None:
        self.update(task_id, advance=advance)

    def remove_task(self, task_id: int) -> None:
        self.tasks.pop(task_id, None)

    def _line(self, task: _Task) -> None:
        if not self.enabled:
            return
        elapsed = time.monotonic() - task.started
        done = f"{task.completed:g}" + ("" if task.total is None else f"/{task.total:g}")
        extra = _fields_text(self.fields, task.fields)
        timing = f"{duration(elapsed)} elapsed"
        if task.total is not None:
            left = elapsed * (task.total - task.completed) / task.completed if task.completed else math.inf
            timing += f", ETA {duration(left)}"
        line = f"{task.description.strip()}: {done}" + (f" {extra}" if extra else "") + f", {timing}"
        stream = self.console.file if self.console is not None else sys.stderr
        print(line, file=stream, flush=True)


def progress_bar(
    fields: str = "",
    console: Console | None = None,
    enabled: bool = True,
    transient: bool = False,
) -> Progress | LineProgress:
    """A progress display for `console` (default: stderr): a live rich bar when it is a terminal,
    else a `LineProgress`. Either is a context manager with `add_task`, `update`, `advance` and
    `remove_task`; `add_task(..., every=N)` sets how often a line is printed (a live bar ignores it).

    Args:
        fields: a format string over a task's fields, shown after the count (e.g.
            "psnr {psnr:.2f} dB"); empty for tasks without one.
        console: where to show it (a rich Console); default: stderr.
        enabled: False shows nothing.
        transient: a live bar disappears when done (lines stay: they are a log).
    """
    console = console if console is not None else Console(stderr=True)
    if not is_live(console):
        return LineProgress(console, fields, enabled)
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        _FieldsColumn(fields),
        TimeElapsedColumn(),
        RemainingAtMeanRate(),
        console=console,
        disable=not enabled,
        transient=transient,
    )


def track(items: Sequence[T], description: str, enabled: bool = True, transient: bool = False) -> Iterator[T]:
    """Iterate over `items` showing progress (as `progress_bar`): `rich.progress.track` with lines
    where stderr is not a terminal."""
    with progress_bar(enabled=enabled, transient=transient) as bar:
        task = bar.add_task(description, total=len(items))
        for done, item in enumerate(items, 1):
            yield item
            bar.update(task, completed=done)
