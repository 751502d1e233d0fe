"""One CPU trial of the paper's protocol, timed phase by phase, with optional engine overrides.

A trial: 6 initial views, 6 more added at step 200 (chosen by `--method`), 2000 steps, 50 test
views, on a Blender-format dataset folder (render one with
`nerfaug scene render lego --out data/lego100 --res 100 --pool 300 --test 50`). Prints the time of
each phase (loading, training before and after the added views in chunks, selection,
evaluation, maps, writing), and, with `--holdout N`, the PSNR on N train-pool views that are
neither initial, nor chosen, nor test views (for judging engine settings without looking at
the test split).

    python benchmarks/bench_trial.py --data data/lego100
    python benchmarks/bench_trial.py --data data/lego100 --override occupancy_warmup_steps=32 --holdout 30
    python benchmarks/bench_trial.py --data data/lego400 --compare-load   # dataset cache vs none

Field points (what `model.field.density` was given) and this process's CPU seconds are reported
beside wall seconds: on a shared machine they compare settings where wall time cannot.
"""

from __future__ import annotations

import argparse
import ast
import cProfile
import json
import pstats
import sys
import tempfile
import time
from pathlib import Path

import torch


def parse_overrides(items: list[str]) -> dict:
    """`name=value` pairs (values as Python literals) -> dict."""
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        out[name] = ast.literal_eval(value)
    return out


def count_field_points(model) -> list[int]:
    """Make `model.field.density` count the points it is given; returns the (growing) counter.
    The count is a measure of a step's work that, unlike its time, other load cannot change."""
    counter = [0]
    density = model.field.density

    def counted(points):
        counter[0] += points.shape[0]
        return density(points)

    model.field.density = counted
    return counter


def chunk_times(trainer, until: int, chunk: int, counter: list[int]) -> list[tuple[int, float, float, int]]:
    """Train to `until` in chunks of `chunk` steps; returns (step reached, wall seconds, CPU
    seconds of this process, field points) per chunk."""
    times = []
    while trainer.step < until:
        target = min(until, trainer.step + chunk)
        start, cpu, points = time.perf_counter(), time.process_time(), counter[0]
        trainer.train(target)
        times.append((target, time.perf_counter() - start, time.process_time() - cpu, counter[0] - points))
        print(
            f"step {target}: {times[-1][1]:.2f} s wall, {times[-1][2]:.2f} s cpu, {times[-1][3]} points",
            file=sys.stderr,
            flush=True,
        )
    return times


def holdout_psnr(model, views) -> float:
    """Mean PSNR (dB) of the model's renders of `views`."""
    from nerfaug.evaluation import psnr

    values = []
    with torch.no_grad():
        for i in range(len(views)):
            rgb = model.render_image(views.cameras, i)["rgb"]
            values.append(float(psnr(rgb, views.images[i])))
    return sum(values) / len(values)


def compare_load(args) -> dict:
    """Seconds of `load_scene_data` without and with the dataset cache (warm), interleaved
    `--repeats` times in this one process, and their ratio (median over repeats)."""
    import statistics

    from nerfaug.experiment.config import ExperimentConfig
    from nerfaug.experiment.protocol import load_scene_data

    config = ExperimentConfig(n_test=args.n_test, resolution=args.resolution)
    with tempfile.TemporaryDirectory() as cache:
        load_scene_data(Path(args.data), config, cache_dir=Path(cache))  # fill the cache
        times = {"uncached": [], "cached": []}
        for _ in range(args.repeats):
            for name, cache_dir in (("uncached", None), ("cached", Path(cache))):
                start = time.perf_counter()
                load_scene_data(Path(args.data), config, cache_dir=cache_dir)
                times[name].append(time.perf_counter() - start)
    median = {name: statistics.median(values) for name, values in times.items()}
    return {
        "load_seconds": times,
        "median": median,
        "ratio_uncached_over_cached": median["uncached"] / median["cached"],
    }


def trial(args) -> dict:
    from nerfaug.device import configure_process
    from nerfaug.evaluation import evaluate_views
    from nerfaug.experiment.config import ExperimentConfig
    from nerfaug.experiment.protocol import cached_lpips, load_scene_data
    from nerfaug.maps import plot_hemisphere_map
    from nerfaug.nerf.trainer import Trainer
    from nerfaug.selection import select_views

    configure_process(threads=args.threads)
    config = ExperimentConfig(steps=args.steps, n_test=args.n_test, resolution=args.resolution, device="cpu")
    timing: dict[str, float] = {}
    start = time.perf_counter()
    data = load_scene_data(Path(args.data), config)
    timing["load"] = time.perf_counter() - start
    cache = tempfile.TemporaryDirectory()
    if args.before_after:
        # Today's protocol reads the dataset through the cache; the same trial before it decoded
        # every image. Every other phase is the same computation (the images are bit-identical).
        load_scene_data(Path(args.data), config, cache_dir=Path(cache.name))  # a sweep's first run
        start = time.perf_counter()
        cached = load_scene_data(Path(args.data), config, cache_dir=Path(cache.name))
        timing["load_cached"] = time.perf_counter() - start
        assert torch.equal(cached.pool.images, data.pool.images) and torch.equal(cached.test.images, data.test.images)
    cache.cleanup()
    engine = config.engine_config("lego").__class__.preset(config.engine, **parse_overrides(args.override))
    start = time.perf_counter()
    trainer = Trainer(data.initial, engine, seed=args.seed, device="cpu", progress=False)
    timing["setup"] = time.perf_counter() - start
    counter = count_field_points(trainer.model)
    before = chunk_times(trainer, config.add_at_step, args.chunk, counter)
    timing["train_before"] = sum(c[1] for c in before)
    start = time.perf_counter()
    generator = torch.Generator().manual_seed(args.seed)
    selection = select_views(
        args.method,
        trainer.model,
        trainer.train_views.cameras,
        data.pool.cameras,
        config.n_new,
        generator,
        config.selection,
    )
    timing["selection"] = time.perf_counter() - start
    chosen = [int(i) for i in selection.indices]
    trainer.add_views(data.pool.subset(chosen))
    after = chunk_times(trainer, config.steps, args.chunk * 4, counter)
    timing["train_after"] = sum(c[1] for c in after)
    lpips = cached_lpips() if args.lpips else None
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        evaluation = evaluate_views(
            lambda cameras, i: trainer.model.render_image(cameras, i)["rgb"],
            data.test,
            lpips=lpips,
            save_dir=Path(tmp) / "renders",
            save_count=3,
            progress=False,
        )
        timing["evaluation"] = time.perf_counter() - start
        start = time.perf_counter()
        plot_hemisphere_map(
            data.pool.cameras.camera_to_world,
            selection.scores,
            data.initial.cameras.camera_to_world,
            data.pool.cameras.camera_to_world[chosen],
            path=Path(tmp) / "map.png",
            title="lego",
        )
        timing["map"] = time.perf_counter() - start
    rest = sum(v for k, v in timing.items() if k not in ("load", "load_cached"))
    timing["total"] = timing["load"] + rest
    if args.before_after:
        timing["total_cached"] = timing["load_cached"] + rest
    result = {
        "timing": timing,
        "metrics": evaluation.mean,
        "chosen": chosen,
        "overrides": args.override,
        "before_chunks": before,
        "after_chunks": after,
        "cpu": {"train_before": sum(c[2] for c in before), "train_after": sum(c[2] for c in after)},
        "field_points": {"train_before": sum(c[3] for c in before), "train_after": sum(c[3] for c in after)},
    }
    if args.holdout:
        # Pool views that are neither chosen nor initial: quality checks that never see the test split.
        rest = [i for i in range(len(data.pool)) if i not in set(chosen)]
        step = max(1, len(rest) // args.holdout)
        held = data.pool.subset(rest[::step][: args.holdout])
        start = time.perf_counter()
        result["holdout_psnr"] = holdout_psnr(trainer.model, held)
        timing["holdout"] = time.perf_counter() - start
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", required=True, help="Blender-format dataset folder")
    parser.add_argument("--method", default="uniform")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--n-test", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--chunk", type=int, default=50, help="steps per timed chunk before the added views")
    parser.add_argument("--override", action="append", default=[], help="NerfConfig field=value over the cpu preset")
    parser.add_argument("--holdout", type=int, default=0, help="held-out pool views to report PSNR on")
    parser.add_argument("--no-lpips", dest="lpips", action="store_false")
    parser.add_argument("--profile", type=Path, help="write cProfile stats here and print the top 25")
    parser.add_argument(
        "--before-after",
        action="store_true",
        help="also time a warm cached load: the trial's total without and with the dataset cache",
    )
    parser.add_argument(
        "--compare-load",
        action="store_true",
        help="only time loading the dataset without and with the cache, interleaved",
    )
    parser.add_argument("--resolution", type=int, default=100, help="image width the dataset is downscaled to")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    if args.compare_load:
        json.dump(compare_load(args), sys.stdout, indent=1)
        print()
        return
    if args.profile:
        profiler = cProfile.Profile()
        result = profiler.runcall(trial, args)
        profiler.dump_stats(args.profile)
        pstats.Stats(str(args.profile)).sort_stats("cumulative").print_stats(25)
    else:
        result = trial(args)
    json.dump(result, sys.stdout, indent=1)
    print()


if __name__ == "__main__":
    main()
