"""Selection benchmark: time to score 500 candidate views per estimator, with the real NerfModel.

    python benchmarks/bench_selection.py                       # cpu preset, model trained 200 steps
    python benchmarks/bench_selection.py --steps 0 --candidates 100 --entropy-resolution 20

The model is trained as at selection time in the protocol (6 views on one half of the hemisphere,
`--steps` iterations) on an analytic scene (two shaded spheres ray-traced in torch), so no Blender
is needed. Then, for `--candidates` poses uniform on the hemisphere, it times:

- entropy: `view_entropy` at `--entropy-resolution` (one rendering of C x res^2 rays),
- distance: `coverage_distance` (SO(3), no rendering),
- fisher: FisherRF's H_train (`--fisher-pixels` training pixels), every candidate's score at
  `--fisher-resolution`, then the greedy pick of 6,
- each registered method end to end through `select_views`,
- one training step of the same model, the yardstick (a CPU trial is `steps` of them).

The trained model is saved in <out> and reused by later runs with the same settings. Prints a
table and writes <out>/bench_selection.json.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from pathlib import Path

import torch

from nerfaug.cameras import Cameras, generate_rays
from nerfaug.data.views import Views
from nerfaug.device import configure_process
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, half_hemisphere_poses
from nerfaug.selection import METHODS, SelectionConfig, hemisphere_candidates, select_views
from nerfaug.selection.estimators import fisher_train_diagonal
from nerfaug.uncertainty.entropy import view_entropy
from nerfaug.uncertainty.fisher import (
    fisherrf_greedy,
    fisherrf_view_scores,
)
from nerfaug.uncertainty.so3 import coverage_distance

# Two spheres (centre, radius, colour) inside the NeRF-synthetic box.
SPHERES = [((0.0, 0.0, 0.0), 0.8, (0.85, 0.3, 0.2)), ((0.6, -0.5, 0.6), 0.35, (0.2, 0.4, 0.9))]


def render_spheres(cameras: Cameras, index: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray-traced image (H, W, 3) over white and alpha (H, W) of the analytic scene."""
    ys, xs = torch.meshgrid(torch.arange(cameras.height), torch.arange(cameras.width), indexing="ij")
    origins, directions = generate_rays(cameras, torch.full((xs.numel(),), index), xs.reshape(-1), ys.reshape(-1))
    nearest = torch.full((origins.shape[0],), math.inf)
    colour = torch.ones(origins.shape[0], 3)
    light = torch.nn.functional.normalize(torch.tensor([0.4, 0.3, 1.0]), dim=0)
    for centre, radius, base in SPHERES:
        offset = origins - torch.tensor(centre)
        b = (offset * directions).sum(-1)
        disc = b**2 - ((offset**2).sum(-1) - radius**2)
        t = -b - disc.clamp_min(0).sqrt()
        hit = (disc > 0) & (t > 0) & (t < nearest)
        normal = torch.nn.functional.normalize(offset + t[:, None] * directions, dim=-1)
        shade = 0.35 + 0.65 * (normal @ light).clamp_min(0)
        colour = torch.where(hit[:, None], shade[:, None] * torch.tensor(base), colour)
        nearest = torch.where(hit, t, nearest)
    alpha = torch.isfinite(nearest).float()
    return colour.reshape(cameras.height, cameras.width, 3), alpha.reshape(cameras.height, cameras.width)


def trained(steps: int, resolution: int, preset: str, checkpoint: Path):
    """A Trainer after `steps` steps on the analytic scene, reloaded from `checkpoint` if there."""
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    if checkpoint.exists():
        try:
            return Trainer.load_checkpoint(checkpoint, progress=False)
        except (ValueError, KeyError, RuntimeError):  # saved by an older version of the model
            checkpoint.unlink()
    cameras = Cameras.from_fov(half_hemisphere_poses(6), BLENDER_CAMERA_ANGLE_X, resolution, resolution)
    images, alphas = zip(*(render_spheres(cameras, i) for i in range(len(cameras))))
    views = Views(cameras, torch.stack(images), [f"view_{i}" for i in range(6)], torch.stack(alphas))
    trainer = Trainer(views, NerfConfig.preset(preset), seed=0, progress=False)
    trainer.train(steps)
    checkpoint.parent.mkdir(parents=True, exist_ok=True)
    trainer.save_checkpoint(checkpoint)
    return trainer


def timed(fn):
    start = time.perf_counter()
    value = fn()
    return time.perf_counter() - start, value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", default="cpu", help="NerfConfig preset")
    parser.add_argument("--steps", type=int, default=200, help="training steps before scoring")
    parser.add_argument("--resolution", type=int, default=100, help="training image size")
    parser.add_argument("--candidates", type=int, default=500)
    parser.add_argument("--entropy-resolution", type=int, default=SelectionConfig.entropy_resolution)
    parser.add_argument("--fisher-resolution", type=int, default=SelectionConfig.fisher_resolution)
    parser.add_argument("--fisher-pixels", type=int, default=SelectionConfig.fisher_train_pixels)
    parser.add_argument("--fisher-method", default=SelectionConfig.fisher_method)
    parser.add_argument("--threads", type=int, default=torch.get_num_threads())
    parser.add_argument("--methods", nargs="*", default=list(METHODS), help="methods timed end to end")
    parser.add_argument("--out", type=Path, default=Path("/tmp/nerfaug_bench_selection"))
    args = parser.parse_args()
    configure_process(threads=args.threads)

    checkpoint = args.out / f"model_{args.preset}_{args.resolution}px_{args.steps}steps.pt"
    train_seconds, trainer = timed(lambda: trained(args.steps, args.resolution, args.preset, checkpoint))
    model, train_cameras = trainer.model, trainer.train_views.cameras
    candidates = hemisphere_candidates(
        train_cameras, args.candidates, torch.Generator().manual_seed(0), training=train_cameras
    )
    config = SelectionConfig(
        entropy_resolution=args.entropy_resolution,
        fisher_resolution=args.fisher_resolution,
        fisher_train_pixels=args.fisher_pixels,
        fisher_method=args.fisher_method,
    ).checked()
    rays = len(candidates) * args.entropy_resolution**2
    rows: dict[str, float] = {}
    rows["entropy (view_entropy)"], _ = timed(
        lambda: view_entropy(model, candidates, args.entropy_resolution, config.chunk)
    )
    rows["distance (coverage_distance)"], _ = timed(
        lambda: coverage_distance(candidates.rotations, train_cameras.rotations)
    )
    generator = torch.Generator().manual_seed(0)
    # H_train as the study's FisherRF takes it (stratified, weighted training pixels).
    rows["fisher H_train"], h_train = timed(lambda: fisher_train_diagonal(model, train_cameras, config, generator))
    rows["fisher candidate scores"], (scores, h_of) = timed(
        lambda: fisherrf_view_scores(
            model,
            candidates,
            h_train,
            config.fisher_lambda,
            config.fisher_cache_floats,
            config.fisher_resolution,
            config.fisher_method,
            config.fisher_probes,
            generator,
        )
    )
    rows["fisher greedy (6 views)"], _ = timed(lambda: fisherrf_greedy(h_train, h_of, 6, config.fisher_lambda, scores))
    for name in args.methods:
        rows[f"select_views({name})"], _ = timed(
            lambda name=name: select_views(
                name, model, train_cameras, candidates, 6, torch.Generator().manual_seed(0), config
            )
        )
    # The yardstick: one training step of the same model on this machine.
    steps_before = trainer.step
    step_seconds, _ = timed(lambda: trainer.train(steps_before + 10))
    step_seconds /= 10

    report = {
        "preset": args.preset,
        "steps": args.steps,
        "candidates": len(candidates),
        "entropy_rays": rays,
        "config": config.to_dict(),
        "threads": torch.get_num_threads(),
        "host": platform.node(),
        "torch": torch.__version__,
        "train_or_load_seconds": train_seconds,
        "n_parameters": sum(p.numel() for p in model.parameters() if p.requires_grad),
        "train_step_seconds": step_seconds,
        "seconds": rows,
    }
    print(
        f"{len(candidates)} candidates, preset {args.preset}, {args.steps} steps, "
        f"{torch.get_num_threads()} threads; entropy over {rays} rays"
    )
    print(f"  {'one training step (yardstick)':34s} {step_seconds:8.3f} s")
    for name, seconds in rows.items():
        print(f"  {name:34s} {seconds:8.3f} s  = {seconds / step_seconds:7.1f} training steps")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_selection.json").write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
