"""An engine version's acceptance on the CPU by paired seeds: the study protocol's runs of one
engine against recorded runs of another, seed by seed, by the planned TOST (docs/study-plan.md,
"acceptance of a new CPU engine version").

Each arm is one sweep of the study protocol (`nerfaug.experiment.config.STUDY_PRESETS["study"]`:
100 px, 6 initial views, 6 added at step 200, 2000 steps, 50 test views) over the given datasets
and seeds. Run k of every arm shares its seed, its initial views and (with "uniform") its added
views, so d = PSNR(one arm) - PSNR(other) isolates the engine. Modes:

- default: runs alone against the same runs in batches of `--batch` (throughput side by side; a
  batch computes each run as alone, so d is 0 unless the engine's batches change a number);
- `--candidate-against ARMS.json`: today's default engine alone against the recorded runs alone;
- `--nudged-against ARMS.json`: the rounding null, the reference engine with a nudge (`--nudge`);
- `--check-against ARMS.json`: whether today's engine reproduces recorded runs to every digit.

    python benchmarks/bench_batch_cpu.py --data data/lego100 data/chair100 --trials 10 \\
        --out /tmp/accept --candidate-against docs/benchmarks/batch-cpu/arms.json --json accept.json

Printed and written: wall and CPU seconds, runs per core-hour, per run both PSNRs, the
equivalence test over all runs and per dataset.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path

import torch

from nerfaug.equivalence import paired_equivalence
from nerfaug.experiment.config import STUDY_PRESETS
from nerfaug.experiment.sweep import run_sweep


def arm(config, root: Path, workers: int) -> dict:
    """Run one arm's sweep; its wall and CPU seconds (this process and its workers) and results."""
    cpu_before = _cpu_seconds()
    start = time.perf_counter()
    outcome = run_sweep(config, root, workers=workers, progress=True, command=sys.argv)
    wall = time.perf_counter() - start
    cpu = _cpu_seconds() - cpu_before
    if outcome.failed:
        print(f"failed runs: {outcome.failed}", file=sys.stderr)
    runs = {(r["scene"], r["trial"]): r for r in outcome.results}
    return {"wall_s": wall, "cpu_s": cpu, "runs": len(runs), "results": runs, "skipped": outcome.skipped}


NUDGES = {
    "one-weight": "the field's first density-network weight [0, 0] moved by one float32 ulp at initialisation",
    "every-parameter": "every float parameter of the model (field and proposal networks) moved by one float32 "
    "ulp towards +inf at initialisation",
}


def nudged_models(kind: str = "every-parameter"):
    """A context in which every run alone starts from a model moved by a rounding-sized amount: the
    reference engine with a difference of the size rounding makes, the null against which an engine
    that rounds otherwise is judged. In this process only (one worker).

    "one-weight" moves one weight of the field by one unit in the last place (float32): in 6 of 20
    runs it changed nothing (the weight's unit was lost in the first sums). "every-parameter" moves
    every element of every float parameter one unit towards +inf, so every product of the first
    step differs: each run's arithmetic changes."""
    import contextlib

    from nerfaug.nerf import trainer as trainer_module

    original = trainer_module.seeded_model
    up = torch.tensor(float("inf"))

    def nudged(*args, **kwargs):
        model = original(*args, **kwargs)
        with torch.no_grad():
            if kind == "one-weight":
                weight = model.field.density_mlp[0].weight
                weight[0, 0] = torch.nextafter(weight[0, 0], up)
            else:
                for parameter in model.parameters():
                    if parameter.is_floating_point():
                        parameter.copy_(torch.nextafter(parameter, up.to(parameter.dtype)))
        return model

    @contextlib.contextmanager
    def patched():
        trainer_module.seeded_model = nudged
        try:
            yield
        finally:
            trainer_module.seeded_model = original

    return patched()


def _cpu_seconds() -> float:
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", required=True, help="prepared dataset folders (Blender format)")
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--batch", type=int, default=10, help="runs per trial batch")
    parser.add_argument("--engine", default="nerfacto-cpu")
    parser.add_argument("--method", default="uniform")
    parser.add_argument("--steps", type=int, default=None, help="override the protocol's 2000 steps (smoke runs)")
    parser.add_argument("--bound", type=float, default=0.2, help="equivalence margin in dB")
    parser.add_argument("--max-seed", type=float, default=1.0, help="largest |d| allowed for any seed, dB")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", type=Path, required=True, help="a folder for both arms' runs")
    parser.add_argument("--json", type=Path, help="where to write the figures")
    parser.add_argument(
        "--nudged-against",
        type=Path,
        help="instead: run the reference engine with one weight moved by one ulp, in this process, and "
        "compare with the runs alone of this earlier --json (the rounding null)",
    )
    parser.add_argument("--nudge", choices=sorted(NUDGES), default="every-parameter", help="the null's nudge")
    parser.add_argument(
        "--candidate-against",
        type=Path,
        help="instead: run today's default engine alone (the candidate engine version) and judge it against the "
        "runs alone of this earlier --json by the TOST (the acceptance of a new engine version)",
    )
    parser.add_argument(
        "--check-against",
        type=Path,
        help="instead: run the reference engine alone on the first --trials seeds and check it reproduces the "
        "runs alone of this earlier --json to every digit (whether that arm can be reused)",
    )
    args = parser.parse_args(argv)

    base = STUDY_PRESETS.choose(
        "study", scenes=tuple(args.data), methods=(args.method,), trials=args.trials, engine=args.engine
    )
    if args.steps is not None:
        base = base.replace(steps=args.steps)
    started = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    if args.nudged_against is not None:
        return nudged_null(base, args, started)
    if args.check_against is not None:
        return reference_check(base, args)
    if args.candidate_against is not None:
        return candidate(base, args, started)
    arms = {
        "alone": arm(base.replace(batch=1), args.out / "alone", args.workers),
        "batched": arm(base.replace(batch=args.batch), args.out / "batched", args.workers),
    }
    pairs = sorted(set(arms["alone"]["results"]) & set(arms["batched"]["results"]))
    psnr = {name: [a["results"][p]["metrics"]["psnr"] for p in pairs] for name, a in arms.items()}
    overall = paired_equivalence(psnr["batched"], psnr["alone"], args.bound)
    per_scene = {}
    for scene in sorted({scene for scene, _ in pairs}):
        index = [i for i, p in enumerate(pairs) if p[0] == scene]
        if len(index) >= 2:
            per_scene[scene] = paired_equivalence(
                [psnr["batched"][i] for i in index], [psnr["alone"][i] for i in index], args.bound
            )
    figures = {
        "date": started,
        "host": platform.node(),
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "load_average_at_start": os.getloadavg(),
        "torch": torch.__version__,
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "arms": {
            name: {
                "wall_s": a["wall_s"],
                "cpu_s": a["cpu_s"],
                "runs": a["runs"],
                "runs_per_core_hour": a["runs"] / (a["wall_s"] * args.workers / 3600.0),
                "runs_per_cpu_hour": a["runs"] / (a["cpu_s"] / 3600.0),
            }
            for name, a in arms.items()
        },
        "runs": [
            {"scene": s, "trial": t, "psnr_alone": a, "psnr_batched": b, "difference": b - a}
            for (s, t), a, b in zip(pairs, psnr["alone"], psnr["batched"])
        ],
        "equivalence": overall,
        "equivalence_per_scene": per_scene,
        "accepted": overall["equivalent"] and overall["max_abs_difference"] <= args.max_seed,
    }
    ratio = figures["arms"]["batched"]["runs_per_core_hour"] / figures["arms"]["alone"]["runs_per_core_hour"]
    figures["throughput_ratio"] = ratio
    for name, a in figures["arms"].items():
        print(
            f"{name}: {a['runs']} runs, {a['wall_s']:.0f} s wall, {a['cpu_s']:.0f} CPU s, "
            f"{a['runs_per_core_hour']:.1f} runs per core-hour"
        )
    print(f"batched / alone: {ratio:.2f}x runs per core-hour")
    print(
        f"PSNR batched - alone over {overall['n_pairs']} seeds: mean {overall['mean']:+.3f} dB, 90% CI "
        f"[{overall['low']:+.3f}, {overall['high']:+.3f}], TOST p = {overall['p_value']:.4f} (bound "
        f"+-{args.bound} dB), largest |d| {overall['max_abs_difference']:.3f} dB: "
        f"{'accepted' if figures['accepted'] else 'NOT accepted'}"
    )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


def nudged_null(base, args, started: str) -> int:
    """The rounding null: runs alone with a one-ulp nudge against the same runs alone without."""
    reference = json.loads(args.nudged_against.read_text())
    before = {(r["scene"], r["trial"]): r["psnr_alone"] for r in reference["runs"]}
    with nudged_models(args.nudge):
        nudged = arm(base.replace(batch=1), args.out / "nudged", workers=1)
    pairs = sorted(set(before) & set(nudged["results"]))
    after = [nudged["results"][p]["metrics"]["psnr"] for p in pairs]
    result = paired_equivalence(after, [before[p] for p in pairs], args.bound)
    figures = {
        "date": started,
        "host": platform.node(),
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "nudge": NUDGES[args.nudge],
        "unchanged_runs": sum(a == before[p] for p, a in zip(pairs, after)),
        "runs": [
            {"scene": s, "trial": t, "psnr_alone": before[(s, t)], "psnr_nudged": a, "difference": a - before[(s, t)]}
            for (s, t), a in zip(pairs, after)
        ],
        "equivalence": result,
    }
    print(
        f"PSNR nudged - alone over {result['n_pairs']} seeds: mean {result['mean']:+.3f} dB, 90% CI "
        f"[{result['low']:+.3f}, {result['high']:+.3f}], TOST p = {result['p_value']:.4f}, largest |d| "
        f"{result['max_abs_difference']:.3f} dB; {figures['unchanged_runs']} of {len(pairs)} runs unchanged"
    )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


def candidate(base, args, started: str) -> int:
    """The acceptance of a new engine version: today's default engine alone against the recorded
    reference runs alone, seed by seed (docs/study-plan.md, "acceptance of a new CPU engine version")."""
    reference = json.loads(args.candidate_against.read_text())
    before = {(r["scene"], r["trial"]): r["psnr_alone"] for r in reference["runs"]}
    now = arm(base.replace(batch=1), args.out / "candidate", args.workers)
    pairs = sorted(set(before) & set(now["results"]))
    after = [now["results"][p]["metrics"]["psnr"] for p in pairs]
    versions = sorted({str(now["results"][p].get("engine_version")) for p in pairs})
    if len(pairs) < 2:  # a check of a few runs: their PSNRs, no test
        for (scene, trial), psnr in zip(pairs, after):
            print(f"{scene} trial {trial}: {psnr!r} ({', '.join(versions)}), reference {before[(scene, trial)]!r}")
        return 0
    result = paired_equivalence(after, [before[p] for p in pairs], args.bound)
    per_scene = {}
    for scene in sorted({scene for scene, _ in pairs}):
        index = [i for i, p in enumerate(pairs) if p[0] == scene]
        if len(index) < 2:
            continue
        per_scene[scene] = paired_equivalence([after[i] for i in index], [before[pairs[i]] for i in index], args.bound)
    figures = {
        "date": started,
        "host": platform.node(),
        "load_average_at_start": os.getloadavg(),
        "torch": torch.__version__,
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "engine_versions": versions,
        "arm": {
            "wall_s": now["wall_s"],
            "cpu_s": now["cpu_s"],
            "runs": now["runs"],
            "runs_per_cpu_hour": now["runs"] / (now["cpu_s"] / 3600.0),
        },
        "runs": [
            {"scene": s, "trial": t, "psnr_alone": b, "psnr_candidate": a, "difference": a - b}
            for (s, t), a, b in zip(pairs, after, [before[p] for p in pairs])
        ],
        "equivalence": result,
        "equivalence_per_scene": per_scene,
    }
    print(
        f"PSNR candidate ({', '.join(versions)}) - reference over {result['n_pairs']} seeds: mean "
        f"{result['mean']:+.3f} dB, 90% CI [{result['low']:+.3f}, {result['high']:+.3f}], TOST p = "
        f"{result['p_value']:.4f} (bound +-{args.bound} dB), largest |d| {result['max_abs_difference']:.3f} dB: "
        f"{'equivalent' if result['equivalent'] else 'NOT shown equivalent'}"
    )
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + "\n")
    return 0


def reference_check(base, args) -> int:
    """Run the reference engine alone on the first `args.trials` seeds of each dataset and compare
    each run's test PSNR with the earlier arm's, exactly: 0 when all equal (the arm can be reused)."""
    reference = json.loads(args.check_against.read_text())
    before = {(r["scene"], r["trial"]): r["psnr_alone"] for r in reference["runs"]}
    now = arm(base.replace(batch=1), args.out / "reference-check", args.workers)["results"]
    equal = True
    for key, result in sorted(now.items()):
        psnr = result["metrics"]["psnr"]
        same = key in before and psnr == before[key]
        equal &= same
        verdict = "equal" if same else "DIFFERENT"
        print(f"{key[0]} trial {key[1]}: {psnr!r} now, {before.get(key)!r} recorded: {verdict}")
    print("the recorded arm is reproduced" if equal else "the recorded arm is NOT reproduced: run it again")
    return 0 if equal else 1


if __name__ == "__main__":
    sys.exit(main())
