"""The GPU study (docs/study-plan.md, "Plan of 2026-11-27: the GPU study"): the paper engine at 400 px
on the plan's scenes, grown by every GPU slot. Its design is `PLAN` below; its table is
docs/results/gpu-study-table.json and its page docs/results-gpu.md.

Three modes:

- `pack` (here, on the CPU machine): a prepared dataset folder (`nerfaug scene prepare` of a
  download, or a built-in scene rendered by `nerfaug scene render`) as one uncompressed tar under
  data/gpu-study/, with the digest of its files; refused over --max-mib (a device call carries at
  most 64 MiB, the repository included).
- `run` (on the GPU machine: no Blender, no network): unpack the packs it finds (the plan's scenes
  among them, in the plan's order), run the next runs that the committed table lacks, in trial
  batches, for at most --budget-s seconds (no run is started that would end later), and write
  every finished run's records and the table as it then stands into one archive under $OUT.
- `merge` (here): unpack such an archive, record its runs in the committed table
  (`nerfaug study --summary-only`) and regenerate the page.

    # here, once per scene (the README's "Real scenes" for the downloads):
    nerfaug scene prepare ~/downloads/mic --out data/real400/mic --width 400
    python benchmarks/gpu_study.py pack data/real400/mic
    # there (device tool; carry data/gpu-study and .whl, or use benchmarks/gpu_study.sh):
    python3 benchmarks/gpu_study.py run --budget-s 540 --archive $OUT/gpu-study.tar.gz
    # here, with what came back:
    python benchmarks/gpu_study.py merge gpu-study.tar.gz

`run` smoke-tests on the CPU through the same code with `--engine`, `--preset tiny` and
`--resolution` of a toy dataset (tests/benchmarks/test_gpu_study.py).
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
    """The next runs of the plan that the table lacks, within the budget; the archive of what finished."""
    from nerfaug.cli.study_work import record_table
    from nerfaug.device import configure_process
    from nerfaug.experiment.study import StudySpec, make_plan, run_study
    from nerfaug.report.study_table import read_table

    began = time.monotonic()
    configure_process(threads=args.threads)
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
        batch=args.batch,
    )
    plan = make_plan(spec, spec.command(), progress=False)
    print(f"GPU study: {', '.join(scenes)}; {args.budget_s:.0f} s for runs", flush=True)
    # One trial batch at a time, each archived when it ends: a call cut short keeps what finished.
    longest, units, failed, unstarted = 0.0, 0, {}, None
    while unstarted != 0:
        left = args.budget_s - (time.monotonic() - began)
        if units and left < 1.1 * longest:
            break
        start = time.monotonic()
        outcomes = run_study(plan, workers=1, table=previous, budget_s=1e-3, progress=not args.quiet)
        longest, units = max(longest, time.monotonic() - start), units + 1
        unstarted = sum(1 if o["unstarted"] is None else o["unstarted"] for o in outcomes.values())
        failed.update({f"{e}: {k}": why for e, o in outcomes.items() for k, why in o["failed"].items()})
        previous = record_table(spec.out, table_path, previous)
        if args.archive is not None:
            archive(args.work, args.archive)
    summary = {
        "scenes": scenes,
        "units": units,
        "longest_unit_s": longest,
        "failed": failed,
        "runs_left_in_plan": unstarted,
        "table_runs": len(previous["runs"]) if previous else 0,
        "wall_s": time.monotonic() - began,
    }
    (args.work / "study" / "gpu-call.json").write_text(json.dumps(summary, indent=2, default=str))
    if args.archive is not None:
        archive(args.work, args.archive)
        print(f"archive: {args.archive}")
    print(json.dumps(summary, default=str))
    return summary


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
    """Record an archive's runs in the committed table and regenerate the page."""
    into = args.work / "merge"
    if into.exists():
        raise SystemExit(f"{into}: exists; choose another --work folder")
    with tarfile.open(args.archive) as tar:
        tar.extractall(into, filter="data")
    from nerfaug.cli import main as nerfaug

    nerfaug(
        [
            "study", "--summary-only", "--out", str(into / "study"),
            "--table", str(args.table), "--results-doc", str(args.page),
        ]
    )  # fmt: skip


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
    # One trial's methods per batch: a unit of work is one seed-paired trial, and a call cut short
    # loses at most one.
    r.add_argument("--batch", type=int, default=len(PLAN["methods"]), help="runs per trial batch (0: auto)")
    r.add_argument("--threads", type=int, default=max(1, min(8, os.cpu_count() or 1)))
    r.add_argument("--quiet", action="store_true")
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
        return run(args)
    return merge(args)


if __name__ == "__main__":
    main()
