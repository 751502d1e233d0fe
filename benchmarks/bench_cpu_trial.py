"""One study run of the `nerfacto-cpu` engine on the CPU, today's engine against an earlier commit's,
timed in one sitting with every loss compared.

A run is the study's own (`experiment.protocol.run_trial`: 100 px, 6 initial views, 6 more chosen
at step 200, 2000 steps, 50 test views, LPIPS when its weights are present), one torch thread. Each
pair of runs (the earlier engine and today's, same scene, method and trial) runs side by side, one
run per core (pinned with `taskset` where it exists), the cores swapped from pair to pair. The
earlier engine is the `src` folder of `--baseline` (a git revision), exported to a temporary folder.

    python benchmarks/bench_cpu_trial.py --data data/lego100 --methods uniform ours --out bench.json

Printed and written: per run, wall and CPU seconds by phase, the step's losses' largest difference
from the baseline's (0 when the engines compute the same numbers) and the test metrics.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RUN = """
import json, resource, sys, tempfile, time
from pathlib import Path
import torch
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.protocol import cached_lpips, run_trial
from nerfaug.experiment.store import RunKey
data, method, trial = sys.argv[1], sys.argv[2], int(sys.argv[3])
config = ExperimentConfig(scenes=(data,), methods=(method,), engine="nerfacto-cpu", view_uncertainty=False)
cached_lpips()
with tempfile.TemporaryDirectory() as root:
    start, cpu = time.perf_counter(), time.process_time()
    result = run_trial(RunKey(Path(data).name, method, trial), Path(data), config, Path(root))
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    folder = RunKey(Path(data).name, method, trial).folder(Path(root))
    history = json.loads((folder / "history.json").read_text())
json.dump({"wall": wall, "cpu": cpu, "timing": result["timing"], "metrics": result["metrics"],
           "chosen": result["chosen"], "lpips_status": result["lpips_status"],
           "losses": [entry["loss"] for entry in history]}, sys.stdout)
"""


def export_source(revision: str, into: Path) -> Path:
    """The `src` folder of `revision`, written under `into`; returns it."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", revision, "src"], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    return into / "src"


def start_run(source: Path, core: int | None, args, method: str) -> subprocess.Popen:
    """A run of `method` (trial `args.trial`) with the engine in `source`, pinned to `core`."""
    env = {**os.environ, "PYTHONPATH": str(source), "OMP_NUM_THREADS": "1"}
    command = [sys.executable, "-c", RUN, str(Path(args.data).resolve()), method, str(args.trial)]
    if core is not None:
        command = ["taskset", "-c", str(core), *command]
    return subprocess.Popen(command, env=env, stdout=subprocess.PIPE, text=True)


def largest_difference(a: list[float], b: list[float]) -> float:
    """Largest absolute difference between two equally long loss lists (inf if lengths differ)."""
    if len(a) != len(b):
        return float("inf")
    return max((abs(x - y) for x, y in zip(a, b)), default=0.0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", required=True, help="Blender-format dataset folder (100 px or larger)")
    parser.add_argument("--methods", nargs="+", default=["uniform", "ours"])
    parser.add_argument("--trial", type=int, default=0)
    parser.add_argument("--baseline", default="e2511ee", help="git revision of the earlier engine")
    parser.add_argument("--out", type=Path, help="write the results here as JSON")
    args = parser.parse_args(argv)
    cores = [0, 1] if shutil.which("taskset") and (os.cpu_count() or 1) >= 2 else [None, None]
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        sources = {"baseline": export_source(args.baseline, Path(tmp)), "today": ROOT / "src"}
        for pair, method in enumerate(args.methods):
            order = ["baseline", "today"] if pair % 2 == 0 else ["today", "baseline"]
            started = time.strftime("%Y-%m-%d %H:%M")
            load = os.getloadavg()[0]
            procs = {name: start_run(sources[name], cores[i], args, method) for i, name in enumerate(order)}
            outputs = {name: json.loads(proc.communicate()[0]) for name, proc in procs.items()}
            difference = largest_difference(outputs["baseline"]["losses"], outputs["today"]["losses"])
            for i, name in enumerate(order):
                out = outputs[name]
                runs.append(
                    {
                        "engine": name,
                        "method": method,
                        "core": cores[i],
                        "started": started,
                        "load_at_start": load,
                        "largest_loss_difference": difference,
                        **{k: v for k, v in out.items() if k != "losses"},
                    }
                )
                phases = ", ".join(f"{k} {v:.1f}" for k, v in out["timing"].items())
                print(
                    f"{method:8s} {name:8s} core {cores[i]}: {out['wall']:.1f} s wall, {out['cpu']:.1f} s cpu "
                    f"({phases}); psnr {out['metrics']['psnr']:.4f}; losses differ by {difference:.3g}",
                    flush=True,
                )
    if args.out:
        args.out.write_text(json.dumps({"baseline": args.baseline, "runs": runs}, indent=1) + "\n")


if __name__ == "__main__":
    main()
