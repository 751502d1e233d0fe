"""`nerfaug serve` left running next to a robot: no read outside the root and no file content in an
error, work per request bounded (image headers before decoding, streamed bodies counted, pose
counts, per-session queues answering 429 with Retry-After while health stays fast), numbers
checked at the schema, the CLI's warnings, images stored under the name their bytes say, and a
session the service holds refused to a `nerfaug` command.

A real server process on a loopback port; every wait is bounded in count and time."""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from test_serve import HOST, SIZE, Server, create, png, poses_at, tiny_dataset

httpx = pytest.importorskip("httpx")
pytestmark = pytest.mark.slow

SECRET = "TOPSECRET-do-not-echo"


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("limits") / "root"
    tiny_dataset(root / "data")
    (root / "data" / "transforms_x").mkdir()  # lets `transforms_x/../..` resolve, as on the tester's machine
    (root.parent / "outside").mkdir()
    (root.parent / "outside" / "evil.json").write_text(json.dumps({"frames": SECRET}))
    (root / "leaky").mkdir()
    (root / "leaky" / "transforms_test.json").write_text(json.dumps({"camera_angle_x": 0.7, "frames": SECRET}))
    return root


@pytest.fixture(scope="module")
def server(root):
    server = Server(root, "--max-upload-mb", "1")
    try:
        for session in ("s1", "s2"):
            answer = create(server, session)
            assert answer.status_code == 201, answer.text
        yield server
    finally:
        server.kill()


def peak_rss_mb(server: Server) -> float:
    """The server process's peak resident memory so far (VmHWM), MB."""
    for line in Path(f"/proc/{server.process.pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


# ---- paths ---------------------------------------------------------------------------------------


def test_a_split_naming_a_path_is_refused_before_any_read(server):
    answer = server.client.post("/sessions/s1/evaluate", json={"dataset": ".", "split": "x/../../outside/evil"})
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    assert detail.startswith("split:") and SECRET not in detail


def test_an_error_about_a_dataset_file_never_echoes_its_content(server):
    answer = server.client.post("/sessions/s1/evaluate", json={"dataset": "leaky", "split": "test"})
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    assert "transforms_test.json" in detail and "frames" in detail and SECRET not in detail


def test_a_split_file_linking_outside_the_root_is_refused(server, root):
    (root / "linked").mkdir(exist_ok=True)
    link = root / "linked" / "transforms_test.json"
    if not link.exists():
        link.symlink_to(root.parent / "outside" / "evil.json")
    answer = server.client.post("/sessions/s1/evaluate", json={"dataset": "linked"})
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    assert "transforms_test.json" in detail and "outside" in detail and SECRET not in detail


# ---- bounded work --------------------------------------------------------------------------------


def bomb_png(width: int = 16000, height: int = 10000) -> bytes:
    """A valid grey PNG of width x height zero pixels: a few hundred KB that decode to width*height bytes."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    packer, row, parts = zlib.compressobj(9), b"\x00" * (width + 1), []
    for _ in range(height // 100):
        parts.append(packer.compress(row * 100))
    parts.append(packer.flush())
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b"")


def test_decompression_bombs_are_refused_from_their_header(server):
    bomb = bomb_png()
    assert len(bomb) < 1_000_000
    before = peak_rss_mb(server)
    answers = []

    def send(i: int) -> None:
        files = [("images", (f"bomb_{i}.png", bomb, "image/png"))]  # under the upload limit of 1 MB
        poses = json.dumps(poses_at([40.0], [10.0]))
        answers.append(server.client.post("/sessions/s1/captures", data={"poses": poses}, files=files))

    senders = [threading.Thread(target=send, args=(i,)) for i in range(3)]
    for thread in senders:
        thread.start()
    for thread in senders:
        thread.join(120)
    assert len(answers) == 3
    for answer in answers:
        assert answer.status_code == 413, answer.text
        assert "images[0]" in answer.json()["detail"]
    # 3 x 160 MB decoded would show; the header alone costs nothing.
    assert peak_rss_mb(server) - before < 100


def test_a_chunked_body_is_cut_off_at_the_limit(server):
    """60 MB streamed without Content-Length: answered 413 long before the client has sent it all."""
    limit = 8 * 1024 * 1024  # a JSON body's limit
    with socket.create_connection((HOST, server.port), timeout=60) as conn:
        conn.sendall(
            b"POST /sessions/s1/proposals HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n"
            b"Content-Type: application/json\r\n\r\n"
        )
        block, sent, reply = b" " * (256 * 1024), 0, b""
        conn.settimeout(0.02)
        deadline = time.monotonic() + 60
        while sent < 60 * 1024 * 1024 and time.monotonic() < deadline:
            try:
                reply += conn.recv(65536)
            except TimeoutError:
                pass
            except OSError:
                break
            if reply:
                break
            try:
                conn.sendall(f"{len(block):x}\r\n".encode() + block + b"\r\n")
            except OSError:  # the server closed the connection after answering
                break
            sent += len(block)
        conn.settimeout(10)
        try:
            while b"}" not in reply:  # the status line, the headers and the JSON detail
                more = conn.recv(65536)
                if not more:
                    break
                reply += more
        except OSError:
            pass
    assert reply.startswith(b"HTTP/1.1 413"), reply[:200]
    assert b"request body" in reply
    assert sent < 3 * limit, f"{sent / 1e6:.1f} MB were sent before the answer"


def test_too_many_reachable_poses_are_refused_by_the_schema(server):
    schema = server.client.get("/openapi.json").json()["components"]["schemas"]["ProposalRequest"]["properties"]
    assert schema["candidates"]["anyOf"][0]["maxItems"] == 10_000
    assert schema["n_candidates"]["maximum"] == 20_000
    pose = poses_at([40.0], [10.0])[0]
    answer = server.client.post("/sessions/s1/proposals", json={"n": 1, "candidates": [pose] * 10_001})
    assert answer.status_code == 422, answer.text[:300]
    assert answer.json()["detail"].startswith("candidates:")


def test_too_many_images_in_one_request_are_refused(server):
    files = [("images", (f"many_{i}.png", png(i), "image/png")) for i in range(65)]
    poses = json.dumps(poses_at([40.0] * 65, list(range(65))))
    answer = server.client.post("/sessions/s1/captures", data={"poses": poses}, files=files)
    assert answer.status_code == 413 and "at most 64" in answer.json()["detail"], answer.text


def test_a_full_session_queue_answers_429_and_health_stays_fast(server):
    body = {"n": 2, "n_candidates": 400, "selection": {"entropy_resolution": 16}, "method": "ours", "allow_empty": True}
    answers, health = [], []

    def propose() -> None:
        with httpx.Client(base_url=f"http://{HOST}:{server.port}", timeout=120.0) as client:
            answers.append(client.post("/sessions/s2/proposals", json=body))

    senders = [threading.Thread(target=propose) for _ in range(10)]
    for thread in senders:
        thread.start()
    deadline = time.monotonic() + 120
    while any(t.is_alive() for t in senders) and time.monotonic() < deadline:
        start = time.monotonic()
        assert server.client.get("/health").status_code == 200
        assert server.client.get("/sessions/s1").status_code == 200
        health.append(time.monotonic() - start)
        time.sleep(0.05)
    for thread in senders:
        thread.join(120)
    codes = sorted(a.status_code for a in answers)
    assert codes.count(200) >= 1 and codes.count(429) >= 1 and set(codes) <= {200, 429}, codes
    refused = next(a for a in answers if a.status_code == 429)
    assert int(refused.headers["retry-after"]) >= 1 and "session 's2'" in refused.json()["detail"]
    assert health and max(health) < 2.0, health


# ---- numbers at the schema -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("path", "body", "field"),
    [
        ("/sessions/s1/proposals", {"n": 1, "selection": {"sharpness": "abc"}}, "sharpness"),
        ("/sessions/s1/proposals", {"n": 1, "seed": 2**64}, "seed:"),
        ("/sessions/s1/proposals", {"n": 1, "selection": {"entropy_resolution": 100_000}}, "entropy_resolution"),
        ("/sessions/s1/proposals", {"n": 1, "constraints": {"elevation": [-100, 10]}}, "constraints.elevation"),
        ("/sessions/from-dataset", {"id": "big", "dataset": "data", "seed": 2**64}, "seed:"),
        ("/sessions/from-dataset", {"id": "tiny", "dataset": "data", "radius": 1e-300}, "radius:"),
        ("/sessions/from-dataset", {"id": "far", "dataset": "data", "radius": 1e5}, "radius"),
        ("/sessions/from-dataset", {"id": "sp", "dataset": "data", "split": "../data/train"}, "split:"),
        ("/sessions/s1/uncertainty", {"pose": np.eye(4).tolist(), "width": 1025}, "width: must be <= 1024"),
        ("/sessions/s1/uncertainty", {"pose": np.eye(4).tolist(), "fisher_width": 0}, "fisher_width: must be >= 1"),
    ],
)
def test_numbers_out_of_range_are_422_naming_the_field_and_leave_nothing(server, root, path, body, field):
    answer = server.client.post(path, json=body)
    assert answer.status_code == 422, answer.text
    assert field in answer.json()["detail"]
    if "id" in body:
        assert not (root / body["id"]).exists()


def test_a_session_from_a_dataset_with_a_truncated_image_leaves_no_folder(server, root):
    broken = tiny_dataset(root / "broken", seed=3)
    image = sorted((broken / "train").glob("*.png"))[2]
    image.write_bytes(image.read_bytes()[:40])
    answer = server.client.post("/sessions/from-dataset", json={"id": "half", "dataset": "broken", "engine": "test"})
    assert answer.status_code == 422, answer.text
    assert image.name in answer.json()["detail"]
    assert not (root / "half").exists()


# ---- what is stored, and what is said ------------------------------------------------------------


def test_a_capture_at_the_pose_of_an_existing_view_is_warned_about(server, root):
    existing = json.loads((root / "s1" / "dataset" / "transforms_train.json").read_text())["frames"][0]
    files = [("images", ("again_0.png", png(7), "image/png"))]
    answer = server.client.post(
        "/sessions/s1/captures", data={"poses": json.dumps([existing["transform_matrix"]])}, files=files
    )
    assert answer.status_code == 201, answer.text
    warned = answer.json()["warnings"]
    assert len(warned) == 1 and "again_0" in warned[0] and Path(existing["file_path"]).stem in warned[0]


def test_an_image_is_stored_under_the_name_its_bytes_say(server, root):
    import imageio.v3 as iio

    pixels = np.random.default_rng(3).integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
    jpeg = iio.imwrite("<bytes>", pixels, extension=".jpg")
    files = [("images", ("photo_0.png", jpeg, "image/png"))]
    answer = server.client.post(
        "/sessions/s1/captures", data={"poses": json.dumps(poses_at([33.0], [77.0]))}, files=files
    )
    assert answer.status_code == 201, answer.text
    signatures = {".png": b"\x89PNG", ".jpg": b"\xff\xd8\xff", ".jpeg": b"\xff\xd8\xff"}
    stored = [p for p in (root / "s1" / "dataset" / "train").iterdir() if p.stem == "photo_0"]
    assert len(stored) == 1
    assert stored[0].read_bytes().startswith(signatures[stored[0].suffix]), stored[0].name


def test_a_session_the_service_holds_is_refused_to_a_command(server, root):
    assert server.client.get("/sessions/s1").status_code == 200
    done = subprocess.run(
        [sys.executable, "-m", "nerfaug.cli", "train", str(root / "s1"), "--steps", "1", "--device", "cpu"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 1, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.startswith("nerfaug:")]
    assert len(lines) == 1 and "`nerfaug serve`" in lines[0] and "s1" in lines[0], done.stderr


def test_state_of_a_session_not_opened_yet_is_read_from_its_files(server, root):
    from nerfaug.capture import CaptureSession, SessionSettings

    CaptureSession.create(root / "data", root / "made_here", SessionSettings(engine="test"))
    answer = server.client.get("/sessions/made_here")
    assert answer.status_code == 200, answer.text
    assert answer.json()["views"] == 4 and answer.json()["step"] == 0 and not answer.json()["running"]
