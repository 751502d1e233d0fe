"""The study protocol's runs per core-hour on the CPU for each CPU engine version, side by side in
one sitting: the reference engine (the hash grids on the PyTorch path), `hash-cpu-1` (the hash grids
in one C loop, `nerfaug.nerf.hash_cpu`) and `cpu-fused-3` (also the proposal sampler's C loops,
`nerfaug.nerf.sampler_cpu`, and the MLPs', `nerfaug.nerf.mlp_cpu`); `--arms` chooses which.

Each run is one run of the study protocol (`STUDY_PRESETS["study"]`: 100 px, 6 initial views, 6
added at step 200 by `--method`, 2000 steps, 50 test views, LPIPS) with `--engine`, alone in this
process on one thread. The arms alternate run by run (reference seed 0, hash-cpu-1 seed 0, ...,
reference seed 1, ...), so all meet the same load; run k of every arm shares its seed, its views and
(with "uniform") its added views.

    python benchmarks/bench_hash_cpu.py --data data/lego100 --runs 2 --out /tmp/hash-bench \\
        --json docs/benchmarks/hash-cpu.json

Printed and written: per arm the runs' CPU seconds, wall seconds, training and evaluation seconds
and seconds a training step, runs per core-hour (by CPU time: one run occupies one core) and its
ratio to the reference's; each run's PSNR and engine version.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import torch

from cpu_engines import ARMS, choice_kept, select
from machine_figures import at_end, at_start
from nerfaug.experiment.config import STUDY_PRESETS
from nerfaug.experiment.sweep import run_sweep


def _cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def one_run(config, arm: str, root: Path) -> dict:
    """One run of `config` in this process on engine `arm`: its record, CPU and wall s."""
    select(arm)
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


def warm_up() -> None:
    """What a process pays once, not each run: importing torchmetrics (SSIM), loading LPIPS and
    the first optimiser (`torch.optim` imports torch._dynamo then, about 2.6 s); done before the
    first arm so that no arm's CPU seconds hold it."""
    from nerfaug.evaluation import ssim
    from nerfaug.experiment.protocol import cached_lpips

    image = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    ssim(image, image)
    cached_lpips()
    torch.optim.Adam([torch.zeros(1, requires_grad=True)])


def step_seconds(data: Path, engine: str, arm: str, steps: int = 100, after: int = 300) -> float:
    """CPU seconds a training step (one thread) of `engine` on all of `data`'s training views on
    engine `arm`: steps `after` .. `after + steps`, past the proposal networks' warm-up."""
    from nerfaug.data import load_dataset
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    select(arm)
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
    parser.add_argument("--resolution", type=int, default=None, help="override the protocol's 100 px (toy data)")
    parser.add_argument("--step-repeats", type=int, default=2, help="timings of 100 training steps per arm")
    parser.add_argument("--out", type=Path, required=True, help="a folder for every run")
    parser.add_argument("--arms", nargs="+", choices=list(ARMS), default=list(ARMS), help="the engines compared")
    parser.add_argument("--json", type=Path, help="where to write the figures")
    args = parser.parse_args(argv)
    if "reference" not in args.arms:
        parser.error("--arms must include reference: every ratio is to the reference's runs per core-hour")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with choice_kept():  # the process's own engine and environment back (a test calls main)
            return _run(args)
    finally:
        torch.set_num_threads(threads)


def _run(args) -> int:
    base = STUDY_PRESETS.choose("study", scenes=(str(args.data),), methods=(args.method,), trials=1, engine=args.engine)
    if args.steps is not None:
        base = base.replace(steps=args.steps)
    if args.resolution is not None:
        base = base.replace(resolution=args.resolution)
    start = at_start()
    warm_up()
    runs: dict[str, list[dict]] = {arm: [] for arm in args.arms}
    for seed in range(args.runs):
        for arm in args.arms:
            run = one_run(base.replace(seed=seed), arm, args.out / f"{arm}-{seed}")
            runs[arm].append(run)
            print(
                f"{arm} seed {seed}: {run['cpu_s']:.1f} CPU s ({run['training_s']:.1f} training, "
                f"{run['evaluation_s']:.1f} evaluation, wall), PSNR {run['psnr']:.3f}, "
                f"engine version {run['engine_version'] or 'reference'}",
                flush=True,
            )
    steps: dict[str, list[float]] = {arm: [] for arm in args.arms}
    for _ in range(args.step_repeats):  # alternating too
        for arm in args.arms:
            steps[arm].append(1000.0 * step_seconds(args.data, args.engine, arm))
    arms = {}
    for arm, records in runs.items():
        cpu = sum(r["cpu_s"] for r in records)
        arms[arm] = {
            "hash_kernel": ARMS[arm][0],
            "cpu_kernels": ARMS[arm][1],
            "runs": len(records),
            "cpu_s": cpu,
            "wall_s": sum(r["wall_s"] for r in records),
            "runs_per_core_hour": len(records) / (cpu / 3600.0),
            "step_ms": steps[arm],
            "training_s": sum(r["training_s"] for r in records) / len(records),
            "evaluation_s": sum(r["evaluation_s"] for r in records) / len(records),
            "records": records,
        }
    for a in arms.values():
        a["runs_per_core_hour_ratio"] = a["runs_per_core_hour"] / arms["reference"]["runs_per_core_hour"]
    figures = {**at_end(start, vars(args)), "arms": arms}
    for arm, a in arms.items():
        print(
            f"{arm}: {a['runs']} runs, {a['cpu_s']:.0f} CPU s, {a['runs_per_core_hour']:.1f} runs per core-hour "
            f"({a['runs_per_core_hour_ratio']:.2f}x the reference), "
            + (f"{min(a['step_ms']):.1f} ms a step (CPU), " if a["step_ms"] else "")
            + f"{a['training_s']:.1f} s training, {a['evaluation_s']:.1f} s evaluation"
        )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
