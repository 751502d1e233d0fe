"""Every bad input of the `cases_*.py` modules through the `nerfaug` CLI: the right exit code, one line naming
the file, field or value, no traceback, and every input folder byte for byte unchanged."""

import pytest
from cases import all_cases
from harness import classify, run_cli, tree_hash

CASES = all_cases()


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_is_refused_clearly_and_changes_nothing(name, bases, tmp_path):
    case = CASES[name](tmp_path, bases)
    assert case.says, f"{name}: a case names the file, field or value its message must name"
    guarded = [*case.inputs, bases.dataset, bases.session, bases.results]
    before = {str(p): tree_hash(p) for p in guarded}
    outcome = run_cli(case.argv, cwd=case.cwd)
    after = {str(p): tree_hash(p) for p in guarded}
    changed = [p for p in before if before[p] != after[p]]
    assert not changed, f"{name} changed {changed}; stderr: {outcome.err}"
    assert not outcome.traceback, f"{name}: traceback\n{outcome.escaped or outcome.err}"
    assert outcome.code == case.code, f"{name}: exit {outcome.code}, stderr: {outcome.err}"
    lines = outcome.error_lines()
    if not case.usage:
        assert len(lines) == 1, f"{name}: expected one 'nerfaug:' line, got: {outcome.err!r}"
    text = " ".join(lines) if not case.usage else outcome.err
    missing = [s for s in case.says if s not in text]
    assert not missing, f"{name}: the message does not name {missing}: {text}"
    assert classify(case, outcome, before, after) == "clear"
