"""The package's shape: every nerfaug import (module-level, inside a function or under
`if TYPE_CHECKING:`) follows the room table of docs/architecture.md, which the test reads, so the
page and the test cannot drift; no import cycle between modules; no module over 600 lines; and the
light modules stay light (JSON helpers and metric names import no torch)."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "nerfaug"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
TABLE_HEADING = "## Rooms: what each owns, what it may import"
MAX_LINES = 600


# --- the package's modules and their imports ---------------------------------------------------


def module_name(path: Path, package: Path = PACKAGE) -> str:
    parts = path.relative_to(package.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Module name -> file, for every module of `package` (a package is named by its __init__)."""
    return {module_name(path, package): path for path in sorted(package.rglob("*.py"))}


@dataclass(frozen=True)
class Import:
    """One import statement's target: the module it makes run (a submodule where `from package
    import name` names one, else the package itself), where it is, and whether it runs when the
    importing module is imported (a statement of its body) or later (inside a function, or under
    `if TYPE_CHECKING:`, which never runs)."""

    target: str
    line: int
    top_level: bool


def imports_of(source: str, name: str, is_package: bool, modules: set[str], root: str = "nerfaug") -> list[Import]:
    """Every import of a `root` module in `source` (the module `name`), relative ones resolved,
    `importlib.import_module("...")` and `__import__("...")` with a literal name included."""
    tree = ast.parse(source)
    top = {id(node) for node in tree.body}
    package = name if is_package else name.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        targets: list[str] = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                origin = f"{base}.{node.module}" if node.module else base
            else:
                origin = node.module or ""
            submodules = {f"{origin}.{alias.name}" for alias in node.names} & modules
            targets = sorted(submodules)
            if len(submodules) < len(node.names):  # some names are objects of `origin` itself
                targets.append(origin)
        elif (
            isinstance(node, ast.Call)
            and (getattr(node.func, "attr", None) == "import_module" or getattr(node.func, "id", None) == "__import__")
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            targets = [node.args[0].value]
        found += [
            Import(target, node.lineno, id(node) in top)
            for target in targets
            if target == root or target.startswith(f"{root}.")
        ]
    return found


def package_imports(package: Path = PACKAGE) -> dict[str, list[Import]]:
    modules = package_modules(package)
    return {
        name: imports_of(path.read_text(), name, path.name == "__init__.py", set(modules), package.name)
        for name, path in modules.items()
    }


# --- the room table ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Room:
    """One row of the room table.

    Attributes:
        name: the first name in its first column (`data`, `evaluation`, `cli`; `shared leaves`).
        packages: the packages it holds (a `x/` entry), each with all its submodules.
        modules: the single modules it holds (a `x.py` entry; `__init__.py` is the root package).
        may_import: the rooms or modules its row names (`experiment.runfolder`: that module only);
            "*" for everything.
    """

    name: str
    packages: frozenset[str]
    modules: frozenset[str]
    may_import: frozenset[str]

    def holds(self, module: str) -> bool:
        return module in self.modules or any(module == p or module.startswith(f"{p}.") for p in self.packages)


class TableError(AssertionError):
    """The room table of docs/architecture.md cannot be read as rooms."""


def _entries(cell: str) -> list[str]:
    """The names in a cell: backquotes dropped, parenthesised remarks dropped, comma-separated."""
    cell = re.sub(r"\([^)]*\)", "", cell).replace("`", "")
    return [entry.strip() for entry in cell.split(",") if entry.strip()]


def parse_rooms(text: str, modules: set[str], root: str = "nerfaug") -> list[Room]:
    """The rooms of the table under TABLE_HEADING, in its order.

    First column: `x/` (a package) and `x.py` (a module) entries, or "shared leaves: ..." (modules
    every room may import). Last column: "everything", "every room above", "one another" (leaves
    only), or comma-separated room names (a room's first name) and module names
    (`experiment.runfolder`), each with an optional remark in parentheses. A row may name only
    rooms above it, so the table is a layering: no arrow back up, no circle.

    Raises:
        TableError: no table, a malformed row, or a name that is no room or module.
    """
    if TABLE_HEADING not in text:
        raise TableError(f"{ARCHITECTURE.name}: no heading {TABLE_HEADING!r}")
    lines = text.split(TABLE_HEADING, 1)[1].strip().splitlines()
    table = lines[: next((i for i, line in enumerate(lines) if not line.startswith("|")), len(lines))]
    if len(table) < 3 or [c.strip() for c in table[0].strip("|").split("|")] != ["room", "owns", "may import"]:
        raise TableError(
            f"{ARCHITECTURE.name}: expected a table '| room | owns | may import |' under {TABLE_HEADING!r}"
        )
    rooms: list[Room] = []
    for line in table[2:]:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3:
            raise TableError(f"{ARCHITECTURE.name}: a room row needs 3 cells: {line!r}")
        first, allowed = cells[0], cells[2]
        leaves = first.startswith("shared leaves")
        entries = _entries(first.split(":", 1)[1] if leaves else first)
        packages = {f"{root}.{e.removesuffix('/').replace('/', '.')}" for e in entries if e.endswith("/")}
        singles = {
            root if e == "__init__.py" else f"{root}.{e.removesuffix('.py').replace('/', '.')}"
            for e in entries
            if e.endswith(".py")
        }
        unknown = [e for e in entries if not e.endswith(("/", ".py"))] + sorted(
            singles - modules | {p for p in packages if not any(m.startswith(f"{p}.") for m in modules)}
        )
        if unknown or not entries:
            raise TableError(f"{ARCHITECTURE.name}: row {first!r}: not a module or package here: {unknown or first}")
        name = "shared leaves" if leaves else entries[0].removesuffix("/").removesuffix(".py")
        if allowed == "everything":
            may = {"*"}
        elif allowed == "every room above":
            may = {room.name for room in rooms}
        elif allowed in ("one another", "—", "-", ""):
            may = set()
        else:
            may = set(_entries(allowed))
        rooms.append(Room(name, frozenset(packages), frozenset(singles), frozenset(may)))
    names = [room.name for room in rooms]
    for i, room in enumerate(rooms):
        for entry in room.may_import - {"*"}:
            if entry in names:
                if names.index(entry) >= i:
                    raise TableError(f"{ARCHITECTURE.name}: {room.name} may import {entry}, which is not above it")
            elif not any(m == f"{root}.{entry}" or m.startswith(f"{root}.{entry}.") for m in modules):
                raise TableError(f"{ARCHITECTURE.name}: {room.name} may import {entry!r}: no such room or module")
            elif not any(r.holds(f"{root}.{entry}") for r in rooms[:i]):
                raise TableError(f"{ARCHITECTURE.name}: {room.name} may import {entry}, which is not above it")
    return rooms


def room_of(module: str, rooms: list[Room]) -> Room | None:
    held = [room for room in rooms if room.holds(module)]
    return held[0] if len(held) == 1 else None


def allowed(source: Room, target: str, rooms: list[Room], root: str = "nerfaug") -> bool:
    home = room_of(target, rooms)
    if home is source or "*" in source.may_import or (home is not None and home.name == "shared leaves"):
        return True
    for entry in source.may_import:
        if home is not None and entry == home.name:
            return True
        if target == f"{root}.{entry}" or target.startswith(f"{root}.{entry}."):
            return True
    return False


def breaches(rooms: list[Room], imports: dict[str, list[Import]], root: str = "nerfaug") -> list[str]:
    """Every import the table does not allow, as 'module:line imports target (room -> room)'."""
    found = []
    for module, its_imports in sorted(imports.items()):
        source = room_of(module, rooms)
        assert source is not None, f"{module} is in no room (or several) of {ARCHITECTURE.name}'s table"
        for imp in its_imports:
            if not allowed(source, imp.target, rooms, root):
                home = room_of(imp.target, rooms)
                where = "" if imp.top_level else ", deferred"
                found.append(
                    f"{module}:{imp.line} imports {imp.target} ({source.name} -> {home.name if home else '?'}{where})"
                )
    return found


def test_every_module_is_in_exactly_one_room():
    rooms = parse_rooms(ARCHITECTURE.read_text(), set(package_modules()))
    homeless = [m for m in package_modules() if sum(room.holds(m) for room in rooms) != 1]
    assert not homeless, f"modules in no room or in several rooms of {ARCHITECTURE.name}'s table: {homeless}"


def test_every_import_follows_the_room_table():
    rooms = parse_rooms(ARCHITECTURE.read_text(), set(package_modules()))
    assert len(rooms) >= 10, "the room table was not read"
    found = breaches(rooms, package_imports())
    assert not found, "imports the room table of docs/architecture.md does not allow:\n" + "\n".join(found)


def test_a_planted_deferred_import_back_up_is_a_breach():
    """A function-level import from a low room into a higher one (and one under TYPE_CHECKING, and
    a relative one) is found, in a module of the real package fed to the checker as source."""
    modules = set(package_modules())
    rooms = parse_rooms(ARCHITECTURE.read_text(), modules)
    source = (PACKAGE / "data" / "views.py").read_text() + (
        "\n\ndef planted():\n"
        "    from nerfaug.report import write_report\n\n"
        "    return write_report\n\n\n"
        "if TYPE_CHECKING:\n"
        "    from nerfaug.experiment.config import ExperimentConfig\n\n\n"
        "def relative():\n"
        "    from ..selection import select_views\n\n"
        "    return select_views\n"
    )
    imports = {"nerfaug.data.views": imports_of(source, "nerfaug.data.views", False, modules)}
    found = breaches(rooms, imports)
    assert len(found) == 3, found
    assert "imports nerfaug.report (data -> report, deferred)" in found[0]
    assert "nerfaug.experiment.config (data -> experiment, deferred)" in found[1]
    assert "nerfaug.selection (data -> selection, deferred)" in found[2]
    clean = {"nerfaug.data.views": imports_of(source.split("\n\ndef planted")[0], "nerfaug.data.views", False, modules)}
    assert breaches(rooms, clean) == []


def test_a_toy_package_with_a_deferred_import_back_up_fails(tmp_path):
    """The checker on a package of its own: the table's order decides, whatever the real code."""
    toy = tmp_path / "toy"
    for path, text in {
        "__init__.py": "",
        "leaf.py": "",
        "low/__init__.py": "from toy.leaf import *\n",
        "low/part.py": "def f():\n    import toy.high.top\n",
        "high/__init__.py": "",
        "high/top.py": "from ..low import part\n",
    }.items():
        (toy / path).parent.mkdir(parents=True, exist_ok=True)
        (toy / path).write_text(text)
    doc = (
        f"{TABLE_HEADING}\n\n| room | owns | may import |\n|---|---|---|\n"
        "| shared leaves: `leaf.py`, `__init__.py` | helpers | one another |\n"
        "| `low/` | the bottom | — |\n"
        "| `high/` | the top | low (its parts) |\n"
    )
    modules = set(package_modules(toy))
    rooms = parse_rooms(doc, modules, root="toy")
    assert [room.name for room in rooms] == ["shared leaves", "low", "high"]
    assert breaches(rooms, package_imports(toy), root="toy") == [
        "toy.low.part:2 imports toy.high.top (low -> high, deferred)"
    ]


@pytest.mark.parametrize(
    "row, problem",
    [
        ("| `low/` | the bottom | high |", "not above it"),
        ("| `low/` | the bottom | nowhere |", "no such room or module"),
        ("| `nowhere/` | nothing | — |", "not a module or package here"),
        ("| `low/` | the bottom |", "needs 3 cells"),
    ],
)
def test_a_table_that_cannot_be_read_is_a_clear_failure(row, problem):
    modules = {"toy", "toy.low", "toy.low.part", "toy.high", "toy.high.top"}
    doc = f"{TABLE_HEADING}\n\n| room | owns | may import |\n|---|---|---|\n{row}\n| `high/` | top | low |\n"
    with pytest.raises(TableError, match=problem):
        parse_rooms(doc, modules, root="toy")
    with pytest.raises(TableError, match="no heading"):
        parse_rooms("# Architecture\n", modules, root="toy")


# --- cycles, sizes, light modules ---------------------------------------------------------------


def import_graph(deferred: bool = False) -> dict[str, set[str]]:
    """nerfaug modules each module imports: module-level statements only (what runs when it is
    imported), or with `deferred` every import, those inside functions too (a dependency all the
    same, even if it cannot fail at import time). `from package import submodule` depends on the
    submodule, not on the package's __init__ (which Python runs first for every submodule import,
    re-exports and all)."""
    modules = package_modules()
    return {
        name: {
            imp.target
            for imp in imports
            if (imp.top_level or deferred) and imp.target in modules and imp.target != name
        }
        for name, imports in package_imports().items()
    }


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


def test_no_import_cycle_between_modules():
    graph = import_graph()
    assert len(graph) > 50, "the package's modules were not found"
    assert find_cycle(graph) is None, f"import cycle: {' -> '.join(find_cycle(graph))}"


def test_no_circle_between_modules_counting_deferred_imports():
    """A deferred import that closes a circle (a config checking names in a registry that
    imports the config) hides a dependency both ways; the room table cannot see it inside a room."""
    graph = import_graph(deferred=True)
    assert find_cycle(graph) is None, f"circle: {' -> '.join(find_cycle(graph))}"


def test_no_circle_between_top_level_modules_and_packages_counting_every_import():
    """The room table orders rooms, not the shared leaves among themselves: a circle between two
    leaves (or any two top-level names), through deferred imports too, is found here."""

    def top(module: str) -> str:
        return ".".join(module.split(".")[:2])

    graph: dict[str, set[str]] = {}
    for module, imports in package_imports().items():
        graph.setdefault(top(module), set()).update(top(i.target) for i in imports if top(i.target) != top(module))
    for targets in list(graph.values()):
        for target in targets:
            graph.setdefault(target, set())
    assert len(graph) > 20, "the package's top-level modules were not found"
    assert find_cycle(graph) is None, f"circle: {' -> '.join(find_cycle(graph))}"


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_module_over_600_lines(path):
    assert len(path.read_text().splitlines()) <= MAX_LINES


def test_light_modules_do_not_import_torch():
    code = (
        "import sys; import nerfaug.jsonio, nerfaug.metrics, nerfaug.errors, nerfaug.owned; "
        "print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
