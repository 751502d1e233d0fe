"""The README's command blocks and the examples run as written, from a fresh folder, in the order
the README gives them, and end with exit 0: the Usage block, the capture walk-through (shell), the
Python block, then every script in examples/. No block rewrites a file an earlier one wrote (each
writes into its own folders), and the examples refuse to go on with a session of other settings.

They run at a small size. How each is made small, so that what runs is still what a user types:
- shell: each line is run as written with options appended (`SMALL`, `USAGE_SMALL`); the option
  given last wins, so `--n 6 ... --n 2` proposes 2 views. Lines that are comments are skipped.
- Python: a few literals are replaced (`PYTHON_SMALL`: engine preset, size of the render, steps,
  views, candidates); each replacement must apply, so a changed block fails here until this list
  follows it.
- examples: their own small-size options (`--engine test`, fewer steps, views and candidates).
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
    # 20 steps at 32 px leave the NeRF empty: proposing from it is what this walk-through runs.
    "propose": ["--n", "2", "--n-candidates", "20", "--device", "cpu", "--allow-empty"],
    "render-proposals": ["--samples", "4"],
    "add": ["--steps", "10", "--device", "cpu"],
    "eval": ["--device", "cpu"],
    "uncertainty": ["--width", "8", "--fisher-width", "3", "--device", "cpu"],
    "export": [],
}
# (literal in the README's Python block, its small replacement). Its render is the walk-through's
# `scene render` at the walk-through's small size, so it finds that dataset rendered already.
PYTHON_SMALL = [
    ('engine="nerfacto-cpu"', 'engine="test"'),
    (
        'render_scene_dataset("lego", "data/lego-100", resolution=100)',
        'render_scene_dataset("lego", "data/lego-100", resolution=32, pool=12, test=4, samples=4)',
    ),
    ('BlenderOracle("lego", 100, 100)', 'BlenderOracle("lego", 32, 32, samples=4)'),
    ("session.train(500)", "session.train(10)"),
    ('ProposalRequest(n=6, method="ours")', 'ProposalRequest(n=2, method="ours", n_candidates=20, allow_empty=True)'),
]
EXAMPLE_SMALL = [
    *["--engine", "test", "--steps-per-round", "10", "--views-per-round", "2", "--n-candidates", "20"],
    "--allow-empty",
]

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


def files(folder: Path) -> dict[str, tuple[int, int]]:
    """Every file under `folder`: relative path -> (modification time in ns, size)."""
    return {
        str(path.relative_to(folder)): (path.stat().st_mtime_ns, path.stat().st_size)
        for path in folder.rglob("*")
        if path.is_file()
    }


def assert_untouched(earlier: dict[str, tuple[int, int]], folder: Path, block: str) -> None:
    now = files(folder)
    changed = sorted(path for path, stamp in earlier.items() if now.get(path) != stamp)
    assert not changed, f"{block} rewrote or removed files an earlier block wrote: {changed[:8]}"


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


def run_the_usage_block(folder: Path) -> None:
    """Every line of the Usage block but those ending in `...` (option examples to combine with
    the lines above) and the venv's activation; the paper preset at one scene."""
    block = block_with("bash", "nerfaug run --preset quick")
    commands = [argv for argv in shell_lines(block) if argv[0] == "nerfaug" and "..." not in argv]
    assert len(commands) >= 8, commands
    for argv in commands:
        argv = [USAGE_DATA[1] if a == USAGE_DATA[0] else a for a in argv]
        small = USAGE_SMALL[argv[1]] + (["--scenes", "lego"] if "paper" in argv else [])
        done = nerfaug([*argv[1:], *small], folder)
        assert done.returncode == 0, f"{shlex.join(argv)}: exit {done.returncode}\n{done.stderr[-3000:]}"
    assert (folder / "results" / "quick" / "report.md").is_file()
    assert (folder / "results" / "mylego" / "report.md").is_file()
    assert (folder / "results" / "study" / "study.md").is_file()


def run_the_capture_walk_through(folder: Path) -> None:
    commands = shell_lines(block_with("bash", "nerfaug train data/lego-100 "))
    assert {argv[1] for argv in commands} <= set(SMALL), "a new subcommand needs its small-size options in SMALL"
    for argv in commands:
        assert argv[0] == "nerfaug", argv
        done = nerfaug([*argv[1:], *SMALL[argv[1]]], folder)
        assert done.returncode == 0, f"{shlex.join(argv)}: exit {done.returncode}\n{done.stderr[-3000:]}"
        if argv[1] == "train":
            assert done.stdout.startswith("training on 6 views: the initial views"), done.stdout
        if argv[1] == "uncertainty":
            assert "uncertainty images: " in done.stderr  # its progress
    assert (folder / "lego-grown" / "transforms.json").is_file()
    poses = json.loads((folder / "poses2.json").read_text())
    assert poses["nerfaug"]["min_separation"] == 20.0
    assert (folder / "uncertainty" / "capture_001_00.png").is_file()


def run_the_python_block(folder: Path) -> None:
    block = block_with("python", "CaptureSession.create")
    for literal, small_literal in PYTHON_SMALL:
        assert literal in block, f"README's Python block no longer holds {literal!r}: update PYTHON_SMALL"
        block = block.replace(literal, small_literal)
    (folder / "python-block.py").write_text(block)
    done = run([sys.executable, "python-block.py"], folder)
    assert done.returncode == 0, f"README's Python block: exit {done.returncode}\n{done.stderr[-3000:]}"
    assert "already rendered with these arguments" in done.stderr  # the walk-through's dataset, reused
    assert "training: 10/10" in done.stderr  # the session shows its training
    assert (folder / "results" / "lego-grown" / "transforms.json").is_file()


def run_the_examples(folder: Path) -> None:
    for example in EXAMPLES:
        done = run([sys.executable, str(example), *EXAMPLE_SMALL], folder)
        assert done.returncode == 0, f"{example.name}: exit {done.returncode}\n{done.stderr[-3000:]}"
        assert "using the dataset already in data/lego-100" in done.stdout
    assert (folder / "results" / "active-capture-export" / "transforms.json").is_file()
    # The robot's loop over HTTP: the first captures, then two rounds of two views, each scored.
    rounds = json.loads((folder / "results" / "robot-capture-loop.json").read_text())["rounds"]
    assert [(r["round"], r["views"], r["step"]) for r in rounds] == [(0, 6, 10), (1, 8, 20), (2, 10, 30)]
    assert all(0 < r["psnr"] < 60 and r["test_views"] == 4 for r in rounds)


def test_the_readme_and_the_examples_run_in_order_in_one_folder(tmp_path):
    written: dict[str, tuple[int, int]] = {}
    for name, block in (
        ("the Usage block", run_the_usage_block),
        ("the capture walk-through", run_the_capture_walk_through),
        ("the Python block", run_the_python_block),
        ("the examples", run_the_examples),
    ):
        block(tmp_path)
        assert_untouched(written, tmp_path, name)
        written = files(tmp_path)
    # The Usage block's dataset is still its own (the capture blocks once re-rendered it smaller).
    assert len(json.loads((tmp_path / "data" / "lego" / "transforms_test.json").read_text())["frames"]) == 20

    # Run again with other settings, each example refuses, naming them, and changes nothing.
    active = ROOT / "examples" / "active_capture.py"
    done = run([sys.executable, str(active), *EXAMPLE_SMALL, "--seed", "1"], tmp_path)
    assert done.returncode == 1
    assert "results/active-capture holds a session made with --seed 0 (asked: 1)" in done.stderr
    done = run([sys.executable, str(active), *EXAMPLE_SMALL, "--data", "path/to/blender_dataset"], tmp_path)
    assert done.returncode == 1 and "--data path/to/blender_dataset: no such folder" in done.stderr
    assert not (tmp_path / "path").exists()
    robot = ROOT / "examples" / "robot_capture_loop.py"
    done = run([sys.executable, str(robot), *EXAMPLE_SMALL[2:], "--engine", "cpu"], tmp_path)
    assert done.returncode == 1 and "was made with --engine test (asked: cpu)" in done.stderr
    assert_untouched(written, tmp_path, "the refused examples")


def test_the_example_with_pool_capture_runs(tmp_path):
    rendered = nerfaug(["scene", "render", "lego", "--out", "data/lego", *SMALL["scene"]], tmp_path)
    assert rendered.returncode == 0, rendered.stderr
    argv = ["--data", "data/lego", "--capture", "pool", "--engine", "test"]
    small = ["--steps-per-round", "10", "--views-per-round", "2", "--allow-empty"]
    done = run([sys.executable, str(ROOT / "examples" / "active_capture.py"), *argv, *small], tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "results" / "active-capture-export" / "transforms.json").is_file()


def test_the_sparse_start_from_a_download_runs(tmp_path):
    """The README's path from a download to six proposed views, on a small NeRF-synthetic stand-in
    for the download (train, val and test splits at 16 px), each line as written with small-size
    options appended."""
    import torch

    from nerfaug.cameras import Cameras
    from nerfaug.data import write_blender_split
    from nerfaug.data.views import Views
    from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

    download = tmp_path / "downloads" / "mic"
    generator = torch.Generator().manual_seed(0)
    for split, count in (("train", 16), ("val", 2), ("test", 4)):
        poses = sample_uniform_poses(count, generator)
        images = torch.rand(count, 16, 16, 3, generator=generator)
        cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 16, 16)
        write_blender_split(download, split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(count)]))
    small = {
        "scene": ["--width", "16"],
        "train": ["--engine", "test", "--steps", "10", "--device", "cpu"],
        "propose": ["--n", "2", "--n-candidates", "20", "--device", "cpu", "--allow-empty"],
        "add": ["--steps", "5", "--device", "cpu"],
        "eval": ["--device", "cpu"],
    }
    block = block_with("bash", "--initial 6").replace("~/downloads/mic", str(download))
    for argv in shell_lines(block):
        done = nerfaug([*argv[1:], *small[argv[1]]], tmp_path)
        assert done.returncode == 0, f"{shlex.join(argv)}: exit {done.returncode}\n{done.stderr[-3000:]}"
        if argv[1] == "train":
            assert done.stdout.startswith("training on 6 of the 16 views"), done.stdout
    chosen = [Path(f["file_path"]).stem for f in json.loads((tmp_path / "mic-poses.json").read_text())["frames"]]
    added = json.loads((tmp_path / "runs" / "mic" / "session.json").read_text())["additions"][0]["names"]
    assert added == chosen and all(name.startswith("r_") for name in chosen)
