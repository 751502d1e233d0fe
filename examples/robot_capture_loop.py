"""A robot's capture loop against `nerfaug serve`, over HTTP only: upload the first captures, then
round after round ask where to look next within the robot's workspace (an elevation band and a
keep-out cone), capture there, upload, train in the background while polling, and score the NeRF
on held-out views. The robot's camera is simulated: Blender renders a built-in scene at the
proposed poses (`BlenderOracle`), as a real robot's camera would take them.

    python examples/robot_capture_loop.py                      # lego at 100x100, 2 rounds of 6 views
    python examples/robot_capture_loop.py --engine test --steps-per-round 10 --views-per-round 2 \\
        --n-candidates 20                                      # a minute
    python examples/robot_capture_loop.py --url http://127.0.0.1:8000 --root sessions   # a running service

Without `--url` it starts `nerfaug serve --root ROOT` on a free port of 127.0.0.1 and stops it at
the end. The held-out views are copied into ROOT (the service scores datasets inside its root
only), so with `--url`, ROOT must be that service's root on this machine. Run again, it goes on
with the session SESSION in ROOT when that was made with the same --engine and --seed, and
refuses, naming them, when it was not.
"""

from __future__ import annotations

import json
import math
import shutil
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import httpx
import imageio.v3 as iio
import numpy as np
import tyro

from nerfaug.capture.requests import replaced_by

HOST = "127.0.0.1"


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def start_service(root: Path, device: str, timeout: float = 180.0) -> tuple[subprocess.Popen, str]:
    """`nerfaug serve` on a free loopback port; returns the process and its URL once it answers."""
    port = free_port()
    root.mkdir(parents=True, exist_ok=True)
    log = open(root.parent / f"{root.name}.log", "ab")  # noqa: SIM115 -- kept open for the child's lifetime
    command = [sys.executable, "-m", "nerfaug.cli", "serve", "--root", str(root), "--host", HOST, "--port", str(port)]
    process = subprocess.Popen([*command, "--device", device], stdout=log, stderr=subprocess.STDOUT)
    url = f"http://{HOST}:{port}"
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise SystemExit(f"nerfaug serve exited with {process.returncode}; see {log.name}")
        try:
            if httpx.get(f"{url}/health", timeout=5).status_code == 200:
                return process, url
        except httpx.TransportError:
            pass
        time.sleep(0.25)
    stop_service(process)
    raise SystemExit(f"nerfaug serve did not answer within {timeout:.0f} s; see {log.name}")


def stop_service(process: subprocess.Popen) -> None:
    """SIGTERM (the service saves every session and stops its training), then SIGKILL after 60 s."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(60)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(30)


def answer(response: httpx.Response) -> dict:
    """The JSON of a successful response; otherwise stop with the service's one-line reason."""
    if response.is_success:
        return response.json()
    detail = response.json().get("detail") if "json" in response.headers.get("content-type", "") else response.text
    raise SystemExit(f"{response.request.method} {response.request.url.path}: {response.status_code} {detail}")


def png_bytes(image: np.ndarray) -> bytes:
    """(H, W, 3) floats in [0, 1] as PNG bytes."""
    return iio.imwrite("<bytes>", (np.clip(image, 0, 1) * 255).round().astype(np.uint8), extension=".png")


def train(client: httpx.Client, session: str, steps: int, timeout: float) -> dict:
    """Train `steps` in the background and poll the state until the job ends (bounded in time)."""
    job = answer(client.post(f"/sessions/{session}/train", json={"steps": steps}))
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        state = answer(client.get(f"/sessions/{session}"))
        if not state["running"]:
            if state["job"]["state"] != "done":
                raise SystemExit(f"training failed: {state['job']['error']}")
            return state
        time.sleep(0.5)
    raise SystemExit(f"training to step {job['target']} still running after {timeout:.0f} s")


def evaluate(client: httpx.Client, session: str, held_out: str, max_views: int) -> dict:
    body = {"dataset": held_out, "split": "test", "max_views": max_views}
    return answer(client.post(f"/sessions/{session}/evaluate", json=body))


@dataclass
class Options:
    """Drive a capture session through rounds of propose -> capture -> add -> train -> evaluate."""

    url: Annotated[str | None, replaced_by("start one on ROOT, stopped at the end", "URL")] = None
    """a running `nerfaug serve`."""
    root: Path = Path("results/robot-service")
    """the service's root folder (the session and a copy of the held-out views go there)."""
    token: Annotated[str | None, replaced_by("none", "STR")] = None
    """the service's token, when it has one."""
    session: str = "robot"
    """the session's id (an existing session of that id is resumed)."""
    data: Annotated[
        Path | None, replaced_by("data/SCENE-RESOLUTION, rendered there by `nerfaug scene render` when absent", "PATH")
    ] = None
    """a Blender dataset of SCENE (initial split: the first captures; test: the held-out views)."""
    scene: str = "lego"
    """the built-in scene the robot's camera sees (lego, chair, materials)."""
    resolution: int = 100
    """image size of DATA when it is rendered here."""
    pool: int = 300
    """candidate pool of DATA when it is rendered here."""
    rounds: int = 2
    """propose-capture-add-train rounds."""
    views_per_round: int = 6
    """views proposed and captured per round."""
    steps_per_round: int = 500
    """training steps before the first proposal and after each round's captures."""
    n_candidates: int = 500
    """hemisphere candidates scored per proposal."""
    method: str = "ours"
    """the selection method (`nerfaug methods`)."""
    elevation: tuple[float, float] = (10.0, 70.0)
    """the workspace's elevation band, degrees above the equator (low, high)."""
    keep_out: tuple[float, float, float, float] = (1.0, 0.0, 0.3, 35.0)
    """a cone the camera must not enter: direction x y z from the centre, half-angle in degrees."""
    engine: Literal["nerfacto-cpu", "cpu", "paper", "test"] = "nerfacto-cpu"
    """the NeRF engine of the session."""
    seed: int = 0
    """seeds the session; the proposal of round k uses seed + k."""
    samples: int = 16
    """Cycles samples per pixel of the robot's captures."""
    eval_views: int = 20
    """score on the first this many held-out views."""
    device: Literal["auto", "cpu", "cuda"] = "cpu"
    """where a service started here trains."""
    allow_empty: bool = False
    """propose even from a NeRF that learned nothing yet (a run of a few steps)."""
    timeout: float = 3600.0
    """seconds one training job may take before the loop gives up."""
    summary: Path = Path("results/robot-capture-loop.json")
    """a JSON file with the test PSNR, SSIM and LPIPS after each round."""


def dataset(o: Options) -> Path:
    """DATA as given (it must exist), or data/SCENE-RESOLUTION: used as it is when there, else
    SCENE rendered there."""
    if o.data is not None:
        if not o.data.is_dir():
            raise SystemExit(f"--data {o.data}: no such folder; give a Blender dataset, or leave --data out")
        return o.data
    data = Path(f"data/{o.scene}-{o.resolution}")
    if data.is_dir():
        print(f"using the dataset already in {data} (--data: another one)")
        return data
    from nerfaug.scenes import render_scene_dataset

    return render_scene_dataset(o.scene, data, resolution=o.resolution, pool=o.pool)


def check_existing_session(o: Options) -> None:
    """Refuse to go on with a session in ROOT made with another engine or seed (naming them)."""
    from nerfaug.capture import SESSION_FILE, SessionState

    folder = o.root / o.session
    if not (folder / SESSION_FILE).exists():
        return
    state = SessionState.read(folder)
    differ = [
        f"--{name} {found} (asked: {wanted})"
        for name, found, wanted in (("engine", state.engine, o.engine), ("seed", state.seed, o.seed))
        if found != wanted
    ]
    if differ:
        raise SystemExit(
            f"session {o.session!r} in {o.root} was made with {', '.join(differ)}; give another --session "
            "(or --root) for these settings, or the session's own"
        )
    print(f"going on with session {o.session!r} in {o.root} (same engine and seed): step {state.step}")


def main(o: Options) -> list[dict]:
    """Run the loop; returns the metrics after each round (round 0: the first captures only)."""
    o.data = dataset(o)
    check_existing_session(o)
    # The held-out views inside the service root, where the service may read them.
    held_out = f"held-out-{o.data.name}"
    if not (o.root / held_out / "transforms_test.json").is_file():
        (o.root / held_out).mkdir(parents=True, exist_ok=True)
        shutil.copy2(o.data / "transforms_test.json", o.root / held_out / "transforms_test.json")
        shutil.copytree(o.data / "test", o.root / held_out / "test", dirs_exist_ok=True)

    process, url = None, o.url
    if url is None:
        process, url = start_service(o.root, o.device)
        print(f"nerfaug serve on {url} (sessions in {o.root})")
    headers = {"Authorization": f"Bearer {o.token}"} if o.token else {}
    try:
        with httpx.Client(base_url=url, headers=headers, timeout=600.0) as client:
            return capture_loop(client, o, held_out)
    finally:
        if process is not None:
            stop_service(process)


def image_file(data: Path, file_path: str) -> Path:
    """A frame's image file (NeRF-synthetic's file_path has no suffix)."""
    path = data / file_path
    return path if path.suffix else path.with_suffix(".png")


def create_session(client: httpx.Client, o: Options) -> None:
    """A session from the first captures: DATA's initial split, uploaded with poses and intrinsics."""
    initial = json.loads((o.data / "transforms_initial.json").read_text())
    frames = initial["frames"]
    files = [image_file(o.data, frame["file_path"]) for frame in frames]
    height, width = iio.improps(files[0]).shape[:2]
    fx = 0.5 * width / math.tan(0.5 * float(initial["camera_angle_x"]))
    settings = {
        "id": o.session,
        "engine": o.engine,
        "seed": o.seed,
        "intrinsics": {"width": width, "height": height, "fx": fx},
        "poses": [frame["transform_matrix"] for frame in frames],
    }
    uploads = [("images", (path.name, path.read_bytes(), "image/png")) for path in files]
    state = answer(client.post("/sessions/from-uploads", data={"settings": json.dumps(settings)}, files=uploads))
    print(f"session {o.session!r}: {state['views']} first captures uploaded")


def capture_loop(client: httpx.Client, o: Options, held_out: str) -> list[dict]:
    """The loop proper; returns and writes (to o.summary) the metrics after each round."""
    from nerfaug.oracle import BlenderOracle

    if client.get(f"/sessions/{o.session}").status_code == 404:
        create_session(client, o)
    k = answer(client.get(f"/sessions/{o.session}"))["intrinsics"]
    angle = 2 * math.atan(0.5 * k["width"] / k["fx"])
    camera = BlenderOracle(o.scene, k["width"], k["height"], angle, samples=o.samples, progress=False)
    constraints = {"elevation": list(o.elevation), "keep_out": [list(o.keep_out)]}

    state = train(client, o.session, o.steps_per_round, o.timeout)
    scores = evaluate(client, o.session, held_out, o.eval_views)
    history = [{"round": 0, "views": state["views"], "step": state["step"], **metrics(scores)}]
    print(f"round 0: {state['views']} views, step {state['step']}: {line(scores)}")
    for number in range(1, o.rounds + 1):
        body = {
            "n": o.views_per_round,
            "method": o.method,
            "n_candidates": o.n_candidates,
            "seed": o.seed + number,
            "constraints": constraints,
            "allow_empty": o.allow_empty,
        }
        proposal = answer(client.post(f"/sessions/{o.session}/proposals", json=body))
        poses = np.array([frame["transform_matrix"] for frame in proposal["frames"]], dtype=np.float32)
        names = [Path(frame["file_path"]).name for frame in proposal["frames"]]
        captured = camera.capture(poses, names)  # the robot drives to each pose and takes a picture
        uploads = [
            ("images", (f"{name}.png", png_bytes(captured.image(i).numpy()), "image/png"))
            for i, name in enumerate(names)
        ]
        body = {"poses": json.dumps(poses.tolist())}
        answer(client.post(f"/sessions/{o.session}/captures", data=body, files=uploads))
        state = train(client, o.session, o.steps_per_round, o.timeout)
        scores = evaluate(client, o.session, held_out, o.eval_views)
        history.append({"round": number, "views": state["views"], "step": state["step"], **metrics(scores)})
        print(f"round {number}: +{len(names)} views -> {state['views']}, step {state['step']}: {line(scores)}")

    options = {name: str(value) for name, value in vars(o).items() if name != "token"}
    o.summary.parent.mkdir(parents=True, exist_ok=True)
    o.summary.write_text(json.dumps({"options": options, "rounds": history}, indent=2) + "\n")
    print(f"summary: {o.summary}")
    return history


def metrics(scores: dict) -> dict:
    return {"psnr": scores["psnr"], "ssim": scores["ssim"], "lpips": scores["lpips"], "test_views": scores["views"]}


def line(scores: dict) -> str:
    lpips = "n/a" if scores["lpips"] is None else f"{scores['lpips']:.4f}"
    return f"test PSNR {scores['psnr']:.2f} dB, SSIM {scores['ssim']:.4f}, LPIPS {lpips} ({scores['views']} views)"


if __name__ == "__main__":
    main(tyro.cli(Options))
