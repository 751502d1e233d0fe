"""Load test of `nerfaug serve`: N clients x M sessions on one server for about a minute.

    python benchmarks/bench_service_load.py                       # 6 clients x 3 sessions, 60 s
    python benchmarks/bench_service_load.py --clients 12 --sessions 4 --duration 90

One server on a loopback port over a tiny dataset (the `test` engine preset, 16x16 images). Each
session trains through the whole run (a training job of many steps, started first). Each client
works on one session in a loop until the time is up: its session's state and the health check
every turn, a proposal every `--propose-every` turns, a batch of one capture every
`--capture-every` turns (a new image at a new pose). Every request has a timeout and the run has a
deadline, so the test is bounded in count and time.

Reported: p50/p99/max latency of health and state (target: p99 <= 200 ms while proposals and
training run), throughput per kind, answers by status (429: a session's queue was full, with
Retry-After; expected back-pressure, not an error), 5xx answers and transport errors (target:
none), and the server's peak resident memory (VmHWM). Writes `<out>/bench_service_load.json`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))

from robot_capture_loop import answer, png_bytes, start_service, stop_service  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clients", type=int, default=6, help="client threads")
    parser.add_argument("--sessions", type=int, default=3, help="sessions on the server (clients share them)")
    parser.add_argument("--duration", type=float, default=60.0, help="seconds of load")
    parser.add_argument("--size", type=int, default=16, help="pixels across the dataset's images")
    parser.add_argument("--views", type=int, default=8, help="views each session starts from")
    parser.add_argument("--preset", default="test", help="engine preset of the sessions")
    parser.add_argument("--candidates", type=int, default=64, help="hemisphere candidates per proposal")
    parser.add_argument("--entropy-resolution", type=int, default=8)
    parser.add_argument("--propose-every", type=int, default=4, help="a proposal every this many turns")
    parser.add_argument("--capture-every", type=int, default=6, help="a capture every this many turns")
    parser.add_argument("--pause", type=float, default=0.05, help="seconds between a client's turns")
    parser.add_argument("--timeout", type=float, default=60.0, help="seconds a request may take")
    parser.add_argument("--out", type=Path, default=Path("bench-out"))
    return parser.parse_args(argv)


def write_dataset(root: Path, views: int, size: int) -> Path:
    import torch

    from nerfaug.cameras import Cameras
    from nerfaug.data import Views, write_blender_split
    from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses

    generator = torch.Generator().manual_seed(0)
    poses = sample_uniform_poses(views, generator)
    images = torch.rand(views, size, size, 3, generator=generator)
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)
    write_blender_split(root, "train", Views(cameras, images, [f"./train/r_{i}" for i in range(views)]))
    return root


def random_pose(rng: np.random.Generator) -> list:
    import torch

    from nerfaug.hemisphere import pose_from_angles

    azimuth = torch.tensor([rng.uniform(0, 2 * np.pi)], dtype=torch.float64)
    polar = torch.tensor([rng.uniform(0.2, 1.3)], dtype=torch.float64)
    return pose_from_angles(azimuth, polar, 4.03)[0].tolist()


class Record:
    """Every request's kind, status (or "transport") and seconds, from every thread."""

    def __init__(self):
        self.lock = threading.Lock()
        self.rows: list[tuple[str, str, float]] = []

    def timed(self, kind: str, send, *args, **kwargs) -> httpx.Response | None:
        start = time.monotonic()
        try:
            response = send(*args, **kwargs)
            status = str(response.status_code)
        except httpx.HTTPError:
            response, status = None, "transport"
        with self.lock:
            self.rows.append((kind, status, time.monotonic() - start))
        return response


def client_loop(index: int, args, url: str, session: str, record: Record, deadline: float) -> None:
    rng = np.random.default_rng(index)
    with httpx.Client(base_url=url, timeout=args.timeout) as client:
        turn = 0
        while time.monotonic() < deadline and turn < 100_000:
            record.timed("state", client.get, f"/sessions/{session}")
            record.timed("health", client.get, "/health")
            if turn % args.propose_every == index % args.propose_every:
                body = {
                    "n": 2,
                    "n_candidates": args.candidates,
                    "selection": {"entropy_resolution": args.entropy_resolution},
                    "allow_empty": True,  # timed, whatever the NeRF learned meanwhile
                }
                record.timed("proposal", client.post, f"/sessions/{session}/proposals", json=body)
            if turn % args.capture_every == index % args.capture_every:
                name = f"c{index}_{turn}.png"
                image = png_bytes(rng.random((args.size, args.size, 3)))
                files = [("images", (name, image, "image/png"))]
                data = {"poses": json.dumps([random_pose(rng)])}
                record.timed("capture", client.post, f"/sessions/{session}/captures", data=data, files=files)
            turn += 1
            time.sleep(args.pause)


def memory_kb(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def summarise(record: Record, seconds: float) -> dict:
    by_kind: dict[str, list] = defaultdict(list)
    statuses: dict[str, Counter] = defaultdict(Counter)
    for kind, status, elapsed in record.rows:
        statuses[kind][status] += 1
        if status == "200" or status == "201":
            by_kind[kind].append(elapsed)
    kinds = {}
    for kind in sorted(statuses):
        times = by_kind[kind]
        kinds[kind] = {
            "answers": dict(statuses[kind]),
            "ok": len(times),
            "per_s": round(len(times) / seconds, 2),
            "p50_ms": round(percentile(times, 50) * 1000, 1),
            "p99_ms": round(percentile(times, 99) * 1000, 1),
            "max_ms": round(max(times) * 1000, 1) if times else None,
        }
    every = Counter(status for _, status, _ in record.rows)
    return {
        "kinds": kinds,
        "requests": len(record.rows),
        "per_s": round(len(record.rows) / seconds, 1),
        "server_errors_5xx": sum(n for status, n in every.items() if status.startswith("5")),
        "transport_errors": every.get("transport", 0),
        "refused_429": every.get("429", 0),
    }


def main(argv=None) -> dict:
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="nerfaug-load-") as tmp:
        root = Path(tmp) / "root"
        write_dataset(root / "data", args.views, args.size)
        process, url = start_service(root, "cpu")
        try:
            with httpx.Client(base_url=url, timeout=300.0) as client:
                ids = [f"load{i}" for i in range(args.sessions)]
                for session in ids:
                    body = {"id": session, "dataset": "data", "engine": args.preset, "seed": 1}
                    answer(client.post("/sessions/from-dataset", json=body))
                for session in ids:  # training runs through the whole test
                    answer(client.post(f"/sessions/{session}/train", json={"steps": 1_000_000}))
            record, memory = Record(), []
            start = time.monotonic()
            deadline = start + args.duration
            threads = [
                threading.Thread(target=client_loop, args=(i, args, url, ids[i % len(ids)], record, deadline))
                for i in range(args.clients)
            ]
            for thread in threads:
                thread.start()
            while any(t.is_alive() for t in threads) and time.monotonic() < deadline + args.timeout + 30:
                memory.append(memory_kb(process.pid, "VmRSS"))
                time.sleep(0.5)
            for thread in threads:
                thread.join(args.timeout)
            elapsed = time.monotonic() - start
            peak_kb = memory_kb(process.pid, "VmHWM")
            with httpx.Client(base_url=url, timeout=60.0) as client:
                steps = {s: client.get(f"/sessions/{s}").json()["step"] for s in ids}
        finally:
            stop_service(process)
    summary = summarise(record, elapsed)
    result = {
        "settings": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpus": os.cpu_count(),
            "load_average_before": [round(x, 2) for x in load_before],
            "load_average_after": [round(x, 2) for x in os.getloadavg()],
        },
        "seconds": round(elapsed, 1),
        "training_steps_reached": steps,
        "server_rss_mb": {
            "peak": round(peak_kb / 1024, 1),
            "median_during": round(statistics.median(memory) / 1024, 1) if memory else None,
        },
        **summary,
    }
    (args.out / "bench_service_load.json").write_text(json.dumps(result, indent=1))
    print(f"{args.clients} clients x {args.sessions} sessions, {elapsed:.0f} s, load {load_before[0]:.1f}")
    for kind, row in summary["kinds"].items():
        print(
            f"  {kind:8s} ok {row['ok']:5d} ({row['per_s']:6.2f}/s)  p50 {row['p50_ms']:7.1f} ms  "
            f"p99 {row['p99_ms']:7.1f} ms  max {row['max_ms']} ms  answers {row['answers']}"
        )
    print(
        f"  requests {summary['requests']} ({summary['per_s']}/s); 5xx {summary['server_errors_5xx']}, transport "
        f"errors {summary['transport_errors']}, 429 {summary['refused_429']}; server peak RSS "
        f"{result['server_rss_mb']['peak']} MB; training steps {steps}"
    )
    return result


if __name__ == "__main__":
    main()
