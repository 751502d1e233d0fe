"""Active capture (`nerfaug.capture`, `nerfaug.cli.session`) on a tiny analytic scene: a shaded
sphere, off the origin and at a non-Blender scale, seen by 8 cameras of 16x16 pixels on one half
of its hemisphere. No Blender needed except for the one test marked `blender`."""

import importlib.util
import json
import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from nerfaug.cameras import Cameras, image_rays
from nerfaug.capture import (
    CaptureSession,
    Hemisphere,
    ProposalRequest,
    SessionSettings,
    estimate_centre,
    estimate_hemisphere,
    read_poses,
)
from nerfaug.data import DatasetError, Views, load_blender_split, load_dataset, load_nerfstudio, write_blender_split
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, half_hemisphere_poses, pose_from_angles, sample_uniform_poses
from nerfaug.selection import SelectionConfig

SIZE = 16
CENTRE = (0.5, -0.3, 0.2)
RADIUS = 2.0  # camera distance; the sphere's radius is a quarter of it
FAST = SelectionConfig(entropy_resolution=6)
PROPOSE = dict(n_candidates=40, selection=FAST)


def render_sphere(poses, size: int = SIZE, centre=CENTRE, radius: float = RADIUS / 4) -> Views:
    """Exact renders of a sphere coloured by its normal, with alpha (1 on the sphere, 0 off)."""
    cameras = Cameras.from_fov(
        torch.as_tensor(poses, dtype=torch.float32).reshape(-1, 4, 4), BLENDER_CAMERA_ANGLE_X, size, size
    )
    c = torch.tensor(centre)
    images, alphas = [], []
    for i in range(len(cameras)):
        origins, directions = image_rays(cameras, i)
        oc = origins - c
        b = (oc * directions).sum(-1)
        disc = b**2 - ((oc**2).sum(-1) - radius**2)
        hit = disc > 0
        normal = (oc + (-b - disc.clamp(min=0).sqrt())[:, None] * directions) / radius
        rgb = torch.where(hit[:, None], 0.5 + 0.5 * normal, torch.ones(3)).clamp(0, 1)
        images.append(rgb.reshape(size, size, 3))
        alphas.append(hit.float().reshape(size, size))
    # Quantise to 8 bits so that images survive a PNG round trip exactly.
    images = (torch.stack(images) * 255).round() / 255
    return Views(cameras, images, [f"./train/r_{i}" for i in range(len(cameras))], torch.stack(alphas))


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("sphere")
    write_blender_split(root, "train", render_sphere(half_hemisphere_poses(8, radius=RADIUS, centre=CENTRE)))
    return root


def files_of(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def new_session(dataset: Path, run: Path, seed: int = 3) -> CaptureSession:
    return CaptureSession.create(dataset, run, SessionSettings(engine="test", seed=seed))


# ---- the hemisphere ----------------------------------------------------------------------------


def test_estimate_hemisphere_recovers_known_centre_and_radius(generator):
    poses = sample_uniform_poses(12, generator, radius=2.5, centre=(0.3, -1.2, 0.7))
    hemisphere = estimate_hemisphere(poses)
    assert hemisphere.centre == pytest.approx((0.3, -1.2, 0.7), abs=1e-5)
    assert hemisphere.radius == pytest.approx(2.5, rel=1e-5)
    # Noisy aim: the least-squares point is still close to the true centre.
    noisy = poses.clone()
    noisy[:, :3, 3] += 0.01 * torch.randn(12, 3, generator=generator)
    assert torch.allclose(estimate_centre(noisy), torch.tensor([0.3, -1.2, 0.7], dtype=torch.float64), atol=0.03)
    # Given values are kept.
    assert estimate_hemisphere(poses, centre=(0, 0, 0), radius=1.0).radius == 1.0


def test_estimate_centre_refuses_parallel_axes():
    poses = torch.eye(4).repeat(3, 1, 1)
    poses[:, 0, 3] = torch.tensor([0.0, 1.0, 2.0])  # three cameras side by side, all looking down -z
    with pytest.raises(ValueError, match="parallel"):
        estimate_centre(poses)


def test_a_capture_whose_world_is_not_z_up_is_warned_about_at_creation(dataset, tmp_path):
    import warnings

    from nerfaug.capture.state import TiltedPole

    # the sphere's capture turned as LLFF and COLMAP frames often are: the world's up along -y
    turn = torch.tensor([[1.0, 0, 0, 0], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]])
    tilted = render_sphere(
        turn @ half_hemisphere_poses(8, radius=RADIUS, centre=CENTRE),
        centre=(turn[:3, :3] @ torch.tensor(CENTRE)).tolist(),
    )
    write_blender_split(tmp_path / "tilted", "train", tilted)
    with pytest.warns(
        TiltedPole, match=r"transforms_train.json: the cameras. mean up axis is 9[0-9] degrees .*--estimate-up"
    ):
        new_session(tmp_path / "tilted", tmp_path / "run")
    with warnings.catch_warnings():
        warnings.simplefilter("error", TiltedPole)  # the pole taken from the cameras, or a z-up world: silent
        CaptureSession.create(
            tmp_path / "tilted", tmp_path / "estimated", SessionSettings(engine="test", estimate_up=True)
        )
        CaptureSession.create(
            tmp_path / "tilted", tmp_path / "given", SessionSettings(engine="test", up=(0.0, -1.0, 0.0))
        )
        new_session(dataset, tmp_path / "upright")


def test_an_evaluation_marks_the_views_the_session_trains_on(dataset, tmp_path, capsys):
    from nerfaug.cli import main

    session = new_session(dataset, tmp_path / "run")
    own = session.evaluate(session.held_out(dataset, "train"), lpips=None)
    assert [row["trained_on"] for row in own.per_view] == [True] * 8
    other = tmp_path / "other"
    write_blender_split(
        other, "test", render_sphere(half_hemisphere_poses(3, azimuth_start=math.pi, radius=RADIUS, centre=CENTRE))
    )
    held_out = session.evaluate(session.held_out(other, "test"), lpips=None)
    assert [row["trained_on"] for row in held_out.per_view] == [False] * 3
    # the command says so in one line, and its JSON keeps which
    main(["eval", str(tmp_path / "run"), "--data", str(dataset), "--split", "train", "--out", str(tmp_path / "e.json")])
    (line,) = [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning:")]
    assert "8 of the 8 views have the pose of a view the session trains on" in line
    assert all(row["trained_on"] for row in json.loads((tmp_path / "e.json").read_text())["per_view"])
    main(["eval", str(tmp_path / "run"), "--data", str(other)])
    assert "warning" not in capsys.readouterr().err


def test_engine_frame_round_trip_and_angles():
    hemisphere = Hemisphere(centre=(1.0, 2.0, -0.5), radius=0.8, up=(0.3, -0.2, 0.9))
    engine = pose_from_angles(torch.tensor([0.4, 2.0]), torch.tensor([0.3, 1.2]))  # on the engine hemisphere
    world = hemisphere.to_world(engine)
    assert torch.allclose(hemisphere.to_engine(world), engine, atol=1e-5)
    azimuth, polar, radius = hemisphere.angles(world)
    assert azimuth.tolist() == pytest.approx([0.4, 2.0], abs=1e-5)
    assert polar.tolist() == pytest.approx([0.3, 1.2], abs=1e-5)
    assert radius.tolist() == pytest.approx([0.8, 0.8], rel=1e-5)
    # A world pose is still a rigid camera looking at the world centre.
    r = world[:, :3, :3].double()
    assert torch.allclose(r.transpose(1, 2) @ r, torch.eye(3, dtype=torch.float64).expand(2, 3, 3), atol=1e-5)
    to_centre = torch.tensor(hemisphere.centre) - world[:, :3, 3]
    cosine = (-world[:, :3, 2] * to_centre).sum(-1) / to_centre.norm(dim=-1)
    assert cosine.tolist() == pytest.approx([1.0, 1.0], abs=1e-5)


# ---- the loop ----------------------------------------------------------------------------------


def test_propose_add_train_propose_round_trip(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    assert session.hemisphere.centre == pytest.approx(CENTRE, abs=1e-4)
    assert session.hemisphere.radius == pytest.approx(RADIUS, rel=1e-4)
    session.train(3)
    first = session.propose(ProposalRequest(allow_empty=True, n=3, method="ours", n_candidates=40, selection=FAST))
    assert first.poses.shape == (3, 4, 4) and first.scores.shape == (len(first.candidates),)
    assert first.map_path is not None and first.map_path.stat().st_size > 0
    assert (first.polar <= math.pi / 2 + 1e-5).all()

    names = session.add_views(render_sphere(first.poses).images, first)
    assert names == first.names
    session.train(2)
    second = session.propose(ProposalRequest(allow_empty=True, n=2, method="ours", **PROPOSE), map=False)
    assert second.number == 1 and second.names == ["capture_001_00", "capture_001_01"]
    assert session.step == 5 and len(session.trainer.train_views) == 11

    grown = load_dataset(session.dataset_dir)  # a standard Blender folder, world frame
    assert len(grown) == 11 and grown.names[-3:] == [f"./train/{n}" for n in names]
    assert torch.allclose(grown.cameras.camera_to_world[-3:], first.poses, atol=1e-6)
    assert torch.equal(grown.images[-3:], render_sphere(first.poses).images)
    # The trainer sees the same pixels, in the engine frame (centred, Blender scale).
    assert torch.equal(session.trainer.train_views.images[-3:], grown.images[-3:])
    engine_positions = session.trainer.train_views.cameras.positions
    assert engine_positions.norm(dim=-1).mean().item() == pytest.approx(4.0311, rel=1e-3)

    session.save()
    state = json.loads((session.run_dir / "session.json").read_text())
    assert state["step"] == 5 and len(state["proposals"]) == 2
    assert state["additions"][0]["proposal"] == 0 and state["additions"][0]["names"] == names


def test_views_added_after_the_last_save_are_not_lost(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    poses = half_hemisphere_poses(2, azimuth_start=-math.pi / 2, radius=RADIUS, centre=CENTRE)
    session.add_views(render_sphere(poses).images, poses)  # no save() afterwards
    reopened = CaptureSession.open(tmp_path / "run")
    assert len(reopened.trainer.train_views) == 10
    assert torch.equal(reopened.trainer.train_views.images, session.trainer.train_views.images)


def test_poses_json_round_trip_and_convention(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    proposal = session.propose(ProposalRequest(allow_empty=True, n=4, method="uniform", n_candidates=40), map=True)
    path = proposal.write(tmp_path / "out" / "poses.json")
    assert path.with_suffix(".png").stat().st_size > 0
    data = json.loads(path.read_text())
    assert data["camera_angle_x"] == pytest.approx(BLENDER_CAMERA_ANGLE_X, rel=1e-6)
    assert (data["w"], data["h"]) == (SIZE, SIZE)
    assert [f["file_path"] for f in data["frames"]] == [f"./{n}" for n in proposal.names]
    poses, names = read_poses(path)
    assert names == proposal.names
    assert torch.allclose(poses, proposal.poses, atol=1e-6)
    # Each proposed camera sits on the hemisphere and looks at its centre down its -z axis, +y up.
    to_centre = torch.tensor(CENTRE) - poses[:, :3, 3]
    assert to_centre.norm(dim=-1).tolist() == pytest.approx([RADIUS] * 4, rel=1e-3)
    cosine = (-poses[:, :3, 2] * to_centre).sum(-1) / to_centre.norm(dim=-1)
    assert cosine.tolist() == pytest.approx([1.0] * 4, abs=1e-4)
    assert (poses[:, 2, 1] >= -1e-6).all()  # camera up never points below the horizon
    assert (poses[:, 2, 3] >= CENTRE[2] - 1e-4).all()  # upper hemisphere
    # The sphere, rendered exactly from a proposed pose, is in the middle of the picture.
    alpha = render_sphere(poses, size=32).alphas
    ys, xs = torch.meshgrid(torch.arange(32.0), torch.arange(32.0), indexing="ij")
    for a in alpha:
        centroid = ((a * xs).sum() / a.sum(), (a * ys).sum() / a.sum())
        assert centroid == pytest.approx((15.5, 15.5), abs=0.6)


def test_user_given_candidates_are_the_only_choices(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    reachable = half_hemisphere_poses(5, azimuth_start=-math.pi / 2, radius=RADIUS, centre=CENTRE)
    already = load_dataset(dataset).cameras.camera_to_world[:2]  # poses it has: never proposed again
    proposal = session.propose(
        ProposalRequest(allow_empty=True, n=2, method="distance", candidates=torch.cat([already, reachable])), map=False
    )
    assert proposal.scores.shape == (5,)
    for pose in proposal.poses:
        assert (reachable - pose).abs().amax(dim=(1, 2)).min() < 1e-6


def test_resume_after_save_gives_the_same_next_proposal(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    session.train(3)
    session.save()
    original = session.propose(ProposalRequest(allow_empty=True, n=3, **PROPOSE), map=False)
    torch.manual_seed(12345)  # the global RNG must not matter
    resumed = CaptureSession.open(tmp_path / "run").propose(
        ProposalRequest(allow_empty=True, n=3, **PROPOSE), map=False
    )
    assert resumed.number == original.number == 0
    assert torch.equal(resumed.indices, original.indices)
    assert torch.equal(resumed.candidates.camera_to_world, original.candidates.camera_to_world)
    assert torch.allclose(resumed.scores, original.scores)
    later = session.propose(
        ProposalRequest(allow_empty=True, n=3, **PROPOSE), map=False
    )  # the next proposal draws new candidates
    assert not torch.equal(later.candidates.camera_to_world, original.candidates.camera_to_world)


# ---- adding images from any source, and refusing bad ones ----------------------------------------


def test_add_accepts_files_folders_arrays_tensors_and_views(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    poses = half_hemisphere_poses(6, azimuth_start=-math.pi / 2, radius=RADIUS, centre=CENTRE)
    views = render_sphere(poses)
    rgba = np.concatenate([views.images.numpy(), views.alphas.numpy()[..., None]], -1)
    uint8 = (rgba * 255).round().astype(np.uint8)
    folder = tmp_path / "captures"
    folder.mkdir()
    for i in range(2):
        iio.imwrite(folder / f"shot_{i}.png", uint8[i])
    assert session.add_views(folder, poses[:2]) == ["shot_0", "shot_1"]  # a folder
    assert session.add_views([folder / "shot_1.png"], poses[2:3], names=["again"]) == ["again"]  # files
    session.add_views(uint8[3:4], poses[3:4])  # uint8 array
    session.add_views(torch.from_numpy(rgba[4:5]), poses[4])  # float tensor, one pose
    # Views hold images composited over the background; stored with their alpha, they must load
    # back as the same composited pixels (here half-transparent: 0.5 * colour + 0.5 * white).
    half = torch.full((1, SIZE, SIZE), 0.5)
    composited = 0.5 * views.images[[5]] + 0.5
    session.add_views(Views(views.cameras[[5]], composited, ["./x/from_views"], half))
    grown = load_dataset(session.dataset_dir)
    assert grown.names[8:] == [
        "./train/shot_0",
        "./train/shot_1",
        "./train/again",
        "./train/view_0011",
        "./train/view_0012",
        "./train/from_views",
    ]
    assert (session.dataset_dir / "train" / "shot_0.png").read_bytes() == (folder / "shot_0.png").read_bytes()
    expected = torch.cat([views.images[:2], views.images[1:2], views.images[3:5], composited])
    assert torch.allclose(grown.images[8:], expected, atol=1 / 255)
    assert torch.equal(grown.images, session.trainer.train_views.images)


def test_bad_adds_fail_clearly_and_leave_the_dataset_untouched(dataset, tmp_path):
    session = new_session(dataset, tmp_path / "run")
    poses = half_hemisphere_poses(2, azimuth_start=-math.pi / 2, radius=RADIUS, centre=CENTRE)
    good = (render_sphere(poses).images.numpy() * 255).round().astype(np.uint8)
    sheared = poses.clone()
    sheared[1, :3, 0] *= 1.5
    (tmp_path / "broken.png").write_bytes(b"not a png at all")
    iio.imwrite(tmp_path / "ok.png", good[0])
    proposal_json = tmp_path / "poses.json"
    proposal_json.write_text(
        json.dumps(
            {
                "camera_angle_x": BLENDER_CAMERA_ANGLE_X,
                "frames": [{"file_path": "./capture_000_00", "transform_matrix": poses[0].tolist()}],
            }
        )
    )
    cases = [
        (good[:1], poses, "got 1 images but 2 poses"),
        (np.zeros((2, 8, 8, 3), np.uint8), poses, r"images\[0\].*8x8 pixels but the dataset's camera is 16x16"),
        (good, sheared, r"poses\[1\].*not rigid"),
        ([tmp_path / "ok.png", tmp_path / "broken.png"], poses, r"broken\.png.*cannot read image"),
        ([tmp_path / "ok.png", tmp_path / "missing.png"], poses, r"missing\.png.*not found"),
        (good.astype(np.float32), poses, r"images\[0\].*\[0, 1\].*max 255"),
        (good[..., :2], poses, r"images\[0\].*\(H, W, 3\) or \(H, W, 4\)"),
        (tmp_path, proposal_json, r"no image named capture_000_00\.\* for pose 0"),
    ]
    before = files_of(session.dataset_dir)
    for images, bad_poses, message in cases:
        with pytest.raises(DatasetError, match=message):
            session.add_views(images, bad_poses)
        assert files_of(session.dataset_dir) == before, message
    assert len(session.trainer.train_views) == 8

    session.add_views(good, poses, names=["a", "b"])
    before = files_of(session.dataset_dir)
    with pytest.raises(DatasetError, match="already has a frame named 'a'"):
        session.add_views(good, poses, names=["a", "c"])
    assert files_of(session.dataset_dir) == before


# ---- formats -----------------------------------------------------------------------------------


def test_nerfstudio_source_with_its_own_intrinsics(tmp_path):
    from nerfaug.data import write_nerfstudio

    views = render_sphere(half_hemisphere_poses(6, radius=RADIUS, centre=CENTRE))
    c = views.cameras
    views.cameras = Cameras(c.camera_to_world, c.fx, c.fy * 1.01, c.cx + 0.5, c.cy, c.width, c.height)
    write_nerfstudio(tmp_path / "ns", views)
    session = new_session(tmp_path / "ns", tmp_path / "run")
    assert (session.dataset_dir / "transforms.json").exists()  # not representable as Blender: kept
    pose = half_hemisphere_poses(1, azimuth_start=-math.pi / 2, radius=RADIUS, centre=CENTRE)
    session.add_views(render_sphere(pose).images, pose)
    grown = load_nerfstudio(session.dataset_dir)
    assert len(grown) == 7
    # The added frame gets the session's camera: the source's first frame's intrinsics.
    assert grown.cameras.fy.tolist() == pytest.approx([c.fy[0].item() * 1.01] * 7, rel=1e-5)
    assert grown.cameras.cx.tolist() == pytest.approx([c.cx[0].item() + 0.5] * 7, rel=1e-5)
    with pytest.raises(ValueError, match="nerfstudio"):
        session.export(tmp_path / "as-blender", "blender")


# ---- the CLI -----------------------------------------------------------------------------------


def test_cli_train_propose_add_export(dataset, tmp_path, capsys):
    from nerfaug.cli import main

    run, poses_json, captures = tmp_path / "run", tmp_path / "poses.json", tmp_path / "captures"
    main(["train", str(dataset), "--out", str(run), "--steps", "2", "--engine", "test", "--seed", "1"])
    main(["train", str(run), "--steps", "3"])  # until step 3
    assert json.loads((run / "session.json").read_text())["step"] == 3
    main(
        [
            "propose",
            str(run),
            "--allow-empty",  # three steps of training: the NeRF is empty, which this round does not test
            "--n",
            "2",
            "--method",
            "ours",
            "--out",
            str(poses_json),
            "--n-candidates",
            "30",
            "--selection.entropy-resolution",
            "6",
        ]
    )
    assert poses_json.with_suffix(".png").exists()
    poses, names = read_poses(poses_json)
    captures.mkdir()
    for name, image in zip(names, render_sphere(poses).images):
        iio.imwrite(captures / f"{name}.png", (image.numpy() * 255).round().astype(np.uint8))
    main(["add", str(run), "--images", str(captures), "--poses", str(poses_json), "--steps", "1"])
    state = json.loads((run / "session.json").read_text())
    assert state["step"] == 4 and state["views_in_model"] == 10 and state["additions"][0]["proposal"] == 0

    main(["export", str(run), "--format", "nerfstudio", "--out", str(tmp_path / "ns")])
    main(["export", str(run), "--format", "blender", "--out", str(tmp_path / "bl")])
    grown = load_dataset(run / "dataset")
    for exported in (load_nerfstudio(tmp_path / "ns"), load_blender_split(tmp_path / "bl", "train")):
        assert torch.equal(exported.images, grown.images)
        assert torch.allclose(exported.cameras.camera_to_world, grown.cameras.camera_to_world, atol=1e-6)
        assert torch.allclose(exported.cameras.fx, grown.cameras.fx)
    meta = json.loads((tmp_path / "ns" / "transforms.json").read_text())
    assert meta["camera_model"] == "OPENCV" and meta["frames"][-1]["file_path"] == f"images/{names[-1]}.png"

    # Adding the same captures again is bad input: one line naming the clash, exit 2.
    with pytest.raises(SystemExit) as refused:
        main(["add", str(run), "--images", str(captures), "--poses", str(poses_json), "--steps", "0"])
    assert refused.value.code == 2
    assert "already has a frame" in capsys.readouterr().err


# ---- a real render ----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.blender
@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="needs bpy")
def test_blender_render_of_a_proposed_pose_shows_the_object_centred(tmp_path):
    from nerfaug.oracle import BlenderOracle

    # A session on NeRF-synthetic's layout (centre at the origin, radius 4.03, where the built-in
    # scenes sit); the sphere is a stand-in for its training images.
    root = tmp_path / "data"
    write_blender_split(root, "train", render_sphere(half_hemisphere_poses(6), 48, centre=(0, 0, 0), radius=1.0))
    session = new_session(root, tmp_path / "run")
    proposal = session.propose(ProposalRequest(allow_empty=True, n=2, method="uniform", n_candidates=40), map=False)
    views = BlenderOracle("chair", 48, 48, samples=4, progress=False).capture(proposal.poses, proposal.names)
    ys, xs = torch.meshgrid(torch.arange(48.0), torch.arange(48.0), indexing="ij")
    for alpha in views.alphas:
        assert alpha.sum() > 20  # the object is in view
        centroid = ((alpha * xs).sum() / alpha.sum(), (alpha * ys).sum() / alpha.sum())
        assert centroid == pytest.approx((23.5, 23.5), abs=48 * 0.15)
    session.add_views(views, proposal)
    assert load_dataset(session.dataset_dir).alphas is not None

    # The simulator path of the CLI: render a proposal's poses, named for `nerfaug add`.
    from nerfaug.cli import main

    session.save()
    second = session.propose(
        ProposalRequest(allow_empty=True, n=1, method="uniform", n_candidates=40), map=False
    ).write(tmp_path / "poses.json")
    main(
        [
            "render-proposals",
            str(session.run_dir),
            "--poses",
            str(second),
            "--scene",
            "chair",
            "--out",
            str(tmp_path / "renders"),
            "--samples",
            "4",
        ]
    )
    main(["add", str(session.run_dir), "--images", str(tmp_path / "renders"), "--poses", str(second), "--steps", "0"])
    assert len(load_dataset(session.dataset_dir)) == 9
