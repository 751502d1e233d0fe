"""nerfaug.jsonio: torch-free JSON reading with one-line errors, atomic writes; and the shape of the
data package's imports (no cycle, no private names across modules)."""

import ast
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from nerfaug.data.errors import DatasetError
from nerfaug.jsonio import (
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    read_json,
)

DATA_PACKAGE = Path(__file__).resolve().parents[2] / "src" / "nerfaug" / "data"


def test_jsonio_and_dataset_error_import_without_torch_or_imageio():
    code = (
        "import sys, nerfaug.jsonio, nerfaug.data.errors; "
        "print(sorted(m for m in ('torch', 'imageio', 'numpy') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_json_round_trip_is_atomic_and_keeps_infinity(tmp_path):
    path = tmp_path / "deep" / "er" / "a.json"
    atomic_write_json(path, {"psnr": float("inf"), "n": [1, 2]})
    assert read_json(path) == {"psnr": float("inf"), "n": [1, 2]}
    atomic_write_text(tmp_path / "t.txt", "é\n")
    assert (tmp_path / "t.txt").read_bytes() == "é\n".encode()
    assert sorted(p.name for p in path.parent.iterdir()) == ["a.json"]  # no temporary left behind
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_a_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "a.json"
    atomic_write_json(path, {"v": 1})
    with pytest.raises(TypeError):
        atomic_write_json(path, {"v": object()})  # not serialisable: fails before anything is written
    with pytest.raises(TypeError):
        atomic_write_bytes(path, "not bytes")  # fails while writing the temporary
    assert read_json(path) == {"v": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "file not found"),
        (b"\xff\xfe{}", "not UTF-8 text"),
        (b'{"a": 1,\n "b": }', "invalid JSON at line 2 column 7"),
        (b'{"a": ' + b"9" * 5000 + b"}", "invalid JSON: Exceeds the limit"),
        (b"[" * 100_000 + b"]" * 100_000, "invalid JSON"),
        (b"[1, 2]", "expected a JSON object at the top level"),
    ],
)
def test_read_json_names_the_file_and_the_problem(tmp_path, content, message):
    path = tmp_path / "transforms.json"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(DatasetError, match=message) as caught:
        read_json(path)
    assert str(caught.value).startswith(str(path)) and "\n" not in str(caught.value)


def test_read_json_accepts_a_byte_order_mark(tmp_path):
    path = tmp_path / "transforms.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps({"frames": []}).encode())
    assert read_json(path) == {"frames": []}


def test_read_json_of_a_folder_is_a_dataset_error(tmp_path):
    with pytest.raises(DatasetError, match="cannot read the file"):
        read_json(tmp_path)


def _data_imports() -> dict[str, set[str]]:
    """For each module of nerfaug.data, the modules of nerfaug.data it imports (anywhere in it)."""
    graph = {}
    for path in DATA_PACKAGE.glob("*.py"):
        name = "nerfaug.data" if path.stem == "__init__" else f"nerfaug.data.{path.stem}"
        found = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("nerfaug.data"):
                found.add(node.module)
                for alias in node.names:
                    assert not alias.name.startswith("_"), f"{name} imports private {node.module}.{alias.name}"
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name.startswith("nerfaug.data"))
        graph[name] = found - {name}
    return graph


def test_the_data_package_has_no_import_cycle():
    graph = _data_imports()
    graph.pop("nerfaug.data")  # the package's __init__ only names its modules (imported on use)
    state = {}

    def visit(module, trail):
        if state.get(module) == "open":
            raise AssertionError(f"import cycle: {' -> '.join(trail + [module])}")
        if state.get(module) == "done":
            return
        state[module] = "open"
        for target in graph.get(module, ()):
            visit(target, trail + [module])
        state[module] = "done"

    for module in graph:
        visit(module, [])
    # No format imports the registry that picks it; only `prepare`, which copies any format, sits above it.
    assert [m for m, targets in graph.items() if "nerfaug.data.formats" in targets] == ["nerfaug.data.prepare"]
    assert graph["nerfaug.data.views"] == set()
    assert graph["nerfaug.data.errors"] == set()


def test_the_package_names_resolve_lazily():
    from nerfaug import data

    assert data.load_dataset.__module__ == "nerfaug.data.formats"
    assert data.Views.__module__ == "nerfaug.data.views"
    assert set(data.__all__) <= set(dir(data))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        data.nope  # noqa: B018
