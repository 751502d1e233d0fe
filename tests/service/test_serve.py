"""`nerfaug serve` as a real process on a free loopback port, driven with httpx on a tiny dataset
(4 views of 8x8 pixels, the "test" engine): the whole capture loop, two sessions at once, the
state answered while training runs, a SIGKILL and restart that loses nothing, the token, and bad
requests each answered with its 4xx and one line naming the field.

Every wait is bounded in count and time; all traffic goes to 127.0.0.1."""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, SessionFolder
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles, sample_uniform_poses

httpx = pytest.importorskip("httpx")
pytest.importorskip("fastapi")

pytestmark = pytest.mark.slow

SIZE = 8
HOST = "127.0.0.1"
START_S = 90.0  # a server start imports torch and FastAPI: seconds on a loaded 2-core machine
FAST = {"entropy_resolution": 4}


def free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def tiny_dataset(root: Path, n: int = 4, split: str = "train", seed: int = 0) -> Path:
    generator = torch.Generator().manual_seed(seed)
    poses = sample_uniform_poses(n, generator)
    images = (torch.rand(n, SIZE, SIZE, 3, generator=generator) * 255).round() / 255
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    write_blender_split(root, split, Views(cameras, images, [f"./{split}/r_{i}" for i in range(n)]))
    return root


def png(seed: int, size: int = SIZE) -> bytes:
    pixels = np.random.default_rng(seed).integers(0, 256, (size, size, 3), dtype=np.uint8)
    return iio.imwrite("<bytes>", pixels, extension=".png")


def poses_at(elevations, azimuths, radius: float = 4.03) -> list:
    polar = torch.deg2rad(90.0 - torch.tensor(elevations, dtype=torch.float64))
    return pose_from_angles(torch.deg2rad(torch.tensor(azimuths, dtype=torch.float64)), polar, radius).tolist()


class Server:
    """A `nerfaug serve` process on a free loopback port, and an httpx client for it."""

    def __init__(self, root: Path, *extra: str, env: dict | None = None, headers: dict | None = None):
        self.root, self.extra = root, extra
        self.port = free_port()
        self.log = root.parent / f"serve-{self.port}.log"
        command = [sys.executable, "-m", "nerfaug.cli", "serve", "--root", str(root), "--host", HOST]
        command += ["--port", str(self.port), "--device", "cpu", "--checkpoint-every", "0.3", *extra]
        with open(self.log, "wb") as log:
            self.process = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})}
            )
        self.client = httpx.Client(base_url=f"http://{HOST}:{self.port}", timeout=120.0, headers=headers or {})
        deadline = time.monotonic() + START_S
        for _ in range(int(START_S * 10)):
            if self.process.poll() is not None:
                raise AssertionError(f"the server exited ({self.process.returncode}): {self.log.read_text()[-2000:]}")
            try:
                if self.client.get("/health").status_code in (200, 401):
                    return
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                break
            time.sleep(0.1)
        self.kill()
        raise AssertionError(f"the server did not answer within {START_S} s: {self.log.read_text()[-2000:]}")

    def kill(self) -> None:
        """SIGKILL: no chance to save."""
        self.client.close()
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(30)

    def poll(self, session: str, timeout: float = 120.0) -> dict:
        """The session's state once its training job has ended (bounded in count and time)."""
        deadline = time.monotonic() + timeout
        for _ in range(int(timeout * 5)):
            state = self.client.get(f"/sessions/{session}").json()
            if not state["running"]:
                return state
            if time.monotonic() > deadline:
                break
            time.sleep(0.2)
        raise AssertionError(f"{session}: training still running after {timeout} s: {state}")


def create(server: Server, session: str, **settings) -> httpx.Response:
    body = {"id": session, "dataset": "data", "engine": "test", "seed": 1, **settings}
    return server.client.post("/sessions/from-dataset", json=body)


def add(server: Server, session: str, names: list[str], poses, images: list[bytes] | None = None) -> httpx.Response:
    images = images if images is not None else [png(i + 100) for i in range(len(names))]
    files = [
        ("images", (f"{name}.png" if "." not in name else name, data, "image/png")) for name, data in zip(names, images)
    ]
    poses = poses if isinstance(poses, str) else json.dumps(poses)
    return server.client.post(f"/sessions/{session}/captures", data={"poses": poses}, files=files)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("service") / "root"
    tiny_dataset(root / "data")
    return root


@pytest.fixture(scope="module")
def server(root):
    server = Server(root, "--max-upload-mb", "0.02")
    yield server
    server.kill()


def test_the_whole_capture_loop(server, root):
    assert server.client.get("/health").json()["status"] == "ok"
    assert server.client.get("/docs").status_code == 200
    assert "/sessions/{session_id}/proposals" in server.client.get("/openapi.json").json()["paths"]
    created = create(server, "loop")
    assert created.status_code == 201, created.text
    assert created.json()["views"] == 4 and created.json()["step"] == 0
    assert server.client.post("/sessions/loop/train", json={"steps": 10}).status_code == 202
    state = server.poll("loop")
    assert state["step"] == 10 and state["job"]["state"] == "done" and state["last_losses"]

    constraints = {"elevation": [20, 70], "azimuth": [0, 180], "keep_out": [[0, 1, 0.3, 20]]}
    body = {"n": 2, "n_candidates": 60, "selection": FAST, "constraints": constraints, "min_separation": 25}
    body["allow_empty"] = True  # ten steps: an empty NeRF, refused otherwise (409, below)
    refused = server.client.post("/sessions/loop/proposals", json={**body, "allow_empty": False})
    assert refused.status_code == 409 and "background only" in refused.json()["detail"], refused.text
    proposal = server.client.post("/sessions/loop/proposals", json=body)
    assert proposal.status_code == 200, proposal.text
    frames = proposal.json()["frames"]
    assert len(frames) == 2 and proposal.json()["nerfaug"]["min_separation"] == 25
    first, second = (np.asarray(frame["transform_matrix"])[:3, 3] for frame in frames)
    centre = np.asarray(SessionFolder.open(root / "loop").hemisphere.centre)
    a, b = first - centre, second - centre
    assert np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))) >= 25 - 1e-3
    for frame in frames:
        assert 20 - 1e-3 <= np.degrees(frame["elevation"]) <= 70 + 1e-3
        assert -1e-3 <= np.degrees(frame["azimuth"]) <= 180 + 1e-3

    names = [Path(frame["file_path"]).stem for frame in frames]
    added = add(server, "loop", names, [frame["transform_matrix"] for frame in frames])
    assert added.status_code == 201, added.text
    assert added.json()["names"] == names and added.json()["views"] == 6
    assert server.client.post("/sessions/loop/train", json={"steps": 10}).status_code == 202
    state = server.poll("loop")
    assert state["step"] == 20 and state["views"] == 6 and state["proposals"] == 1

    # A robot's reachable set as the pool: the proposal comes from it.
    reachable = poses_at([30.0, 40.0, 50.0], [10.0, 100.0, 200.0])
    body = {"n": 1, "candidates": reachable, "selection": FAST, "method": "uniform", "allow_empty": True}
    answer = server.client.post("/sessions/loop/proposals", json=body)
    assert answer.status_code == 200, answer.text
    chosen = answer.json()["frames"][0]["transform_matrix"]
    assert any(np.allclose(chosen, pose, atol=1e-4) for pose in reachable)

    # The folder is a session the library (and the CLI) open, with the captures in it.
    session = SessionFolder.open(root / "loop")
    assert [Path(str(f["file_path"])).stem for f in session.frames()][-2:] == names


def test_uncertainty_images_of_a_pose(server):
    if create(server, "look").status_code != 201:
        pytest.fail("session not created")
    pose = poses_at([35.0], [60.0])[0]
    answer = server.client.post("/sessions/look/uncertainty", json={"pose": pose, "fisher_width": 4, "width": 6})
    assert answer.status_code == 200, answer.text
    assert answer.headers["content-type"] == "image/png" and answer.content[:8] == b"\x89PNG\r\n\x1a\n"
    arrays = server.client.post(
        "/sessions/look/uncertainty", json={"pose": pose, "fisher_width": 4, "width": 6, "format": "npz"}
    )
    data = np.load(io.BytesIO(arrays.content))
    assert data["rgb"].shape == (6, 6, 3) and data["entropy"].shape == (6, 6) and data["depth"].shape == (6, 6)
    assert data["fisher"].shape == (4, 4) and (data["fisher"] >= 0).all() and data["fisher"].sum() > 0
    assert np.allclose(data["pose"], pose, atol=1e-5)


def test_held_out_views_are_scored_as_the_library_scores_them(server, root):
    tiny_dataset(root / "held-out", n=3, split="test", seed=5)
    assert create(server, "scored").status_code == 201
    assert server.client.post("/sessions/scored/train", json={"steps": 10}).status_code == 202
    server.poll("scored")
    # 0 is a step count over HTTP as on the command line: a training job that ends at once.
    assert server.client.post("/sessions/scored/train", json={"steps": 0}).status_code == 202
    assert server.poll("scored")["step"] == 10
    answer = server.client.post("/sessions/scored/evaluate", json={"dataset": "held-out", "max_views": 2})
    assert answer.status_code == 200, answer.text
    scored = answer.json()
    assert scored["step"] == 10 and scored["views"] == 2 and len(scored["per_view"]) == 2
    assert scored["split"] == "test" and scored["dataset"] == "held-out"
    assert 0 < scored["psnr"] < 60 and 0 <= scored["ssim"] <= 1
    assert scored["lpips"] is None and "smaller than" in scored["lpips_status"]  # 8x8 pixels: below AlexNet's size
    assert scored["trained_on"] == 0 and not any(v["trained_on"] for v in scored["per_view"])  # other poses
    # The same numbers as `nerfaug eval` computes in process.
    session = CaptureSession.open(root / "scored")
    local = session.evaluate(session.held_out(root / "held-out", "test", max_views=2), lpips=None)
    assert scored["psnr"] == pytest.approx(local.mean["psnr"], abs=1e-6)
    assert [v["name"] for v in scored["per_view"]] == [v["name"] for v in local.per_view]
    every = server.client.post("/sessions/scored/evaluate", json={"dataset": "held-out", "lpips": False}).json()
    assert every["views"] == 3 and every["lpips_status"].startswith("not computed")


def test_a_session_from_uploaded_images(server):
    poses = poses_at([20.0, 40.0, 30.0, 60.0], [0.0, 90.0, 180.0, 270.0])
    settings = {"id": "uploaded", "engine": "test", "intrinsics": {"width": SIZE, "height": SIZE, "fx": 10.0}}
    files = [("images", (f"shot_{i}.png", png(i), "image/png")) for i in range(4)]
    answer = server.client.post(
        "/sessions/from-uploads", data={"settings": json.dumps({**settings, "poses": poses})}, files=files
    )
    assert answer.status_code == 201, answer.text
    state = answer.json()
    assert state["views"] == 4 and state["intrinsics"]["fx"] == pytest.approx(10.0)
    assert sorted(Path(n).stem for n in state["names"]) == [f"shot_{i}" for i in range(4)]
    assert state["warnings"] == []
    # the same captures in a world whose up is -y (as LLFF's): the answer says the pole is off
    turn = np.array([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    sideways = [(turn @ np.array(pose)).tolist() for pose in poses]
    answer = server.client.post(
        "/sessions/from-uploads",
        data={"settings": json.dumps({**settings, "id": "sideways", "poses": sideways})},
        files=[("images", (f"shot_{i}.png", png(i), "image/png")) for i in range(4)],
    )
    assert answer.status_code == 201, answer.text
    (line,) = answer.json()["warnings"]
    assert line.startswith("the poses: the cameras' mean up axis is") and "--estimate-up" in line


def test_two_sessions_train_at_once_and_the_state_answers_meanwhile(server):
    for session in ("left", "right"):
        assert create(server, session).status_code == 201
    for session in ("left", "right"):
        assert server.client.post(f"/sessions/{session}/train", json={"steps": 20}).status_code == 202
    # Both jobs started; the state and health are answered while they run.
    states = [server.client.get(f"/sessions/{s}") for s in ("left", "right")]
    assert all(s.status_code == 200 for s in states)
    assert server.client.get("/health").status_code == 200
    seen_running = [s.json()["running"] for s in states]
    assert any(seen_running), "a 20-step job had ended before its state was asked"
    assert {s: server.poll(s)["step"] for s in ("left", "right")} == {"left": 20, "right": 20}


def test_a_killed_server_restarts_with_every_capture_and_resumes_training(tmp_path):
    root = tmp_path / "root"
    tiny_dataset(root / "data")
    token = {"NERFAUG_TOKEN": "s3cret"}
    auth = {"Authorization": "Bearer s3cret"}
    first = Server(root, env=token, headers=auth)
    try:
        assert httpx.get(f"http://{HOST}:{first.port}/health").status_code == 401
        wrong = httpx.get(f"http://{HOST}:{first.port}/health", headers={"Authorization": "Bearer nope"})
        assert wrong.status_code == 401 and "token" in wrong.json()["detail"]
        assert create(first, "robot").status_code == 201
        assert add(first, "robot", ["before_0"], poses_at([45.0], [30.0])).status_code == 201
        job = first.client.post("/sessions/robot/train", json={"steps": 100000})
        assert job.status_code == 202
        target = job.json()["target"]
        busy = first.client.post("/sessions/robot/train", json={"steps": 5})
        assert busy.status_code == 409 and "already running" in busy.json()["detail"]
        state = first.client.get("/sessions/robot").json()
        assert state["running"] and state["job"]["state"] == "running"
        # A capture added while training runs (it waits for the current chunk of steps).
        during = add(first, "robot", ["during_0", "during_1"], poses_at([50.0, 60.0], [120.0, 240.0]))
        assert during.status_code == 201, during.text
        step_at_add = during.json()["step"]
        deadline = time.monotonic() + 60
        for _ in range(600):  # until a periodic save after the addition
            state = first.client.get("/sessions/robot").json()
            if state["step"] >= step_at_add + 10 or time.monotonic() > deadline:
                break
            time.sleep(0.1)
    finally:
        first.kill()
    saved = json.loads((root / "robot" / "session.json").read_text())["step"]
    reached = json.loads((root / ".service" / "jobs" / "robot.json").read_text())["step"]

    second = Server(root, env=token, headers=auth)
    try:
        state = second.client.get("/sessions/robot").json()
        assert state["views"] == 7
        stems = {Path(n).stem for n in state["names"]}
        assert {"before_0", "during_0", "during_1"} <= stems
        assert state["step"] >= step_at_add
        assert state["running"] and state["job"]["target"] == target
        # The resumed job says from which save it went on and how many steps it trains again.
        assert state["job"]["resumed_from"] == saved and state["job"]["redone"] == max(0, reached - saved)
        said = f"session robot: training resumed from step {saved}, its last save ({max(0, reached - saved)} steps"
        assert said in second.log.read_text()
        session = SessionFolder.open(root / "robot")
        assert len(session.frames()) == 7
    finally:
        second.kill()


# ---- bad requests: each a 4xx with one line naming the field ------------------------------------

NAN_POSE = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]]
SCALED = [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 4], [0, 0, 0, 1]]
GOOD = poses_at([40.0], [10.0])


def _json(method: str, path: str, body=None):
    return lambda c: c.request(method, path, json=body)


BAD_REQUESTS = {
    "unknown session": (_json("GET", "/sessions/nope"), 404, "session 'nope'"),
    "session id with a dot": (_json("GET", "/sessions/a.b"), 422, "session id: must be 1-64 letters"),
    "session id starting with a dash": (_json("POST", "/sessions/-x/train", {"steps": 1}), 422, "(got '-x')"),
    "id naming a path": (_json("POST", "/sessions/from-dataset", {"id": "../evil", "dataset": "data"}), 422, "id:"),
    "dataset outside the root": (
        _json("POST", "/sessions/from-dataset", {"id": "x1", "dataset": "../../etc"}),
        422,
        "leads outside",
    ),
    "absolute dataset": (
        _json("POST", "/sessions/from-dataset", {"id": "x2", "dataset": "/etc"}),
        422,
        "dataset '/etc'",
    ),
    "missing dataset": (_json("POST", "/sessions/from-dataset", {"id": "x3", "dataset": "nothere"}), 404, "nothere"),
    "unknown engine": (
        _json("POST", "/sessions/from-dataset", {"id": "x4", "dataset": "data", "engine": "huge"}),
        422,
        "engine:",
    ),
    "the engine's old name": (
        _json("POST", "/sessions/from-dataset", {"id": "x6", "dataset": "data", "preset": "test"}),
        422,
        "preset: unknown field: not one of this request's; renamed engine",
    ),
    "unknown field": (_json("POST", "/sessions/from-dataset", {"id": "x5", "dataset": "data", "sed": 1}), 422, "sed:"),
    "existing session": (_json("POST", "/sessions/from-dataset", {"id": "bad", "dataset": "data"}), 409, "'bad'"),
    "negative steps": (_json("POST", "/sessions/bad/train", {"steps": -1}), 422, "steps:"),
    "steps not a number": (_json("POST", "/sessions/bad/train", {"steps": "many"}), 422, "steps:"),
    "zero views": (_json("POST", "/sessions/bad/proposals", {"n": 0}), 422, "n:"),
    "unknown method": (_json("POST", "/sessions/bad/proposals", {"method": "best"}), 422, "unknown selection method"),
    "separation of 180 degrees": (
        _json("POST", "/sessions/bad/proposals", {"min_separation": 180}),
        422,
        "min_separation: must be < 180",
    ),
    "reversed elevation": (
        _json("POST", "/sessions/bad/proposals", {"constraints": {"elevation": [60, 10]}}),
        422,
        "constraints.elevation: low must be <= high",
    ),
    "constraints leave too few": (
        _json(
            "POST",
            "/sessions/bad/proposals",
            {"n": 2, "n_candidates": 30, "selection": FAST, "constraints": {"radius": [100, 200]}},
        ),
        422,
        "constraints leave 0 of 30 candidates; 2 asked",
    ),
    "unknown selection setting": (
        _json("POST", "/sessions/bad/proposals", {"selection": {"bogus": 1}}),
        422,
        "selection.bogus: unknown field",
    ),
    "non-finite candidate": (
        lambda c: c.post(
            "/sessions/bad/proposals",
            content=json.dumps({"candidates": [NAN_POSE]}),
            headers={"content-type": "application/json"},
        ),
        422,
        "candidates[0]: not finite",
    ),
    "uncertainty pose not 4x4": (
        _json("POST", "/sessions/bad/uncertainty", {"pose": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}),
        422,
        "pose: transform_matrix must be 4x4",
    ),
    "not an image": (lambda c: add_to(c, ["x.png"], GOOD, [b"hello"]), 422, "images[0] (x.png): not an image"),
    "wrong image size": (
        lambda c: add_to(c, ["big.png"], GOOD, [png(0, SIZE * 2)]),
        422,
        "images[0] (big.png): image is 16x16 pixels but the dataset's camera is 8x8",
    ),
    "non-finite pose": (lambda c: add_to(c, ["y.png"], json.dumps([NAN_POSE])), 422, "poses[0]: not finite"),
    "scaled pose": (lambda c: add_to(c, ["y.png"], [SCALED]), 422, "poses[0]: transform_matrix rotation is not rigid"),
    "two images of one name": (
        lambda c: add_to(c, ["twice.png", "twice.png"], GOOD * 2),
        422,
        "images[1] (twice.png): the same name as images[0]",
    ),
    "fewer poses than images": (lambda c: add_to(c, ["p.png", "q.png"], GOOD), 422, "got 2 images but 1 poses"),
    "poses not JSON": (lambda c: add_to(c, ["y.png"], "[[1, 2"), 422, "poses: not valid JSON"),
    "image over the limit": (
        lambda c: add_to(c, ["huge.png"], GOOD, [png(1) + bytes(30_000)]),
        413,
        "images[0] (huge.png): larger than the upload limit of 0.02 MB",
    ),
    "request body over the limit": (
        lambda c: add_to(c, ["huge.png"], GOOD, [bytes(3_000_000)]),
        413,
        "request body:",
    ),
    "bad file name": (lambda c: add_to(c, ["a b.png"], GOOD), 422, "images[0] (a b.png): a file name may hold only"),
    "not an image suffix": (lambda c: add_to(c, ["notes.txt"], GOOD), 422, "images[0] (notes.txt): the file name"),
    "name already in the dataset": (lambda c: add_to(c, ["r_0.png"], GOOD), 422, "already has a frame named 'r_0'"),
    "images missing": (
        lambda c: c.post("/sessions/bad/captures", data={"poses": json.dumps(GOOD)}),
        422,
        "images: Field required",
    ),
    "settings not JSON": (
        lambda c: c.post(
            "/sessions/from-uploads", data={"settings": "{"}, files=[("images", ("a.png", png(0), "image/png"))]
        ),
        422,
        "settings: not valid JSON",
    ),
    "evaluate outside the root": (
        _json("POST", "/sessions/bad/evaluate", {"dataset": "../.."}),
        422,
        "leads outside",
    ),
    "evaluate a missing split": (
        _json("POST", "/sessions/bad/evaluate", {"dataset": "data", "split": "val"}),
        422,
        "transforms_val.json",
    ),
    "evaluate zero views": (
        _json("POST", "/sessions/bad/evaluate", {"dataset": "data", "max_views": 0}),
        422,
        "max_views:",
    ),
    "uploads with a bad intrinsic": (
        lambda c: c.post(
            "/sessions/from-uploads",
            data={
                "settings": json.dumps({"id": "u1", "poses": GOOD, "intrinsics": {"width": 8, "height": 8, "fx": -1}})
            },
            files=[("images", ("a.png", png(0), "image/png"))],
        ),
        422,
        "intrinsics.fx:",
    ),
}


def add_to(client, names, poses, images=None):
    images = images if images is not None else [png(i) for i in range(len(names))]
    files = [("images", (name, data, "image/png")) for name, data in zip(names, images)]
    poses = poses if isinstance(poses, str) else json.dumps(poses)
    return client.post("/sessions/bad/captures", data={"poses": poses}, files=files)


def test_bad_requests_are_answered_with_their_4xx_and_one_line(server, root):
    assert len(BAD_REQUESTS) >= 20
    if not (root / "bad").exists():
        assert create(server, "bad").status_code == 201
    before = sorted(p.name for p in (root / "bad" / "dataset" / "train").iterdir())
    wrong = {}
    for name, (send, status, says) in BAD_REQUESTS.items():
        answer = send(server.client)
        detail = answer.json().get("detail")
        if answer.status_code != status or not isinstance(detail, str) or says not in detail or "\n" in detail:
            wrong[name] = (answer.status_code, detail)
    assert not wrong, wrong
    # Nothing was added to the session by any of them.
    assert sorted(p.name for p in (root / "bad" / "dataset" / "train").iterdir()) == before
    assert server.client.get("/sessions/bad").json()["views"] == 4
