"""How often a NeRF ends empty (renders its training views as background only, `nerfaug.health`)
on prepared real scenes, per engine, seed and number of views, as `nerfaug train` trains it:

    python benchmarks/bench_empty_nerfs.py data/real/mic --engines cpu nerfacto-cpu --seeds 0 1 2 \\
        --views 12 all --steps 1000 --out docs/benchmarks/empty-nerfs.json

An engine may be a variant ("cpu+average_init_density=0.01"). "12" starts sparse (`SparseStart`:
12 views on one half, layout 0); "all" trains on the whole train split (the default of `nerfaug
train`). Each run is a capture session on the CPU, one torch thread, one at a time; the record
keeps the health check, the training PSNR, the share of the occupancy grid's cells left occupied
(occupancy engines) and the seconds. Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from datetime import date
from pathlib import Path

import torch

from nerfaug.capture import CaptureSession, SessionSettings
from nerfaug.capture.requests import SparseStart
from nerfaug.nerf.config import NerfConfig, parse_variant


def one_run(data: Path, engine: str, seed: int, views: str, steps: int, split: str | None = None) -> dict:
    start = None if views == "all" else SparseStart(initial=int(views))
    with tempfile.TemporaryDirectory(prefix="nerfaug-empty-") as tmp:
        began = time.perf_counter()
        base, changes = parse_variant(engine)  # a preset, or a variant: "cpu+average_init_density=0.01"
        settings = SessionSettings(engine=base, seed=seed)
        config = NerfConfig.preset(base, **changes) if changes else None
        session = CaptureSession.create(data, Path(tmp) / "run", settings, split=split, config=config, start=start)
        last = session.train(steps)
        seconds = time.perf_counter() - began
        health = session.health()
        grid = getattr(session.trainer.model.sampler, "grid", None)
        occupied = None if grid is None else float(grid.occupied.float().mean())
        return {
            "scene": data.name,
            "engine": engine,
            "seed": seed,
            "views": views,
            "trained_views": len(session.cameras),
            "steps": steps,
            "train_psnr": float(last.get("psnr", float("nan"))),
            "occupied_fraction": occupied,
            "seconds": round(seconds, 1),
            "date": date.today().isoformat(),  # the file's "date" is its last write; records span days
            "health": health.to_dict(),
        }


def table(records: list[dict]) -> str:
    cells: dict[tuple, list[dict]] = {}
    for r in records:
        cells.setdefault((r["scene"], r["engine"], r["views"]), []).append(r)
    lines = [
        "| scene | engine | views | empty / runs | median train PSNR (dB) | median s |",
        "|---|---|---|---|---|---|",
    ]
    for (scene, engine, views), runs in sorted(cells.items()):
        empty = sum(r["health"]["empty"] for r in runs)
        psnr = sorted(r["train_psnr"] for r in runs)[len(runs) // 2]
        secs = sorted(r["seconds"] for r in runs)[len(runs) // 2]
        lines.append(f"| {scene} | {engine} | {views} | {empty} / {len(runs)} | {psnr:.2f} | {secs:.0f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="+", type=Path, help="prepared scene folders (`nerfaug scene prepare`)")
    parser.add_argument("--engines", nargs="+", default=["cpu", "nerfacto-cpu"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--views", nargs="+", default=["12", "all"], help='initial views ("all": the train split)')
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument(
        "--split", default=None, help='the split ("train": the pool of a scene `nerfaug scene render` wrote)'
    )
    parser.add_argument("--out", type=Path, required=True, help="JSON file (runs already in it are kept)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    done = json.loads(args.out.read_text())["runs"] if args.out.is_file() else []
    key = lambda r: (r["scene"], r["engine"], r["seed"], r["views"], r["steps"])  # noqa: E731
    have = {key(r) for r in done}
    for data in args.scenes:
        for views in args.views:
            for engine in args.engines:
                for seed in args.seeds:
                    if (data.name, engine, seed, views, args.steps) in have:
                        continue
                    record = one_run(data, engine, seed, views, args.steps, args.split)
                    done.append(record)
                    h = record["health"]
                    print(
                        f"{data.name} {engine} seed {seed} views {views}: train PSNR {record['train_psnr']:.2f} dB, "
                        f"opacity {h['object_opacity']:.3f}, {'EMPTY' if h['empty'] else 'ok'} "
                        f"({record['seconds']:.0f} s)",
                        flush=True,
                    )
                    machine = {"machine": platform.processor() or platform.machine(), "date": date.today().isoformat()}
                    args.out.parent.mkdir(parents=True, exist_ok=True)
                    args.out.write_text(json.dumps({**machine, "runs": done}, indent=1) + "\n")
    print(table(done))


if __name__ == "__main__":
    main()
