"""docs/results.md is what its committed per-run table gives, and every number in its hand-written
reading is one the generated page (or the committed FisherRF measurement) shows."""

import dataclasses
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "results.md"
TABLE = ROOT / "docs" / "results" / "study-table.json"
FISHER = ROOT / "docs" / "results" / "fisher-stability.json"
REAL_PAGE = ROOT / "docs" / "results-real.md"
REAL_TABLE = ROOT / "docs" / "results" / "real-study-table.json"
NUMBER = re.compile(r"[-+]?\d+\.\d+")

pytestmark = pytest.mark.skipif(not TABLE.is_file(), reason="no committed study table yet")


def split_page(text: str) -> tuple[str, str]:
    """(the generated part, the hand-written reading) of a results page."""
    from nerfaug.report.study_page import READING_END, READING_START

    start, end = text.find(READING_START), text.find(READING_END)
    if start < 0:
        return text, ""
    return text[:start] + text[end + len(READING_END) :], text[start:end]


def without_provenance(text: str) -> str:
    return "\n".join(line for line in text.splitlines() if not line.startswith("Generated on "))


@pytest.mark.slow
def test_the_committed_page_is_what_the_committed_table_gives(tmp_path):
    from nerfaug.report.study_page import write_results_doc
    from nerfaug.report.study_table import read_table

    page = write_results_doc(read_table(TABLE), TABLE.relative_to(ROOT), tmp_path / "results.md")
    generated, _ = split_page(PAGE.read_text())
    assert without_provenance(page.read_text()).split() == without_provenance(generated).split()


@pytest.mark.slow
def test_the_committed_real_scene_page_is_what_its_table_gives(tmp_path):
    from nerfaug.report.study_page import write_results_doc
    from nerfaug.report.study_table import read_table

    page = write_results_doc(read_table(REAL_TABLE), REAL_TABLE.relative_to(ROOT), tmp_path / "results-real.md")
    generated, _ = split_page(REAL_PAGE.read_text())
    assert without_provenance(page.read_text()).split() == without_provenance(generated).split()


@pytest.mark.parametrize("page", [PAGE, REAL_PAGE], ids=["procedural", "real"])
def test_every_number_in_the_reading_is_on_the_generated_page(page):
    generated, reading = split_page(page.read_text())
    sources = generated + (json.dumps(json.loads(FISHER.read_text())) if FISHER.is_file() and page == PAGE else "")
    shown = {float(x) for x in NUMBER.findall(sources)} | {abs(float(x)) for x in NUMBER.findall(sources)}
    missing = [x for x in NUMBER.findall(reading) if abs(float(x)) not in shown and float(x) not in shown]
    assert not missing, f"numbers in the reading that the generated page does not show: {missing}"


@pytest.mark.slow
def test_the_readmes_command_rederives_the_page_without_run_folders(tmp_path):
    """The README's block, run as written in a folder holding only the committed table."""
    import shlex
    import subprocess
    import sys

    readme = (ROOT / "README.md").read_text()
    (line,) = [x for x in readme.splitlines() if x.startswith("nerfaug study --summary-only --table")]
    (tmp_path / "docs" / "results").mkdir(parents=True)
    (tmp_path / "docs" / "results" / "study-table.json").write_bytes(TABLE.read_bytes())
    argv = shlex.split(line)
    done = subprocess.run(
        [sys.executable, "-m", "nerfaug.cli", *argv[1:]], cwd=tmp_path, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-2000:]
    generated, _ = split_page(PAGE.read_text())
    again, _ = split_page((tmp_path / "docs" / "results.md").read_text())
    assert without_provenance(again).split() == without_provenance(generated).split()


def findings(where: str) -> str:
    """The paragraph on what the committed study found: the README's, or that of the page
    `nerfaug propose --help` links to for which method to use (docs/methods.md)."""
    if where == "README":
        text, opening = (ROOT / "README.md").read_text(), "What the committed study found"
    else:
        text, opening = (ROOT / "docs" / "methods.md").read_text(), "Which method to use:"
    (paragraph,) = [p for p in text.split("\n\n") if p.startswith(opening)]
    return paragraph


def test_propose_help_links_to_the_findings_and_states_none_itself():
    """Study findings live in docs (they change with the study), not in `--help`."""
    from nerfaug.cli import session as session_cli

    help_text = " ".join(session_cli.propose.__doc__.split())
    assert "docs/methods.md" in help_text
    assert not re.search(r"beat uniform|no method did|worse than uniform", help_text)


@pytest.mark.parametrize("where", ["docs/methods.md", "README"])
def test_the_user_facing_advice_says_what_it_rests_on(where):
    """Advice from the procedural study says so until the real-scene study decides something."""
    from nerfaug.report.study import collect_study
    from nerfaug.report.study_table import read_table

    real = collect_study(read_table(REAL_TABLE))
    text = " ".join(findings(where).lower().split())
    if not all(cell.complete for cell in real.cells) or len(real.cells) < 8:
        assert "procedural stand-ins" in text and "measured on stand-ins only" in text, where


@pytest.mark.parametrize("where", ["docs/methods.md", "README"])
def test_the_user_facing_texts_state_what_the_real_scene_study_found_per_complete_engine(where):
    """Per engine whose four planned real scenes are complete, the advice says what the test
    across them found (the method better than uniform, or that none was), and claims nothing of
    an engine part-way."""
    from nerfaug.report.study import collect_study
    from nerfaug.report.study_hypotheses import REAL_SCENES, real_engines
    from nerfaug.report.study_table import read_table

    real = collect_study(read_table(REAL_TABLE))
    text = " ".join(findings(where).lower().split())
    for engine in real_engines(real):
        cells = [c for c in real.cells if c.engine == engine and c.scene in REAL_SCENES]
        claim = f"on real scenes with the {engine} engine"
        if len(cells) < len(REAL_SCENES) or not all(c.complete for c in cells):
            assert claim not in text, engine
            continue
        regime = real.regimes[engine]
        better = sorted((e["difference"], m) for m, e in regime.items() if e["significant"] and e["better"])
        if better:
            assert f"{claim}, {better[-1][1]} beat uniform" in text, engine
        else:
            assert re.search(f"{re.escape(claim)}[^;]* no method (did|beat uniform)", text), engine


@pytest.mark.parametrize("where", ["docs/methods.md", "README"])
def test_the_user_facing_texts_state_what_the_committed_study_found_per_engine(where):
    """docs/methods.md (which `nerfaug propose --help` links to) and the README name, per engine
    whose three scenes are complete, the method the across-scene test finds better than uniform
    (or say none did), and claim nothing of the engines not yet complete."""
    from nerfaug.nerf.config import PRESETS
    from nerfaug.report.study import collect_study
    from nerfaug.report.study_table import read_table

    study = collect_study(read_table(TABLE))
    text = findings(where)
    text = " ".join(text.lower().split())  # "On the cpu engine" claims as much as "on the ..."
    for engine in PRESETS:  # every engine, so a preset added later cannot be claimed unmeasured
        cells = [c for c in study.cells if c.engine == engine]
        regime = study.regimes.get(engine, {})
        if len(cells) < 3 or not all(c.complete for c in cells):
            assert f"on the {engine} engine" not in text, engine
            continue
        better = sorted((e["difference"], m) for m, e in regime.items() if e["significant"] and e["better"])
        if better:
            assert f"on the {engine} engine, {better[-1][1]} beat uniform" in text, engine
        else:
            assert re.search(f"on the {re.escape(engine)} engine[^;]* no method did", text), engine
    if "entropy was worse than uniform on every engine measured" in text:
        for engine, regime in study.regimes.items():
            assert regime["entropy"]["significant"] and not regime["entropy"]["better"], engine


ROUNDS_PAGE = ROOT / "docs" / "results-rounds.md"
ROUNDS_TABLE = ROOT / "docs" / "results" / "rounds-study-table.json"
ONE_SHOT_TABLE = ROOT / "docs" / "results" / "rounds-oneshot-table.json"


@pytest.mark.slow
@pytest.mark.skipif(not ROUNDS_TABLE.is_file(), reason="no committed table of the study of rounds yet")
def test_the_committed_page_of_the_study_of_rounds_is_what_its_table_gives(tmp_path):
    """Part-way or complete, the page and every verdict on it come from the committed table alone."""
    from nerfaug.cli.study_work import one_shot_arm
    from nerfaug.report.study_page import write_results_doc
    from nerfaug.report.study_table import read_table

    table = read_table(ROUNDS_TABLE)
    # The page is made with `--one-shot-table` once the one-shot arm's table is committed (Q2 reads it).
    one_shot = None
    if ONE_SHOT_TABLE.is_file():  # named on the page as the command from the repository's root names it
        one_shot = dataclasses.replace(one_shot_arm(ONE_SHOT_TABLE), source=str(ONE_SHOT_TABLE.relative_to(ROOT)))
    page = write_results_doc(
        table, ROUNDS_TABLE.relative_to(ROOT), tmp_path / ROUNDS_PAGE.name, "rounds", one_shot=one_shot
    )
    generated, _ = split_page(ROUNDS_PAGE.read_text())
    assert without_provenance(page.read_text()).split() == without_provenance(generated).split()


def rounds_findings() -> str:
    """The README's paragraph on what the study of rounds found (or that it is under way), in one line."""
    readme = (ROOT / "README.md").read_text()
    openings = ("That study is under way", "What the study of rounds found")
    (paragraph,) = [p for p in readme.split("\n\n") if p.startswith(openings)]
    return " ".join(paragraph.split())


@pytest.mark.skipif(not ROUNDS_TABLE.is_file(), reason="no committed table of the study of rounds yet")
def test_the_readme_states_the_verdicts_of_the_study_of_rounds_as_computed_and_no_advice_before():
    """Each of Q1-Q4 the committed tables decide is stated in the README as the page computes it
    ("Q1, not supported"); one they do not decide yet (partial, not judged) is claimed nowhere, and
    while Q1 is undecided the README gives no advice for the protocol."""
    from nerfaug.cli.study_work import one_shot_arm
    from nerfaug.report.rounds_verdicts import rounds_rows
    from nerfaug.report.study import collect_study
    from nerfaug.report.study_table import read_table

    study = collect_study(read_table(ROUNDS_TABLE))
    arm = one_shot_arm(ONE_SHOT_TABLE) if ONE_SHOT_TABLE.is_file() else None
    text = rounds_findings()
    for engine in study.engines:
        verdicts = {row[0]: row[3].strip("*") for row in rounds_rows(study, engine, arm)}
        decided = {q: v for q, v in verdicts.items() if not v.startswith(("partial", "not judged"))}
        if "Q1" not in decided:
            assert "gives no advice for this protocol yet" in text, verdicts
        for q in verdicts:
            if q in decided:
                assert f"{q}, {decided[q]}" in text, (q, decided[q])
            else:
                assert not re.search(rf"\b{q}, (holds|not supported|contradicted|not applicable)", text), q
