"""The study of rounds' one-shot arm read from a table of its own (`nerfaug study --one-shot-table`):
its runs count for Q2 only with the fingerprints the settings its plan records give them now
(computed here as a run computes its own, `protocol`'s formula), the page names the table by its
file name, and a table that cannot be that arm is refused in one line naming the file and field.

The tables are constructed with known answers (tests/report/test_rounds_verdicts.py's)."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from nerfaug.experiment.config import STUDY_PRESETS, ExperimentConfig
from nerfaug.experiment.store import fingerprint, run_fingerprint
from nerfaug.report.rounds_verdicts import OneShotArm, rounds_rows
from nerfaug.report.study import collect_study
from nerfaug.report.study_hypotheses import hypotheses_blocks
from nerfaug.report.study_table import write_table
from nerfaug.selection.methods import get_method

_spec = importlib.util.spec_from_file_location("verdicts", Path(__file__).with_name("test_rounds_verdicts.py"))
verdicts = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(verdicts)

ENGINE, VERSION = verdicts.ENGINE, "hash-cpu-1"


def one_shot_config(**changes) -> ExperimentConfig:
    """The one-shot arm's protocol as a study runs it: the study preset, uniform and ours, 3 layouts."""
    config = STUDY_PRESETS.choose("study", device="cpu", methods=("uniform", "ours"), trials=10, layouts=3, **changes)
    return config.replace(engine=ENGINE)


def one_shot_plan(config: ExperimentConfig) -> dict:
    """The plan a study of `config` records (study.json, kept by its table)."""
    return {"engines": [ENGINE], "methods": ["uniform", "ours"], "trials": 10, "config": config.to_record()}


def run_fingerprints(config: ExperimentConfig, monkeypatch) -> dict[str, str]:
    """Each method's fingerprint as a run of `config` computes it (`protocol`: the sweep's
    fingerprint of `fingerprinted()`, this machine's engine version set to `VERSION`, with the
    method's definition)."""
    with monkeypatch.context() as patch:
        patch.setattr(ExperimentConfig, "engine_version", lambda self: VERSION)
        sweep = fingerprint(config.fingerprinted())
    return {m: run_fingerprint(sweep, get_method(m).definition()) for m in ("uniform", "ours")}


def tables(monkeypatch, shift: float = -1.5) -> tuple[dict, dict]:
    """(the arm in rounds, the one-shot arm's table): the one-shot runs are the rounds runs' `shift`
    dB apart, every run of engine version `VERSION`, the one-shot runs with the fingerprints their
    plan gives them."""
    rounds, one_shot = verdicts.table({"ours": 0.5}), verdicts.table({"ours": 0.5}, shift=shift, rounds=1)
    config = one_shot_config()
    one_shot["plan"] = one_shot_plan(config)
    made = run_fingerprints(config, monkeypatch)
    one_shot["runs"] = [r for r in one_shot["runs"] if r["method"] in made and r["scene"] in verdicts.ROUNDS_SCENES]
    for run in one_shot["runs"]:
        run["fingerprint"] = made[run["method"]]
    for run in rounds["runs"] + one_shot["runs"]:
        run["engine_version"] = VERSION
    return rounds, one_shot


def arm_of(one_shot: dict, path: Path) -> OneShotArm:
    from nerfaug.cli.study_work import one_shot_arm

    return one_shot_arm(write_table(path, one_shot))


def q2(rounds: dict, arm: OneShotArm) -> list[str]:
    return rounds_rows(collect_study(rounds), ENGINE, arm)[1]


def test_the_other_tables_runs_count_with_the_fingerprints_their_plan_gives(tmp_path, monkeypatch):
    rounds, one_shot = tables(monkeypatch)
    arm = arm_of(one_shot, tmp_path / "rounds-oneshot-table.json")
    assert arm.current == {r["fingerprint"] for r in one_shot["runs"]} and len(one_shot["runs"]) == 80
    row = q2(rounds, arm)
    for method in ("uniform", "ours"):
        means = verdicts.seed_means(rounds, method, one_shot, method)
        p = min(1.0, 2 * verdicts.sign_flip_by_enumeration(means))
        assert f"{method}: rounds - one-shot: mean {np.mean(means):+.2f} dB" in row[4]
        assert f"p x 2 = {p:.3f}" in row[4]
    assert row[3] == "**holds**" and "left out" not in " ".join(row[4])
    # One run recorded with another fingerprint than its settings give: left out, and the arm part-way.
    one_shot["runs"][0]["fingerprint"] = "0123456789abcdef"
    row = q2(rounds, arm_of(one_shot, tmp_path / "one-stale.json"))
    assert row[3] == "**partial: 79 of 80 one-shot runs**"
    assert "1 one-shot run(s) left out: their fingerprints no longer match their settings" in row[4]
    # A plan whose settings give other fingerprints (another number of steps): no run counts.
    _, other = tables(monkeypatch)
    other["plan"] = one_shot_plan(one_shot_config(steps=1900))
    row = q2(rounds, arm_of(other, tmp_path / "other-steps.json"))
    assert row[3] == "**not judged: no current one-shot runs of uniform, ours**"
    assert "80 one-shot run(s) left out" in row[4]
    # The runs' recorded engine version is re-derived, not this machine's: on the reference engine
    # (the fused loop off), the same table counts every run.
    monkeypatch.setattr(ExperimentConfig, "engine_version", lambda self: None)
    assert arm_of(tables(monkeypatch)[1], tmp_path / "reference.json").current == arm.current


def test_the_page_names_the_other_table_by_its_file_name_only(tmp_path, monkeypatch):
    rounds, one_shot = tables(monkeypatch)
    arm = arm_of(one_shot, tmp_path / "rounds-oneshot-table.json")
    text = " ".join(str(b) for b in hypotheses_blocks(collect_study(rounds), "auto", arm))
    assert "one round, read from the table rounds-oneshot-table.json)" in text
    assert str(tmp_path) not in text and "in the same table" not in text
    # Given with the page of another plan, it is refused rather than left unread.
    with pytest.raises(ValueError, match="rounds-oneshot-table.json: read for the study of rounds' Q2 only"):
        hypotheses_blocks(collect_study(one_shot), "auto", arm)


def nerfaug(argv: list[str], capsys) -> tuple[int, str]:
    from nerfaug.cli import main

    try:
        main(argv)
    except SystemExit as done:
        return done.code, capsys.readouterr().err
    return 0, capsys.readouterr().err


def test_summary_only_reads_the_one_shot_arm_from_its_table(tmp_path, monkeypatch, capsys):
    rounds, one_shot = tables(monkeypatch)
    monkeypatch.chdir(tmp_path)
    write_table(Path("rounds.json"), rounds)
    write_table(Path("tables/oneshot.json"), one_shot)
    argv = ["study", "--out", "gone", "--summary-only", "--table", "rounds.json", "--one-shot-table"]
    code, err = nerfaug([*argv, "tables/oneshot.json", "--results-doc", "docs/results-rounds.md"], capsys)
    assert code == 0, err
    page = (tmp_path / "docs" / "results-rounds.md").read_text()
    assert "one round, read from the table oneshot.json)" in page and str(tmp_path) not in page
    assert "--table rounds.json --results-doc docs/results-rounds.md --one-shot-table tables/oneshot.json`" in page
    expected = q2(rounds, arm_of(one_shot, tmp_path / "copy.json"))
    (line,) = [x for x in page.splitlines() if x.startswith("| Q2 |")]
    assert expected[3] == "**holds**" and expected[3] in line and expected[4][0].split(";")[0] in line
    assert "read from the table oneshot.json" in (tmp_path / "gone" / "study.md").read_text()


def test_a_table_that_cannot_be_the_one_shot_arm_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    rounds, one_shot = tables(monkeypatch)
    write_table(tmp_path / "rounds.json", rounds)
    write_table(tmp_path / "oneshot.json", one_shot)
    summary = ["study", "--out", str(tmp_path / "gone"), "--summary-only", "--table"]
    curves = dict(one_shot, runs=[*one_shot["runs"][:-1], rounds["runs"][0] | {"trial": 11, "seed": 11}])
    write_table(tmp_path / "curves.json", curves)
    damaged = dict(one_shot, plan=one_shot["plan"] | {"config": one_shot["plan"]["config"] | {"warm_start": 2}})
    write_table(tmp_path / "damaged.json", damaged)
    cases = [
        (["rounds.json", "--one-shot-table", "missing.json"], "missing.json: not readable"),
        (["rounds.json", "--one-shot-table", "curves.json"], f"curves.json: runs[{len(curves['runs']) - 1}].curve:"),
        (["rounds.json", "--one-shot-table", "damaged.json"], "damaged.json: plan.config.warm_start 2: unknown field"),
        (
            ["rounds.json", "--one-shot-table", "oneshot.json", "--hypotheses", "real"],
            "oneshot.json: read for the study of rounds' Q2 only, not with --hypotheses real",
        ),
        (["oneshot.json", "--one-shot-table", "oneshot.json"], "is judged by the real plan (plan.config.rounds: 1)"),
    ]
    for args, message in cases:
        args = [str(tmp_path / a) if a.endswith(".json") else a for a in args]
        code, err = nerfaug([*summary, *args], capsys)
        assert code == 2 and message in err and err.count("\n") == 1 and "--one-shot-table" in err, (args, err)
        assert not (tmp_path / "gone").exists()
    # A study run with one round and no plan named is refused before any run.
    given = ["--one-shot-table", str(tmp_path / "oneshot.json")]
    code, err = nerfaug(["study", "--out", str(tmp_path / "gone"), *given], capsys)
    assert code == 2 and "not with a study of one round (--rounds 1)" in err
    assert not (tmp_path / "gone").exists()
