"""`make bench`: every benchmark's quick mode, one after the other, through each one's own CLI,
then a summary (results/bench/summary.md and summary.json) with each command, its exit status,
wall time, the load average around it and the last lines it printed.

    python benchmarks/run_all.py                    # all benchmarks/bench_*.py
    python benchmarks/run_all.py --only bench_gpu bench_selection --timeout 300

A benchmark whose CLI has a `--quick` flag runs with it; the others run with the small settings
listed in QUICK below (their own flags, nothing patched). A benchmark this file does not know and
that has no `--quick` is listed as skipped, never silently left out. Benchmarks needing a dataset
share one analytic dataset written by bench_engine (no Blender); bench_experiment's tiny preset
renders a toy lego with Blender when bpy is installed. The figures are CPU smoke figures on a
shared machine: the benchmarks' full modes (see BENCHMARKS.md) are what is recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TAIL_LINES = 12

# Per benchmark: arguments always given, and the small settings used when it has no --quick.
# "{work}" is the scratch folder, "{out}" the summary folder.
QUICK: dict[str, dict] = {
    "bench_engine": {
        "always": ["--synthetic", "{work}/synthetic", "--threads", "1", "--out", "{out}/bench_engine.json"],
        # --no-compare: the preset comparison times paper-preset steps, ~10 s each on a CPU.
        "small": ["--resolution", "50", "--iterations", "100,200", "--test-views", "5", "--no-ceiling", "--no-compare"],
    },
    "bench_selection": {
        "always": ["--threads", "1", "--out", "{work}/selection"],
        "small": [
            "--steps",
            "20",
            "--resolution",
            "50",
            "--candidates",
            "50",
            "--entropy-resolution",
            "10",
            "--methods",
            "ours",
            "fisherrf",
            "uniform",
        ],
    },
    "bench_propose": {
        "always": ["{work}/synthetic", "--threads", "1", "--device", "cpu", "--out", "{work}/propose"],
        "small": [
            "--split",
            "initial",
            "--steps",
            "30",
            "--candidates",
            "50",
            "--entropy-resolution",
            "10",
            "--repeat",
            "1",
        ],
        "needs": "{work}/synthetic/transforms_initial.json",
    },
    "bench_experiment": {
        "always": ["--out", "{work}/experiment"],
        "small": ["--preset", "tiny"],
    },
    "bench_fisher": {
        "always": ["--data", "{work}/synthetic", "--threads", "1", "--out", "{work}/fisher"],
        "small": [
            "--steps",
            "30",
            "--candidates",
            "12",
            "--resolutions",
            "8",
            "--train-pixels",
            "256",
            "--seeds",
            "1",
            "--no-whole",
        ],
        "needs": "{work}/synthetic/transforms_initial.json",
    },
    "bench_dense": {
        "always": ["--data", "{work}/synthetic", "--threads", "1", "--out", "{work}/dense.json"],
        "small": None,
        "needs": "{work}/synthetic/transforms_train.json",
    },
    "bench_engine_walk": {
        "always": ["--data", "{work}/synthetic", "--threads", "1", "--out", "{work}/walk"],
        "small": None,
        "needs": "{work}/synthetic/transforms_initial.json",
    },
    "bench_trial": {
        "always": ["--data", "{work}/synthetic", "--threads", "1"],
        "small": ["--steps", "240", "--n-test", "3", "--no-lpips"],
        "needs": "{work}/synthetic/transforms_initial.json",
    },
}
# bench_gpu is two commands: pack the shared analytic dataset, then a quick trial on any device.
GPU_STEPS = [
    ["pack", "--from", "{work}/synthetic", "--out", "{work}/gpu/toy.npz", "--max-test", "5", "--no-lpips"],
    [
        "trial",
        "--quick",
        "--data",
        "{work}/gpu/toy.npz",
        "--unpack-to",
        "{work}/gpu/toy",
        "--device",
        "auto",
        "--threads",
        "1",
        "--out",
        "{work}/gpu/trial",
        "--json",
        "{out}/bench_gpu.json",
    ],
]
# Run first: the others read the dataset it writes.
ORDER = [
    "bench_engine",
    "bench_selection",
    "bench_propose",
    "bench_fisher",
    "bench_trial",
    "bench_gpu",
    "bench_experiment",
]


def has_quick(script: Path) -> bool:
    """Whether the benchmark's own --help offers --quick."""
    result = subprocess.run([sys.executable, str(script), "--help"], capture_output=True, text=True, timeout=120)
    return "--quick" in result.stdout


def commands_for(name: str, script: Path, work: Path, out: Path) -> tuple[list[list[str]], str | None]:
    """The commands that run `name`'s quick mode, or ([], why it is skipped)."""
    fill = lambda args: [a.format(work=work, out=out) for a in args]  # noqa: E731
    if name == "bench_gpu":
        return [[sys.executable, str(script), *fill(step)] for step in GPU_STEPS], None
    spec = QUICK.get(name)
    needs = spec.get("needs") if spec else None
    if needs and not Path(needs.format(work=work, out=out)).exists():
        return [], f"needs {needs.format(work=work, out=out)} (written by bench_engine, which did not run)"
    if has_quick(script):
        return [[sys.executable, str(script), *fill(spec["always"] if spec else []), "--quick"]], None
    if spec is None or spec["small"] is None:
        return [], "no --quick flag and no small settings known to run_all.py"
    return [[sys.executable, str(script), *fill(spec["always"]), *fill(spec["small"])]], None


def loadavg() -> list[float] | None:
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else None


def run_one(name: str, commands: list[list[str]], log: Path, timeout: float) -> dict:
    """Run the commands in order (stopping at the first failure); output to `log`."""
    record = {"name": name, "commands": [" ".join(c) for c in commands], "load_before": loadavg()}
    start = time.perf_counter()
    status, lines = "ok", []
    env = dict(os.environ, PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    with open(log, "w") as handle:
        for command in commands:
            handle.write(f"$ {' '.join(command)}\n")
            handle.flush()
            left = timeout - (time.perf_counter() - start)
            try:
                result = subprocess.run(
                    command,
                    stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT,
                    text=True,
                    timeout=max(1.0, left),
                    env=env,
                )
            except subprocess.TimeoutExpired as expired:
                output = expired.stdout or ""
                output = output.decode() if isinstance(output, bytes) else output
                handle.write(output)
                lines += output.splitlines()
                status = f"timed out after {timeout:.0f} s"
                break
            handle.write(result.stdout)
            lines += result.stdout.splitlines()
            if result.returncode != 0:
                status = f"failed (exit {result.returncode})"
                break
    record.update(
        status=status,
        wall_s=round(time.perf_counter() - start, 1),
        load_after=loadavg(),
        tail=[line for line in lines if line.strip()][-TAIL_LINES:],
        log=str(log),
    )
    return record


def write_summary(records: list[dict], out: Path) -> Path:
    (out / "summary.json").write_text(json.dumps(records, indent=2))
    lines = [
        "# make bench: quick modes",
        "",
        "CPU smoke figures (shared machine; see BENCHMARKS.md for the recorded full runs).",
        "",
        "| benchmark | status | wall | load avg before -> after |",
        "|---|---|---|---|",
    ]
    for r in records:
        load = f"{r.get('load_before')} -> {r.get('load_after')}" if r.get("load_before") is not None else ""
        wall = f"{r['wall_s']} s" if "wall_s" in r else ""
        lines.append(f"| {r['name']} | {r['status']} | {wall} | {load} |")
    for r in records:
        lines += ["", f"## {r['name']}: {r['status']}", ""]
        for command in r.get("commands", []):
            lines.append(f"    $ {command}")
        if r.get("tail"):
            lines += ["", "```", *r["tail"], "```"]
    path = out / "summary.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/bench"), help="summary and logs")
    parser.add_argument("--work", type=Path, help="scratch folder (default: OUT/work)")
    parser.add_argument("--only", nargs="+", help="run only these benchmarks (names without .py)")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per benchmark")
    args = parser.parse_args(argv)
    out = args.out.resolve()
    work = (args.work or out / "work").resolve()
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    found = {p.stem: p for p in sorted(HERE.glob("bench_*.py"))}
    names = [n for n in ORDER if n in found] + [n for n in found if n not in ORDER]
    if args.only:
        unknown = sorted(set(args.only) - set(found))
        if unknown:
            raise SystemExit(f"--only: no benchmark named {', '.join(unknown)} in {HERE}; have {', '.join(found)}")
        names = [n for n in names if n in args.only]
    records = []
    for name in names:
        commands, skipped = commands_for(name, found[name], work, out)
        if skipped:
            records.append({"name": name, "status": f"skipped: {skipped}"})
            print(f"[run_all] {name}: skipped ({skipped})", flush=True)
            continue
        print(f"[run_all] {name}: {' ; '.join(' '.join(c[1:]) for c in commands)}", flush=True)
        record = run_one(name, commands, out / f"{name}.log", args.timeout)
        records.append(record)
        print(f"[run_all] {name}: {record['status']} in {record['wall_s']} s", flush=True)
    path = write_summary(records, out)
    print(f"[run_all] summary: {path}")
    failed = [r["name"] for r in records if not (r["status"] == "ok" or r["status"].startswith("skipped"))]
    if failed:
        print(f"[run_all] failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
