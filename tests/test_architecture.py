"""The package's shape: every nerfaug import (module-level, inside a function or under
`if TYPE_CHECKING:`) keeps the import contracts of pyproject.toml (`[tool.importlinter]`: the rooms
as layers, checked by import-linter), whose layers the room table of docs/architecture.md lists in
order; no import cycle between modules; no module over 600 lines; and the light modules stay light
(JSON helpers and metric names import no torch)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "nerfaug"
PYPROJECT = ROOT / "pyproject.toml"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
TABLE_HEADING = "## Rooms: what each owns, as layers"
MAX_LINES = 600


def lint_imports(config: Path, cwd: Path, path: Path) -> subprocess.CompletedProcess:
    """import-linter's check of the contracts in `config`, with `path` first on the import path."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(path), os.environ.get("PYTHONPATH", "")])}
    code = "import sys; from importlinter.cli import lint_imports; sys.exit(lint_imports(sys.argv[1], no_cache=True))"
    return subprocess.run(
        [sys.executable, "-c", code, str(config)], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


# --- the contracts ---------------------------------------------------------------------------------


def test_every_import_keeps_the_contracts():
    done = lint_imports(PYPROJECT, ROOT, ROOT / "src")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout


def test_import_linter_finds_a_deferred_and_a_type_checking_import_back_up(tmp_path):
    """The contracts hold for imports inside functions and under TYPE_CHECKING too: a toy package
    whose low layer imports its high one in both ways, and one module no layer names, is refused
    on each count."""
    toy = tmp_path / "toy"
    for path, text in {
        "__init__.py": "",
        "low.py": (
            "from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n    from toy import high\n\n\n"
            "def deferred():\n    from toy import top\n\n    return top\n"
        ),
        "high.py": "from toy import low\n",
        "top.py": "from toy import high\n",
    }.items():
        (toy / path).parent.mkdir(parents=True, exist_ok=True)
        (toy / path).write_text(text)
    config = tmp_path / "contracts.toml"
    layers = '["top", "high", "low"]'
    contract = f'type = "layers"\ncontainers = ["toy"]\nexhaustive = true\nlayers = {layers}\n'
    config.write_text(
        f'[tool.importlinter]\nroot_package = "toy"\n\n[[tool.importlinter.contracts]]\nname = "toy"\n{contract}'
    )
    done = lint_imports(config, tmp_path, tmp_path)
    assert done.returncode == 1, done.stdout
    assert "toy.low -> toy.high" in done.stdout and "toy.low -> toy.top" in done.stdout
    config.write_text(config.read_text().replace(layers, '["high", "low"]'))
    done = lint_imports(config, tmp_path, tmp_path)
    assert done.returncode == 1 and "toy.top" in done.stdout + done.stderr


# --- the room table --------------------------------------------------------------------------------


def contract_layers(pyproject: Path = PYPROJECT) -> list[tuple[list[str], bool]]:
    """The layers contract's layers, top first: each its rooms (module names under nerfaug) and
    whether they are independent of one another ("|") or may import one another (":")."""
    contracts = tomllib.loads(pyproject.read_text())["tool"]["importlinter"]["contracts"]
    layers = next(c for c in contracts if c["type"] == "layers")
    assert layers["containers"] == ["nerfaug"] and layers["exhaustive"], "the rooms are every module of nerfaug"
    return [([room.strip() for room in re.split(r"[|:]", layer)], "|" in layer) for layer in layers["layers"]]


def table_rows(text: str) -> list[str]:
    """The room table's rows (below its header), top first."""
    if TABLE_HEADING not in text:
        raise AssertionError(f"{ARCHITECTURE.name}: no heading {TABLE_HEADING!r}")
    lines = text.split(TABLE_HEADING, 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    end = next((i for i, line in enumerate(lines[start:], start) if not line.startswith("|")), len(lines))
    return lines[start + 2 : end]


def row_rooms(row: str) -> list[str]:
    """A row's rooms: its first column's entries (`x/` a package, `x.py` a module), as module names."""
    first = row.strip().strip("|").split("|")[0]
    return [entry.removesuffix("/").removesuffix(".py") for entry in re.findall(r"`([\w/]+(?:\.py|/))`", first)]


def table_layers(text: str) -> list[tuple[list[str], bool]]:
    """The room table's rows, top first, read as `contract_layers` reads the contract: its first
    column's entries and "(independent)" after them."""
    return [(row_rooms(row), "(independent)" in row.strip().strip("|").split("|")[0]) for row in table_rows(text)]


def missing_table_paths(text: str, package: Path = PACKAGE) -> list[str]:
    """The paths the room table names (`x.py` a file, `x/` a folder, in either column) that lie
    neither in the package nor in one of their row's rooms (`registry.py` in the selection row is
    `selection/registry.py`)."""
    missing = []
    for row in table_rows(text):
        for path in re.findall(r"`([\w/]+(?:\.py|/))`", row):
            if not any((package / room / path).exists() for room in ["", *row_rooms(row)]):
                missing.append(path)
    return missing


def test_the_room_table_lists_the_contracts_layers_in_order():
    assert table_layers(ARCHITECTURE.read_text()) == contract_layers()


def test_a_room_table_that_differs_from_the_contract_is_found():
    text = ARCHITECTURE.read_text()
    assert table_layers(text.replace("| `cli/` |", "| `clis/` |", 1)) != contract_layers()
    assert table_layers(text.replace(" (independent)", "", 1)) != contract_layers()


def test_every_file_and_folder_the_room_table_names_exists():
    """A module renamed, moved or removed without the table is found."""
    assert missing_table_paths(ARCHITECTURE.read_text()) == []


def test_a_path_the_room_table_names_that_does_not_exist_is_found():
    text = ARCHITECTURE.read_text()
    assert "`sampler.py`" in text and "`assets/cow/`" in text
    renamed = text.replace("`sampler.py`", "`samplers.py`", 1).replace("`assets/cow/`", "`assets/cows/`", 1)
    assert missing_table_paths(renamed) == ["assets/cows/", "samplers.py"]


# --- cycles, sizes, light modules ----------------------------------------------------------------


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """A cycle as a list of modules, or None (depth-first search with colours)."""
    state, stack = {}, []

    def visit(node: str) -> list[str] | None:
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                return stack[stack.index(nxt) :] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        stack.pop()
        state[node] = "done"
        return None

    for node in sorted(graph):
        if node not in state and (cycle := visit(node)):
            return cycle
    return None


def test_the_cycle_finder_finds_a_cycle_and_accepts_a_tree():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b", "c"}, "b": {"c"}, "c": set()}) is None


@pytest.fixture(scope="module")
def imports() -> dict[str, set[str]]:
    """nerfaug module -> the nerfaug modules it imports, wherever the import stands (grimp, as
    import-linter reads them)."""
    graph = grimp.build_graph("nerfaug", cache_dir=None)
    return {module: graph.find_modules_directly_imported_by(module) for module in graph.modules}


def test_no_import_cycle_between_modules_counting_every_import(imports):
    """A deferred import that closes a circle hides a dependency both ways; the layers cannot see
    one inside a room."""
    assert len(imports) > 50, "the package's modules were not found"
    assert find_cycle(imports) is None, f"circle: {' -> '.join(find_cycle(imports))}"


def test_no_circle_between_top_level_modules_and_packages(imports):
    """The layers let the rooms of one layer import one another (the shared leaves, the commands):
    a circle between two of them is found here."""

    def top(module: str) -> str:
        return ".".join(module.split(".")[:2])

    graph: dict[str, set[str]] = {}
    for module, targets in imports.items():
        graph.setdefault(top(module), set()).update(top(t) for t in targets if top(t) != top(module))
    assert len(graph) > 20, "the package's top-level modules were not found"
    assert find_cycle(graph) is None, f"circle: {' -> '.join(find_cycle(graph))}"


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_module_over_600_lines(path):
    assert len(path.read_text().splitlines()) <= MAX_LINES


def test_light_modules_do_not_import_torch():
    code = (
        "import sys; import nerfaug.jsonio, nerfaug.metrics, nerfaug.errors, nerfaug.owned, nerfaug.runfiles; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# --- one way into a run folder ---------------------------------------------------------------------

# The names of what a run folder holds (a session's, an experiment run's, the service's jobs,
# nerfaug's marker), and the names a run folder goes by in the code.
RUN_FILE_NAMES = {
    "SESSION_FILE",
    "CHECKPOINT_FILE",
    "DATASET_DIR",
    "PROPOSALS_DIR",
    "POOL_FILE",
    "LOCK_FILE",
    "TENSORBOARD_FOLDER",
    "RESULT_FILE",
    "JOBS_DIR",
    "MARKER",
    "FILES",
}
RUN_FOLDER_NAMES = {"run_dir", "run", "run_folder"}


def _dotted(node) -> str:
    import ast

    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return f"{_dotted(node.value)}.{node.attr}"
    return ""


def paths_into_run_folders(source: str) -> list[int]:
    """The lines of `source` that join a path into a run folder by hand (`run_dir / SESSION_FILE`,
    `folder / FILES.result`, `self.run_dir / name`, `self.run_dir / self.state.pool`) instead of
    asking `nerfaug.runfiles`, which holds every such path to the containment rule."""
    import ast

    found = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div)):
            continue
        left, right = _dotted(node.left).split("."), _dotted(node.right).split(".")
        if right[0] in RUN_FILE_NAMES or right[-1] == "pool" or left[-1] in RUN_FOLDER_NAMES:
            found.append(node.lineno)
    return found


def test_every_path_into_a_run_folder_is_made_by_runfiles():
    """`grep` finds one way to open a file inside a run folder: `nerfaug.runfiles`."""
    offending = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name != "runfiles.py":
            offending += [f"{path.relative_to(PACKAGE)}:{line}" for line in paths_into_run_folders(path.read_text())]
    assert offending == [], f"paths into a run folder made by hand, not by nerfaug.runfiles: {offending}"


@pytest.mark.parametrize(
    "line",
    [
        "data = (run_dir / SESSION_FILE).read_text()",
        "atomic_write_json(Path(folder) / FILES.metrics, {})",
        "torch.load(self.run_dir / 'extra.pt')",
        "read_poses(self.run_dir / self.state.pool)",
        "SummaryWriter(log_dir=str(run / TENSORBOARD_FOLDER))",
    ],
)
def test_the_run_folder_guard_finds_a_path_made_by_hand(line):
    assert paths_into_run_folders(f"def f():\n    {line}\n") == [2]
    assert paths_into_run_folders("def f():\n    runfiles.read_text(run_dir, SESSION_FILE)\n") == []
