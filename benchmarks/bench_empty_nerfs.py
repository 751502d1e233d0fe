"""How often a NeRF ends empty (renders its training views as background only, `nerfaug.health`)
on prepared real scenes, per engine, seed and number of views, as `nerfaug train` trains it:

    python benchmarks/bench_empty_nerfs.py data/real/mic --engines cpu nerfacto-cpu --seeds 0 1 2 \\
        --views 12 all --steps 1000 --out docs/benchmarks/empty-nerfs.json

Re-judge the records of such runs with the health check as it now is, without training: the
verdict needs the runs' stored renders' PSNR and opacity and the scene's own baselines (the blank
and the mean-colour image), which depend only on the images the run trained on:

    python benchmarks/bench_empty_nerfs.py rejudge docs/benchmarks/empty-nerfs/cow.json \
        --data data/cow100 --split train --out docs/benchmarks/empty-nerfs/rejudged-cow.json

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
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import torch

from nerfaug.capture import CaptureSession, SessionSettings
from nerfaug.capture.requests import SparseStart
from nerfaug.health import Health, health_targets, image_baselines
from nerfaug.nerf.config import NerfConfig, parse_variant

# Poses drawn on the hemisphere for the report on untrained poses (the check renders a few of them).
UNTRAINED_CANDIDATES = 8


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
        health = session.health(untrained_cameras(session))
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


def untrained_cameras(session: CaptureSession):
    """A few hemisphere poses the session's NeRF did not train on (seeded: the same each run)."""
    from nerfaug.capture.proposal_request import ProposalRequest

    request = ProposalRequest(n=1, n_candidates=UNTRAINED_CANDIDATES)
    return session.candidate_cameras(request, torch.Generator().manual_seed(0))


def scene_baselines(data: Path, views: str, split: str | None) -> dict:
    """The health check's targets of a run that trained on `views` of `data` ("12": a sparse
    start, "all": the split), and their blank and mean-colour baselines (dB)."""
    start = None if views == "all" else SparseStart(initial=int(views))
    with tempfile.TemporaryDirectory(prefix="nerfaug-rejudge-") as tmp:
        settings = SessionSettings(engine="test", seed=0)  # the views do not depend on the engine or seed
        session = CaptureSession.create(data, Path(tmp) / "run", settings, split=split, start=start)
        background = tuple(session.state.background)
        _, targets = health_targets(session.trainer.train_views)
    blank, mean = image_baselines(targets, background)
    return {"blank_psnr": blank, "mean_psnr": mean, "targets": tuple(targets.shape)}


def rejudge(records: Path, data: Path, split: str | None) -> list[dict]:
    """Each run of `records` judged again from its stored health and `data`'s baselines: the
    baselines' blank PSNR must equal the stored one (the same images), else the run is refused."""
    runs = json.loads(records.read_text())["runs"]
    baselines = {views: scene_baselines(data, views, split) for views in sorted({r["views"] for r in runs})}
    out = []
    for r in runs:
        base, stored = baselines[r["views"]], r["health"]
        if abs(base["blank_psnr"] - stored["blank_psnr"]) > 1e-4:
            raise SystemExit(
                f"{records}: {r['scene']} {r['engine']} seed {r['seed']} views {r['views']}: blank_psnr "
                f"{stored['blank_psnr']:.6f} stored, {base['blank_psnr']:.6f} from {data}: not the same images"
            )
        now = Health.from_dict({**stored, "mean_psnr": base["mean_psnr"]})
        out.append(
            {
                **{k: r[k] for k in ("scene", "engine", "seed", "views", "steps", "train_psnr")},
                "was_empty": bool(stored["empty"]),
                "health": now.to_dict(),
                "gain_over_mean_db": now.psnr - base["mean_psnr"],
            }
        )
    return out


def rejudge_main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(description="re-judge stored runs with today's health check")
    parser.add_argument("records", type=Path, help="a JSON file this script wrote")
    parser.add_argument("--data", type=Path, required=True, help="the prepared scene its runs trained on")
    parser.add_argument("--split", default=None)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    runs = rejudge(args.records, args.data, args.split)
    machine = {"machine": platform.processor() or platform.machine(), "date": date.today().isoformat()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({**machine, "records": str(args.records), "runs": runs}, indent=1) + "\n")
    for r in runs:
        h = r["health"]
        verdict = f"EMPTY ({h['reason']})" if h["empty"] else "ok"
        print(
            f"{r['scene']} {r['engine']} seed {r['seed']} views {r['views']}: PSNR {h['psnr']:.2f} dB, blank "
            f"{h['blank_psnr']:.2f}, mean colour {h['mean_psnr']:.2f} ({r['gain_over_mean_db']:+.2f}): {verdict}, "
            f"was {'EMPTY' if r['was_empty'] else 'ok'}"
        )


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
    if sys.argv[1:2] == ["rejudge"]:
        return rejudge_main(sys.argv[2:])
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
