"""FisherRF stability benchmark: how much of the candidates' ranking comes from the pixel subsamples.

    python benchmarks/bench_fisher.py --data data/lego100            # 100 pool candidates, 2 seeds
    python benchmarks/bench_fisher.py --data data/lego100 --seeds 4 --no-whole --resolutions 45 64 \
        --train-pixels 4096 8192                                      # around one setting, 4 seeds

Trains the `cpu` engine preset on the dataset's initial views (the protocol's `load_scene_data`
and `engine_config`, seed 0) to `--steps` (200: where the protocol selects), then computes, with
the functions `fisherrf_candidates` calls and `SelectionConfig`'s other fisher_* settings:

- H_train over n training pixels (`sample_pixel_rays`, as the protocol draws them), for n doubling
  from 1024, and over every training pixel once (`stratified_pixel_rays` with one block per pixel);
- H_cand of each candidate (`fisher_views`) over r x r stratified pixels, the pixel count doubling
  from 8 x 8 (r = 8, 11, 16, 23, 32, 45, 64) to the whole image;

each for `--seeds` seeds, and scores every candidate for every pair (sum_k H_cand / (H_train +
lambda)). A setting S = (r, n) is compared with S at twice the candidate pixels (r -> ~1.41 r, n
fixed; same H_train), with S at twice the training pixels (n -> 2n, r fixed; same H_cand), and
with itself at the next seed: Spearman correlation of the scores (scipy.stats.spearmanr) and
overlap of the top 6 (and of FisherRF's greedy 6), averaged over the seeds. Costs are wall
seconds of each part and the same in training steps (seconds of one training step of the same
model, measured in the same run). Candidates come from the pool (train split)
only; test views are never read for anything but what `load_scene_data` loads.

Writes <out>/bench_fisher.json and prints the tables.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import torch
from scipy.stats import spearmanr

from nerfaug.device import configure_process
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.protocol import engine_config, load_scene_data
from nerfaug.nerf.trainer import Trainer
from nerfaug.selection import SelectionConfig
from nerfaug.uncertainty.fisher import (
    fisher_diagonal,
    fisher_views,
    fisherrf_greedy,
    fisherrf_scores,
    sample_pixel_rays,
    stratified_pixel_rays,
)

TOP = 6
CANDIDATE_RESOLUTIONS = (8, 11, 16, 23, 32, 45, 64)  # r x r pixels, doubling from 64
TRAIN_PIXELS = (1024, 2048, 4096, 8192, 16384, 32768)
WHOLE = "whole"


def timed(fn, *args):
    """(seconds, fn(*args))."""
    start = time.perf_counter()
    value = fn(*args)
    return time.perf_counter() - start, value


def trained(data, config: ExperimentConfig, steps: int, checkpoint: Path) -> tuple[Trainer, float]:
    """The protocol's trainer after `steps` steps (saved to `checkpoint`), and the seconds of one
    training step, timed over the last half of the steps in this process."""
    engine = engine_config(config, "lego")
    trainer = Trainer(data.initial, engine, seed=config.seed, device="cpu", progress=False)
    trainer.train(steps // 2)
    seconds, _ = timed(trainer.train, steps)
    per_step = seconds / (steps - steps // 2)
    trainer.save_checkpoint(checkpoint)
    return trainer, per_step


def compare(a: torch.Tensor, b: torch.Tensor, greedy_a: list[int], greedy_b: list[int]) -> dict:
    top_a = set(torch.topk(a, TOP).indices.tolist())
    top_b = set(torch.topk(b, TOP).indices.tolist())
    return {
        "spearman": float(spearmanr(a.numpy(), b.numpy()).statistic),
        "top6": len(top_a & top_b),
        "greedy6": len(set(greedy_a) & set(greedy_b)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("data/lego100"))
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--candidates", type=int, default=100, help="pool views scored, evenly spaced in the pool")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--resolutions", type=int, nargs="*", default=list(CANDIDATE_RESOLUTIONS))
    parser.add_argument("--train-pixels", type=int, nargs="*", default=list(TRAIN_PIXELS))
    parser.add_argument("--seeds", type=int, default=2, help="seeds of every estimate; comparisons average them")
    parser.add_argument("--no-whole", action="store_true", help="skip the whole-image settings (the costliest)")
    parser.add_argument("--out", type=Path, default=Path("data/bench_fisher"))
    args = parser.parse_args()

    configure_process(threads=args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    config = ExperimentConfig(resolution=100)
    selection = SelectionConfig()
    background = None if selection.background is None else torch.tensor(selection.background)
    data = load_scene_data(args.data, config)
    trainer, step_seconds = trained(data, config, args.steps, args.out / "model.pt")
    model, train_cameras = trainer.model, trainer.train_views.cameras
    pick = torch.linspace(0, len(data.pool) - 1, min(args.candidates, len(data.pool))).round().long().tolist()
    candidates = data.pool.cameras[pick]
    width = candidates.width
    print(
        f"{len(train_cameras)} training views, {len(candidates)} candidates, {width} px; "
        f"one training step {step_seconds * 1e3:.1f} ms; load {os.getloadavg()}",
        flush=True,
    )

    seeds = tuple(range(args.seeds))
    whole = [] if args.no_whole else [WHOLE]
    h_train: dict[tuple, torch.Tensor] = {}
    cost: dict[str, float] = {}
    for n in [*args.train_pixels, *whole]:
        for seed in seeds:
            generator = torch.Generator().manual_seed(1000 + seed)
            if n == WHOLE:
                origins, directions, weights = stratified_pixel_rays(train_cameras, 10**9, generator)
            else:
                origins, directions = sample_pixel_rays(train_cameras, n, generator)
                weights = None
            seconds, h = timed(
                fisher_diagonal,
                model,
                origins,
                directions,
                selection.fisher_method,
                selection.fisher_train_probes,
                generator,
                selection.fisher_train_chunk,
                background,
                weights,
            )
            h_train[n, seed] = h
            cost[f"train {n}"] = seconds if seed == 0 else cost[f"train {n}"]
            print(f"H_train n={n} seed={seed}: {seconds:.1f} s", flush=True)

    scores: dict[tuple, torch.Tensor] = {}
    greedy: dict[tuple, list[int]] = {}
    for r in [*args.resolutions, *whole]:
        resolution = width if r == WHOLE else r
        for seed in seeds:
            generator = torch.Generator().manual_seed(2000 + seed)
            seconds, h_cand = timed(
                fisher_views,
                model,
                candidates,
                resolution,
                selection.fisher_method,
                selection.fisher_probes,
                generator,
                1024,
                background,
            )
            if seed == 0:
                cost[f"cand {r}"] = seconds
            print(f"H_cand r={r} seed={seed}: {seconds:.1f} s", flush=True)
            for (n, train_seed), h in h_train.items():
                if train_seed != seed:  # each comparison pairs the two sides' estimates of one seed
                    continue
                scores[r, seed, n, train_seed] = fisherrf_scores(h, h_cand, selection.fisher_lambda)
                greedy[r, seed, n, train_seed] = fisherrf_greedy(h, h_cand, TOP, selection.fisher_lambda)[0].tolist()
            del h_cand

    def key_cmp(a, b):
        """Settings a = (r, n) and b compared at every seed (b's seed shifted by `shift`), averaged."""
        (ra, na), (rb, nb, shift) = a, b
        each = [
            compare(scores[ra, s, na, s], scores[rb, t, nb, t], greedy[ra, s, na, s], greedy[rb, t, nb, t])
            for s in seeds
            for t in [(s + shift) % len(seeds)]
        ]
        return {key: sum(c[key] for c in each) / len(each) for key in each[0]} | {
            "min_top6": min(c["top6"] for c in each),
            "pairs": len(each),
        }

    rs = [*args.resolutions, *whole]
    ns = [*args.train_pixels, *whole]
    rows = []
    for r_index, r in enumerate(rs):
        for n_index, n in enumerate(ns):
            row = {"r": r, "n": n, "seconds": cost[f"cand {r}"] + cost[f"train {n}"]}
            row["steps"] = row["seconds"] / step_seconds
            if r_index + 1 < len(rs):
                row["cand_2x"] = key_cmp((r, n), (rs[r_index + 1], n, 0))
            if n_index + 1 < len(ns):
                row["train_2x"] = key_cmp((r, n), (r, ns[n_index + 1], 0))
            if len(seeds) > 1:
                row["seed"] = key_cmp((r, n), (r, n, 1))
            if whole:
                row["vs_whole"] = key_cmp((r, n), (WHOLE, WHOLE, 0))
            rows.append(row)

    def fmt(c):
        if c is None:
            return "        -         "
        return f"{c['spearman']:.2f} {c['top6']:.1f}/6 (min {c['min_top6']}) {c['greedy6']:.1f}/6"

    print(f"\nload after: {os.getloadavg()}")
    print(f"means over {len(seeds)} seeds of Spearman, top-6 overlap (its minimum), greedy-6 overlap")
    print("r x r cand | n train | cand 2x | train 2x | seed vs seed | vs whole/whole | s | steps")
    for row in rows:
        print(
            f"{row['r']!s:>5} | {row['n']!s:>6} | {fmt(row.get('cand_2x'))} | {fmt(row.get('train_2x'))} | "
            f"{fmt(row.get('seed'))} | {fmt(row.get('vs_whole'))} | {row['seconds']:.1f} | {row['steps']:.0f}"
        )
    record = {
        "rows": rows,
        "costs": cost,
        "step_seconds": step_seconds,
        "candidates": pick,
        "steps": args.steps,
        "threads": args.threads,
        "host": platform.node(),
        "torch": torch.__version__,
        "load_end": os.getloadavg(),
        "selection": selection.to_dict(),
    }
    (args.out / "bench_fisher.json").write_text(json.dumps(record, indent=1, default=str))


if __name__ == "__main__":
    main()
