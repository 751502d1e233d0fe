"""Active-capture benchmark: the time of one `CaptureSession.propose` step on a dataset.

    python benchmarks/bench_propose.py DATA                          # DATA: a Blender-format folder
    python benchmarks/bench_propose.py data/lego --split initial --steps 300 --repeat 3

A session is created from DATA's `--split` views in a temporary run folder and trained `--steps`
steps (timed too); then `propose(6, method, 500 hemisphere candidates)` is timed `--repeat`
times, each a fresh proposal (new candidates, as a user calling it again would get): scoring and
selection (`map=False`; wall and CPU time), and separately the hemisphere map `propose` draws.
Prints a summary and writes `<out>/bench_propose.json`.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch

from nerfaug.device import configure_process
from nerfaug.maps import plot_hemisphere_map
from nerfaug.selection import SelectionConfig
from nerfaug.session import CaptureSession, ProposalRequest, SessionSettings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path, help="a Blender-format (or nerfstudio) dataset folder")
    parser.add_argument("--split", default="train", help="the split with the views captured so far")
    parser.add_argument("--preset", default="cpu", choices=("cpu", "paper", "test"))
    parser.add_argument("--steps", type=int, default=300, help="training steps before proposing")
    parser.add_argument("--n", type=int, default=6, help="views per proposal")
    parser.add_argument("--method", default="ours")
    parser.add_argument("--candidates", type=int, default=500, help="hemisphere candidates")
    parser.add_argument("--entropy-resolution", type=int, default=40)
    parser.add_argument("--downscale", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args()
    configure_process(threads=args.threads)

    config = SelectionConfig(entropy_resolution=args.entropy_resolution).checked()
    with tempfile.TemporaryDirectory(prefix="nerfaug-bench-propose-") as run:
        start = time.perf_counter()
        settings = SessionSettings(engine=args.preset, downscale=args.downscale)
        session = CaptureSession.create(args.data, Path(run) / "run", settings, split=args.split, device=args.device)
        create_s = time.perf_counter() - start
        start = time.perf_counter()
        session.train(args.steps)
        train_s = time.perf_counter() - start

        train = session.trainer.train_views.cameras
        # One untimed call first: imports, allocator and thread pool warm-up.
        request = ProposalRequest(n=args.n, method=args.method, n_candidates=args.candidates, selection=config)
        session.propose(request, map=False)
        scoring, scoring_cpu, maps = [], [], []
        for _ in range(args.repeat):
            start, start_cpu = time.perf_counter(), time.process_time()
            proposal = session.propose(request, map=False)
            scoring.append(time.perf_counter() - start)
            scoring_cpu.append(time.process_time() - start_cpu)
            start = time.perf_counter()
            to_engine = session.hemisphere.to_engine  # the frame `propose` draws its map in
            plot_hemisphere_map(
                to_engine(proposal.candidates.camera_to_world),
                proposal.scores,
                train.camera_to_world,
                to_engine(proposal.poses),
                path=Path(run) / "map.png",
            )
            maps.append(time.perf_counter() - start)

    result = {
        "benchmark": "propose",
        "data": str(args.data),
        "split": args.split,
        "views": len(train),
        "image_size": [train.width, train.height],
        "preset": args.preset,
        "steps": args.steps,
        "method": args.method,
        "n": args.n,
        "candidates": len(proposal.candidates),
        "entropy_resolution": args.entropy_resolution,
        "rays_scored": len(proposal.candidates)
        * args.entropy_resolution
        * round(args.entropy_resolution * train.height / train.width),
        "create_s": create_s,
        "train_s": train_s,
        "train_steps_per_s": args.steps / max(train_s, 1e-9),
        "propose_s": scoring,
        "propose_median_s": statistics.median(scoring),
        # CPU time of this process (all threads): what the step costs when others share the machine.
        "propose_cpu_s": scoring_cpu,
        "propose_cpu_median_s": statistics.median(scoring_cpu),
        "map_s": maps,
        "map_median_s": statistics.median(maps),
        "device": args.device,
        "threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "cpu": platform.processor() or platform.machine(),
        "host": platform.node(),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "bench_propose.json"
    path.write_text(json.dumps(result, indent=2) + "\n")
    print(
        f"{args.data} ({args.split}: {len(train)} views, {train.width}x{train.height}), {args.preset} preset, "
        f"{args.steps} steps in {train_s:.1f} s"
    )
    print(
        f"propose {args.n} of {result['candidates']} candidates ({args.method}, entropy at "
        f"{args.entropy_resolution} px): median {result['propose_median_s']:.2f} s "
        f"(runs: {', '.join(f'{t:.2f}' for t in scoring)}; CPU time {result['propose_cpu_median_s']:.2f} s); "
        f"map +{result['map_median_s']:.2f} s"
    )
    print(f"written to {path}")


if __name__ == "__main__":
    main()
