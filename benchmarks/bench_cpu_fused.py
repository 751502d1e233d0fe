"""CPU seconds of a `nerfacto-cpu` training step and of rendering test views on the three CPU
engine versions, side by side in one sitting: the reference (hash grids on the PyTorch path,
`NERFAUG_HASH_KERNEL=torch`), `hash-cpu-1` (the fused hash loop, today's default) and
`cpu-fused-3` (the hash loop, the proposal sampler's and the MLPs' C loops, `NERFAUG_CPU_KERNELS=fused`).

One trainer is trained on the reference engine to step `--after` (past the proposal networks'
warm-up) and checkpointed; each arm restores that checkpoint into its own trainer (its encodings
built with its kernel), so the arms start from the same model state. The arms then alternate in
short blocks (`--block-steps` training steps and one rendered test view each: reference,
hash-cpu-1, cpu-fused-3, reference, ...) `--blocks` times, so they meet the same load on a shared
machine. CPU seconds by `getrusage` of this process (one torch thread): other processes slow a
block only through shared caches and memory, which the alternation spreads over the arms.

    python benchmarks/bench_cpu_fused.py --data data/lego100 --json docs/benchmarks/cpu-fused.json

Printed and written: per arm and block the ms a training step and a rendered test view, and the
load average; per arm the medians, and their ratios to the reference and to hash-cpu-1.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import tempfile
from pathlib import Path

import torch

import cpu_engines
from cpu_engines import ARMS
from machine_figures import at_end, at_start
from nerfaug.data import load_dataset
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.trainer import Trainer


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    return own.ru_utime + own.ru_stime


def select(arm: str) -> str | None:
    """Make `arm` this process's engine; returns the engine version a study run would record."""
    from nerfaug.experiment.config import STUDY_PRESETS

    cpu_engines.select(arm)
    return STUDY_PRESETS.choose("study", engine="nerfacto-cpu").engine_version()


def block(trainer: Trainer, test, steps: int, view: int) -> tuple[float, float]:
    """ms of CPU a training step (`steps` more steps of `trainer`) and for rendering test view
    `view`, with the engine selected now."""
    start = _cpu_seconds()
    trainer.train(trainer.step + steps)
    step_ms = 1000.0 * (_cpu_seconds() - start) / steps
    start = _cpu_seconds()
    trainer.model.render_image(test.cameras, view % len(test.cameras))
    return step_ms, 1000.0 * (_cpu_seconds() - start)


def main(argv=None) -> dict:
    """Run the benchmark; returns the figures written to `--json`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="a prepared dataset folder (Blender format)")
    parser.add_argument("--engine", default="nerfacto-cpu")
    parser.add_argument("--after", type=int, default=300, help="steps trained before the timed ones")
    parser.add_argument("--blocks", type=int, default=15, help="alternations of the three arms")
    parser.add_argument("--block-steps", type=int, default=10, help="timed training steps an arm's block")
    parser.add_argument("--json", type=Path, help="where to write the figures")
    args = parser.parse_args(argv)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with cpu_engines.choice_kept():
            return _run(args)
    finally:
        torch.set_num_threads(threads)


def _run(args) -> dict:
    start = at_start()
    test = load_dataset(args.data, "test")
    versions = {arm: select(arm) for arm in ARMS}
    measurements: dict[str, list[dict]] = {arm: [] for arm in ARMS}
    with tempfile.TemporaryDirectory() as scratch:
        select("reference")
        trainer = Trainer(load_dataset(args.data, "train"), NerfConfig.preset(args.engine), seed=0, progress=False)
        trainer.train(args.after)
        checkpoint = trainer.save_checkpoint(Path(scratch) / "after.pt")
        trainers = {}
        for arm in ARMS:  # each arm's encodings built with its kernel, 2 untimed steps
            select(arm)
            trainers[arm] = Trainer.load_checkpoint(checkpoint, progress=False)
            trainers[arm].train(args.after + 2)
    for index in range(args.blocks):
        for arm in ARMS:
            select(arm)
            step_ms, view_ms = block(trainers[arm], test, args.block_steps, index)
            load = os.getloadavg()[0]
            measurements[arm].append({"step_ms": step_ms, "view_ms": view_ms, "load_average_1min": load})
        print(
            f"block {index}: "
            + ", ".join(f"{arm} {rows[-1]['step_ms']:.1f} ms a step" for arm, rows in measurements.items())
            + f", load {load:.1f}",
            flush=True,
        )
    arms = {}
    for arm, rows in measurements.items():
        arms[arm] = {
            "hash_kernel": ARMS[arm][0],
            "cpu_kernels": ARMS[arm][1],
            "engine_version": versions[arm],
            "measurements": rows,
            "step_ms_median": statistics.median(r["step_ms"] for r in rows),
            "step_ms_mean": statistics.fmean(r["step_ms"] for r in rows),
            "view_ms_median": statistics.median(r["view_ms"] for r in rows),
        }
    for arm, a in arms.items():
        a["step_speedup_over_reference"] = arms["reference"]["step_ms_median"] / a["step_ms_median"]
        a["step_speedup_over_hash_cpu_1"] = arms["hash-cpu-1"]["step_ms_median"] / a["step_ms_median"]
        a["view_speedup_over_reference"] = arms["reference"]["view_ms_median"] / a["view_ms_median"]
        print(
            f"{arm} ({a['engine_version'] or 'reference'}): {a['step_ms_median']:.1f} ms a step "
            f"({a['step_speedup_over_reference']:.2f}x the reference, {a['step_speedup_over_hash_cpu_1']:.2f}x "
            f"hash-cpu-1), {a['view_ms_median']:.0f} ms a view ({a['view_speedup_over_reference']:.2f}x)"
        )
    figures = {**at_end(start, vars(args)), "arms": arms}
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return figures


if __name__ == "__main__":
    main()
    sys.exit(0)
