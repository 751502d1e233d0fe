"""The study protocol's runs per core-hour on the CPU with the hash grids on the PyTorch path (the
reference engine) and on the fused C loop (`nerfaug.nerf.hash_cpu`, engine version hash-cpu-1),
side by side in one sitting.

Each run is one run of the study protocol (`STUDY_PRESETS["study"]`: 100 px, 6 initial views, 6
added at step 200 by `--method`, 2000 steps, 50 test views, LPIPS) with `--engine`, alone in this
process on one thread. The arms alternate run by run (reference seed 0, fused seed 0, reference
seed 1, ...), so both meet the same load; run k of both arms shares its seed, its views and (with
"uniform") its added views.

    python benchmarks/bench_hash_cpu.py --data data/lego100 --runs 2 --out /tmp/hash-bench \\
        --json docs/benchmarks/hash-cpu.json

Printed and written: per arm the runs' CPU seconds, wall seconds, training and evaluation seconds
and seconds a training step, runs per core-hour (by CPU time: one run occupies one core) and the
ratio; each run's PSNR and engine version.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

import torch

from machine_figures import at_end, at_start
from nerfaug.experiment.config import STUDY_PRESETS
from nerfaug.experiment.sweep import run_sweep
from nerfaug.nerf.encoding import HashEncoding

ARMS = {"reference": "torch", "fused": "auto"}
"""Each arm's hash-encoding kernel (`HashEncoding.default_kernel`, as NERFAUG_HASH_KERNEL sets it)."""


def _cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def one_run(config, kernel: str, root: Path) -> dict:
    """One run of `config` in this process with the hash kernel `kernel`: its record, CPU and wall s."""
    HashEncoding.default_kernel = kernel
    os.environ["NERFAUG_HASH_KERNEL"] = kernel  # for any process the run starts
    cpu, start = _cpu_seconds(), time.perf_counter()
    outcome = run_sweep(config, root, workers=1, progress=False, command=sys.argv)
    wall, cpu = time.perf_counter() - start, _cpu_seconds() - cpu
    if outcome.failed or len(outcome.results) != 1:
        raise RuntimeError(f"the run under {root} failed: {outcome.failed}")
    result = outcome.results[0]
    timing = result["timing"]
    return {
        "seed": result["seed"],
        "engine_version": result.get("engine_version"),
        "psnr": result["metrics"]["psnr"],
        "cpu_s": cpu,
        "wall_s": wall,
        "training_s": timing["train_before"] + timing["train_after"],
        "evaluation_s": timing["evaluation"],
    }


def step_seconds(data: Path, engine: str, kernel: str, steps: int = 100, after: int = 300) -> float:
    """CPU seconds a training step (one thread) of `engine` on all of `data`'s training views with
    the hash kernel `kernel`: steps `after` .. `after + steps`, past the proposal networks' warm-up."""
    from nerfaug.data import load_dataset
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    HashEncoding.default_kernel = kernel
    trainer = Trainer(load_dataset(data, "train"), NerfConfig.preset(engine), seed=0, progress=False)
    trainer.train(after)
    start = time.process_time()
    trainer.train(after + steps)
    return (time.process_time() - start) / steps


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="a prepared dataset folder (Blender format)")
    parser.add_argument("--runs", type=int, default=2, help="runs per arm (seeds 0 .. runs - 1)")
    parser.add_argument("--engine", default="nerfacto-cpu")
    parser.add_argument("--method", default="uniform")
    parser.add_argument("--steps", type=int, default=None, help="override the protocol's 2000 steps (smoke runs)")
    parser.add_argument("--step-repeats", type=int, default=2, help="timings of 100 training steps per arm")
    parser.add_argument("--out", type=Path, required=True, help="a folder for every run")
    parser.add_argument("--json", type=Path, help="where to write the figures")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    base = STUDY_PRESETS.choose("study", scenes=(str(args.data),), methods=(args.method,), trials=1, engine=args.engine)
    if args.steps is not None:
        base = base.replace(steps=args.steps)
    start = at_start()
    runs: dict[str, list[dict]] = {arm: [] for arm in ARMS}
    for seed in range(args.runs):
        for arm, kernel in ARMS.items():
            run = one_run(base.replace(seed=seed), kernel, args.out / f"{arm}-{seed}")
            runs[arm].append(run)
            print(
                f"{arm} seed {seed}: {run['cpu_s']:.1f} CPU s ({run['training_s']:.1f} training, "
                f"{run['evaluation_s']:.1f} evaluation, wall), PSNR {run['psnr']:.3f}, "
                f"engine version {run['engine_version'] or 'reference'}",
                flush=True,
            )
    steps: dict[str, list[float]] = {arm: [] for arm in ARMS}
    for _ in range(args.step_repeats):  # alternating too: reference, fused, reference, ...
        for arm, kernel in ARMS.items():
            steps[arm].append(1000.0 * step_seconds(args.data, args.engine, kernel))
    arms = {}
    for arm, records in runs.items():
        cpu = sum(r["cpu_s"] for r in records)
        arms[arm] = {
            "kernel": ARMS[arm],
            "runs": len(records),
            "cpu_s": cpu,
            "wall_s": sum(r["wall_s"] for r in records),
            "runs_per_core_hour": len(records) / (cpu / 3600.0),
            "step_ms": steps[arm],
            "training_s": sum(r["training_s"] for r in records) / len(records),
            "evaluation_s": sum(r["evaluation_s"] for r in records) / len(records),
            "records": records,
        }
    ratio = arms["fused"]["runs_per_core_hour"] / arms["reference"]["runs_per_core_hour"]
    figures = {**at_end(start, vars(args)), "arms": arms, "runs_per_core_hour_ratio": ratio}
    for arm, a in arms.items():
        print(
            f"{arm}: {a['runs']} runs, {a['cpu_s']:.0f} CPU s, {a['runs_per_core_hour']:.1f} runs per core-hour, "
            f"{min(a['step_ms']):.1f} ms a step (CPU), "
            f"{a['training_s']:.1f} s training, {a['evaluation_s']:.1f} s evaluation"
        )
    print(f"fused / reference: {ratio:.2f}x runs per core-hour")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
