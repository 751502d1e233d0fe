"""Are a real scene's cameras registered with its images? The dense-view check on a dataset folder.

A real scene enters the study through a format's conversion (LLFF's `poses_bounds.npy`, IDR's
`cameras_sphere.npz`, ...) and the captured set's frame estimate. If either were wrong, every run
on the scene would train on images paired with the wrong rays, and no selection method could help:
the study would measure noise. Sparse runs cannot tell that apart from a hard scene; dense ones can.

For each scene, the engine is trained on every view the study does not keep for testing (its
initial views and its whole candidate pool, as `load_scene_data` divides the folder) and scored
on the study's own test views. A negative control trains on the same images with their cameras
permuted among them (each image given another view's pose). The rule, fixed before the first run:
a scene is registered when the dense run's test PSNR exceeds its control's by at least
`MARGIN_DB`. The check touches no method and chooses nothing.

    python benchmarks/bench_dense_real.py --scenes data/real/mic data/real/maryRose --out dense-real.json

Exits with status 1 when a scene fails the rule.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

STEPS = 1000
MARGIN_DB = 3.0
"""How far above the permuted-pose control a registered scene's dense test PSNR must be (dB)."""


def permuted_cameras(views, seed: int):
    """The same images with their cameras permuted so that no image keeps its own (a derangement
    by a random rotation of a shuffled order)."""
    from nerfaug.data.views import Views

    generator = torch.Generator().manual_seed(seed)
    order = torch.randperm(len(views), generator=generator).tolist()
    target = {order[i]: order[(i + 1) % len(order)] for i in range(len(order))}
    cameras = views.cameras[[target[i] for i in range(len(views))]]
    return Views(cameras, views.images, list(views.names), views.alphas)


def train_and_score(train, test, engine: str, steps: int, seed: int) -> dict:
    from bench_dense import evaluate as psnr_over  # the dense check's own scoring: mean PSNR over views
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    cpu = time.process_time()
    trainer = Trainer(train, NerfConfig.preset(engine), seed=seed, progress=False)
    trainer.train(steps)
    return {
        "test_psnr": psnr_over(trainer.model, test),
        "train_psnr": psnr_over(trainer.model, train.subset(range(0, len(train), max(1, len(train) // 10)))),
        "cpu_seconds": time.process_time() - cpu,
    }


def check_scene(folder: Path, engine: str, steps: int, seed: int, layouts: int) -> dict:
    from nerfaug.data.views import Views
    from nerfaug.experiment.config import STUDY_PRESETS
    from nerfaug.experiment.protocol import load_scene_data

    config = STUDY_PRESETS.choose("study", engine=engine, layouts=layouts)
    data = load_scene_data(folder, config, layout=0)
    train = Views.cat([data.initial, data.pool])
    dense = train_and_score(train, data.test, engine, steps, seed)
    control = train_and_score(permuted_cameras(train, seed), data.test, engine, steps, seed)
    return {
        "scene": folder.name,
        "engine": engine,
        "steps": steps,
        "seed": seed,
        "train_views": len(train),
        "test_views": len(data.test),
        "resolution": [train.cameras.width, train.cameras.height],
        "dense": dense,
        "permuted_control": control,
        "margin_db": dense["test_psnr"] - control["test_psnr"],
        "registered": dense["test_psnr"] - control["test_psnr"] >= MARGIN_DB,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", type=Path, required=True, help="dataset folders, as the study takes")
    parser.add_argument("--out", type=Path, required=True, help="JSON results (appended scene by scene)")
    parser.add_argument("--engine", default="nerfacto-cpu")
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--layouts", type=int, default=3, help="as the study divides (test views do not vary)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)

    from nerfaug.device import configure_process

    configure_process(threads=args.threads)
    results = json.loads(args.out.read_text()) if args.out.exists() else []
    failed = []
    for folder in args.scenes:
        result = check_scene(folder, args.engine, args.steps, args.seed, args.layouts)
        key = (result["scene"], result["engine"], result["steps"], result["seed"])
        results = [r for r in results if (r["scene"], r["engine"], r["steps"], r["seed"]) != key] + [result]
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=1) + "\n")
        verdict = "registered" if result["registered"] else "NOT registered"
        print(
            f"{result['scene']}: dense {result['dense']['test_psnr']:.2f} dB on {result['test_views']} test views, "
            f"permuted-pose control {result['permuted_control']['test_psnr']:.2f} dB: {verdict}",
            file=sys.stderr,
            flush=True,
        )
        if not result["registered"]:
            failed.append(result["scene"])
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
