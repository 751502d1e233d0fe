"""The README's command blocks and the examples run as written, from a fresh folder, and end with
exit 0: the capture walk-through (shell), the Python snippet, and every script in examples/.

They run at a small size. How each is made small, so that what runs is still what a user types:
- shell: each line is run as written with options appended (`SMALL`); the option given last wins,
  so `--n 6 ... --n 2` proposes 2 views. Lines that are comments are skipped.
- Python: a few literals are replaced (`PYTHON_SMALL`: engine preset, steps, views, candidates);
  each replacement must apply, so a changed snippet fails here until this list follows it.
- examples: their own small-size options (`--preset test`, fewer steps, views and candidates).
The dataset every block starts from is rendered first with the README's own command, shrunk.
"""

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))

# Options appended to each `nerfaug` subcommand of the walk-through (the last of a repeated option wins).
SMALL = {
    "scene": ["--res", "32", "--pool", "12", "--test", "4", "--samples", "4"],
    "train": ["--engine", "test", "--steps", "20", "--device", "cpu"],
    "propose": ["--n", "2", "--n-candidates", "20", "--device", "cpu"],
    "render-proposals": ["--samples", "4"],
    "add": ["--steps", "10", "--device", "cpu"],
    "eval": ["--device", "cpu"],
    "export": [],
}
# (literal in the README's Python snippet, its small replacement)
PYTHON_SMALL = [
    ('preset="cpu"', 'preset="test"'),
    ("session.train(500)", "session.train(10)"),
    ('session.propose(6, method="ours")', 'session.propose(2, method="ours", n_candidates=20)'),
]
# The snippet's dataset, as its comment says to render it, with a small pool and test split.
LEGO_100 = ["scene", "render", "lego", "--out", "data/lego-100", "--res", "100", "--pool", "12", "--test", "4"]

pytestmark = pytest.mark.slow


def blocks(language: str) -> list[str]:
    """The README's fenced code blocks in `language`."""
    return re.findall(rf"```{language}\n(.*?)```", README.read_text(), flags=re.S)


def block_with(language: str, text: str) -> str:
    found = [b for b in blocks(language) if text in b]
    assert len(found) == 1, f"README: expected one {language} block holding {text!r}, found {len(found)}"
    return found[0]


def nerfaug(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return run([sys.executable, "-m", "nerfaug.cli", *argv], cwd)


def run(command: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    env.pop("NERFAUG_DEBUG", None)
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def shell_lines(block: str) -> list[list[str]]:
    """Each command of a shell block as argv (comments dropped)."""
    commands = []
    for line in block.splitlines():
        argv = shlex.split(line, comments=True)
        if argv:
            commands.append(argv)
    return commands


def test_the_capture_walk_through_runs_as_written(tmp_path):
    commands = shell_lines(block_with("bash", "nerfaug train "))
    assert {argv[1] for argv in commands} <= set(SMALL), "a new subcommand needs its small-size options in SMALL"
    for argv in commands:
        assert argv[0] == "nerfaug", argv
        done = nerfaug([*argv[1:], *SMALL[argv[1]]], tmp_path)
        assert done.returncode == 0, f"{shlex.join(argv)}: exit {done.returncode}\n{done.stderr[-3000:]}"
        if argv[1] == "train":
            assert done.stdout.startswith("training on 6 views: the initial views"), done.stdout
    assert (tmp_path / "lego-grown" / "transforms.json").is_file()


def test_the_example_then_the_python_snippet_run_in_one_folder(tmp_path):
    """Both as a newcomer runs them, one after the other: their output folders must not collide."""
    rendered = nerfaug([*LEGO_100, "--samples", "4"], tmp_path)
    assert rendered.returncode == 0, rendered.stderr
    small = ["--preset", "test", "--steps-per-round", "10", "--views-per-round", "2", "--n-candidates", "20"]
    for example in EXAMPLES:
        done = run([sys.executable, str(example), *small], tmp_path)
        assert done.returncode == 0, f"{example.name}: exit {done.returncode}\n{done.stderr[-3000:]}"
    assert (tmp_path / "results" / "active-capture-export" / "transforms.json").is_file()
    # The robot's loop over HTTP: the first captures, then two rounds of two views, each scored.
    rounds = json.loads((tmp_path / "results" / "robot-capture-loop.json").read_text())["rounds"]
    assert [(r["round"], r["views"], r["step"]) for r in rounds] == [(0, 6, 10), (1, 8, 20), (2, 10, 30)]
    assert all(0 < r["psnr"] < 60 and r["test_views"] == 4 for r in rounds)

    snippet = block_with("python", "CaptureSession.create")
    for literal, small_literal in PYTHON_SMALL:
        assert literal in snippet, f"README's Python snippet no longer holds {literal!r}: update PYTHON_SMALL"
        snippet = snippet.replace(literal, small_literal)
    (tmp_path / "snippet.py").write_text(snippet)
    done = run([sys.executable, "snippet.py"], tmp_path)
    assert done.returncode == 0, f"README's Python snippet: exit {done.returncode}\n{done.stderr[-3000:]}"
    assert (tmp_path / "results" / "lego-grown" / "transforms.json").is_file()


def test_the_example_with_pool_capture_runs(tmp_path):
    argv = ["--data", "data/lego", "--capture", "pool", "--resolution", "32", "--pool", "12", "--preset", "test"]
    small = ["--steps-per-round", "10", "--views-per-round", "2"]
    done = run([sys.executable, str(ROOT / "examples" / "active_capture.py"), *argv, *small], tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "results" / "active-capture-export" / "transforms.json").is_file()


# Options appended to each line of the README's Usage block (the last of a repeated option wins):
# the test engine, a few steps past the step where views are added (200), one trial, 32 px (the
# size the block's `scene render` line renders at here).
USAGE_SMALL = {
    "scene": ["--res", "32", "--pool", "12", "--test", "20", "--samples", "4"],  # 20: the quick preset's test views
    "run": ["--engine", "test", "--steps", "210", "--trials", "1", "--resolution", "32", "--device", "cpu"],
    "study": ["--preset", "tiny", "--engines", "test", "--scenes", "lego", "--trials", "2", "--device", "cpu"],
    "report": [],
    "methods": [],
    "--help": [],
}
# The README's stand-in for a user's dataset, and the one the block's own `scene render` line writes.
USAGE_DATA = ("path/to/nerf_synthetic/lego", "data/lego")


def test_the_usage_block_runs_as_written(tmp_path):
    """Every line of the Usage block but those ending in `...` (option examples to combine with
    the lines above) and the venv's activation; the paper preset at one scene."""
    block = block_with("bash", "nerfaug run --preset quick")
    commands = [argv for argv in shell_lines(block) if argv[0] == "nerfaug" and "..." not in argv]
    assert len(commands) >= 8, commands
    for argv in commands:
        argv = [USAGE_DATA[1] if a == USAGE_DATA[0] else a for a in argv]
        small = USAGE_SMALL[argv[1]] + (["--scenes", "lego"] if "paper" in argv else [])
        done = nerfaug([*argv[1:], *small], tmp_path)
        assert done.returncode == 0, f"{shlex.join(argv)}: exit {done.returncode}\n{done.stderr[-3000:]}"
    assert (tmp_path / "results" / "quick" / "report.md").is_file()
    assert (tmp_path / "results" / "mylego" / "report.md").is_file()
    assert (tmp_path / "results" / "study" / "study.md").is_file()
