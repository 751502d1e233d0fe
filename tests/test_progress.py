"""Progress where output is not a terminal: plain lines (a line per finished run of a sweep, a line
every tenth of a long task), and a live bar only in a terminal."""

import io
import re

import torch
from rich.console import Console
from rich.progress import Progress

from nerfaug.cameras import Cameras
from nerfaug.data import Views, write_blender_split
from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.sweep import run_sweep
from nerfaug.hemisphere import sample_uniform_poses
from nerfaug.progress import LineProgress, duration, progress_bar, track

LINE = re.compile(r"^(?P<what>.+): (?P<done>\d+)/(?P<total>\d+).*, (\d+:\d\d:\d\d) elapsed, ETA (\d+:\d\d:\d\d)$")


def test_a_terminal_gets_a_live_bar_and_a_pipe_gets_lines():
    assert isinstance(progress_bar(console=Console(file=io.StringIO(), force_terminal=True)), Progress)
    assert isinstance(progress_bar(console=Console(file=io.StringIO())), LineProgress)


def test_a_task_prints_a_line_each_tenth_with_elapsed_time_and_eta():
    out = io.StringIO()
    with progress_bar(fields="psnr {psnr:.2f} dB", console=Console(file=out)) as bar:
        task = bar.add_task("training", total=1000, psnr=float("nan"))
        for step in range(10, 1001, 10):
            bar.update(task, completed=step, psnr=20.0 + step / 1000)
    lines = out.getvalue().splitlines()
    assert [LINE.match(line)["done"] for line in lines] == [str(k) for k in range(100, 1001, 100)]
    assert lines[-1].startswith("training: 1000/1000 psnr 21.00 dB, ") and lines[-1].endswith("ETA 0:00:00")


def test_every_sets_the_interval_and_a_disabled_bar_prints_nothing():
    out = io.StringIO()
    bar = progress_bar(console=Console(file=out))
    task = bar.add_task("runs", total=3, every=1)
    for _ in range(3):
        bar.advance(task)
    assert len(out.getvalue().splitlines()) == 3
    quiet = io.StringIO()
    bar = progress_bar(console=Console(file=quiet), enabled=False)
    bar.update(bar.add_task("runs", total=2), completed=2)
    assert quiet.getvalue() == ""


def test_track_yields_every_item_and_prints_lines(capsys):
    assert list(track(range(20), "evaluating")) == list(range(20))
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 10 and lines[-1].startswith("evaluating: 20/20")


def test_duration_reads_as_hours_minutes_seconds():
    assert duration(3725) == "1:02:05"
    assert duration(float("inf")) == "?"


def write_dataset(root, size=24):
    """A Blender-format dataset of random images on the hemisphere (no Blender needed)."""
    generator = torch.Generator().manual_seed(0)
    for split, n in (("train", 8), ("test", 3)):
        poses = sample_uniform_poses(n, generator)
        images = torch.rand(n, size, size, 3, generator=generator)
        views = Views(Cameras.from_fov(poses, 0.69, size, size), images, [f"r_{i}" for i in range(n)])
        write_blender_split(root, split, views)
    return root


def test_a_sweep_without_a_terminal_prints_a_line_per_finished_run(tmp_path, capsys):
    data = write_dataset(tmp_path / "data")
    config = PROTOCOL_PRESETS.choose("tiny").replace(scenes=(str(data),), methods=("uniform",), trials=2, device="cpu")
    outcome = run_sweep(config, tmp_path / "results", progress=True)
    assert not outcome.failed
    lines = [LINE.match(line) for line in capsys.readouterr().err.splitlines()]
    runs = [m for m in lines if m is not None and m["what"].startswith("runs:")]
    assert [(m["done"], m["total"]) for m in runs] == [("1", "2"), ("2", "2")]
    assert "(data/uniform/trial 0 done)" in runs[0].group(0) and "(data/uniform/trial 1 done)" in runs[1].group(0)
    steps = [m for m in lines if m is not None and m["what"].strip() == "data/uniform/trial 0"]
    assert len(steps) >= 2, "a run's steps are reported while it trains"


def test_the_live_bars_eta_is_the_mean_rate_so_far_and_does_not_swing_on_a_burst():
    """Runs ending together (parallel workers) must not make the ETA drop to the last seconds'
    rate: 5 of 10 units in 101 s leave 101 s, though 4 of them ended in the last second."""
    import io

    from rich.console import Console
    from rich.progress import Progress

    from nerfaug.progress import RemainingAtMeanRate, progress_bar

    clock = [0.0]
    column = RemainingAtMeanRate()
    bar = Progress(column, get_time=lambda: clock[0], console=Console(file=io.StringIO()))
    task = bar.add_task("runs", total=10)
    assert column.render(bar.tasks[0]).plain == "-:--:--"
    clock[0] = 100.0
    bar.update(task, completed=1)
    assert column.render(bar.tasks[0]).plain == "0:15:00"
    clock[0] = 101.0
    bar.update(task, completed=5)
    assert column.render(bar.tasks[0]).plain == "0:01:41"
    live = progress_bar(console=Console(file=io.StringIO(), force_terminal=True))
    assert any(isinstance(c, RemainingAtMeanRate) for c in live.columns)
