"""Count what `nerfaug` does with every bad input of the reliability cases (BENCHMARKS.md,
"Reliability"): clear error, traceback, silent (exit 0), unclear (wrong exit code, several lines,
or a message that does not name the file/field/value), wrote (added files to a folder it had to
leave alone), or lost (deleted or changed a file there). The first that applies, from the last.

    .venv/bin/python tests/reliability/count.py                 # the code in src/
    PYTHONPATH=/tmp/old/src .venv/bin/python tests/reliability/count.py   # an older version, same cases

Each case runs in-process through `nerfaug.cli.main` exactly as `test_bad_inputs.py` runs it.
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import tempfile
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

import harness  # noqa: E402
from cases import all_cases  # noqa: E402
from harness import classify, make_bases, tree_hash  # noqa: E402

KINDS = ("clear", "traceback", "silent", "unclear", "wrote", "lost")


def _compatible_run_cli():
    """`harness.run_cli`, minus `run --device X` where this version's `nerfaug run` has no
    --device (versions before it trained on the CPU, which the cases ask for anyway)."""
    import inspect

    from nerfaug import cli

    run_cli = harness.run_cli
    if "device" in inspect.signature(cli.run).parameters:
        return run_cli

    def without_device(argv, cwd=None):
        argv = list(argv)
        if argv[:1] == ["run"] and "--device" in argv:
            i = argv.index("--device")
            del argv[i : i + 2]
        return run_cli(argv, cwd)

    return without_device


def count(names: list[str] | None = None) -> tuple[dict[str, str], collections.Counter]:
    """Each case's class, and how many cases fall in each (plus "usage": clear refusals made by
    the argument parser's usage text rather than a one-line message)."""
    warnings.simplefilter("ignore")
    harness.run_cli = run_cli = _compatible_run_cli()  # make_bases runs through it too
    cases = all_cases()
    outcome_of, totals = {}, collections.Counter()
    with tempfile.TemporaryDirectory() as tmp:
        bases = make_bases(Path(tmp) / "bases")
        for i, name in enumerate(sorted(names or cases)):
            folder = Path(tmp) / f"case_{i:03d}"
            folder.mkdir()
            case = cases[name](folder, bases)
            guarded = [*case.inputs, bases.dataset, bases.session, bases.results]
            before = {str(p): tree_hash(p) for p in guarded}
            outcome = run_cli(case.argv, cwd=case.cwd)
            after = {str(p): tree_hash(p) for p in guarded}
            kind = classify(case, outcome, before, after)
            outcome_of[name] = kind
            totals[kind] += 1
            totals["usage"] += kind == "clear" and case.usage
            print(f"{kind:9s} {name}", file=sys.stderr, flush=True)
    return outcome_of, totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="also write every case's class here")
    parser.add_argument("names", nargs="*", help="only these cases")
    args = parser.parse_args()
    import nerfaug

    outcome_of, totals = count(args.names)
    print(f"nerfaug from {Path(nerfaug.__file__).parent}")
    print(
        f"cases {len(outcome_of)}: "
        + ", ".join(f"{k} {totals[k]}" for k in KINDS)
        + f" (of the clear ones, {totals['usage']} by the argument parser's usage text)"
    )
    if args.json:
        args.json.write_text(json.dumps({"totals": dict(totals), "cases": outcome_of}, indent=1))


if __name__ == "__main__":
    main()
