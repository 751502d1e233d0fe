"""Where proposed views may lie (`nerfaug.capture.constraints`): each constraint on hand-computed
cases, then `CaptureSession.propose` and `nerfaug propose` keeping within them."""

import json
import math
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession, Hemisphere, ProposalRequest, SessionSettings
from nerfaug.capture.constraints import (
    TooFewCandidates,
    ViewConstraints,
    angle_range_mask,
    azimuth_mask,
    constrained_indices,
    constraints_mask,
    keep_out_mask,
)
from nerfaug.capture.requests import RequestError
from nerfaug.cli import main
from nerfaug.data import Views, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, pose_from_angles, sample_uniform_poses
from nerfaug.selection import SelectionConfig

FAST = SelectionConfig(entropy_resolution=4)


def poses_at(elevation_deg, azimuth_deg, radius=2.0, centre=(0.0, 0.0, 0.0)) -> torch.Tensor:
    polar = torch.deg2rad(90.0 - torch.tensor(elevation_deg, dtype=torch.float64))
    return pose_from_angles(torch.deg2rad(torch.tensor(azimuth_deg, dtype=torch.float64)), polar, radius, centre)


# ---- the pure functions, by hand -------------------------------------------------------------


def test_elevation_range_includes_its_ends():
    mask = angle_range_mask(torch.tensor([-10.0, 20.0, 45.0, 60.0, 60.5]), 20.0, 60.0)
    assert mask.tolist() == [False, True, True, True, False]


@pytest.mark.parametrize(("low", "high"), [(-60.0, 60.0), (300.0, 420.0), (660.0, 780.0)])
def test_an_azimuth_arc_wraps_through_zero(low, high):
    mask = azimuth_mask(torch.tensor([0.0, 50.0, 60.0, 61.0, 180.0, 299.0, 300.0, 330.0, -30.0]), low, high)
    assert mask.tolist() == [True, True, True, False, False, False, True, True, True]


def test_an_azimuth_arc_without_wrap_and_a_full_circle():
    angles = torch.tensor([0.0, 90.0, 135.0, 180.0, 270.0])
    assert azimuth_mask(angles, 90.0, 180.0).tolist() == [False, True, True, True, False]
    assert azimuth_mask(angles, -10.0, 350.0).all()
    assert azimuth_mask(angles, 45.0, 45.0).tolist() == [False] * 5


def test_keep_out_cones_by_hand():
    centre = torch.tensor([1.0, 1.0, 0.0])
    # Directions from the centre: +x (0 deg from the axis), +y (90), the xy diagonal (45 deg).
    positions = torch.tensor([[3.0, 1.0, 0.0], [1.0, 4.0, 0.0], [2.0, 2.0, 0.0]])
    axis = torch.tensor([[2.0, 0.0, 0.0]])  # length does not matter
    assert keep_out_mask(positions, centre, axis, torch.tensor([30.0])).tolist() == [False, True, True]
    assert keep_out_mask(positions, centre, axis, torch.tensor([45.0])).tolist() == [False, True, True]  # boundary
    assert keep_out_mask(positions, centre, axis, torch.tensor([46.0])).tolist() == [False, True, False]
    two = keep_out_mask(positions, centre, torch.tensor([[1.0, 0, 0], [0, 1.0, 0]]), torch.tensor([10.0, 10.0]))
    assert two.tolist() == [False, False, True]
    assert keep_out_mask(positions, centre, torch.zeros(0, 3), torch.zeros(0)).all()


def test_constraints_on_known_poses_about_an_off_origin_centre():
    centre = (0.5, -1.0, 2.0)
    hemisphere = Hemisphere(centre, 2.0)
    elevations = [30.0, 80.0, 10.0, 45.0, 45.0]
    azimuths = [10.0, 200.0, 100.0, 350.0, 90.0]
    poses = poses_at(elevations, azimuths, 2.0, centre)
    poses[4, :3, 3] = torch.tensor(centre) + 1.5 * (poses[4, :3, 3] - torch.tensor(centre)) / 2.0  # radius 1.5

    def kept(constraints: ViewConstraints) -> list[bool]:
        return constraints_mask(constraints, poses, hemisphere).tolist()

    assert kept(ViewConstraints(elevation=(20, 60))) == [True, False, False, True, True]
    assert kept(ViewConstraints(azimuth=(-20, 20))) == [True, False, False, True, False]
    assert kept(ViewConstraints(radius=(1.9, 2.1))) == [True, True, True, True, False]
    # A cone straight up (half-angle 20 deg) holds the pose at elevation 80 only.
    assert kept(ViewConstraints(keep_out=((0, 0, 1, 20),))) == [True, False, True, True, True]
    assert kept(ViewConstraints(elevation=(20, 60), azimuth=(0, 180))) == [True, False, False, False, True]


def test_elevation_follows_the_hemispheres_up_axis():
    # A y-up world: the camera straight above the centre is at +y, at elevation 90.
    hemisphere = Hemisphere((0.0, 0.0, 0.0), 2.0, (0.0, 1.0, 0.0))
    above = torch.eye(4)[None].clone()
    above[0, :3, 3] = torch.tensor([0.0, 2.0, 0.0])
    beside = torch.eye(4)[None].clone()
    beside[0, :3, 3] = torch.tensor([0.0, 0.0, 2.0])
    poses = torch.cat([above, beside])
    assert constraints_mask(ViewConstraints(elevation=(80, 90)), poses, hemisphere).tolist() == [True, False]
    assert constraints_mask(ViewConstraints(elevation=(-5, 5)), poses, hemisphere).tolist() == [False, True]


def test_too_few_candidates_names_the_numbers():
    hemisphere = Hemisphere((0.0, 0.0, 0.0), 2.0)
    poses = poses_at([10.0, 30.0, 50.0, 70.0], [0.0, 0.0, 0.0, 0.0])
    constraints = ViewConstraints(elevation=(40, 60))
    assert constrained_indices(poses, hemisphere, constraints, 1).tolist() == [2]
    with pytest.raises(TooFewCandidates, match=r"^constraints leave 1 of 4 candidates; 2 asked"):
        constrained_indices(poses, hemisphere, constraints, 2)
    assert constrained_indices(poses, hemisphere, None, 4).tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize(
    ("kwargs", "says"),
    [
        ({"elevation": (1, 2, 3)}, "elevation (1, 2, 3): Tuple should have at most 2 items"),
        ({"elevation": (60, 10)}, "elevation (60, 10): low must be <= high"),
        ({"elevation": (-100, 10)}, "elevation[0] -100: must be >= -90"),
        ({"azimuth": (0, float("nan"))}, "azimuth[1] nan: Input should be a finite number"),
        ({"azimuth": (0, 800)}, "azimuth[1] 800: must be <= 720"),
        ({"radius": (-1, 2)}, "radius[0] -1: must be >= 0"),
        ({"keep_out": ((0, 0, 0, 10),)}, "keep_out[0] (0, 0, 0, 10): the direction (x, y, z) must not be zero"),
        ({"keep_out": ((0, 0, 1, 180),)}, "keep_out[0][3] 180: must be < 180"),
        ({"keep_out": ((0, 0, 1),)}, "keep_out[0][3] None: Field required"),
        ({"keep_out": ((0, 0, 1, 10),) * 65}, "keep_out"),
    ],
)
def test_bad_constraints_are_one_line_naming_the_field(kwargs, says):
    with pytest.raises(RequestError) as error:
        ViewConstraints(**kwargs).checked()
    assert str(error.value).startswith(says)
    assert "\n" not in str(error.value)


def test_constraints_round_trip_through_a_dict():
    constraints = ViewConstraints(elevation=(10, 60), azimuth=(-45, 45), radius=(1, 3), keep_out=((1, 0, 0, 30),))
    data = json.loads(json.dumps(constraints.to_dict()))
    assert ViewConstraints.from_dict(data) == constraints.checked()
    assert ViewConstraints.from_dict({}).empty
    with pytest.raises(RequestError, match=r"^height \[0, 1\]: unknown field"):
        ViewConstraints.from_dict({"height": [0, 1]})


# ---- in a session ------------------------------------------------------------------------------

SIZE = 8


def tiny_dataset(root: Path) -> Path:
    generator = torch.Generator().manual_seed(0)
    poses = sample_uniform_poses(4, generator)
    images = (torch.rand(4, SIZE, SIZE, 3, generator=generator) * 255).round() / 255
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, SIZE, SIZE)
    write_blender_split(root, "train", Views(cameras, images, [f"./train/r_{i}" for i in range(4)]))
    return root


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("constrained")
    data = tiny_dataset(tmp / "data")
    settings = SessionSettings(engine="test", seed=1, centre=(0, 0, 0), radius=4.03)
    session = CaptureSession.create(data, tmp / "run", settings)
    session.train(2)
    session.save()
    return tmp / "run"


def test_a_session_proposes_within_the_constraints(session_dir):
    session = CaptureSession.open(session_dir)
    constraints = ViewConstraints(elevation=(30, 70), azimuth=(-90, 45), keep_out=((1, 0, 0.5, 25),))
    proposal = session.propose(
        ProposalRequest(allow_empty=True, n=3, n_candidates=80, selection=FAST, constraints=constraints), map=False
    )
    assert len(proposal) == 3
    assert constraints_mask(constraints, proposal.poses, session.hemisphere).all()
    assert constraints_mask(constraints, proposal.candidates.camera_to_world, session.hemisphere).all()
    elevation = 90 - torch.rad2deg(proposal.polar)
    assert ((elevation >= 30) & (elevation <= 70)).all()
    assert session.proposals[-1].model_extra["constraints"] == constraints.checked().to_dict()
    assert session.proposals[-1].n_candidates == len(proposal.candidates) < 80


def test_constraints_apply_to_a_list_of_reachable_poses(session_dir):
    session = CaptureSession.open(session_dir)
    reachable = poses_at([20.0, 40.0, 60.0, 80.0, 35.0], [0.0, 90.0, 180.0, 270.0, 45.0], radius=4.03)
    constraints = ViewConstraints(elevation=(30, 65))
    request = ProposalRequest(allow_empty=True, n=2, candidates=reachable, selection=FAST, constraints=constraints)
    proposal = session.propose(request, map=False)
    chosen = {tuple(p[:3, 3].round(decimals=3).tolist()) for p in proposal.poses}
    allowed = {tuple(p[:3, 3].round(decimals=3).tolist()) for p in reachable[[1, 2, 4]]}
    assert chosen <= allowed
    with pytest.raises(TooFewCandidates, match=r"^constraints leave 3 of 5 candidates; 4 asked"):
        session.propose(replace(request, n=4), map=False)
    as_dict = session.propose(replace(request, n=1, constraints={"elevation": [55, 90]}), map=False)
    assert any(torch.allclose(as_dict.poses[0], reachable[i], atol=1e-4) for i in (2, 3))
    assert len(as_dict.candidates) == 2


def test_nerfaug_propose_takes_the_constraints(session_dir, tmp_path, capsys):
    out = tmp_path / "poses.json"
    args = [
        "propose",
        str(session_dir),
        "--allow-empty",
        "--out",
        str(out),
        "--n",
        "2",
        "--n-candidates",
        "60",
        "--device",
        "cpu",
    ]
    main([*args, "--elevation", "40", "90", "--azimuth", "90", "270", "--selection.entropy-resolution", "4"])
    frames = json.loads(out.read_text())["frames"]
    assert len(frames) == 2
    for frame in frames:
        assert "polar" not in frame  # one angle convention in every output: elevation
        assert 40 - 1e-3 <= math.degrees(frame["elevation"]) <= 90 + 1e-3
        assert 90 - 1e-3 <= math.degrees(frame["azimuth"]) <= 270 + 1e-3
    # The printed angles are the constraint's: elevation, in degrees.
    printed = [
        float(line.split("elevation")[1].split()[0])
        for line in capsys.readouterr().out.splitlines()
        if "elevation" in line
    ]
    assert len(printed) == 2 and all(40 - 0.1 <= e <= 90 + 0.1 for e in printed)
    with pytest.raises(SystemExit) as done:
        main([*args, "--force", "--elevation", "89.9", "90"])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("nerfaug: constraints leave ") and err.endswith("ask for fewer views)")
    assert "of 60 candidates; 2 asked" in err and "\n" not in err
    with pytest.raises(SystemExit) as done:
        main([*args, "--force", "--elevation", "60", "10"])
    assert done.value.code == 2
    assert capsys.readouterr().err.strip() == "nerfaug: --elevation 60 10: low must be <= high"
