"""FisherRF stability benchmark: how much of the candidates' ranking comes from the pixel subsamples.

    python benchmarks/bench_fisher.py --data data/lego100            # 100 pool candidates, 2 seeds
    python benchmarks/bench_fisher.py --data data/lego100 --seeds 4 --resolutions 45 64 \
        --train-pixels 4096 8192                                      # around the study's setting, 4 seeds

Trains the `cpu` engine preset on the dataset's initial views (the protocol's `load_scene_data`
and `ExperimentConfig.engine_config`, seed 0) to `--steps` (200: where the protocol selects), then computes, with
`SelectionConfig`'s fisher_* settings and the functions the study's estimator calls:

- H_train over about n training pixels exactly as `fisherrf_candidates` computes it
  (`fisher_train_diagonal`: stratified pixels spread evenly over the training views, weighted to
  estimate the sum over every pixel; `fisher_train_pixels` = n), for n doubling from 1024;
- H_cand of each candidate (`fisher_views`, with the arguments `fisherrf_candidates` gives
  `fisherrf_view_scores`) over r x r stratified pixels, the pixel count doubling from 8 x 8
  (r = 8, 11, 16, 23, 32, 45, 64);

each for `--seeds` seeds (H_train from generator 1000 + seed, H_cand from 2000 + seed, so that
one H_cand is scored against every H_train), and scores every candidate for every pair (sum_k
H_cand / (H_train + lambda)). A setting S = (r, n) is compared with S at twice the candidate
pixels (r -> ~1.41 r, n fixed; same H_train), with S at twice the training pixels (n -> 2n, r
fixed; same H_cand), with itself at the next seed, and with a reference on whole images (every
pixel of each candidate, every training pixel): `--reference exact` (fisher_method "exact",
computed once; about 5 ms per ray for the `cpu` preset on one core, 1.06 M rays for 100
candidates at 100 px) or `random-sign` (the study's probes on whole images, H_train and H_cand
averaged over `--reference-seeds` seeds). Spearman correlation of the scores (scipy.stats.spearmanr)
and overlap of the top 6 (and of FisherRF's greedy 6), averaged over the seeds. Costs are wall
seconds of each part and the same in training steps (seconds of one training step of the same
model, measured in the same run). Candidates come from the pool (train split) only; test views
are never read for anything but what `load_scene_data` loads.

Writes <out>/bench_fisher.json and prints the tables.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import torch
from scipy.stats import spearmanr

from nerfaug.device import configure_process
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.protocol import load_scene_data
from nerfaug.nerf.trainer import Trainer
from nerfaug.selection import SelectionConfig
from nerfaug.selection.estimators import fisher_background, fisher_train_diagonal
from nerfaug.uncertainty.fisher import fisher_views, fisherrf_greedy, fisherrf_scores

TOP = 6
CANDIDATE_RESOLUTIONS = (8, 11, 16, 23, 32, 45, 64)  # r x r pixels, doubling from 64
TRAIN_PIXELS = (1024, 2048, 4096, 8192, 16384, 32768)
WHOLE = "whole"
EVERY_PIXEL = 10**9  # fisher_train_pixels that gives one block per pixel: every training pixel, weight 1


def h_train_of(model, train_cameras, selection: SelectionConfig, n_pixels: int, generator) -> torch.Tensor:
    """H_train over about `n_pixels` training pixels, as `fisherrf_candidates` computes it."""
    return fisher_train_diagonal(model, train_cameras, replace(selection, fisher_train_pixels=n_pixels), generator)


def h_cand_of(model, candidates, selection: SelectionConfig, resolution: int, generator) -> torch.Tensor:
    """H_cand of every candidate (n_candidates, P) over `resolution` x ~`resolution` stratified
    pixels: each row the H_cand `fisherrf_candidates` computes for that candidate (its
    `fisherrf_view_scores` calls `fisher_views`' computation with these arguments)."""
    return fisher_views(
        model,
        candidates,
        resolution,
        selection.fisher_method,
        selection.fisher_probes,
        generator,
        background=fisher_background(selection),
    )


def timed(fn, *args):
    """(seconds, fn(*args))."""
    start = time.perf_counter()
    value = fn(*args)
    return time.perf_counter() - start, value


def trained(data, config: ExperimentConfig, steps: int, checkpoint: Path) -> tuple[Trainer, float]:
    """The protocol's trainer after `steps` steps (saved to `checkpoint`), and the seconds of one
    training step, timed over the last half of the steps in this process."""
    engine = config.engine_config("lego")
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
    parser.add_argument(
        "--reference",
        choices=("random-sign", "exact", "none"),
        default="random-sign",
        help="whole-image reference: the study's probes averaged over --reference-seeds, or the exact diagonal",
    )
    parser.add_argument(
        "--reference-seeds", type=int, default=None, help="random-sign reference: estimates averaged (--seeds)"
    )
    parser.add_argument("--no-whole", action="store_true", help="no whole-image reference (--reference none)")
    parser.add_argument("--out", type=Path, default=Path("data/bench_fisher"))
    args = parser.parse_args()
    reference = "none" if args.no_whole else args.reference

    configure_process(threads=args.threads)
    args.out.mkdir(parents=True, exist_ok=True)
    load_start = os.getloadavg()
    config = ExperimentConfig(resolution=100)
    selection = SelectionConfig()
    data = load_scene_data(args.data, config)
    trainer, step_seconds = trained(data, config, args.steps, args.out / "model.pt")
    model, train_cameras = trainer.model, trainer.train_views.cameras
    pick = torch.linspace(0, len(data.pool) - 1, min(args.candidates, len(data.pool))).round().long().tolist()
    candidates = data.pool.cameras[pick]
    width = candidates.width
    print(
        f"{len(train_cameras)} training views, {len(candidates)} candidates, {width} px; "
        f"one training step {step_seconds * 1e3:.1f} ms; load {load_start}",
        flush=True,
    )

    seeds = tuple(range(args.seeds))
    h_train: dict[tuple, torch.Tensor] = {}
    cost: dict[str, float] = {}
    for n in args.train_pixels:
        for seed in seeds:
            generator = torch.Generator().manual_seed(1000 + seed)
            seconds, h = timed(h_train_of, model, train_cameras, selection, n, generator)
            h_train[n, seed] = h
            cost[f"train {n}"] = seconds if seed == 0 else cost[f"train {n}"]
            print(f"H_train n={n} seed={seed}: {seconds:.1f} s", flush=True)

    scores: dict[tuple, torch.Tensor] = {}
    greedy: dict[tuple, list[int]] = {}
    for r in args.resolutions:
        for seed in seeds:
            generator = torch.Generator().manual_seed(2000 + seed)
            seconds, h_cand = timed(h_cand_of, model, candidates, selection, r, generator)
            if seed == 0:
                cost[f"cand {r}"] = seconds
            print(f"H_cand r={r} seed={seed}: {seconds:.1f} s", flush=True)
            for (n, train_seed), h in h_train.items():
                if train_seed != seed:  # each comparison pairs the two sides' estimates of one seed
                    continue
                scores[r, seed, n, train_seed] = fisherrf_scores(h, h_cand, selection.fisher_lambda)
                greedy[r, seed, n, train_seed] = fisherrf_greedy(h, h_cand, TOP, selection.fisher_lambda)[0].tolist()
            del h_cand

    split_half = None
    if reference != "none":
        # Every pixel at both sides; its own seeds (3000 +, 4000 +), apart from the settings' draws.
        ref_selection = replace(selection, fisher_method=reference)
        ref_seeds = range(1 if reference == "exact" else (args.reference_seeds or len(seeds)))
        # Sums over the even and the odd seeds: their means' agreement is the reference's own noise.
        halves = {0: [0.0, 0.0], 1: [0.0, 0.0]}
        ref_seconds = 0.0
        for seed in ref_seeds:
            generator = torch.Generator().manual_seed(3000 + seed)
            seconds, h = timed(h_train_of, model, train_cameras, ref_selection, EVERY_PIXEL, generator)
            print(f"reference H_train ({reference}, every pixel) seed={seed}: {seconds:.1f} s", flush=True)
            halves[seed % 2][0], ref_seconds = halves[seed % 2][0] + h, ref_seconds + seconds
            generator = torch.Generator().manual_seed(4000 + seed)
            seconds, h = timed(h_cand_of, model, candidates, ref_selection, width, generator)
            print(f"reference H_cand ({reference}, every pixel) seed={seed}: {seconds:.1f} s", flush=True)
            halves[seed % 2][1], ref_seconds = halves[seed % 2][1] + h, ref_seconds + seconds
            del h
        cost["reference"] = ref_seconds
        if len(ref_seeds) > 1:
            for half, (train_sum, cand_sum) in halves.items():
                count = len(ref_seeds[half::2])
                scores[WHOLE, half] = fisherrf_scores(train_sum / count, cand_sum / count, selection.fisher_lambda)
                greedy[WHOLE, half] = fisherrf_greedy(
                    train_sum / count, cand_sum / count, TOP, selection.fisher_lambda
                )[0].tolist()
            split_half = compare(scores[WHOLE, 0], scores[WHOLE, 1], greedy[WHOLE, 0], greedy[WHOLE, 1])
        ref_train = (halves[0][0] + halves[1][0]) / len(ref_seeds)
        ref_cand = (halves[0][1] + halves[1][1]) / len(ref_seeds)
        del halves
        scores[WHOLE] = fisherrf_scores(ref_train, ref_cand, selection.fisher_lambda)
        greedy[WHOLE] = fisherrf_greedy(ref_train, ref_cand, TOP, selection.fisher_lambda)[0].tolist()
        del ref_cand

    def averaged(each: list[dict]) -> dict:
        return {key: sum(c[key] for c in each) / len(each) for key in each[0]} | {
            "min_top6": min(c["top6"] for c in each),
            "pairs": len(each),
        }

    def key_cmp(a, b):
        """Settings a = (r, n) and b compared at every seed (b's seed shifted by `shift`), averaged."""
        (ra, na), (rb, nb, shift) = a, b
        return averaged(
            [
                compare(scores[ra, s, na, s], scores[rb, t, nb, t], greedy[ra, s, na, s], greedy[rb, t, nb, t])
                for s in seeds
                for t in [(s + shift) % len(seeds)]
            ]
        )

    def ref_cmp(r, n):
        """Setting (r, n) at every seed compared with the whole-image reference, averaged."""
        return averaged([compare(scores[r, s, n, s], scores[WHOLE], greedy[r, s, n, s], greedy[WHOLE]) for s in seeds])

    rs, ns = args.resolutions, args.train_pixels
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
            if reference != "none":
                row["vs_whole"] = ref_cmp(r, n)
            rows.append(row)

    def fmt(c):
        if c is None:
            return "        -         "
        return f"{c['spearman']:.2f} {c['top6']:.1f}/6 (min {c['min_top6']}) {c['greedy6']:.1f}/6"

    print(f"\nload after: {os.getloadavg()}")
    print(f"means over {len(seeds)} seeds of Spearman, top-6 overlap (its minimum), greedy-6 overlap")
    print(f"r x r cand | n train | cand 2x | train 2x | seed vs seed | vs whole ({reference}) | s | steps")
    for row in rows:
        print(
            f"{row['r']!s:>5} | {row['n']!s:>6} | {fmt(row.get('cand_2x'))} | {fmt(row.get('train_2x'))} | "
            f"{fmt(row.get('seed'))} | {fmt(row.get('vs_whole'))} | {row['seconds']:.1f} | {row['steps']:.0f}"
        )
    if reference != "none":
        print(f"reference: {cost['reference']:.1f} s ({cost['reference'] / step_seconds:.0f} steps)")
    if split_half is not None:
        print(
            f"reference, mean of even seeds vs mean of odd seeds: {split_half['spearman']:.2f} "
            f"{split_half['top6']}/6 {split_half['greedy6']}/6"
        )
    record = {
        "rows": rows,
        "costs": cost,
        "step_seconds": step_seconds,
        "candidates": pick,
        "steps": args.steps,
        "seeds": args.seeds,
        "reference": {
            "method": reference,
            "seeds": 0 if reference == "none" else len(ref_seeds),
            "top6": sorted(torch.topk(scores[WHOLE], TOP).indices.tolist()) if reference != "none" else None,
            "greedy6": greedy.get(WHOLE),
            "split_half": split_half,
        },
        "threads": args.threads,
        "host": platform.node(),
        "torch": torch.__version__,
        "load_start": load_start,
        "load_end": os.getloadavg(),
        "selection": selection.to_dict(),
    }
    (args.out / "bench_fisher.json").write_text(json.dumps(record, indent=1, default=str))


if __name__ == "__main__":
    main()
