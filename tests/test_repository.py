"""The repository after the README's commands: what they write into its root is ignored by git,
and the package metadata uses the current form of its fields."""

import re
import shutil
import subprocess
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# Written into the root by the README's commands (`nerfaug train/propose/render-proposals/export/serve`).
WRITTEN = [
    "runs/lego/session.json",
    "poses.json",
    "poses.png",
    "poses2.json",
    "captures/capture_000_00.png",
    "uncertainty/capture_001_00.png",  # `nerfaug uncertainty runs/lego --out uncertainty/`
    "poses-robot.json",  # the service's block
    "captures-robot/capture_000_00.png",
    "sessions/lego/session.json",  # `nerfaug serve --root sessions`
]


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(), reason="needs git and a checkout")
@pytest.mark.parametrize("path", [*WRITTEN, "lego-grown/transforms.json"])
def test_what_the_readme_writes_is_ignored(path):
    done = subprocess.run(["git", "check-ignore", "--no-index", "-q", path], cwd=ROOT)
    assert done.returncode == 0, f"{path} is not ignored"


def test_the_readme_still_writes_those_paths():
    readme = (ROOT / "README.md").read_text()
    words = ("--out runs/lego", "--out poses.json", "--out captures/", "--out uncertainty/", "--out lego-grown")
    for word in (*words, "-o poses-robot.json", "--out captures-robot/"):
        assert word in readme


def test_license_is_an_spdx_string():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"


def test_the_readmes_http_round_trains_on_its_captures_before_it_evaluates():
    """Scores taken right after the captures are added, before any step on them, make the new
    views look useless: the curl round trains between adding and evaluating."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = next(b for b in re.findall(r"```bash\n(.*?)```", readme, flags=re.S) if "/captures" in b)
    calls = re.findall(r"/sessions/\w+/(captures|train|evaluate)", block)
    after_captures = calls[calls.index("captures") + 1 :]
    assert "evaluate" in after_captures and after_captures.index("train") < after_captures.index("evaluate")
