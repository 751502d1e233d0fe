"""Experiment benchmark: wall time of a sweep, per-trial time split, and Ray's overhead vs local.

    python benchmarks/bench_experiment.py --preset quick --out /tmp/bench_exp
    python benchmarks/bench_experiment.py --preset tiny --ray   # Ray vs local on the same grid

Prints a table and writes <out>/bench_experiment.json. The Ray comparison runs the same grid with
both backends in this one process, one after the other, and reports the ratio.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import time
from pathlib import Path

from nerfaug.experiment.config import PROTOCOL_PRESETS
from nerfaug.experiment.sweep import run_sweep

PHASES = ("setup", "train_before", "selection", "oracle", "train_after", "evaluation", "total")


def timed_sweep(config, out: Path, backend: str) -> tuple[float, list[dict]]:
    shutil.rmtree(out, ignore_errors=True)
    start = time.perf_counter()
    outcome = run_sweep(config, out, backend=backend, progress=False)
    if outcome.failed:
        raise SystemExit(f"runs failed: {outcome.failed}")
    return time.perf_counter() - start, outcome.results


def phase_medians(results: list[dict]) -> dict[str, float]:
    return {p: statistics.median(r["timing"][p] for r in results) for p in PHASES}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--out", type=Path, default=Path("/tmp/nerfaug_bench_experiment"))
    parser.add_argument("--ray", action="store_true", help="also run the grid on a local Ray instance")
    args = parser.parse_args()
    config = PROTOCOL_PRESETS.choose(args.preset)

    # Render the scene once so neither backend's time includes Blender.
    scene_cache = args.out / "scene_cache"
    from nerfaug.experiment.protocol import prepare_scene

    start = time.perf_counter()
    dataset = {s: prepare_scene(scene_cache, s, config) for s in config.scenes}
    render_seconds = time.perf_counter() - start
    config = config.replace(scenes=tuple(str(p) for p in dataset.values()))

    local_seconds, results = timed_sweep(config, args.out / "local", "local")
    report = {
        "preset": args.preset,
        "runs": len(results),
        "scene_render_seconds": render_seconds,
        "local_sweep_seconds": local_seconds,
        "per_trial_median_seconds": phase_medians(results),
    }
    if args.ray:
        ray_seconds, ray_results = timed_sweep(config, args.out / "ray", "ray")
        same = sorted((r["method"], r["trial"], r["metrics"]["psnr"]) for r in results) == sorted(
            (r["method"], r["trial"], r["metrics"]["psnr"]) for r in ray_results
        )
        report.update(
            ray_sweep_seconds=ray_seconds, ray_over_local=ray_seconds / local_seconds, ray_identical_metrics=same
        )
    print(json.dumps(report, indent=2))
    (args.out / "bench_experiment.json").write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
