"""The GPU study (docs/study-plan.md, "Plan of 2026-11-27: the GPU study"): the paper engine at 400 px
on the plan's scenes, grown by every GPU slot. Its design is `PLAN` below; its table is
docs/results/gpu-study-table.json and its page docs/results-gpu.md.

Three modes:

- `pack` (here, on the CPU machine): a prepared dataset folder (`nerfaug scene prepare` of a
  download, or a built-in scene rendered by `nerfaug scene render`) as one uncompressed tar under
  data/gpu-study/, with the digest of its files; refused over --max-mib (a device call carries at
  most 64 MiB, the repository included).
- `run` (on the GPU machine: no Blender, no network): unpack the packs it finds (the plan's scenes
  among them, in the plan's order), measure this machine at the study's size (a few training
  steps alone and in a trial batch, one test view), then run the plan's next runs that the
  committed table lacks, in the plan's order (ours and uniform on a scene first), each batch as
  many runs as the memory holds and the time left fits, until --budget-s; the archive under $OUT
  (every finished run's records, the table, gpu-call.json: what was measured and why the call
  stopped) is re-written after each batch. `--toy DIR` first makes a toy scene (the CPU mode).
- `merge` (here): unpack such an archive, record its runs in the committed table
  (`nerfaug study --summary-only`) and regenerate the page; a cell whose runs would mix engine
  versions is refused.

    # here, once per scene (the README's "Real scenes" for the downloads):
    nerfaug scene prepare ~/downloads/mic --out data/real400/mic --width 400
    python benchmarks/gpu_study.py pack data/real400/mic
    # there (device tool; carry data/gpu-study and .whl, or use benchmarks/gpu_study.sh):
    python3 benchmarks/gpu_study.py run --budget-s 540 --archive $OUT/gpu-study.tar.gz
    # here, with what came back:
    python benchmarks/gpu_study.py merge gpu-study.tar.gz

`DEVICE=cpu bash benchmarks/gpu_study.sh` runs the same code on the CPU with a toy scene, a small
engine and `--preset tiny` (tests/benchmarks/test_gpu_study.py).
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
import tarfile
import time
from pathlib import Path

try:  # the GPU machine runs this from a checkout, without installing the package
    import nerfaug  # noqa: F401
except ImportError:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

ROOT = Path(__file__).resolve().parents[1]
PACKS = ROOT / "data" / "gpu-study"
TABLE = ROOT / "docs" / "results" / "gpu-study-table.json"
PAGE = ROOT / "docs" / "results-gpu.md"
MANIFEST = "gpu-study-pack.json"


def _plan() -> dict:
    from nerfaug.experiment.study import GPU_STUDY_ENGINES, GPU_STUDY_HELD_BACK, GPU_STUDY_SCENES

    return {
        # Written before the first run (docs/study-plan.md); a change is a dated amendment there.
        "engines": GPU_STUDY_ENGINES,
        "scenes": GPU_STUDY_SCENES,
        "held_back": GPU_STUDY_HELD_BACK,
        "methods": ("uniform", "ours", "ours-batch-sharp", "fisherrf", "entropy-sampling", "furthest"),
        "trials": 10,
        "layouts": 3,
        "resolution": 400,
        "steps": 10_000,
        "preset": "gpu",
    }


PLAN = _plan()


def folder_digest(folder: Path) -> str:
    """sha256 over every file of `folder` but the pack's manifest (relative path and bytes,
    sorted): the pack's identity."""
    digest = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST):
        digest.update(path.relative_to(folder).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def pack(folder: Path, out: Path | None = None, scene: str | None = None, max_mib: float = 60.0) -> dict:
    """`folder` (a prepared dataset) as one tar `out` (default data/gpu-study/<scene>.tar)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SystemExit(f"{folder}: not a dataset folder")
    scene = scene or folder.name
    out = Path(out) if out is not None else PACKS / f"{scene}.tar"
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    size = sum(p.stat().st_size for p in files)
    if size > max_mib * 2**20:
        raise SystemExit(
            f"{folder}: {size / 2**20:.1f} MiB of files, over --max-mib {max_mib:g}: prepare it at a smaller "
            "--width, or carry it alone"
        )
    manifest = {"scene": scene, "digest": folder_digest(folder), "files": len(files), "mib": size / 2**20}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with tarfile.open(tmp, "w") as tar:
        for path in files:
            tar.add(path, arcname=f"{scene}/{path.relative_to(folder).as_posix()}")
        data = json.dumps(manifest, indent=2).encode()
        info = tarfile.TarInfo(f"{scene}/{MANIFEST}")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
    os.replace(tmp, out)
    print(f"{out}: {scene}, {len(files)} files, {size / 2**20:.1f} MiB, digest {manifest['digest'][:12]}")
    return manifest | {"pack": str(out)}


def unpack(packs: Path, into: Path) -> dict[str, Path]:
    """Every pack in `packs` unpacked under `into` (links and paths out of it refused); scene ->
    its dataset folder, checked against the digest it was packed with."""
    found = {}
    for archive in sorted(Path(packs).glob("*.tar")):
        with tarfile.open(archive) as tar:
            tar.extractall(into, filter="data")
            scenes = {Path(name).parts[0] for name in tar.getnames()}
        for scene in sorted(scenes):
            folder = Path(into) / scene
            manifest = json.loads((folder / MANIFEST).read_text())
            if folder_digest(folder) != manifest["digest"]:
                raise SystemExit(f"{archive}: the files of {scene} do not match the digest they were packed with")
            found[manifest["scene"]] = folder
    return found


def run(args) -> dict:
    """The next runs of the plan that the table lacks, in the plan's order, as many as fit the
    budget; the archive of what finished, re-written after each batch."""
    from nerfaug.cli.study_work import record_table
    from nerfaug.device import configure_process
    from nerfaug.experiment.study import EngineSweep, StudySpec, gpu_study_order, make_plan
    from nerfaug.report.study_table import read_table

    began = time.monotonic()
    deadline = began + args.budget_s
    configure_process(threads=args.threads)
    if args.toy is not None:
        toy(args.toy, args.packs)
    datasets = unpack(args.packs, args.work / "data")
    scenes = [s for s in PLAN["scenes"] if s in datasets] + sorted(set(datasets) - set(PLAN["scenes"]))
    if not scenes:
        raise SystemExit(f"{args.packs}: no packs (make them here with `gpu_study.py pack`)")
    table_path = args.work / "gpu-study-table.json"
    if args.table.is_file():
        table_path.write_bytes(args.table.read_bytes())
    previous = read_table(table_path) if table_path.is_file() else None
    methods = PLAN["methods"] if args.methods is None else tuple(args.methods)
    # The held-back scene runs only once every other planned cell is complete (the plan's order).
    waiting = [s for s in PLAN["scenes"] if s not in PLAN["held_back"] and not _complete(previous, s, args, methods)]
    if waiting:
        held = [s for s in scenes if s in PLAN["held_back"]]
        if held:
            print(f"held back until {', '.join(waiting)} are complete: {', '.join(held)}")
        scenes = [s for s in scenes if s not in held]
        if not scenes:
            raise SystemExit("only held-back scenes were carried; carry the packs of the scenes still running")
    most = args.batch or (_memory_batch(args) if args.device != "cpu" else 2)
    spec = StudySpec(
        out=args.work / "study",
        engines=(args.engine,),
        scenes=tuple(str(datasets[s]) for s in scenes),
        methods=methods,
        trials=args.trials,
        resolution=args.resolution,
        layouts=args.layouts,
        steps=args.steps,
        device=args.device,
        preset=args.preset,
        table=table_path,
        # The units' sizes are the scheduler's (`EngineSweep.run`); a batch's size changes no number.
        batch=max(1, most),
    )
    plan = make_plan(spec, spec.command(), progress=False)
    sweep = EngineSweep(plan, args.engine, previous)
    names = [Path(datasets[s]).resolve().name for s in scenes]
    todo = [k for k in gpu_study_order(names, methods, plan.config.trials) if sweep.pending(k)]
    summary = {"scenes": scenes, "device": args.device, "budget_s": args.budget_s, "max_batch": most,
               "batches": [], "finished": 0, "failed": {}}  # fmt: skip
    print(f"GPU study: {', '.join(scenes)}; {len(todo)} runs to go; {args.budget_s:.0f} s in all", flush=True)
    if todo and deadline - time.monotonic() < args.margin_s:
        summary["stopped"] = (
            f"{len(todo)} runs to go; {max(0.0, deadline - time.monotonic()):.0f} s of the budget were left after "
            f"start-up, under the {args.margin_s:.0f} s kept back: nothing measured, no run started"
        )
        print("stopped: " + summary["stopped"], flush=True)
        todo_left = todo
        todo = []
    else:
        todo_left = None
    if todo:
        model = measure(sweep, todo[0], most, args)
        summary["measured"] = model.to_dict()
        single = model.predict([todo[0].method])
        left = deadline - time.monotonic()
        summary["single_run_s"] = single
        print(f"measured: {_rates(model, most)}; a single run about {single:.0f} s; {left:.0f} s left", flush=True)
        if single * args.margin > args.budget_s:
            summary["cannot_fit"] = (
                f"a single run at this size takes about {single:.0f} s, more than a whole call's "
                f"{args.budget_s:.0f} s: "
                "no run can finish in one call; a run split across calls would have to carry its trial batch's "
                "models and optimiser state, " + _checkpoint_size(sweep) + ", over the 64 MiB a call carries"
            )
            print(summary["cannot_fit"], flush=True)
        if args.measure_only:
            summary["stopped"], todo_left, todo = "measured only (--measure-only)", todo, []
    while todo:
        left = deadline - time.monotonic() - args.margin_s
        unit = _one_config(sweep, todo)
        n = model.fits([k.method for k in unit], left, most, args.margin)
        if n == 0:
            summary["stopped"] = (
                f"{len(todo)} runs left; the next ({todo[0]}) needs about {model.predict([todo[0].method]):.0f} s "
                f"(x{args.margin:g} and {args.margin_s:.0f} s kept), {max(0.0, left + args.margin_s):.0f} s were left"
            )
            print("stopped: " + summary["stopped"], flush=True)
            break
        unit, todo = unit[:n], [k for k in todo if k not in unit[:n]]
        predicted, start = model.predict([k.method for k in unit]), time.monotonic()
        print(f"batch of {n}: {', '.join(map(str, unit))} (about {predicted:.0f} s)", flush=True)
        outcomes = sweep.run(unit)
        results = [o for o in outcomes.values() if isinstance(o, dict)]
        summary["failed"].update({str(k): o for k, o in outcomes.items() if isinstance(o, str)})
        summary["finished"] += len(results)
        previous = record_table(sweep.root.parent, table_path, previous) if results else previous
        wall = time.monotonic() - start
        summary["batches"].append({"runs": [str(k) for k in unit], "finished": len(results), "predicted_s": predicted,
                                   "wall_s": wall})  # fmt: skip
        model.learn(results, wall)
        _write_summary(args, summary, began, todo, previous)
        print(f"  {len(results)} of {n} finished in {wall:.0f} s", flush=True)
    todo = todo_left if todo_left is not None else todo
    if summary["finished"] == 0 and "stopped" not in summary and todo:
        summary["stopped"] = "no run finished (see failed)"
    _write_summary(args, summary, began, todo, previous)
    if args.archive is not None:
        print(f"archive: {args.archive}")
    print(json.dumps({k: v for k, v in summary.items() if k not in ("batches", "measured")}, default=str))
    return summary


def _write_summary(args, summary: dict, began: float, todo: list, previous: dict | None) -> None:
    """gpu-call.json (what this call did and why it stopped) and the archive, as they now stand."""
    summary.update(
        runs_left_in_plan=len(todo),
        table_runs=len(previous["runs"]) if previous else 0,
        wall_s=time.monotonic() - began,
    )
    path = args.work / "study" / "gpu-call.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(summary, indent=2, default=str))
    if args.archive is not None:
        archive(args.work, args.archive)


def _one_config(sweep, todo: list) -> list:
    """The head of `todo` that trains under one engine configuration (a scene with its own field
    learning rate trains apart): what one trial batch may hold."""
    first = repr(sweep.config.engine_config(todo[0].scene))
    head = []
    for key in todo:
        if repr(sweep.config.engine_config(key.scene)) != first:
            break
        head.append(key)
    return head


def _memory_batch(args) -> int:
    """Runs a trial batch may hold on this GPU, by its free memory (`auto_batch_size`)."""
    from nerfaug.nerf.batch_size import auto_batch_size
    from nerfaug.nerf.engine import Engine

    size, text = auto_batch_size(Engine.read(args.engine).config, args.device, 10**6)
    print(text, flush=True)
    return size


def measure(sweep, key, most: int, args):
    """This machine's times at the study's size (the smoke part of a call): a trial batch of one
    run and one of `most` runs of `key`'s scene trained `--probe-steps` steps after a warm-up,
    one test view rendered and scored; a `TimeModel` from them."""
    import torch

    from nerfaug.evaluation import psnr
    from nerfaug.experiment.budget import TimeModel
    from nerfaug.experiment.protocol import load_scene_data
    from nerfaug.nerf.trainer import Trainer

    def sync():
        if sweep.config.device == "cuda" or str(sweep.config.device).startswith("cuda"):
            torch.cuda.synchronize()

    start = time.monotonic()
    data = load_scene_data(sweep.datasets[key.scene], sweep.config, layout=0)
    setup = time.monotonic() - start
    engine = sweep.config.engine_config(key.scene)
    step_s, warm = {}, max(2, args.probe_steps // 4)
    for n in sorted({1, most}):
        trainer = Trainer([data.initial] * n, engine, list(range(n)), sweep.config.device, progress=False)
        trainer.train(warm)
        sync()
        start = time.monotonic()
        trainer.train(warm + args.probe_steps)
        sync()
        step_s[n] = (time.monotonic() - start) / args.probe_steps
    model = trainer.runs[0].model
    start = time.monotonic()
    with torch.no_grad():
        render = model.render_image(data.test.cameras, 0)["rgb"].clamp(0, 1)
        psnr(render, data.test.image(0).to(render.device))
    sync()
    view_s = (time.monotonic() - start) * 1.2  # LPIPS and SSIM besides the PSNR
    del trainer, model
    if torch.cuda.is_available():
        torch.cuda.empty_cache()
    # Before any run finished, a selection is allowed what scoring a tenth of the test views takes.
    return TimeModel(
        steps=sweep.config.steps,
        n_test=len(data.test),
        step_s=step_s,
        view_s=view_s,
        overhead_s=setup + 2.0,
        default_select_s=max(2.0, 0.1 * len(data.test) * view_s),
    )


def _rates(model, most: int) -> str:
    sizes = sorted({1, most})
    steps = ", ".join(f"{model.step_seconds(n):.4f} s a step with {n} run(s) in a batch" for n in sizes)
    return f"{steps}, {model.view_s:.3f} s a test view"


def _checkpoint_size(sweep) -> str:
    """What one run's training state weighs (parameters and Adam's two moments, float32)."""
    from nerfaug.nerf.model import NerfModel

    model = NerfModel(sweep.config.engine_config(sweep.config.scenes[0]))
    n = sum(p.numel() for p in model.parameters())
    return f"{n * 12 / 2**20:.0f} MiB a run ({n / 1e6:.1f} M parameters with Adam's two moments)"


def _complete(table: dict | None, scene: str, args, methods) -> bool:
    """Whether `table` holds every run of the plan's cell (engine, scene) for `methods`."""
    done = {
        (r["method"], r["trial"])
        for r in (table or {}).get("runs", [])
        if r["scene"] == scene and r["engine"] == args.engine
    }
    return all((m, t) in done for m in methods for t in range(args.trials))


def archive(work: Path, out: Path) -> Path:
    """The study folder's records (every .json: study.json, sweeps, each run's result, selection,
    metrics, history, config) and the table, as one .tar.gz, small enough to come back."""
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    with tarfile.open(tmp, "w:gz") as tar:
        for path in sorted((work / "study").rglob("*")):
            parts = set(path.relative_to(work).parts)
            if path.is_file() and (path.suffix == ".json" or path.name == ".nerfaug") and "datasets" not in parts:
                tar.add(path, arcname=str(path.relative_to(work)))
        if (work / "gpu-study-table.json").is_file():
            tar.add(work / "gpu-study-table.json", arcname="gpu-study-table.json")
    os.replace(tmp, out)
    return out


def merge(args) -> None:
    """Record an archive's runs in the committed table and regenerate the page. Refused when a
    cell (engine, scene) would hold runs of more than one engine version; an archive without a
    finished run is reported (its call's record says why) and changes nothing."""
    into = args.work / "merge"
    if into.exists():
        raise SystemExit(f"{into}: exists; choose another --work folder")
    with tarfile.open(args.archive) as tar:
        tar.extractall(into, filter="data")
    # A run's engine is its sweep's folder: study/<engine>/...
    results = [
        json.loads(p.read_text()) | {"engine": p.relative_to(into / "study").parts[0]}
        for p in sorted((into / "study").rglob("result.json"))
    ]
    call = into / "study" / "gpu-call.json"
    if not results:
        why = json.loads(call.read_text()).get("stopped", "") if call.is_file() else "no record of the call"
        print(f"{args.archive}: no finished run; nothing merged. The call's record: {why}")
        return
    table = json.loads(args.table.read_text()) if args.table.is_file() else {"runs": []}
    check_versions(table.get("runs", []), results, args.archive)
    from nerfaug.cli import main as nerfaug

    nerfaug(
        [
            "study", "--summary-only", "--out", str(into / "study"),
            "--table", str(args.table), "--results-doc", str(args.page),
            # The plan's hypotheses G1-G4, also for a toy table whose engine and scenes are not the plan's.
            "--hypotheses", "gpu",
        ]
    )  # fmt: skip


def check_versions(recorded: list[dict], results: list[dict], source) -> None:
    """Refuse (SystemExit naming the cell and the versions) runs that would put more than one
    engine version in a cell (engine, scene) of the table: the plan compares methods within one
    engine version only. `recorded`: the table's runs; `results`: an archive's result.json
    records with their "engine"."""
    versions: dict[tuple, set] = {}
    for run in [*recorded, *results]:
        versions.setdefault((run["engine"], run["scene"]), set()).add(run.get("engine_version"))
    mixed = {cell: found for cell, found in versions.items() if len(found) > 1}
    if mixed:
        (engine, scene), found = next(iter(mixed.items()))
        names = ", ".join(sorted(v or "the reference engine (none recorded)" for v in found))
        raise SystemExit(
            f"{source}: the cell {engine}/{scene} would hold runs of engine versions {names}; a cell never mixes "
            "versions (docs/study-plan.md): nothing merged"
        )


def toy(out: Path, packs: Path) -> dict:
    """A toy scene made here without Blender or a download (an analytic sphere coloured by its
    normal, on white: 3 initial, 12 train and 4 test views of 24 px), packed as a study scene:
    what the CPU mode of `gpu_study.sh` runs."""
    import torch

    from nerfaug.data import write_blender_split
    from nerfaug.hemisphere import half_hemisphere_poses, sample_uniform_poses
    from nerfaug.scenes.sphere import sphere_views as views

    out = Path(out)
    write_blender_split(out, "initial", views(half_hemisphere_poses(3), "i"))
    write_blender_split(out, "train", views(sample_uniform_poses(12, torch.Generator().manual_seed(0)), "r"))
    write_blender_split(out, "test", views(sample_uniform_poses(4, torch.Generator().manual_seed(1)), "t"))
    return pack(out, Path(packs) / f"{out.name}.tar")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = p.add_subparsers(dest="mode", required=True)
    k = sub.add_parser("pack", help="a prepared dataset folder as one tar under data/gpu-study/")
    k.add_argument("folder", type=Path)
    k.add_argument("--scene", help="its name in the study (default: the folder's name)")
    k.add_argument("--out", type=Path, help="the pack (default data/gpu-study/<scene>.tar)")
    k.add_argument("--max-mib", type=float, default=60.0)
    r = sub.add_parser("run", help="the next runs the table lacks, within --budget-s (the GPU machine)")
    r.add_argument("--packs", type=Path, default=PACKS)
    r.add_argument("--work", type=Path, default=Path("/tmp/gpu-study"))
    r.add_argument("--table", type=Path, default=TABLE, help="the committed table (read; a copy is updated)")
    r.add_argument("--budget-s", type=float, default=540.0)
    r.add_argument("--archive", type=Path, help="write the finished runs' records here (.tar.gz)")
    r.add_argument("--device", default="cuda")
    r.add_argument("--engine", default=PLAN["engines"][0])
    r.add_argument("--preset", default=PLAN["preset"], help="the study protocol (tiny: a smoke test)")
    r.add_argument("--resolution", type=int, default=PLAN["resolution"])
    r.add_argument("--steps", type=int, default=PLAN["steps"])
    r.add_argument("--trials", type=int, default=PLAN["trials"])
    r.add_argument("--methods", nargs="+")
    r.add_argument("--layouts", type=int, default=PLAN["layouts"])
    r.add_argument(
        "--batch",
        type=int,
        default=0,
        help="the most runs in a trial batch (0: what the GPU's memory holds; 2 on a CPU)",
    )
    r.add_argument("--margin", type=float, default=1.15, help="a batch starts when this times its predicted time fits")
    r.add_argument("--margin-s", type=float, default=20.0, help="seconds kept back at the end (records, archive)")
    r.add_argument("--probe-steps", type=int, default=40, help="training steps timed by the measurement")
    r.add_argument("--measure-only", action="store_true", help="measure this machine's times, run nothing")
    r.add_argument("--toy", type=Path, help="first make the toy scene here and pack it into --packs (the CPU mode)")
    r.add_argument("--threads", type=int, default=max(1, min(8, os.cpu_count() or 1)))
    r.add_argument("--quiet", action="store_true")
    t = sub.add_parser("toy", help="a toy scene made here (no Blender, no download), packed: the CPU mode's")
    t.add_argument("--out", type=Path, required=True, help="the dataset folder to write (its name is the scene's)")
    t.add_argument("--packs", type=Path, default=PACKS)
    m = sub.add_parser("merge", help="record an archive's runs in the committed table; regenerate the page")
    m.add_argument("archive", type=Path)
    m.add_argument("--work", type=Path, default=Path("/tmp/gpu-study-merge"))
    m.add_argument("--table", type=Path, default=TABLE)
    m.add_argument("--page", type=Path, default=PAGE)
    return p


def main(argv: list[str] | None = None):
    args = parser().parse_args(argv)
    if args.mode == "pack":
        return pack(args.folder, args.out, args.scene, args.max_mib)
    if args.mode == "run":
        from nerfaug.nerf.engine import Engine

        args.engine = Engine.read(args.engine).cell_name()  # the study's cell and table name it so
        return run(args)
    if args.mode == "toy":
        return toy(args.out, args.packs)
    return merge(args)


if __name__ == "__main__":
    main()
