"""A damaged study table given to `nerfaug study` (--table FILE, or OUT's own study-table.json) is
bad input: one line naming the file and the field where known, exit 2, and nothing run or written.
The tables are a small valid one (`make_table`) damaged one way each."""

import json

import pytest

from nerfaug.hemisphere import half_hemisphere_poses
from nerfaug.report.study_table import RunRow, make_table, rounded_poses, table_bytes

SCENE = "mic"


def valid_table() -> dict:
    """One engine, one scene, uniform and ours, two trials each: a table `read_table` accepts."""
    initial = rounded_poses(half_hemisphere_poses(4).numpy())
    near = rounded_poses(half_hemisphere_poses(3).numpy())
    rows = [
        RunRow("nerfacto-cpu", SCENE, method, trial, trial, 20.0 + trial, 0.8, 0.2, "ok", [0, 1, 2], near, "v",
               f"fp-{method}")
        for method in ("uniform", "ours")
        for trial in range(2)
    ]  # fmt: skip
    plan = {"engines": ["nerfacto-cpu"], "scenes": [SCENE], "methods": ["uniform", "ours"], "trials": 2}
    return make_table(plan, rows, {SCENE: {"initial_poses": initial, "layouts": {"0": initial}}})


def damaged(kind: str) -> bytes:
    table = valid_table()
    if kind == "not JSON":
        return table_bytes(table)[:-40]  # cut short, as an interrupted copy leaves it
    if kind == "another format":
        return json.dumps(table | {"format": "nerfaug-results"}).encode()
    del table["runs"][1]["psnr"]
    return table_bytes(table)


EXPECTED = {
    "not JSON": ": invalid JSON (",
    "another format": ": format: not a ",
    "a row missing a field": ": runs[1]: missing ['psnr']",
}


def refused(argv: list[str], capsys) -> tuple[int, str]:
    """`nerfaug argv`, which must end with SystemExit: its exit code and what it printed on stderr."""
    from nerfaug.cli import main

    with pytest.raises(SystemExit) as done:
        main(argv)
    return done.value.code, capsys.readouterr().err


@pytest.mark.parametrize("kind", list(EXPECTED))
def test_a_damaged_table_given_with_table_is_one_line_and_exit_2(kind, tmp_path, capsys):
    path = tmp_path / "study-table.json"
    path.write_bytes(damaged(kind))
    docs = tmp_path / "docs" / "results.md"
    argv = ["study", "--out", str(tmp_path / "gone"), "--summary-only", "--table", str(path)]
    code, err = refused([*argv, "--results-doc", str(docs)], capsys)
    assert code == 2, err
    assert err.startswith(f"nerfaug: --table {path}{EXPECTED[kind]}"), err
    assert err.count("\n") == 1 and "internal error" not in err
    assert path.read_bytes() == damaged(kind)  # the table is left as it was
    assert not (tmp_path / "gone").exists() and not docs.parent.exists()


def test_a_damaged_table_in_out_is_named_by_its_path(tmp_path, capsys):
    out = tmp_path / "study"
    out.mkdir()
    (out / "study-table.json").write_bytes(damaged("a row missing a field"))
    code, err = refused(["study", "--out", str(out), "--summary-only"], capsys)
    assert code == 2 and err == f"nerfaug: {out / 'study-table.json'}{EXPECTED['a row missing a field']}\n", err
    assert sorted(p.name for p in out.iterdir()) == ["study-table.json"]


def test_the_undamaged_table_is_read(tmp_path):
    """The same table before its damage makes the page: the refusals above are the damage's."""
    path = tmp_path / "study-table.json"
    path.write_bytes(table_bytes(valid_table()))
    from nerfaug.cli import main

    main(["study", "--out", str(tmp_path / "page"), "--summary-only", "--table", str(path)])
    assert (tmp_path / "page" / "study.md").is_file()
