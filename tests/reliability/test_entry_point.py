"""A few bad inputs through the installed `nerfaug` command in a fresh process: what a user sees
on stderr is exactly one line (no warnings, no progress noise, no traceback) and the exit code.

The in-process cases (`test_bad_inputs.py`) cannot see output made once per process, such as
numpy's warnings after subnormals are flushed at start-up; these can.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from cases import TINY


def _nerfaug() -> list[str]:
    script = Path(sys.executable).parent / "nerfaug"
    return [str(script)] if script.exists() else [sys.executable, "-m", "nerfaug.cli"]


ARGVS = {
    "report_on_a_missing_folder": lambda tmp, bases: ["report", tmp / "nope"],
    "train_on_a_missing_dataset": lambda tmp, bases: ["train", tmp / "nope", "--out", tmp / "run", "--device", "cpu"],
    "propose_zero_views": lambda tmp, bases: ["propose", bases.session, "--n", "0", "--out", tmp / "p.json"],
    "run_zero_trials": lambda tmp, bases: ["run", "--data", bases.dataset, "--out", tmp / "r", *TINY, "--trials", "0"],
}


@pytest.mark.parametrize("name", sorted(ARGVS))
def test_stderr_is_one_line_and_the_exit_code_2(name, bases, tmp_path):
    argv = [str(a) for a in ARGVS[name](tmp_path, bases)]
    env = {k: v for k, v in os.environ.items() if k != "NERFAUG_DEBUG"}
    done = subprocess.run(_nerfaug() + argv, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2, done.stderr
    assert len(lines) == 1 and lines[0].startswith("nerfaug: "), done.stderr
    assert not list(tmp_path.iterdir()), "a refused command wrote files"
