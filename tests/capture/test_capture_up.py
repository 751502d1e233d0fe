"""A captured set's up direction where its format records none: the README's real-scene recipe
(`nerfaug train DATA --out RUN --initial 6`, then `nerfaug propose RUN --n 6`), run as written on
an LLFF capture taken in a y-down world (as COLMAP's often are), proposes no view below the
capture's horizon: the session's pole is the cameras' mean up axis unless told otherwise. A
Blender scene keeps world +z; `--up` or `--no-estimate-up` keeps the pole given."""

from __future__ import annotations

import json
import math

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.capture import CaptureSession
from nerfaug.capture.requests import SessionSettings
from nerfaug.cli import main
from nerfaug.hemisphere import pose_from_angles

H, W = 12, 16
# The capture's world: z-up turned by +90 degrees about x, so its up is -y.
TURN = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
TRUE_UP = TURN @ np.array([0.0, 0.0, 1.0])


def ring_poses(n: int = 16) -> np.ndarray:
    """n OpenGL cameras all round an object at the origin, 15 to 60 degrees above its horizon,
    looking at it (a z-up world), float64 (n, 4, 4)."""
    azimuth = torch.linspace(0, 2 * math.pi, n + 1, dtype=torch.float64)[:-1]
    elevation = torch.deg2rad(15 + 45 * (torch.arange(n, dtype=torch.float64) % 4) / 3)
    return pose_from_angles(azimuth, math.pi / 2 - elevation, radius=3.0).double().numpy()


def llff_capture(root, world=TURN):
    """An LLFF capture (`poses_bounds.npy`, `images/`) of `ring_poses` moved into `world`."""
    rng = np.random.default_rng(0)
    (root / "images").mkdir(parents=True)
    rows = []
    for i, pose in enumerate(ring_poses()):
        moved = np.eye(4)
        moved[:3, :3], moved[:3, 3] = world @ pose[:3, :3], world @ pose[:3, 3]
        # OpenGL (right, up, backwards) as LLFF's (down, right, backwards) columns, then hwf.
        matrix = np.stack([-moved[:3, 1], moved[:3, 0], moved[:3, 2], moved[:3, 3], [H, W, 20.0]], axis=1)
        rows.append(np.concatenate([matrix.reshape(-1), [1.0, 5.0]]))
        iio.imwrite(root / "images" / f"IMG_{i:02d}.png", rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
    np.save(root / "poses_bounds.npy", np.stack(rows))
    return root


def elevation_above_horizon(pose) -> float:
    """Degrees of a camera above the capture's own horizon (the plane through the object at the
    origin, normal to the capture's up)."""
    position = np.asarray(pose, dtype=np.float64)[:3, 3]
    return math.degrees(math.asin(float(position @ TRUE_UP) / float(np.linalg.norm(position))))


@pytest.mark.parametrize("initial", [("--initial", "6"), ()], ids=["sparse-start", "hemisphere"])
def test_the_readme_recipe_on_an_llff_capture_proposes_nothing_below_its_horizon(tmp_path, capsys, initial):
    data, run, poses = llff_capture(tmp_path / "capture"), tmp_path / "run", tmp_path / "poses.json"
    # The recipe's commands as written, only shorter (and on the small test engine).
    main(["train", str(data), "--out", str(run), *initial, "--steps", "2", "--engine", "test", "--device", "cpu"])
    created = capsys.readouterr().out
    assert "up: the cameras' mean up axis" in created, "the estimated pole is not said"
    assert created.splitlines()[0].endswith("; engine test (--engine chooses another)")  # said at the start
    main(["propose", str(run), "--n", "6", "--out", str(poses), "--allow-empty", "--device", "cpu"])
    frames = json.loads(poses.read_text())["frames"]
    assert len(frames) == 6
    heights = [elevation_above_horizon(frame["transform_matrix"]) for frame in frames]
    assert min(heights) > 0, f"proposed below the capture's horizon: {heights}"
    # What propose says agrees: the elevation it reports is the height above the capture's horizon.
    said = [math.degrees(frame["elevation"]) for frame in frames]
    assert np.allclose(said, heights, atol=1.0), (said, heights)
    pole = CaptureSession.open(run).hemisphere.up
    assert math.degrees(math.acos(min(1.0, float(np.dot(pole, TRUE_UP))))) < 5


@pytest.mark.parametrize("keep", [("--up", "0", "0", "1"), ("--no-estimate-up",)])
def test_a_pole_given_or_estimation_turned_off_is_kept_on_an_llff_capture(tmp_path, capsys, keep):
    data, run = llff_capture(tmp_path / "capture"), tmp_path / "run"
    main(["train", str(data), "--out", str(run), *keep, "--steps", "0", "--engine", "test", "--device", "cpu"])
    out, err = capsys.readouterr()
    assert CaptureSession.open(run).hemisphere.up == (0.0, 0.0, 1.0)
    assert "--estimate-up" in err and "mean up axis" not in out  # the tilted pole is warned about, as before


def test_an_llff_capture_already_z_up_gets_its_own_up_estimated(tmp_path):
    """On a z-up LLFF capture the estimate is +z to within the ring's own tilt (nothing is lost)."""
    data = llff_capture(tmp_path / "capture", world=np.eye(3))
    session = CaptureSession.create(data, tmp_path / "run", SessionSettings(engine="test"), device="cpu")
    assert session.state.hemisphere_estimated["up"]
    assert np.allclose(session.hemisphere.up, (0.0, 0.0, 1.0), atol=1e-6)


def turned_about_up(pose: np.ndarray, degrees: float) -> np.ndarray:
    """`pose` (4, 4) turned about the capture's up through the object (Rodrigues' formula)."""
    k, t = TRUE_UP, math.radians(degrees)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    rotation = np.eye(3) + math.sin(t) * cross + (1 - math.cos(t)) * cross @ cross
    turned = np.eye(4)
    turned[:3, :3], turned[:3, 3] = rotation @ pose[:3, :3], rotation @ pose[:3, 3]
    return turned


def test_propose_names_each_views_nearest_training_view_and_says_when_it_is_beside_one(tmp_path, capsys):
    """Candidates 3 degrees from training views IMG_00 to IMG_07 (neighbours lie 22.5 degrees
    apart): `propose` names each chosen view's nearest training view and the angle, and says in one
    line that they lie beside training views (the selection does not keep them away)."""
    data, run = llff_capture(tmp_path / "capture"), tmp_path / "run"
    main(["train", str(data), "--out", str(run), "--steps", "2", "--engine", "test", "--device", "cpu"])
    trained, expected = {}, {}
    for i, pose in enumerate(ring_poses()[:8]):
        moved = np.eye(4)
        moved[:3, :3], moved[:3, 3] = TURN @ pose[:3, :3], TURN @ pose[:3, 3]
        trained[i] = turned_about_up(moved, 3.0)
        a, b = moved[:3, 3], trained[i][:3, 3]  # seen from the object at the origin
        expected[i] = math.degrees(math.acos(float(a @ b) / float(np.linalg.norm(a) * np.linalg.norm(b))))
    candidates = tmp_path / "reachable.json"
    frames = [{"file_path": f"reach_{i}", "transform_matrix": p.tolist()} for i, p in trained.items()]
    candidates.write_text(json.dumps({"frames": frames}))
    capsys.readouterr()
    poses = tmp_path / "poses.json"
    main(
        ["propose", str(run), "--n", "3", "--candidates", str(candidates), "--out", str(poses)]
        + ["--allow-empty", "--min-separation", "0", "--device", "cpu"]
    )
    out = capsys.readouterr().out
    chosen = json.loads(poses.read_text())["frames"]
    lines = [line for line in out.splitlines() if "nearest training view" in line]
    assert len(lines) == 3
    for frame, line in zip(chosen, lines):
        # Which candidate it is, by its pose: then its training view is the one it was turned from.
        source = next(i for i, p in trained.items() if np.allclose(p, frame["transform_matrix"], atol=1e-4))
        name, angle = line.split("nearest training view ")[1].split(", ")
        assert name == f"IMG_{source:02d}"
        assert abs(float(angle.split()[0]) - expected[source]) < 0.1
    assert "3 of 3 views lie within 15 deg of a training view" in out
