"""Every test marked `rounding` runs in `make test-rounding`: its files are the Makefile's list."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def listed_files(makefile: str) -> set[str]:
    """The paths of the Makefile's `ROUNDING_TESTS := ...` (continued over `\\` lines)."""
    match = re.search(r"^ROUNDING_TESTS\s*:=((?:.*\\\n)*.*)$", makefile, re.MULTILINE)
    assert match, "the Makefile has no ROUNDING_TESTS"
    return set(match.group(1).replace("\\\n", " ").split())


def marked_files(root: Path) -> set[str]:
    return {
        str(path.relative_to(root))
        for path in (root / "tests").rglob("*.py")
        if path != Path(__file__).resolve() and re.search(r"pytest\.mark\.rounding\b", path.read_text())
    }


def test_every_file_with_a_rounding_test_is_in_the_makefiles_list():
    listed = listed_files((ROOT / "Makefile").read_text())
    assert marked_files(ROOT) == listed
    assert all((ROOT / path).is_file() for path in listed)


def test_a_marked_file_missing_from_the_list_is_found(tmp_path):
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "test_a.py").write_text("import pytest\n\npytestmark = pytest.mark.rounding\n")
    (tmp_path / "tests" / "test_b.py").write_text("@pytest.mark.roundingish\ndef test(): pass\n")
    assert marked_files(tmp_path) == {"tests/test_a.py"}
    makefile = "X := 1\nROUNDING_TESTS := tests/a.py \\\n\ttests/b.py\nY := 2\n"
    assert listed_files(makefile) == {"tests/a.py", "tests/b.py"}
