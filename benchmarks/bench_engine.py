"""Benchmark the NeRF engine: speed, learning curve and memory of one CPU trial, the ceiling
with every pool view, and encodings / presets compared as time ratios within one run.

Variants are built through the engine's registries (`nerfaug.nerf.registry`): every registered
encoding at each preset's sizes, and fields passed to the trainer (the naive hash grid below).

A trial: 12 training views (the 6 of `transforms_initial.json` plus 6 spread over the
`transforms_train.json` pool by farthest-point sampling), trained with a preset and evaluated
(mean PSNR over the test views) at each checkpoint iteration.

    python benchmarks/bench_engine.py DATA [--resolution 100] [--iterations 500,1000,2000,5000]
    python benchmarks/bench_engine.py --synthetic /tmp/spheres   # writes an analytic dataset first

Timings on a shared machine are noisy: compare the ratios, which are measured interleaved.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import time
from pathlib import Path

import torch
from torch import Tensor, nn

from nerfaug.cameras import Cameras, image_rays
from nerfaug.data import Views, load_dataset, write_blender_split
from nerfaug.device import configure_process
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.encoding import hash_grid_indices, hash_resolutions
from nerfaug.nerf.registry import ENCODINGS, build_field
from nerfaug.nerf.trainer import Trainer, psnr_from_mse

SPHERES = (  # centre, radius, colour of the analytic scene
    ((0.0, 0.0, 0.0), 0.8, (0.9, 0.2, 0.2)),
    ((0.7, 0.6, 0.3), 0.4, (0.2, 0.7, 0.3)),
    ((-0.6, 0.5, -0.2), 0.45, (0.2, 0.3, 0.9)),
    ((0.2, -0.8, 0.5), 0.35, (0.9, 0.8, 0.1)),
)


def sphere_views(azimuth: Tensor, polar: Tensor, resolution: int) -> Views:
    """Striped, lit spheres over white, ray-cast exactly (no Blender needed), with alpha."""
    cameras = Cameras.from_fov(pose_from_angles(azimuth, polar), BLENDER_CAMERA_ANGLE_X, resolution, resolution)
    light = torch.tensor([0.3, 0.4, 0.866])
    images, alphas = [], []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        nearest = torch.full((origins.shape[0],), math.inf)
        colour, alpha = torch.ones(origins.shape[0], 3), torch.zeros(origins.shape[0])
        for centre, radius, rgb in SPHERES:
            offset = origins - torch.tensor(centre)
            b = (offset * directions).sum(-1)
            disc = b * b - (offset.square().sum(-1) - radius**2)
            t = -b - disc.clamp_min(0).sqrt()
            hit = (disc > 0) & (t > 0) & (t < nearest)
            normal = (offset + t[:, None] * directions) / radius
            shade = 0.35 + 0.65 * (normal @ light).clamp_min(0)
            stripes = 0.75 + 0.25 * torch.sign(torch.sin(6 * math.pi * normal[:, 2]))
            nearest = torch.where(hit, t, nearest)
            colour = torch.where(hit[:, None], torch.tensor(rgb) * (shade * stripes)[:, None], colour)
            alpha = torch.where(hit, 1.0, alpha)
        images.append(colour.reshape(resolution, resolution, 3))
        alphas.append(alpha.reshape(resolution, resolution))
    return Views(cameras, torch.stack(images), [f"r_{i}" for i in range(len(cameras))], torch.stack(alphas))


def write_synthetic_dataset(root: Path, resolution: int, pool: int = 100, test: int = 50, seed: int = 0) -> Path:
    """An analytic Blender-format dataset: 6 initial views on one half of the hemisphere, a
    uniform pool, and uniform test views."""
    generator = torch.Generator().manual_seed(seed)

    def uniform(n: int, azimuth_span: float = 2 * math.pi) -> tuple[Tensor, Tensor]:
        u = torch.rand(n, 2, generator=generator)
        return u[:, 0] * azimuth_span, torch.arccos(0.05 + 0.9 * u[:, 1])

    write_blender_split(root, "initial", sphere_views(*uniform(6, math.pi), resolution))
    write_blender_split(root, "train", sphere_views(*uniform(pool), resolution))
    write_blender_split(root, "test", sphere_views(*uniform(test), resolution))
    return root


def farthest_views(chosen: Tensor, pool: Tensor, n: int) -> list[int]:
    """Greedy farthest-point picks: indices of `n` pool positions (m, 3) far from `chosen` (k, 3)."""
    picks: list[int] = []
    distance = torch.cdist(pool, chosen).min(dim=1).values
    for _ in range(n):
        index = int(distance.argmax())
        picks.append(index)
        distance = torch.minimum(distance, (pool - pool[index]).norm(dim=-1))
    return picks


def load_split(root: Path, split: str, resolution: int) -> Views:
    width = load_dataset(root, split, lazy=True).cameras.width
    if width % resolution:
        raise SystemExit(f"{root}: images are {width} wide, not a multiple of --resolution {resolution}")
    return load_dataset(root, split, downscale=width // resolution)


def mean_psnr(trainer: Trainer, views: Views) -> float:
    """Mean over views of each view's PSNR (as the paper reports it)."""
    values = []
    for i in range(len(views)):
        rendered = trainer.model.render_image(views.cameras, i)["rgb"].cpu()
        values.append(psnr_from_mse(float((rendered - views.images[i]).square().mean())))
    return statistics.fmean(values)


def run_trial(train_views: Views, test_views: Views, config: NerfConfig, checkpoints: list[int], seed: int) -> dict:
    """Train to each checkpoint; record training seconds, PSNR and rendering seconds."""
    trainer = Trainer(train_views, config, seed=seed, progress=False)
    curve, train_seconds = [], 0.0
    for step in checkpoints:
        start = time.perf_counter()
        trainer.train(step)
        train_seconds += time.perf_counter() - start
        start = time.perf_counter()
        psnr = mean_psnr(trainer, test_views)
        render_seconds = time.perf_counter() - start
        curve.append({"step": step, "train_seconds": train_seconds, "psnr": psnr, "render_seconds": render_seconds})
        print(
            f"  step {step:5d}  train {train_seconds:6.1f} s  test PSNR {psnr:5.2f} dB  render {render_seconds:5.1f} s",
            flush=True,
        )
    best = max(point["psnr"] for point in curve)
    plateau = next(point for point in curve if point["psnr"] >= best - 0.5)
    return {
        "views": len(train_views),
        "curve": curve,
        "seconds_per_iteration": train_seconds / checkpoints[-1],
        "plateau": {"step": plateau["step"], "train_seconds": plateau["train_seconds"], "psnr": plateau["psnr"]},
        "max_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


class NaiveHashEncoding(nn.Module):
    """The textbook hash grid: one table and one Python iteration per level, 8 gathers each.
    Only here, as the baseline the vectorised `HashEncoding` is measured against."""

    def __init__(
        self,
        num_levels=16,
        features_per_level=2,
        log2_table_size=19,
        base_resolution=16,
        max_resolution=2048,
        init_scale=1e-4,
    ):
        super().__init__()
        self.table_size = 2**log2_table_size
        self.resolutions = hash_resolutions(num_levels, base_resolution, max_resolution)
        self.tables = nn.ParameterList(
            [
                nn.Parameter(torch.empty(self.table_size, features_per_level).uniform_(-init_scale, init_scale))
                for _ in self.resolutions
            ]
        )
        self.output_dim = num_levels * features_per_level

    def forward(self, x: Tensor) -> Tensor:
        out = []
        for resolution, table in zip(self.resolutions, self.tables):
            scaled = x * resolution
            base = scaled.floor().long()
            frac = scaled - base
            feature = 0
            for corner in range(8):
                offset = torch.tensor([(corner >> k) & 1 for k in range(3)])
                vertex = (base + offset).clamp(max=resolution)
                weight = torch.where(offset.bool(), frac, 1 - frac).prod(-1, keepdim=True)
                feature = feature + weight * table[hash_grid_indices(vertex, torch.tensor(resolution), self.table_size)]
            out.append(feature)
        return torch.cat(out, dim=-1)


def naive_hash_encoding(config: NerfConfig) -> NaiveHashEncoding:
    return NaiveHashEncoding(
        config.field.hash.levels,
        config.field.hash.features_per_level,
        config.field.hash.log2_table_size,
        config.field.hash.base_resolution,
        config.field.hash.max_resolution,
    )


def time_encodings(points: int = 32768, repeats: int = 5) -> dict:
    """Seconds per forward+backward of `points` points, interleaved over every registered
    encoding at the sizes of each preset that uses it, and the naive hash grid."""
    encodings = {}
    for preset in ("cpu", "nerfacto-cpu", "paper"):
        config = NerfConfig.preset(preset)
        encodings[f"{config.field.encoding} ({preset} preset)"] = ENCODINGS[config.field.encoding](config)
    encodings["hash, naive per-level loop (paper preset)"] = naive_hash_encoding(NerfConfig.preset("paper"))
    x = torch.rand(points, 3, generator=torch.Generator().manual_seed(0))
    times: dict[str, list[float]] = {name: [] for name in encodings}
    for round_ in range(repeats + 1):
        for name, encoding in encodings.items():
            start = time.perf_counter()
            encoding(x).square().sum().backward()
            if round_:  # the first round warms up allocators and kernels
                times[name].append(time.perf_counter() - start)
            encoding.zero_grad(set_to_none=True)
    return {name: statistics.median(values) for name, values in times.items()}


def time_steps(train_views: Views, steps: int = 3) -> dict:
    """Seconds per training step from step 0, interleaved over presets and over fields passed
    to the trainer. The cpu preset is still in its occupancy warm-up here (every sample
    evaluated): its steady state is faster, see the trial."""
    paper = NerfConfig.preset("paper")
    trainers = {
        "cpu preset": Trainer(train_views, NerfConfig.preset("cpu"), progress=False),
        "nerfacto-cpu preset": Trainer(train_views, NerfConfig.preset("nerfacto-cpu"), progress=False),
        "paper preset (hash + proposal, 4096 rays)": Trainer(train_views, paper, progress=False),
        "paper preset, kplanes encoding": Trainer(
            train_views, paper, progress=False, field=build_field(paper, encoding=ENCODINGS["kplanes"](paper))
        ),
        "paper preset with naive hash grid": Trainer(
            train_views, paper, progress=False, field=build_field(paper, encoding=naive_hash_encoding(paper))
        ),
    }
    times: dict[str, list[float]] = {name: [] for name in trainers}
    for round_ in range(steps + 1):
        for name, trainer in trainers.items():
            start = time.perf_counter()
            trainer.train_step()
            if round_:
                times[name].append(time.perf_counter() - start)
    return {name: statistics.median(values) for name, values in times.items()}


def print_table(title: str, rows: list[tuple], header: tuple) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    for column in header:
        table.add_column(column)
    for row in rows:
        table.add_row(*[f"{v:.4g}" if isinstance(v, float) else str(v) for v in row])
    Console().print(table)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data", nargs="?", type=Path, help="Blender-format dataset folder")
    parser.add_argument("--synthetic", type=Path, help="write an analytic dataset here and use it")
    parser.add_argument("--resolution", type=int, default=100)
    parser.add_argument("--iterations", default="500,1000,2000,5000", help="checkpoints, comma-separated")
    parser.add_argument("--test-views", type=int, default=50)
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-ceiling", action="store_true", help="skip the all-pool-views trial")
    parser.add_argument("--no-compare", action="store_true", help="skip the encoding/preset ratios")
    parser.add_argument("--compare-steps", type=int, default=2, help="timed steps per preset")
    parser.add_argument("--out", type=Path, default=Path("results/bench_engine.json"))
    args = parser.parse_args()
    configure_process(threads=args.threads)
    if args.synthetic:
        root = write_synthetic_dataset(args.synthetic, args.resolution, test=args.test_views)
    elif args.data:
        root = args.data
    else:
        parser.error("give a dataset folder or --synthetic DIR")

    initial = load_split(root, "initial", args.resolution)
    pool = load_split(root, "train", args.resolution)
    test = load_split(root, "test", args.resolution)
    test = test.subset(range(min(args.test_views, len(test))))
    extra = farthest_views(initial.cameras.positions, pool.cameras.positions, 12 - len(initial))
    train = Views.cat([initial, pool.subset(extra)])
    checkpoints = sorted(int(s) for s in args.iterations.split(","))
    config = NerfConfig.preset(args.preset)
    blank = statistics.fmean(psnr_from_mse(float((im - 1.0).square().mean())) for im in test.images)
    report = {
        "data": str(root),
        "resolution": args.resolution,
        "threads": args.threads,
        "preset": args.preset,
        "config": config.to_dict(),
        "test_views": len(test),
        "blank_white_psnr": blank,
    }
    print(f"{root}: {len(train)} training views, {len(test)} test views, white image PSNR {blank:.2f} dB")

    print(f"trial: {len(train)} views, preset {args.preset}")
    report["trial"] = run_trial(train, test, config, checkpoints, args.seed)
    if not args.no_ceiling:
        print(f"ceiling: all {len(pool)} pool views")
        report["ceiling"] = run_trial(pool, test, config, checkpoints, args.seed)
    if not args.no_compare:
        report["encoding_seconds_per_32k_points"] = time_encodings()
        report["seconds_per_step_from_step_0"] = time_steps(train, args.compare_steps)

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    for name in ("trial", "ceiling"):
        if name in report:
            r = report[name]
            rows = [(p["step"], p["train_seconds"], p["psnr"], p["render_seconds"]) for p in r["curve"]]
            print_table(
                f"{name}: {r['views']} views, {r['seconds_per_iteration'] * 1e3:.1f} ms/iteration, plateau at step "
                f"{r['plateau']['step']} ({r['plateau']['train_seconds']:.0f} s), peak RSS {r['max_rss_mib']:.0f} MiB",
                rows,
                ("step", "train s", "test PSNR", f"render {len(test)} views s"),
            )
    for key in ("encoding_seconds_per_32k_points", "seconds_per_step_from_step_0"):
        if key in report:
            times = report[key]
            fastest = min(times.values())
            print_table(key, [(name, t, t / fastest) for name, t in times.items()], ("variant", "seconds", "ratio"))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
