import math

import numpy as np
import pytest
import torch

from nerfaug.hemisphere import fibonacci_angles, half_hemisphere_poses, pose_from_angles, sample_uniform_poses
from nerfaug.maps import hemisphere_xy, plot_hemisphere_map, plot_method_maps

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def candidates():
    azimuth, polar = fibonacci_angles(200)
    return pose_from_angles(azimuth, polar), azimuth, polar


def test_projection_puts_the_pole_at_the_centre_and_the_horizon_on_the_rim():
    poses = pose_from_angles(
        torch.tensor([0.0, 0.0, math.pi / 2, 1.0]), torch.tensor([0.0, math.pi / 2, math.pi / 2, math.pi / 3])
    )
    for projection in ("equal-area", "equidistant"):
        xy = hemisphere_xy(poses, projection)
        assert np.allclose(xy[0], 0.0, atol=1e-6)
        assert np.allclose(xy[1], [1.0, 0.0], atol=1e-6)  # azimuth 0 to the right
        assert np.allclose(xy[2], [0.0, 1.0], atol=1e-6)  # azimuth pi/2 up
    assert np.linalg.norm(hemisphere_xy(poses, "equidistant")[3]) == pytest.approx(2 / 3, abs=1e-6)
    with pytest.raises(ValueError, match="equal-area"):
        hemisphere_xy(poses, "mercator")


def test_hemisphere_map_writes_a_png(tmp_path):
    poses, azimuth, _ = candidates()
    scores = torch.cos(azimuth) + 1.0
    train = half_hemisphere_poses(6)
    path = plot_hemisphere_map(poses, scores, train, poses[:3], tmp_path / "sub" / "map.png", title="t")
    assert path.read_bytes()[:8] == PNG_MAGIC
    numpy_path = plot_hemisphere_map(poses.numpy(), scores.numpy(), train.numpy(), path=tmp_path / "np.png")
    assert numpy_path.stat().st_size > 1000


def test_hemisphere_map_checks_its_inputs(tmp_path):
    poses, _, _ = candidates()
    with pytest.raises(ValueError, match="200 candidate poses but 3 scores"):
        plot_hemisphere_map(poses, torch.ones(3), half_hemisphere_poses(6), path=tmp_path / "bad.png")
    with pytest.raises(ValueError, match="path"):
        plot_hemisphere_map(poses, torch.ones(200), half_hemisphere_poses(6))


def test_method_maps_write_one_png_with_a_panel_per_method(tmp_path):
    poses, azimuth, polar = candidates()
    maps = {
        "ours": (torch.cos(azimuth) + 1.0, poses[:6]),
        "uniform": (torch.ones(200), None),  # constant scores still draw
        "entropy": (polar.numpy(), poses[10:16].numpy()),
    }
    path = plot_method_maps(maps, poses, half_hemisphere_poses(6), tmp_path / "maps.png", title="lego")
    assert path.read_bytes()[:8] == PNG_MAGIC
    with pytest.raises(ValueError, match="no methods"):
        plot_method_maps({}, poses, half_hemisphere_poses(6), tmp_path / "none.png")


def test_degenerate_candidate_sets_still_draw(tmp_path):
    pole = pose_from_angles(torch.tensor([0.0, 1.0, 2.0]), torch.zeros(3))  # one point on the map
    line = pose_from_angles(torch.zeros(3), torch.tensor([0.2, 0.5, 0.9]))  # collinear points
    for i, poses in enumerate((pole, line, line[:1])):
        path = plot_hemisphere_map(poses, torch.rand(len(poses)), half_hemisphere_poses(6), path=tmp_path / f"{i}.png")
        assert path.read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize("polar_deg", [95.0, 150.0])
def test_views_below_the_horizon_stay_in_frame_and_are_explained(polar_deg):
    from matplotlib.figure import Figure

    from nerfaug.maps import _draw

    poses, azimuth, _ = candidates()
    below = pose_from_angles(torch.tensor([math.pi / 4]), torch.tensor([math.radians(polar_deg)]))
    ax = Figure().subplots()
    _draw(ax, poses, torch.cos(azimuth), below, below, "equal-area", (0.0, 0.0, 0.0))
    (x, y) = hemisphere_xy(below)[0]
    assert ax.get_xlim()[1] > x > ax.get_xlim()[0] and ax.get_ylim()[1] > y > ax.get_ylim()[0]
    assert "below the horizon" in " ".join(t.get_text() for t in ax.texts)
    above = Figure().subplots()  # the upper hemisphere only: the frame and the words as before
    _draw(above, poses, torch.cos(azimuth), half_hemisphere_poses(6), None, "equal-area", (0.0, 0.0, 0.0))
    assert above.get_xlim() == (-1.18, 1.18) and "below the horizon" not in " ".join(t.get_text() for t in above.texts)


def test_a_map_leaves_blank_where_no_candidate_lies_and_nowhere_else():
    from nerfaug.maps import _interpolate

    axis = np.linspace(-1.0, 1.0, 120)
    gx, gy = np.meshgrid(axis, axis)
    inside = gx**2 + gy**2 <= 1.0
    spread = hemisphere_xy(sample_uniform_poses(200, torch.Generator().manual_seed(3)))
    assert not np.ma.getmaskarray(_interpolate(spread, np.random.rand(200), gx, gy))[inside].any()
    # a wedge of candidates (as a DTU scan's): the map keeps to the wedge, the rest is blank
    generator = torch.Generator().manual_seed(0)
    azimuth = torch.deg2rad(283 + 52 * torch.rand(31, generator=generator))
    wedge = hemisphere_xy(pose_from_angles(azimuth, torch.deg2rad(20 + 50 * torch.rand(31, generator=generator))))
    masked = np.ma.getmaskarray(_interpolate(wedge, np.random.rand(31), gx, gy))
    assert 0.6 < masked[inside].mean() < 0.95
    opposite = (gx < -0.3) & inside  # the far side of the disk from the wedge (azimuth ~300 deg)
    assert masked[opposite].all()


def test_the_rings_are_labelled_as_elevation_and_the_bar_says_what_the_scores_are():
    from nerfaug.maps import hemisphere_map_figure
    from nerfaug.selection import METHODS

    poses, azimuth, _ = candidates()
    label = METHODS["ours"].score_label()
    figure = hemisphere_map_figure(poses, torch.cos(azimuth), half_hemisphere_poses(6), poses[:2], label=label)
    texts = {t.get_text() for t in figure.axes[0].texts}
    assert {"30° elev.", "60° elev.", "90° az."} <= texts
    assert figure.axes[1].get_ylabel() == label  # the colour bar
    assert "bits" in label and "rad²" in label and "no unit" in label


def legend_labels(figure) -> list[str]:
    return [
        text.get_text()
        for legend in figure.legends + [ax.get_legend() for ax in figure.axes]
        if legend
        for text in legend.get_texts()
    ]


def test_the_grey_where_no_candidate_lies_is_named_in_the_legend_and_only_then():
    """A pool of captured views 5 to 55 degrees up leaves the disk's centre unscored: the legend
    names that grey; candidates all over the hemisphere leave none, and the legend has no such entry."""
    from nerfaug.maps import NO_CANDIDATE, hemisphere_map_figure, method_maps_figure

    generator = torch.Generator().manual_seed(0)
    azimuth = 2 * math.pi * torch.rand(200, generator=generator)
    low = pose_from_angles(azimuth, torch.deg2rad(35 + 50 * torch.rand(200, generator=generator)))
    train = half_hemisphere_poses(4)
    assert NO_CANDIDATE in legend_labels(hemisphere_map_figure(low, torch.cos(azimuth), train))
    assert NO_CANDIDATE in legend_labels(method_maps_figure({"ours": (torch.cos(azimuth), None)}, low, train))
    spread, spread_azimuth, _ = candidates()
    assert NO_CANDIDATE not in legend_labels(hemisphere_map_figure(spread, torch.cos(spread_azimuth), train))


def test_a_method_without_scores_is_drawn_grey_not_in_a_colour_of_the_score_scale():
    """uniform gives every candidate one score: its panel has no colour image (it was drawn a flat
    mid-scale colour, as if it scored every view alike on the others' scale), and the legend says why."""
    from nerfaug.maps import NO_SCORE, method_maps_figure

    poses, azimuth, _ = candidates()
    figure = method_maps_figure(
        {"ours": (torch.cos(azimuth), poses[:2]), "uniform": (torch.ones(len(poses)), poses[2:4])},
        poses,
        half_hemisphere_poses(4),
    )
    ours, uniform = figure.axes[:2]
    assert len(ours.images) == 1 and len(uniform.images) == 0
    assert NO_SCORE in legend_labels(figure)
    assert "min-max scaled per panel" in figure.axes[2].get_ylabel()  # the bar stays for the scored panel
    alone = method_maps_figure({"uniform": (torch.zeros(len(poses)), None)}, poses, half_hemisphere_poses(4))
    assert len(alone.axes) == 1  # no colour bar where nothing has a score
