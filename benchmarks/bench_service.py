"""Service benchmark: what HTTP adds to a proposal, and the robot loop's quality per round.

    python benchmarks/bench_service.py                    # lego at 64x64, about 5 minutes on 2 cores
    python benchmarks/bench_service.py --repeat 7 --resolution 100

1. One `POST /sessions/{id}/proposals` to a `nerfaug serve` process against the same proposal
   made in this process (`CaptureSession.propose` then `save`, what the endpoint runs): the same
   session (the service's folder, copied once it has trained, so both hold the same model), the
   same method, seed and settings, one torch thread each. The two are interleaved (ABBA) `--repeat`
   times after one untimed call each; the medians and their ratio (HTTP / in process) are reported,
   and whether both chose the same poses.
2. The session's state and the health check while that service trains: a training job of
   `--status-steps` steps is started and `GET /sessions/{id}` and `GET /health` are each timed
   `--status-polls` times while it runs (target: every answer within 200 ms).
3. `examples/robot_capture_loop.py` at a small size: the held-out PSNR after each round.

Prints a summary and writes `<out>/bench_service.json`.
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))

from robot_capture_loop import answer, start_service, stop_service, train  # noqa: E402

SESSION = "bench"


def propose_body(args, seed: int) -> dict:
    constraints = {"elevation": [10.0, 70.0], "keep_out": [[1.0, 0.0, 0.3, 35.0]]}
    return {
        "n": args.n,
        "method": args.method,
        "n_candidates": args.candidates,
        "seed": seed,
        "selection": {"entropy_resolution": args.entropy_resolution},
        "constraints": constraints,
        "allow_empty": True,  # a timing: the proposal runs whatever the NeRF learned in --steps
    }


def bench_propose(args, work: Path, data: Path) -> dict:
    """Part 1: the medians of the same proposal over HTTP and in process, and their ratio."""
    from nerfaug.capture import ProposalRequest
    from nerfaug.device import configure_process
    from nerfaug.health import EmptyModelWarning
    from nerfaug.session import CaptureSession

    configure_process(threads=1)  # as `nerfaug serve` (its --threads default)
    root = work / "service"
    (root / "data").mkdir(parents=True)
    shutil.copytree(data, root / "data" / data.name)
    process, url = start_service(root, "cpu")
    try:
        with httpx.Client(base_url=url, timeout=600.0) as client:
            body = {"id": SESSION, "dataset": f"data/{data.name}", "split": "initial", "engine": args.engine}
            answer(client.post("/sessions/from-dataset", json=body))
            state = train(client, SESSION, args.steps, timeout=1800.0)
            # The same session in this process: a copy of the folder the service saved after training.
            shutil.copytree(root / SESSION, work / "local")
            local = CaptureSession.open(work / "local")
            assert local.step == state["step"], (local.step, state["step"])

            def over_http() -> list:
                frames = answer(client.post(f"/sessions/{SESSION}/proposals", json=propose_body(args, args.seed)))
                return [frame["transform_matrix"] for frame in frames["frames"]]

            def in_process() -> list:
                with warnings.catch_warnings():  # allowed in the body; the service answers without a warning
                    warnings.simplefilter("ignore", EmptyModelWarning)
                    proposal = local.propose(
                        ProposalRequest(**propose_body(args, args.seed))
                    )  # as the service reads it
                local.save()
                return proposal.transforms()["frames"]

            first_http, first_local = over_http(), [f["transform_matrix"] for f in in_process()]  # untimed
            same = all(
                abs(a - b) < 1e-5
                for pose_a, pose_b in zip(first_http, first_local)
                for row_a, row_b in zip(pose_a, pose_b)
                for a, b in zip(row_a, row_b)
            )
            times = {"http": [], "in_process": []}
            for rep in range(args.repeat):
                order = ("http", "in_process") if rep % 2 == 0 else ("in_process", "http")
                for kind in order:
                    start = time.perf_counter()
                    over_http() if kind == "http" else in_process()
                    times[kind].append(time.perf_counter() - start)
            status = bench_status(client, args)
    finally:
        stop_service(process)
    medians = {kind: statistics.median(values) for kind, values in times.items()}
    return {
        "times_s": times,
        "median_s": medians,
        "ratio": medians["http"] / medians["in_process"],
        "same_poses": same,
        "step": state["step"],
        "status_while_training": status,
    }


def bench_status(client: httpx.Client, args) -> dict:
    """Part 2: seconds per state and health request while a training job runs (bounded polls)."""
    answer(client.post(f"/sessions/{SESSION}/train", json={"steps": args.status_steps}))
    found = {"state": [], "health": [], "running": []}
    for _ in range(args.status_polls):
        for kind, path in (("state", f"/sessions/{SESSION}"), ("health", "/health")):
            start = time.perf_counter()
            reply = answer(client.get(path))
            found[kind].append(time.perf_counter() - start)
            if kind == "state":
                found["running"].append(bool(reply["running"]))
        time.sleep(0.05)
    summary = {
        kind: {"median_s": statistics.median(values), "max_s": max(values)}
        for kind, values in found.items()
        if kind != "running"
    }
    return {**summary, "polls": args.status_polls, "polls_while_running": sum(found["running"])}


def bench_loop(args, work: Path, data: Path) -> dict:
    """Part 2: the example loop at a small size; its held-out metrics after each round."""
    summary = work / "loop.json"
    command = [
        sys.executable,
        str(ROOT / "examples" / "robot_capture_loop.py"),
        "--root",
        str(work / "loop-service"),
        "--data",
        str(data),
        "--engine",
        args.engine,
        "--rounds",
        str(args.rounds),
        "--views-per-round",
        str(args.views_per_round),
        "--steps-per-round",
        str(args.steps_per_round),
        "--n-candidates",
        str(args.candidates),
        "--samples",
        str(args.samples),
        "--eval-views",
        str(args.eval_views),
        "--summary",
        str(summary),
        "--allow-empty",  # a timing: the loop proposes whatever the NeRF learned in its rounds
    ]
    start = time.perf_counter()
    subprocess.run(command, check=True, timeout=1800)
    return {"rounds": json.loads(summary.read_text())["rounds"], "seconds": time.perf_counter() - start}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="lego")
    parser.add_argument("--resolution", type=int, default=64)
    parser.add_argument("--samples", type=int, default=8, help="Cycles samples per pixel of every render")
    parser.add_argument("--engine", default="cpu", choices=("cpu", "nerfacto-cpu", "paper", "test"))
    parser.add_argument("--steps", type=int, default=200, help="training steps before the timed proposals")
    parser.add_argument("--n", type=int, default=4, help="views per proposal")
    parser.add_argument("--method", default="ours")
    parser.add_argument("--candidates", type=int, default=200, help="hemisphere candidates per proposal")
    parser.add_argument("--entropy-resolution", type=int, default=24)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=6, help="timed proposals of each kind, interleaved")
    parser.add_argument("--status-steps", type=int, default=2000, help="steps of the job the status polls run beside")
    parser.add_argument("--status-polls", type=int, default=20, help="timed state and health requests each")
    parser.add_argument("--rounds", type=int, default=2, help="rounds of the example loop")
    parser.add_argument("--views-per-round", type=int, default=4)
    parser.add_argument("--steps-per-round", type=int, default=300)
    parser.add_argument("--eval-views", type=int, default=10)
    parser.add_argument("--out", type=Path, default=Path("results/bench"))
    args = parser.parse_args()

    from nerfaug.scenes import render_scene_dataset

    with tempfile.TemporaryDirectory(prefix="nerfaug-bench-service-") as tmp:
        work = Path(tmp)
        data = render_scene_dataset(
            args.scene,
            work / f"{args.scene}-{args.resolution}",
            resolution=args.resolution,
            pool=12,
            test=args.eval_views,
            initial=6,
            samples=args.samples,
            progress=False,
        )
        propose = bench_propose(args, work, data)
        loop = bench_loop(args, work, data)

    record = {
        "settings": vars(args) | {"out": str(args.out)},
        "propose": propose,
        "loop": loop,
        "host": platform.node(),
        "cpu": platform.processor() or platform.machine(),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_service.json").write_text(json.dumps(record, indent=2) + "\n")
    m = propose["median_s"]
    print(
        f"propose ({args.n} of {args.candidates} candidates, {args.method}, step {propose['step']}): "
        f"HTTP median {m['http']:.3f} s, in process {m['in_process']:.3f} s, ratio {propose['ratio']:.3f} "
        f"over {args.repeat} interleaved repetitions; same poses: {propose['same_poses']}"
    )
    status = propose["status_while_training"]
    print(
        f"while training ({status['polls_while_running']} of {status['polls']} polls during the job): state "
        f"median {status['state']['median_s'] * 1000:.0f} ms, max {status['state']['max_s'] * 1000:.0f} ms; "
        f"health median {status['health']['median_s'] * 1000:.0f} ms, max {status['health']['max_s'] * 1000:.0f} ms"
    )
    for r in loop["rounds"]:
        print(f"loop round {r['round']}: {r['views']} views, step {r['step']}: test PSNR {r['psnr']:.2f} dB")
    print(f"loop: {loop['seconds']:.0f} s; written to {args.out / 'bench_service.json'}")


if __name__ == "__main__":
    main()
