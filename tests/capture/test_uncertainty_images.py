"""`nerfaug uncertainty RUN --poses POSES --out DIR`: a figure and arrays per pose, in world units,
and an --out that is the user's is refused."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfaug.capture import CaptureSession, SessionSettings
from nerfaug.capture.requests import MAX_FISHER_WIDTH, MAX_IMAGE_WIDTH, RequestError
from nerfaug.cli import main
from nerfaug.hemisphere import pose_from_angles

from .test_constraints import tiny_dataset


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("uncertainty")
    # Twice NeRF-synthetic's scale: depths in world units are twice the engine's.
    settings = SessionSettings(engine="test", seed=2, radius=8.06)
    session = CaptureSession.create(tiny_dataset(tmp / "data"), tmp / "run", settings)
    session.train(3)
    session.save()
    return tmp / "run"


def poses_file(path: Path, n: int = 2) -> Path:
    poses = pose_from_angles(torch.linspace(0.3, 2.0, n), torch.full((n,), 0.8), 8.06)
    frames = [{"file_path": f"./look_{i}", "transform_matrix": p.tolist()} for i, p in enumerate(poses)]
    path.write_text(json.dumps({"frames": frames}))
    return path


def test_the_command_writes_a_figure_and_arrays_per_pose(run, tmp_path, capsys):
    out = tmp_path / "images"
    args = ["uncertainty", str(run), "--poses", str(poses_file(tmp_path / "poses.json")), "--out", str(out)]
    main([*args, "--width", "6", "--fisher-width", "3", "--device", "cpu"])
    for name in ("look_0", "look_1"):
        assert (out / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
        assert np.load(out / f"{name}_rgb.npy").shape == (6, 6, 3)
        assert np.load(out / f"{name}_entropy.npy").shape == (6, 6)
        assert np.load(out / f"{name}_depth.npy").shape == (6, 6)
        assert np.load(out / f"{name}_fisher.npy").shape == (3, 3)
        assert np.load(out / f"{name}_pose.npy").shape == (4, 4)
    assert "look_1: mean entropy" in capsys.readouterr().out
    main([*args, "--width", "6", "--no-fisher", "--device", "cpu"])  # its own folder: written again


def test_depth_is_in_world_units(run):
    session = CaptureSession.open(run)
    pose = pose_from_angles(torch.tensor([1.0]), torch.tensor([0.7]), 8.06)
    maps = session.uncertainty_maps(pose, width=5, fisher=False)[0]
    assert maps.fisher is None
    engine = session.hemisphere.to_engine(pose)
    camera = session.template(5, 5)
    from nerfaug.selection.candidates import with_poses

    rendered = session.trainer.model.render_image(with_poses(camera, engine), 0)
    assert session.hemisphere.scale == pytest.approx(2.0, rel=1e-3)
    np.testing.assert_allclose(maps.depth, rendered["depth"].numpy() * session.hemisphere.scale, rtol=1e-4)


@pytest.mark.parametrize(
    ("sizes", "line"),
    [
        ({"width": 0}, "width 0: must be >= 1"),
        ({"width": MAX_IMAGE_WIDTH + 1}, f"width {MAX_IMAGE_WIDTH + 1}: must be <= {MAX_IMAGE_WIDTH}"),
        ({"fisher_width": MAX_FISHER_WIDTH + 1}, f"fisher_width {MAX_FISHER_WIDTH + 1}: must be <= {MAX_FISHER_WIDTH}"),
    ],
)
def test_image_widths_are_bounded_by_the_library_before_any_render(run, sizes, line):
    pose = pose_from_angles(torch.tensor([1.0]), torch.tensor([0.7]), 8.06)
    with pytest.raises(RequestError) as refused:
        CaptureSession.open(run).uncertainty_maps(pose, **sizes)
    assert str(refused.value) == line


def test_the_command_refuses_a_width_as_the_service_does(run, tmp_path, capsys):
    args = ["uncertainty", str(run), "--poses", str(poses_file(tmp_path / "poses.json")), "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as done:
        main([*args, "--width", "2000"])
    assert done.value.code == 2 and not (tmp_path / "o").exists()
    assert capsys.readouterr().err.strip() == "nerfaug: --width 2000: must be <= 1024"


def test_a_users_folder_is_refused(run, tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(SystemExit) as done:
        main(["uncertainty", str(run), "--poses", str(poses_file(tmp_path / "p.json")), "--out", str(mine)])
    assert done.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"nerfaug: {mine}: not empty") and "\n" not in err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]


def fake_view(depth: float, fisher_high: float, seed: int = 0):
    """A 4x4 view: the left half background (opacity 0, depth noise), the right half at `depth`."""
    from nerfaug.capture.uncertainty_images import ViewMaps

    rng = np.random.default_rng(seed)
    opacity = np.zeros((4, 4), np.float32)
    opacity[:, 2:] = 1.0
    depths = np.where(opacity > 0, depth, rng.uniform(0, 100, (4, 4))).astype(np.float32)
    fisher = np.full((4, 4), fisher_high * 1e-20, np.float32)
    fisher[0, 0], fisher[1, 1] = fisher_high, fisher_high / 100
    return ViewMaps(
        pose=np.eye(4),
        rgb=np.zeros((4, 4, 3), np.float32),
        depth=depths,
        opacity=opacity,
        entropy=np.full((4, 4), depth / 10, np.float32),
        fisher=fisher,
        step=1,
        azimuth=0.0,
        elevation=30.0,
    )


def test_a_batch_shares_its_colour_scales_and_background_and_faint_fisher_are_left_out():
    from nerfaug.capture.uncertainty_images import colour_scales
    from nerfaug.plotting import LOG_DECADES

    views = [fake_view(3.0, 10.0, 0), fake_view(5.0, 1000.0, 1)]
    scales = colour_scales(views)
    assert scales.depth == (3.0, 5.0)  # the background's noisy depths (up to 100) are not in the range
    assert scales.entropy == pytest.approx(0.5)
    assert scales.fisher == pytest.approx((1000.0 / 10**LOG_DECADES, 1000.0))  # not down to 1e-17
    own = colour_scales(views[:1])
    assert own.depth == (3.0, 3.0) and own.fisher == pytest.approx((10.0 / 10**LOG_DECADES, 10.0))


def test_the_figures_draw_depth_only_where_rays_are_opaque_on_the_scales_given():
    from nerfaug.capture.uncertainty_images import colour_scales, figure

    views = [fake_view(3.0, 10.0, 0), fake_view(5.0, 1000.0, 1)]
    shared = colour_scales(views)
    limits = []
    for view in views:
        fig = figure(view, "v", shared)
        depth, fisher = fig.axes[1].images[0], fig.axes[3].images[0]
        assert (np.ma.getmaskarray(depth.get_array()) == (view.opacity < 0.5)).all()
        limits.append((*depth.get_clim(), fisher.norm.vmin, fisher.norm.vmax, *fig.axes[2].images[0].get_clim()))
    assert limits[0] == pytest.approx(limits[1]) == (3.0, 5.0, 0.1, 1000.0, 0.0, 0.5)  # a colour: one value
    alone = figure(views[0], "v").axes[3].images[0].norm
    assert (alone.vmin, alone.vmax) == pytest.approx((1e-3, 10.0))


def test_each_colour_bar_names_its_unit_and_fisherrf_is_drawn_at_the_renders_size():
    from dataclasses import replace

    from nerfaug.capture.uncertainty_images import figure

    view = fake_view(3.0, 10.0)
    coarse = replace(view, fisher=np.array([[10.0, 1e-19], [0.1, 0.0]], np.float32))  # 2x2 beside a 4x4 render
    fig = figure(coarse, "v")
    images = [ax.images[0] for ax in fig.axes[:4]]
    assert images[3].get_array().shape == images[0].get_array().shape[:2] == (4, 4)
    bars = [ax.get_ylabel() for ax in fig.axes[4:]]
    assert bars[0] == "depth (world units)" and bars[1] == "ray entropy (bits)"
    assert "FisherRF" in bars[2] and "no unit" in bars[2] and "log scale, top 4 decades" in bars[2]
    assert "computed at 2x2 px" in fig.axes[3].get_title()
    norm = images[3].norm
    assert (norm.vmin, norm.vmax) == pytest.approx((1e-3, 10.0))  # clipped: not down to 1e-19


def test_the_command_shares_the_scale_unless_told_and_writes_the_opacity(run, tmp_path, capsys):
    poses = poses_file(tmp_path / "poses.json", 3)
    main(
        ["uncertainty", str(run), "--poses", str(poses), "--out", str(tmp_path / "a"), "--width", "6"]
        + ["--fisher-width", "3", "--device", "cpu", "--threads", "1"]
    )
    out, err = capsys.readouterr()
    assert "the 3 figures share their colour scales" in out
    assert "uncertainty images: 7/7" in err  # progress: the training diagonal, then 2 kinds per view
    opacity = np.load(tmp_path / "a" / "look_0_opacity.npy")
    assert opacity.shape == (6, 6) and ((opacity >= 0) & (opacity <= 1)).all()
    main(
        ["uncertainty", str(run), "--poses", str(poses), "--out", str(tmp_path / "b"), "--width", "6"]
        + ["--no-fisher", "--no-shared-scale", "--device", "cpu"]
    )
    assert "share their colour scales" not in capsys.readouterr().out
    with pytest.raises(SystemExit) as done:
        main(["uncertainty", str(run), "--poses", str(poses), "--out", str(tmp_path / "c"), "--threads", "0"])
    assert done.value.code == 2
    assert capsys.readouterr().err.strip() == "nerfaug: --threads 0: must be >= 1"
