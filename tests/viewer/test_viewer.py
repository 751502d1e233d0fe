"""`nerfaug view`: a session's scene as viser's server side holds it (cameras, candidates coloured
by score, proposals by rank, hemisphere, box), the live render, a proposal that appears without a
restart, a run folder left byte for byte as it was, and the page drawn by a real headless Chromium
(skipped, saying why, where no Chromium binary exists)."""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")

from nerfaug.capture import CaptureSession, ProposalRequest, SessionSettings  # noqa: E402
from nerfaug.health import EmptyModelWarning  # noqa: E402
from nerfaug.selection import SelectionConfig  # noqa: E402
from nerfaug.viewer import scene  # noqa: E402
from nerfaug.viewer.app import Viewer  # noqa: E402
from nerfaug.viewer.snapshot import read_snapshot  # noqa: E402

from ..capture.test_constraints import tiny_dataset  # noqa: E402

FAST = SelectionConfig(entropy_resolution=4)
RADIUS = 4.03
BROWSERS = ("chromium", "chromium-browser", "google-chrome")
OFFLINE = ["--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1", "--proxy-server=http://127.0.0.1:9"]


def browser() -> str | None:
    return next((path for path in map(shutil.which, BROWSERS) if path), None)


def propose(run: Path, n: int = 3) -> None:
    """A proposal of `n` views, saved (a two-step NeRF: empty, as the warning says; scored all the same)."""
    session = CaptureSession.open(run)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EmptyModelWarning)
        session.propose(ProposalRequest(allow_empty=True, n=n, n_candidates=60, selection=FAST, seed=0), map=False)
    session.save()


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("viewed")
    settings = SessionSettings(engine="test", seed=1, centre=(0, 0, 0), radius=RADIUS)
    session = CaptureSession.create(tiny_dataset(tmp / "data"), tmp / "run", settings)
    session.train(2)
    session.save()
    propose(tmp / "run")
    return tmp / "run"


def contents(folder: Path) -> dict[str, tuple[str, int]]:
    """Every file under `folder`: its digest and modification time."""
    return {
        str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def wait_for(condition, seconds: float = 60.0) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.1)
    return False


def test_the_snapshot_reads_the_sessions_cameras_and_the_last_scores(run):
    snapshot = read_snapshot(run)
    assert [c.name for c in snapshot.training] == [f"r_{i}" for i in range(4)]
    assert all(c.image is not None and c.image.is_file() for c in snapshot.training)
    assert snapshot.step == 2 and snapshot.views == 4
    candidates = snapshot.candidates
    assert candidates.positions.shape == (60, 3) and candidates.scores.shape == (60,)
    assert np.allclose(np.linalg.norm(candidates.positions, axis=1), RADIUS, rtol=1e-4)
    record = snapshot.proposals[-1]
    assert candidates.chosen and len(candidates.chosen) == len(record.names) == 3
    # The proposed poses are the chosen candidates', in rank order.
    assert np.allclose(candidates.positions[candidates.chosen], record.poses[:, :3, 3], atol=1e-4)
    assert "score" in candidates.label and record.method in candidates.label


def test_the_hemisphere_and_the_box_are_drawn_where_they_lie(run):
    h = read_snapshot(run).hemisphere
    rings = scene.hemisphere_lines(h).reshape(-1, 3)
    assert np.allclose(np.linalg.norm(rings - np.asarray(h.centre), axis=1), RADIUS, rtol=1e-6)
    assert ((rings - np.asarray(h.centre)) @ np.asarray(h.up) >= -1e-9 * RADIUS).all()  # the upper half only
    box = scene.box_lines(h, 1.5)
    assert box.shape == (12, 2, 3)
    lengths = np.linalg.norm(box[:, 0] - box[:, 1], axis=1)
    assert np.allclose(lengths, 2 * 1.5 * h.scale)
    assert np.allclose(np.linalg.norm(box.reshape(-1, 3), axis=1), math.sqrt(3) * 1.5 * h.scale)


def test_scores_run_from_dark_to_bright():
    tint = scene.colours(np.array([0.3, 5.0, 1.0])).astype(int)
    assert tint[0].sum() < tint[2].sum() < tint[1].sum()
    assert tuple(tint[1]) == tuple(scene.COLOUR_MAP[-1].astype(int))


def test_the_viewer_serves_the_scene_renders_and_writes_nothing(run):
    before = contents(run)
    viewer = Viewer(run, port=0, poll_s=0.2)
    try:
        handle = viewer.server.scene.get_handle_by_name
        assert viewer.url.startswith("http://127.0.0.1:") and viewer.server.get_port() > 0
        training = [handle(f"/training/{i:03d}_r_{i}") for i in range(4)]
        assert all(h is not None for h in training)
        snapshot = viewer.snapshot
        wxyz, position = scene.opencv_pose(snapshot.training[1].pose)
        assert np.allclose(training[1].position, position, atol=1e-5)
        cloud = handle("/candidates")
        colours = np.asarray(cloud.colors)
        assert colours.shape == (60, 3)
        best = int(np.argmax(snapshot.candidates.scores))
        assert tuple(colours[best]) == tuple(scene.COLOUR_MAP[-1].astype(np.uint8))
        for rank in (1, 2, 3):
            assert handle(f"/proposals/0/rank_{rank}") is not None
            assert handle(f"/proposals/0/rank_{rank}/label") is not None
        assert np.allclose(handle("/hemisphere/centre").position, (0, 0, 0))
        assert handle("/box") is not None and handle("/hemisphere/rings") is not None
        assert "step 2" in viewer.status.content and "4 views" in viewer.status.content
        # The live render: the checkpoint loaded read-only, a frame from the first view's camera.
        assert wait_for(lambda: viewer.live.step == 2), "the checkpoint was not loaded"
        position, look_at = scene.first_view(snapshot)
        assert math.isclose(np.linalg.norm(position - look_at), 2.6 * RADIUS, rel_tol=1e-6)
        pose = snapshot.training[0].pose @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL to OpenCV: viser's
        image = viewer.live.render(pose, snapshot.training[0].fov_y, 1.0, 32)
        assert image.shape == (32, 32, 3) and image.dtype == np.uint8
        assert viewer.live.seconds_per_pixel > 0
    finally:
        viewer.stop()
    assert contents(run) == before  # read only: not one file written, touched or added


@pytest.mark.timeout(300)
def test_a_proposal_made_while_the_viewer_is_open_appears_without_a_restart(run):
    viewer = Viewer(run, port=0, poll_s=0.2, live=False)
    try:
        assert viewer.server.scene.get_handle_by_name("/proposals/1/rank_1") is None
        propose(run, n=2)
        # The scene is drawn before the panel within one redraw (another thread): wait for the
        # redraw to end, not only for its first node.
        drawn = viewer.redraws
        assert wait_for(lambda: viewer.server.scene.get_handle_by_name("/proposals/1/rank_2") is not None, 30)
        assert wait_for(lambda: viewer.redraws > drawn and "#1: 2 views" in viewer.proposal_menu.value, 30)
        assert viewer.picked == 1
        assert "proposal 1" in viewer.score_label.content
        # Picking the first proposal in the panel highlights its views instead (labelled by rank).
        viewer.proposal_menu.value = next(o for o in viewer.proposal_menu.options if o.startswith("#0:"))
        assert viewer.picked == 0
        assert viewer.server.scene.get_handle_by_name("/proposals/0/rank_1/label") is not None
        assert viewer.server.scene.get_handle_by_name("/proposals/1/rank_1/label") is None
    finally:
        viewer.stop()
    # Opened on a session of two proposals, the viewer shows the last one (and starts: the panel's
    # menu, set while the scene is drawn, calls back into the viewer).
    reopened = Viewer(run, port=0, live=False)
    try:
        assert reopened.picked == 1 and reopened.proposal_menu.value.startswith("#1:")
    finally:
        reopened.stop()


def test_without_the_extra_the_command_says_how_to_install_it(run):
    code = "import sys; sys.modules['viser'] = None; from nerfaug.cli import main; main(['view', sys.argv[1]])"
    done = subprocess.run([sys.executable, "-c", code, str(run)], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0
    assert done.stderr.strip().splitlines()[-1].endswith("pip install 'nerfaug[viewer]' (viser is missing)")


@pytest.mark.slow
@pytest.mark.skipif(browser() is None, reason=f"no Chromium binary ({', '.join(BROWSERS)}) on PATH")
def test_headless_chromium_draws_the_scene(run, tmp_path):
    viewer = Viewer(run, port=0, live=False)
    try:
        shot = tmp_path / "shot.png"
        command = [browser(), "--headless", "--no-sandbox", "--disable-dev-shm-usage", *OFFLINE]
        command += ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=900,600"]
        command += [f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=8000", f"--screenshot={shot}"]
        env = {**os.environ, "HOME": str(tmp_path)}
        done = subprocess.run([*command, viewer.url], capture_output=True, text=True, timeout=240, env=env)
        assert shot.is_file(), done.stderr[-2000:]
    finally:
        viewer.stop()
    from PIL import Image

    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(int).reshape(-1, 3)

    r, g, b = pixels.T
    # The frusta's thin lines, blended with the white page by anti-aliasing: counted by hue. The
    # training cameras are blue (`scene.TRAINING`), the picked proposal's views magenta (`scene.PICKED`).
    blue = int(((b - r > 60) & (b > 150)).sum())
    magenta = int(((r - g > 80) & (b - g > 40)).sum())
    assert blue > 50 and magenta > 20, (blue, magenta)


def test_a_proposal_linked_out_of_the_run_and_a_damaged_session_are_said_in_the_panel(run, tmp_path):
    copy = tmp_path / "run"
    shutil.copytree(run, copy, symlinks=True)
    outside = tmp_path / "elsewhere.json"
    outside.write_text("{}")
    proposal = next((copy / "proposals").glob("proposal_*.json"))
    proposal.unlink()
    proposal.symlink_to(outside)
    snapshot = read_snapshot(copy)
    assert snapshot.proposals[0].refused, "a proposal file linked out of the run is refused, not followed"
    viewer = Viewer(copy, port=0, poll_s=0.2, live=False)
    try:
        assert "could not be read" not in viewer.status.content
        session_file = copy / "session.json"
        good = session_file.read_bytes()
        session_file.write_text("{ damaged")
        assert wait_for(lambda: "could not be read" in viewer.status.content, 30)
        assert viewer.server.scene.get_handle_by_name("/proposals/0/rank_1") is not None  # the last view stays
        session_file.write_bytes(good)
        assert wait_for(lambda: "could not be read" not in viewer.status.content, 30)
    finally:
        viewer.stop()
