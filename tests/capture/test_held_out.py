"""`nerfaug eval`'s held-out views: a limited number of them covers the whole test orbit; a sparse
start from a set without a test split (LLFF, IDR, nerfstudio) keeps a spread quarter of its views
apart, out of the pool, and `eval` scores those."""

import json
import math
import shutil

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.capture import CaptureSession
from nerfaug.capture.evaluate import load_held_out
from nerfaug.cli import main
from nerfaug.data import load_dataset, write_nerfstudio
from nerfaug.data.blender import load_blender_split, write_blender_split
from nerfaug.data.views import Views
from nerfaug.experiment.config import ExperimentConfig
from nerfaug.experiment.scene_views import split_captured
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, angles_from_pose, pose_from_angles, sample_uniform_poses
from nerfaug.layouts import HELD_OUT_MOST, held_out_count

from ..data.test_captured_formats import idr_fixture, llff_fixture


def orbit_dataset(root, n=24, size=8) -> Views:
    """A Blender-format test split whose frames go once round the object, in order (as
    NeRF-synthetic's test orbit does)."""
    azimuths = torch.linspace(0, 2 * math.pi, n + 1)[:-1]
    poses = pose_from_angles(azimuths, torch.full_like(azimuths, 0.5), 4.0)
    images = torch.randint(0, 256, (n, size, size, 3), generator=torch.Generator().manual_seed(0)).float() / 255
    views = Views(
        Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size), images, [f"./test/r_{i}" for i in range(n)]
    )
    write_blender_split(root, "test", views)
    return load_blender_split(root, "test")


def test_a_few_held_out_views_are_spread_over_the_orbit_with_their_own_images(tmp_path):
    full = orbit_dataset(tmp_path)
    held = load_held_out(tmp_path, "test", max_views=6)
    assert len(held) == 6
    azimuth = torch.rad2deg(angles_from_pose(held.cameras.camera_to_world)[0]) % 360
    gaps = torch.diff(torch.sort(azimuth).values, append=azimuth.min()[None] + 360)
    assert float(gaps.max()) < 90  # the first 6 of 24 frames would leave a gap of 285 degrees
    for i, name in enumerate(held.names):
        assert torch.equal(held.image(i), full.images[full.names.index(name)])


def test_all_views_when_the_limit_is_not_below_their_number(tmp_path):
    full = orbit_dataset(tmp_path, n=5)
    assert load_held_out(tmp_path, "test", max_views=9).names == full.names


# ---- a sparse start keeps views apart on a set without a test split -------------------------------

N = 16  # one in 4 kept apart: 4 views


def nerfstudio_fixture(root):
    """A nerfstudio capture: one transforms.json listing 16 views all round the object."""
    generator = torch.Generator().manual_seed(4)
    poses = sample_uniform_poses(N, generator)
    images = (torch.rand(N, 8, 8, 3, generator=generator) * 255).round() / 255
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 8, 8)
    write_nerfstudio(root, Views(cameras, images, [f"images/frame_{i:03d}" for i in range(N)]))
    return root


CAPTURES = {
    "llff": lambda root: llff_fixture(root, n=N, masks=False),
    "idr": lambda root: idr_fixture(root, n=N)[0],
    "nerfstudio": nerfstudio_fixture,
}


def train_sparse(data, run, *extra):
    common = ["--engine", "test", "--steps", "1", "--device", "cpu", "--seed", "1", "--estimate-up"]
    main(["train", str(data), "--out", str(run), "--initial", "3", *common, *extra])


def evaluated(run, out, *extra) -> dict:
    main(["eval", str(run), "--no-lpips", "--device", "cpu", "--out", str(out), *extra])
    return json.loads(out.read_text())


@pytest.mark.parametrize("fmt", sorted(CAPTURES))
def test_a_sparse_start_keeps_a_spread_quarter_out_of_the_pool_and_eval_scores_only_those(fmt, tmp_path, capsys):
    data, run = CAPTURES[fmt](tmp_path / "data"), tmp_path / "run"
    train_sparse(data, run)
    said = capsys.readouterr().out
    assert "3 of the 16 views" in said and "4 views spread over all directions are held out" in said
    assert "the other 9 are the candidates" in said
    state = json.loads((run / "session.json").read_text())
    kept, started = state["start"]["held_out"], state["start"]["names"]
    pool = [f["file_path"] for f in json.loads((run / "pool.json").read_text())["frames"]]
    assert len(kept) == 4 and not set(kept) & (set(pool) | set(started))
    assert sorted(kept + started + pool) == sorted(load_dataset(data, "train", lazy=True).names)

    # The experiments' split of the same set keeps the same views apart (one protocol).
    cameras = load_dataset(data, "train", lazy=True)
    study = split_captured(cameras.cameras.camera_to_world, HELD_OUT_MOST, 3, 0, 3)
    assert sorted(kept) == sorted(cameras.names[i] for i in study.test)

    # eval, with neither --data nor --split, and with the split a captured set's users name.
    for extra in ((), ("--data", str(data), "--split", "test")):
        result = evaluated(run, tmp_path / "eval.json", *extra)
        printed = capsys.readouterr()
        assert sorted(v["name"] for v in result["per_view"]) == sorted(kept)
        assert not any(v["trained_on"] for v in result["per_view"])
        assert "4 views of" in printed.out and "kept apart for testing" in printed.out
        assert f"  views: {', '.join(kept)}\n" in printed.out  # the record's order: the listing's
        assert "note:" not in printed.err and "warning:" not in printed.err and "kept apart" in result["views"]


def test_views_added_from_the_pool_never_reach_the_held_out_ones(tmp_path, capsys):
    data, run = llff_fixture(tmp_path / "data", n=N, masks=False), tmp_path / "run"
    train_sparse(data, run)
    poses = tmp_path / "poses.json"
    main(["propose", str(run), "--n", "9", "--n-candidates", "9", "--allow-empty", "--out", str(poses)])
    main(["add", str(run), "--images", str(data / "images"), "--poses", str(poses), "--steps", "0"])
    capsys.readouterr()
    result = evaluated(run, tmp_path / "eval.json")
    kept = json.loads((run / "session.json").read_text())["start"]["held_out"]
    assert len(CaptureSession.open(run).cameras) == 12  # every candidate added
    assert sorted(v["name"] for v in result["per_view"]) == sorted(kept)
    assert not any(v["trained_on"] for v in result["per_view"])


def test_an_older_session_and_a_whole_set_score_every_view_and_say_why(tmp_path, capsys):
    data = llff_fixture(tmp_path / "data", n=N, masks=False)
    older = tmp_path / "older"
    train_sparse(data, older)
    state = json.loads((older / "session.json").read_text())
    del state["start"]["held_out"]  # as a session started before views were kept apart
    (older / "session.json").write_text(json.dumps(state))
    capsys.readouterr()
    result = evaluated(older, tmp_path / "older.json")
    said = capsys.readouterr()
    assert len(result["per_view"]) == N and result["split"] == "test"
    assert sum(v["trained_on"] for v in result["per_view"]) == 3
    note = [line for line in said.err.splitlines() if line.startswith("note:")]
    assert len(note) == 1 and "started before a sparse start kept views apart" in note[0]

    whole = tmp_path / "whole"
    main(["train", str(data), "--out", str(whole), "--engine", "test", "--steps", "1", "--device", "cpu"])
    said = capsys.readouterr().out
    assert [line for line in said.splitlines() if line.startswith("no view is held out")] != []
    result = evaluated(whole, tmp_path / "whole.json")
    assert len(result["per_view"]) == N and all(v["trained_on"] for v in result["per_view"])
    assert "note: the session trains on a whole set" in capsys.readouterr().err


def test_a_set_with_a_test_split_keeps_scoring_it(tmp_path, capsys):
    data = tmp_path / "data"
    generator = torch.Generator().manual_seed(6)
    poses = sample_uniform_poses(N, generator)
    images = (torch.rand(N, 8, 8, 3, generator=generator) * 255).round() / 255
    cameras = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 8, 8)
    write_blender_split(data, "train", Views(cameras, images, [f"./train/r_{i}" for i in range(N)]))
    orbit_dataset(data, n=5)
    train_sparse(data, tmp_path / "run")
    state = json.loads((tmp_path / "run" / "session.json").read_text())
    assert "held_out" not in state["start"]
    assert len(json.loads((tmp_path / "run" / "pool.json").read_text())["frames"]) == N - 3
    capsys.readouterr()
    result = evaluated(tmp_path / "run", tmp_path / "eval.json")
    assert [v["name"] for v in result["per_view"]] == [f"./test/r_{i}" for i in range(5)]
    assert result["views"] == f"split 'test' of {data}"
    assert "note:" not in capsys.readouterr().err


def test_the_kept_share_and_its_bound_are_the_studys():
    assert [held_out_count(n) for n in (3, 4, 16, 135, 199, 200, 1000)] == [0, 1, 4, 33, 49, 50, 50]
    assert ExperimentConfig().n_test == HELD_OUT_MOST


def test_eval_without_data_names_the_option_when_the_starting_folder_is_gone(tmp_path, capsys):
    data, run = llff_fixture(tmp_path / "data", n=N, masks=False), tmp_path / "run"
    train_sparse(data, run)
    shutil.rmtree(data)
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:
        main(["eval", str(run), "--no-lpips", "--device", "cpu"])
    assert refused.value.code == 2
    assert capsys.readouterr().err.strip().endswith(f"the dataset {run} started from is gone; name one with --data")
