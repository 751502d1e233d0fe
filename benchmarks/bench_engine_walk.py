"""The engine walk (issue 30, item 1): from `nerfacto-cpu-last-sample` to `paper`, one group of
settings at a time, on the study's protocol at 100 px, to find which setting makes the paper
preset collapse.

Each entry of the walk is an engine variant (`BASE+FIELD=VALUE`, as `nerfaug study --engines`
takes them) trained on the protocol: the dataset's 6 initial views, 6 views added at
`--add-at` (uniform selection, seeded), `--steps` steps in all. For each (entry, seed) it records
the PSNR on the 12 training views, on `--holdout` train-pool views that were neither initial nor
chosen (the number to choose by: never the test split), on `--n-test` test views, the mean
accumulation (opacity) of the training renders on object and on background pixels, and the
seconds; for seed 0 it writes a small PNG of test view 0 (render | ground truth) and of its
accumulation.

    python benchmarks/bench_engine_walk.py --data data/lego100 --out docs/benchmarks/walk
    python benchmarks/bench_engine_walk.py --data data/lego100 --out docs/benchmarks/walk \
        --entries hash-table-only hash-resolution-only      # probes inside a group
    python benchmarks/bench_engine_walk.py --quick --data DIR --out /tmp/walk   # smoke run

Results are appended to `OUT/walk.json` one run at a time; a run already there is skipped, so a
walk stopped part-way resumes (and one process at a time can walk on a shared machine).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

try:  # a GPU machine runs this from a checkout, without installing the package
    import nerfaug  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

START = "nerfacto-cpu-last-sample"

# The walk: each group of settings that differs between the two presets, applied cumulatively in
# this order (cheapest on a CPU first, so that the walk stops early if an early group collapses).
# The groups the issue names that are not here are the same in both presets (density activation
# and initial density, learning rates and their schedule), which
# `check_walk_reaches_paper` verifies: the last entry is the paper preset itself.
GROUPS: list[tuple[str, str, dict[str, str]]] = [
    ("start", "nerfacto-cpu-last-sample", {}),
    (
        "hash-capacity",
        "hash grid: 16 levels, 2^19 entries, finest resolution 2048",
        {"hash_levels": "16", "hash_log2_table_size": "19", "hash_max_resolution": "2048"},
    ),
    ("mlp-widths", "density and colour MLPs 64 wide", {"hidden_dim": "64", "color_hidden_dim": "64"}),
    (
        "proposal-schedule",
        "proposal networks updated on nerfacto's schedule (every 5 after a 5000-step warm-up)",
        {"proposal_update_every": "5", "proposal_warmup_steps": "5000"},
    ),
    (
        "samples-proposals",
        "48 samples; proposal samples 256/96; proposal grids 5 levels, 2^17, up to 128/256",
        {
            "num_samples": "48",
            "proposal_samples": "256,96",
            "proposal_hash_levels": "5",
            "proposal_max_resolutions": "128,256",
            "proposal_log2_table_size": "17",
        },
    ),
    ("rays-per-step", "4096 rays a step", {"batch_size": "4096"}),
    ("background", "the fixed white background (the paper preset's since 2026-11-26)", {"background_mode": "fixed"}),
]

# Probes: single settings (or a group with one change), run by name with --entries, to bisect
# inside the group where the walk collapses, or to test the cause named.
PROBES: dict[str, tuple[str, dict[str, str]]] = {
    "hash-levels-only": ("start + 16 hash levels (table 2^14, finest 256)", {"hash_levels": "16"}),
    "hash-table-only": ("start + 2^19 hash entries per level", {"hash_log2_table_size": "19"}),
    "hash-resolution-only": ("start + finest hash resolution 2048", {"hash_max_resolution": "2048"}),
    "hash-table-resolution": (
        "start + 2^19 entries and finest resolution 2048 (6 levels)",
        {"hash_log2_table_size": "19", "hash_max_resolution": "2048"},
    ),
    "hash-capacity-fixed-bg": (
        "hash-capacity with the fixed white background instead of last_sample",
        {
            "hash_levels": "16",
            "hash_log2_table_size": "19",
            "hash_max_resolution": "2048",
            "background_mode": "fixed",
        },
    ),
    "start-fixed-bg": ("start with the fixed white background (= nerfacto-cpu)", {"background_mode": "fixed"}),
}
# The end of the walk (the paper preset) with another background: a probe whose settings are
# the whole walk's plus one change, run where the full preset is affordable (a GPU). The walk's
# step before "background" is the paper preset with nerfacto's "last_sample" as this engine
# defines it (the box exit); this is nerfacto's definition to the letter.
END_PROBES: dict[str, tuple[str, dict[str, str]]] = {
    "paper-last-composited-bg": (
        "the paper preset with nerfacto's own last_sample (the last composited sample's colour)",
        {"background_mode": "last_composited"},
    ),
}


def walk_entries() -> list[tuple[str, str, str]]:
    """(name, what changed, engine variant) of each walk step, cumulative."""
    entries, settings = [], {}
    for name, what, changes in GROUPS:
        settings = {**settings, **changes}
        entries.append((name, what, variant(settings)))
    return entries


def variant(settings: dict[str, str]) -> str:
    """The engine name of `START` with `settings` changed (`BASE+FIELD=VALUE...`)."""
    return "+".join([START, *(f"{k}={v}" for k, v in settings.items())])


def all_entries() -> dict[str, tuple[str, str]]:
    """Every runnable entry: name -> (what changed, engine variant)."""
    out = {name: (what, engine) for name, what, engine in walk_entries()}
    out.update({name: (what, variant(changes)) for name, (what, changes) in PROBES.items()})
    whole_walk = {key: value for _, _, changes in GROUPS for key, value in changes.items()}
    out.update({name: (what, variant({**whole_walk, **changes})) for name, (what, changes) in END_PROBES.items()})
    return out


def check_walk_reaches_paper() -> None:
    """The walk's last step must be the paper preset, setting for setting."""
    from nerfaug.nerf.config import NerfConfig

    last = NerfConfig.preset(walk_entries()[-1][2])
    if last != NerfConfig.preset("paper"):
        paper = NerfConfig.preset("paper").flat()
        differ = {k: (v, paper[k]) for k, v in last.flat().items() if paper[k] != v}
        raise AssertionError(f"the walk does not end at the paper preset: {differ}")


def keep_freed_memory() -> None:
    """Ask glibc to keep freed memory instead of returning it to the system. The full-size hash
    grid's dense gradients (16 x 2^19 x 2 floats) are allocated and freed every step; glibc
    serves allocations that large with fresh mmaps, and the page faults of ~400 MB a step doubled
    the CPU time of a step (measured: 0.55 -> 0.27 s/step, 97k -> 0 minor faults a step). The
    numbers computed are unchanged: only where the memory comes from."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if name is None:
        return
    libc = ctypes.CDLL(name)
    if hasattr(libc, "mallopt"):
        libc.mallopt(-4, 0)  # M_MMAP_MAX: no mmapped chunks
        libc.mallopt(-1, 2**31 - 1)  # M_TRIM_THRESHOLD: never trim the heap


def render_on_cpu(model, views, index: int) -> dict[str, torch.Tensor]:
    """`model.render_image` of view `index`, its maps moved to the CPU (where the views are)."""
    return {key: value.cpu() for key, value in model.render_image(views.cameras, index).items()}


def view_metrics(model, views) -> tuple[float, dict[str, float | None]]:
    """Mean PSNR of the renders of `views`, and their mean opacity (accumulation) on object
    pixels (alpha > 0.5) and on background pixels (None without alphas). A NeRF that paints its
    training images onto the "last sample" backdrop at the far end of the rays, instead of
    building the object, has a low opacity on the object."""
    from nerfaug.evaluation import psnr

    values, obj, bg = [], [], []
    with torch.no_grad():
        for i in range(len(views)):
            out = render_on_cpu(model, views, i)
            values.append(float(psnr(out["rgb"].clamp(0, 1), views.images[i])))
            if views.alphas is not None:
                mask = views.alphas[i] > 0.5
                obj.append(float(out["accumulation"][mask].mean()))
                bg.append(float(out["accumulation"][~mask].mean()))
    opacity = {"object": sum(obj) / len(obj) if obj else None, "background": sum(bg) / len(bg) if bg else None}
    return sum(values) / len(values), opacity


def save_render(model, views, index: int, path: Path) -> None:
    """render | ground truth | accumulation of view `index`, one small PNG."""
    from PIL import Image

    with torch.no_grad():
        out = render_on_cpu(model, views, index)
    acc = out["accumulation"].clamp(0, 1)[..., None].expand(-1, -1, 3)
    row = torch.cat([out["rgb"].clamp(0, 1), views.images[index], acc], dim=1)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray((row * 255).round().to(torch.uint8).numpy()).save(path, optimize=True)


def run_one(
    data, engine: str, seed: int, steps: int, add_at: int, holdout: int, render_path: Path | None, device: str = "cpu"
) -> dict:
    from nerfaug.device import synchronize
    from nerfaug.experiment.config import ExperimentConfig
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer
    from nerfaug.selection import select_views

    config = NerfConfig.preset(engine)
    n_new = ExperimentConfig().n_new
    wall, cpu = time.perf_counter(), time.process_time()
    trainer = Trainer(data.initial, config, seed=seed, device=device, progress=False)
    trainer.train(min(add_at, steps))
    selection = select_views(
        "uniform",
        trainer.model,
        trainer.train_views.cameras,
        data.pool.cameras,
        n_new,
        torch.Generator().manual_seed(seed),
    )
    chosen = [int(i) for i in selection.indices]
    trainer.add_views(data.pool.subset(chosen))
    trainer.train(steps)
    synchronize(torch.device(device))
    train_seconds, train_cpu = time.perf_counter() - wall, time.process_time() - cpu
    model = trainer.model
    rest = [i for i in range(len(data.pool)) if i not in set(chosen)]
    held = data.pool.subset(rest[:: max(1, len(rest) // holdout)][:holdout]) if holdout else None
    train_psnr, train_opacity = view_metrics(model, trainer.train_views)
    test_psnr, test_opacity = view_metrics(model, data.test)
    result = {
        "engine": engine,
        "seed": seed,
        "steps": steps,
        "chosen": chosen,
        "train_psnr": train_psnr,
        "holdout_psnr": view_metrics(model, held)[0] if held is not None else None,
        "test_psnr": test_psnr,
        "accumulation": train_opacity,
        "test_accumulation": test_opacity,
        "last_batch_psnr": trainer.history[-1]["psnr"],
        "train_seconds": train_seconds,
        "train_cpu_seconds": train_cpu,
        "seconds_per_step": train_seconds / steps,
    }
    if render_path is not None:
        save_render(model, data.test, 0, render_path)
        result["render"] = render_path.name
    return result


def load_data(folder: Path, n_test: int, resolution: int):
    from nerfaug.experiment.config import ExperimentConfig
    from nerfaug.experiment.protocol import load_scene_data

    return load_scene_data(folder, ExperimentConfig(n_test=n_test, resolution=resolution))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="Blender-format dataset folder with an initial split")
    parser.add_argument("--out", type=Path, required=True, help="folder for walk.json and the renders")
    parser.add_argument("--entries", nargs="*", help="walk steps or probes to run (default: the walk, in order)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--add-at", type=int, default=200)
    parser.add_argument("--n-test", type=int, default=20)
    parser.add_argument("--holdout", type=int, default=10)
    parser.add_argument("--resolution", type=int, default=100)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--device", default="cpu", help="cpu or cuda (GPU runs are not bit-reproducible)")
    parser.add_argument(
        "--stop-below",
        type=float,
        default=None,
        help="stop the walk after the first step whose mean held-out PSNR is this many dB below the start's",
    )
    parser.add_argument("--quick", action="store_true", help="smoke run: 2 walk steps, 40 steps, 1 seed, 2 views")
    parser.add_argument("--list", action="store_true", help="print the entries and their engine names, then exit")
    args = parser.parse_args(argv)
    check_walk_reaches_paper()
    entries = all_entries()
    if args.list:
        for name, (what, engine) in entries.items():
            print(f"{name}: {what}\n    {engine}")
        return
    names = args.entries or [name for name, _, _ in walk_entries()]
    if args.quick:
        names, args.seeds, args.steps, args.add_at, args.n_test, args.holdout = names[:2], [0], 40, 20, 2, 2
    unknown = [n for n in names if n not in entries]
    if unknown:
        parser.error(f"unknown entries {unknown}; known: {', '.join(entries)}")

    from nerfaug.device import configure_process

    configure_process(threads=args.threads)
    keep_freed_memory()
    data = load_data(args.data, args.n_test, args.resolution)
    args.out.mkdir(parents=True, exist_ok=True)
    table_path = args.out / "walk.json"
    table = json.loads(table_path.read_text()) if table_path.exists() else {"runs": []}
    table["protocol"] = {
        "data": str(args.data),
        "resolution": args.resolution,
        "initial_views": len(data.initial),
        "added_views": f"6 (uniform) at step {args.add_at}",
        "steps": args.steps,
        "test_views": len(data.test),
        "holdout_views": args.holdout,
        "threads": args.threads,
        "device": args.device,
    }
    table["entries"] = {name: {"what": what, "engine": engine} for name, (what, engine) in entries.items()}
    done = {(r["name"], r["seed"], r["steps"], r.get("device", "cpu")) for r in table["runs"]}
    start_holdout = None
    for name in names:
        what, engine = entries[name]
        for seed in args.seeds:
            if (name, seed, args.steps, args.device) in done:
                print(f"{name} seed {seed}: already in {table_path}", file=sys.stderr)
                continue
            render = args.out / f"{name}-seed{seed}-test0.png" if seed == args.seeds[0] else None
            run = run_one(data, engine, seed, args.steps, args.add_at, args.holdout, render, args.device)
            result = {"name": name, "device": args.device, **run}
            table["runs"].append(result)
            table_path.write_text(json.dumps(table, indent=1) + "\n")
            print(
                f"{name} seed {seed}: train {result['train_psnr']:.2f} held-out {result['holdout_psnr']} "
                f"test {result['test_psnr']:.2f} dB, opacity object {result['accumulation']['object']}, "
                f"{result['seconds_per_step'] * 1000:.0f} ms/step",
                file=sys.stderr,
                flush=True,
            )
        runs = [
            r for r in table["runs"] if r["name"] == name and r["steps"] == args.steps and r["holdout_psnr"] is not None
        ]
        held = sum(r["holdout_psnr"] for r in runs) / len(runs) if runs else None
        if name == "start":
            start_holdout = held
        if (
            args.stop_below is not None
            and start_holdout is not None
            and held is not None
            and held < start_holdout - args.stop_below
        ):
            print(
                f"stopping: {name} is {start_holdout - held:.2f} dB below the start on held-out views", file=sys.stderr
            )
            break


if __name__ == "__main__":
    main()
