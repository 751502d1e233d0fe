import dataclasses
import json
import math
import warnings

import pytest
import torch
from torch import nn

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, angles_from_pose, half_hemisphere_poses
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights
from nerfaug.schema import RequestError
from nerfaug.selection import (
    METHODS,
    Selection,
    SelectionConfig,
    candidate_scores,
    hemisphere_candidates,
    select_views,
)
from nerfaug.selection.selectors import UniformFill

EXPECTED = {
    "ours",
    "ours-paper-sum",
    "ours-nbv",
    "uniform",
    "entropy",
    "entropy-sampling",
    "fisherrf",
    "fisherrf-sampling",
    "distance",
    "distance-nbv",
    "furthest",
    "ours-authors",
    "entropy-authors-nbv",
    "distance-authors-nbv",
    "ours-batch",
    "ours-batch-local",
    "ours-batch-sharp",
}


class BlobNerf(nn.Module):
    """A fuzzy blob whose density falls off from a point off-centre, plus a tiny MLP tint, with
    fixed samples in [2, 6]: enough for entropy and Fisher scores that differ between views."""

    def __init__(self, n_samples: int = 12):
        super().__init__()
        generator = torch.Generator().manual_seed(0)
        self.centre = nn.Parameter(torch.tensor([0.3, -0.2, 0.1]))
        self.log_density = nn.Parameter(torch.tensor(1.5))
        self.tint = nn.Linear(3, 3)
        nn.init.normal_(self.tint.weight, std=0.5, generator=generator)
        self.register_buffer("t", torch.linspace(2.0, 6.0, n_samples + 1))

    def forward(self, origins, directions, background=None):
        n = origins.shape[0]
        t_starts, t_ends = self.t[:-1].expand(n, -1), self.t[1:].expand(n, -1)
        points = origins[:, None] + directions[:, None] * (0.5 * (t_starts + t_ends))[..., None]
        sigma = self.log_density.exp() * torch.exp(-((points - self.centre) ** 2).sum(-1) / 0.5)
        weights, _ = render_weights(sigma, t_ends - t_starts)
        rgb, acc, depth = composite(weights, torch.sigmoid(self.tint(points)), t_starts, t_ends, background)
        return RenderOutput(rgb, acc, depth, weights, t_starts, t_ends)


@pytest.fixture(scope="module")
def scene():
    train = Cameras.from_fov(half_hemisphere_poses(6), BLENDER_CAMERA_ANGLE_X, 40, 40)
    candidates = hemisphere_candidates(train, 60, torch.Generator().manual_seed(0), training=train)
    return BlobNerf(), train, candidates


FAST = SelectionConfig(entropy_resolution=6, fisher_resolution=3, fisher_train_pixels=64, fisher_train_probes=2)


def test_registry_covers_every_method_of_the_paper():
    assert set(METHODS) == EXPECTED
    for name, spec in METHODS.items():
        assert spec.name == name and spec.description


def test_unknown_method_lists_the_valid_names(scene):
    model, train, candidates = scene
    with pytest.raises(ValueError, match="unknown selection method 'bayes'.*ours.*furthest"):
        select_views("bayes", model, train, candidates, 2, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match="unknown selection method 'fisher'; did you mean 'fisherrf'"):
        select_views("fisher", model, train, candidates, 2, torch.Generator().manual_seed(0))


@pytest.mark.parametrize("method", sorted(EXPECTED))
def test_every_method_chooses_n_distinct_candidates_deterministically(scene, method):
    model, train, candidates = scene
    first = select_views(method, model, train, candidates, 4, torch.Generator().manual_seed(1), FAST)
    second = select_views(method, model, train, candidates, 4, torch.Generator().manual_seed(1), FAST)
    assert first.method == method
    assert first.indices.shape == (4,) and len(set(first.indices.tolist())) == 4
    assert 0 <= first.indices.min() and first.indices.max() < len(candidates)
    assert first.scores.shape == (len(candidates),)
    assert torch.isfinite(first.scores).all() and (first.scores >= 0).all()
    assert torch.equal(first.indices, second.indices)
    assert torch.equal(first.scores, second.scores)
    for component in first.components.values():
        assert component.shape == (len(candidates),)


def test_ours_combines_normalised_entropy_and_distance(scene):
    model, train, candidates = scene
    selection = select_views("ours", model, train, candidates, 3, torch.Generator().manual_seed(0), FAST)
    entropy, distance = selection.components["entropy"], selection.components["distance"]
    normalise = lambda x: (x - x.min()) / (x.max() - x.min())  # noqa: E731
    assert torch.allclose(selection.scores, normalise(entropy) + normalise(distance), atol=1e-6)
    assert entropy.max() > entropy.min()  # the model gives views different entropies


def test_nbv_takes_the_top_scores(scene):
    model, train, candidates = scene
    nbv = select_views("ours-nbv", model, train, candidates, 5, torch.Generator().manual_seed(0), FAST)
    assert nbv.indices.tolist() == torch.argsort(nbv.scores, descending=True)[:5].tolist()
    scores, _ = candidate_scores("ours", model, train, candidates, FAST)
    assert torch.equal(scores, nbv.scores)


def test_distance_methods_and_uniform_need_no_model(scene):
    _, train, candidates = scene
    for method in ("distance", "distance-nbv", "furthest", "uniform"):
        select_views(method, None, train, candidates, 3, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match="model=None"):
        select_views("ours", None, train, candidates, 3, torch.Generator().manual_seed(0))


def test_furthest_starts_with_the_view_farthest_from_training(scene):
    _, train, candidates = scene
    selection = select_views("furthest", None, train, candidates, 2, torch.Generator().manual_seed(0))
    assert selection.indices[0] == selection.scores.argmax()
    assert selection.scores.max() <= math.pi


def test_authors_variant_runs_end_to_end(scene):
    model, train, candidates = scene
    config = FAST.authors_variant()
    assert (config.entropy_mode, config.normalisation, config.sampler) == ("authors", "authors", "authors")
    selection = select_views("ours", model, train, candidates, 2, torch.Generator().manual_seed(0), config)
    assert selection.scores.max().item() == pytest.approx(1.0)
    assert (selection.scores[selection.indices] > 0.75).all()


def test_too_many_views_and_bad_config_are_refused(scene):
    model, train, candidates = scene
    with pytest.raises(ValueError, match="cannot choose"):
        select_views("uniform", model, train, candidates, len(candidates) + 1, torch.Generator())
    with pytest.raises(ValueError, match="^entropy_mode 'nats': Input should be 'escape'"):
        SelectionConfig(entropy_mode="nats").checked()


@pytest.mark.parametrize(
    "name, value",
    [
        ("chunk", 0),
        ("max_draws", 0),
        ("fisher_train_pixels", 0),
        ("fisher_resolution", -1),
        ("fisher_probes", 0),
        ("fisher_cache_floats", 0),
        ("fisher_lambda", 0.0),
        ("scale_m", -1.0),
        ("authors_threshold", -0.5),
    ],
)
def test_counts_and_scales_out_of_range_are_refused_by_name(name, value):
    with pytest.raises(RequestError, match=f"^{name} {value}: must be "):
        SelectionConfig(**{name: value}).checked()


@pytest.mark.parametrize(
    "name, value, says",
    [
        ("entropy_resolution", 300, "must be <= 256"),
        ("fisher_resolution", 257, "must be <= 256"),
        ("chunk", 65_537, "must be <= 65536"),
        ("sharpness", 1.5, "must be <= 1"),
        ("sharpness", float("inf"), "Input should be a finite number"),
        ("entropy_resolution", True, "Input should be a valid integer"),
        ("entropy_weight", "heavy", "Input should be a valid number"),
    ],
)
def test_each_setting_has_its_bounds_next_to_its_type(name, value, says):
    with pytest.raises(RequestError) as error:
        SelectionConfig(**{name: value}).checked()
    assert (error.value.argument, error.value.problem.split(",")[0]) == (name, says)


def test_a_checked_config_is_not_checked_again_until_it_changes():
    config = SelectionConfig(sharpness=0.5).checked()
    assert config.checked() is config
    config.sharpness = 2.0
    with pytest.raises(RequestError, match="^sharpness 2.0: must be <= 1$"):
        config.checked()


@pytest.mark.parametrize(
    "metric, problem",
    [
        ([[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]], "3x3"),  # one row of nine
        ([[1.0, 0.0], [0.0, 1.0]], "3x3"),
        ([[1.0, 0.0, 0.0], [0.0, 1.0]], "3x3"),  # ragged
        ([[1.0, 0.0, 0.0], [0.0, float("nan"), 0.0], [0.0, 0.0, 1.0]], "finite"),
        ([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "symmetric"),
        ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]], "positive definite"),
        ([[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "positive definite"),  # eigenvalues 3, -1, 1
    ],
)
def test_a_metric_that_is_not_spd_3x3_is_refused_by_name(metric, problem):
    with pytest.raises(RequestError, match=f"^metric.*{problem}"):
        SelectionConfig(metric=metric).checked()


def test_an_spd_metric_is_accepted():
    metric = [[2.0, 0.5, 0.0], [0.5, 1.0, 0.0], [0.0, 0.0, 3.0]]
    assert SelectionConfig(metric=metric).checked().metric == metric


def test_selection_round_trips_through_json(scene):
    _, train, candidates = scene
    selection = select_views("distance", None, train, candidates, 3, torch.Generator().manual_seed(0))
    data = json.loads(json.dumps(selection.to_dict()))
    assert data["method"] == "distance" and len(data["indices"]) == 3
    restored = Selection.from_dict(data)
    assert torch.equal(restored.indices, selection.indices)
    assert torch.allclose(restored.scores, selection.scores)
    assert torch.allclose(restored.components["distance"], selection.components["distance"])
    json.dumps(SelectionConfig().to_dict())


# --- The authors' code's variants, the registries and the families -------------------------


def test_ours_paper_sum_scores_by_the_raw_sum_as_the_paper_writes_it(scene):
    """U = H + D with H in bits and D in rad^2, no normalisation: its scores are the sum of the
    raw components, while ours (min-max) rescales each term to [0, 1] first."""
    model, train, candidates = scene
    raw = select_views("ours-paper-sum", model, train, candidates, 3, torch.Generator().manual_seed(0), FAST)
    torch.testing.assert_close(raw.scores, raw.components["entropy"] + raw.components["distance"])
    normalised = select_views("ours", model, train, candidates, 3, torch.Generator().manual_seed(0), FAST)

    def minmax(x):
        return (x - x.min()) / (x.max() - x.min())

    torch.testing.assert_close(
        normalised.scores, minmax(normalised.components["entropy"]) + minmax(normalised.components["distance"])
    )
    assert not torch.allclose(raw.scores, normalised.scores)
    from nerfaug.selection import method_label

    assert "raw sum" in method_label("ours-paper-sum") and "min-max" in method_label("ours")


def test_ours_authors_is_ours_with_the_authors_settings(scene):
    from nerfaug.selection import AUTHORS_SETTINGS, get_method

    spec = get_method("ours-authors")
    assert (spec.estimator, spec.selector) == ("combined", "sampling")
    assert spec.effective_config(FAST) == FAST.authors_variant()
    config = FAST.authors_variant()
    for name, value in AUTHORS_SETTINGS.items():
        assert getattr(config, name) == value
    assert (config.sampler, config.authors_threshold, config.min_polar) == ("authors", 15.0, 0.4)
    model, train, candidates = scene
    _, polar, _ = angles_from_pose(candidates.camera_to_world)
    assert (polar < 0.4).any(), "the fixture should hold candidates near the pole"
    for seed in range(4):
        selection = select_views("ours-authors", model, train, candidates, 4, torch.Generator().manual_seed(seed), FAST)
        assert (polar[selection.indices] >= 0.4).all()
        assert (selection.scores[selection.indices] > 0.75).all()  # w > 15 nu, nu >= 0.05, max w = 1
        assert selection.scores.max().item() == pytest.approx(1.0)


def test_scoring_view_of_the_authors_code():
    """75 degrees, central half: the crop spans 2 atan(tan(37.5 deg) / 2) = 42.0 degrees."""
    from nerfaug.selection.estimators import scoring_cameras

    cams = Cameras.from_fov(half_hemisphere_poses(3), BLENDER_CAMERA_ANGLE_X, 80, 60)
    authors = scoring_cameras(cams, 20, 75.0, 0.5)
    assert (authors.width, authors.height) == (20, 15)
    expected = 2 * math.atan(0.5 * math.tan(math.radians(37.5)))
    assert torch.allclose(authors.camera_angle_x, torch.tensor(expected), atol=1e-6)
    assert math.degrees(expected) == pytest.approx(42.0, abs=0.05)
    assert torch.equal(authors.camera_to_world, cams.camera_to_world)
    own = scoring_cameras(cams, 20)
    assert torch.allclose(own.camera_angle_x, cams.camera_angle_x, atol=1e-6)
    half = scoring_cameras(cams, 20, None, 0.5)
    assert torch.allclose(torch.tan(half.camera_angle_x / 2), torch.tan(cams.camera_angle_x / 2) / 2, atol=1e-6)


def test_rotations_match_the_authors_euler_construction():
    """The authors build rotations as Euler 'xyz' (polar, 0, azimuth + pi/2); their NBV distance
    zeroes the candidates' polar angle. scipy is the reference."""
    from scipy.spatial.transform import Rotation

    from nerfaug.hemisphere import pose_from_angles
    from nerfaug.selection.estimators import distance_rotations

    azimuth = torch.tensor([0.3, 1.7, 4.0, 5.9])
    polar = torch.tensor([0.2, 0.9, 1.3, 0.6])
    poses = pose_from_angles(azimuth, polar)
    cams = Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 8, 8)
    euler = torch.stack([polar, torch.zeros(4), azimuth + math.pi / 2], dim=1).double().numpy()
    reference = torch.from_numpy(Rotation.from_euler("xyz", euler).as_matrix())
    assert torch.allclose(distance_rotations(cams, "pose"), reference, atol=1e-6)
    euler[:, 0] = 0.0
    reference = torch.from_numpy(Rotation.from_euler("xyz", euler).as_matrix())
    assert torch.allclose(distance_rotations(cams, "azimuth"), reference, atol=1e-6)


def test_authors_entropy_nbv_follows_their_code(scene):
    """top-k of minmax(H^3) + minmax(D): H zeroed beyond 0.75 rad polar before the cube, D over
    azimuth-only rotations without the 1/2 (which min-max removes)."""
    from nerfaug.selection.estimators import distance_rotations, scoring_cameras
    from nerfaug.uncertainty.entropy import mean_view_entropy, minmax_normalise
    from nerfaug.uncertainty.so3 import so3_geodesic_sq

    model, train, candidates = scene
    selection = select_views("entropy-authors-nbv", model, train, candidates, 5, torch.Generator().manual_seed(0), FAST)
    _, polar, _ = angles_from_pose(candidates.camera_to_world)
    means = mean_view_entropy(model, scoring_cameras(candidates, 6, 75.0, 0.5), 6, mode="authors")
    means[polar > 0.75] = 0.0
    entropy = minmax_normalise(means**3)
    rotations = distance_rotations(candidates, "azimuth")
    no_half = so3_geodesic_sq(train.rotations.double()[None], rotations[:, None]).sum(dim=1)
    expected = entropy + minmax_normalise(no_half).float()
    assert torch.allclose(selection.components["entropy"], entropy, atol=1e-6)
    assert (selection.components["entropy"][polar > 0.75] == 0).all()
    assert torch.allclose(selection.scores / selection.scores.max(), expected / expected.max(), atol=1e-5)
    assert selection.indices.tolist() == torch.argsort(expected, descending=True)[:5].tolist()


def test_max_distance_baseline_depends_on_azimuth_alone(scene):
    _, train, _ = scene
    from nerfaug.hemisphere import pose_from_angles

    azimuth = torch.tensor([1.0, 1.0, 2.5, 2.5])
    polar = torch.tensor([0.3, 1.2, 0.5, 1.4])
    cams = Cameras.from_fov(pose_from_angles(azimuth, polar), BLENDER_CAMERA_ANGLE_X, 8, 8)
    selection = select_views("distance-authors-nbv", None, train, cams, 2, torch.Generator().manual_seed(0))
    distance = selection.components["distance"]
    assert distance[0] == pytest.approx(float(distance[1]), rel=1e-5)
    assert distance[2] == pytest.approx(float(distance[3]), rel=1e-5)
    assert not torch.allclose(distance[0], distance[2])
    plain = select_views("distance-nbv", None, train, cams, 2, torch.Generator().manual_seed(0))
    assert not torch.allclose(plain.components["distance"][0], plain.components["distance"][1])


@pytest.mark.parametrize("method", ["uniform", "ours", "ours-nbv", "furthest", "ours-batch", "fisherrf"])
def test_min_polar_holds_for_every_selector(scene, method):
    model, train, candidates = scene
    _, polar, _ = angles_from_pose(candidates.camera_to_world)
    config = dataclasses.replace(FAST, min_polar=0.6)
    for seed in range(3):
        selection = select_views(method, model, train, candidates, 5, torch.Generator().manual_seed(seed), config)
        assert (polar[selection.indices] >= 0.6).all()


def test_a_new_method_is_one_function_and_one_line(scene, monkeypatch):
    from nerfaug.selection import ESTIMATORS, METHODS, Estimate, MethodSpec

    def height(request):  # prefer views from high up
        return Estimate(request.candidates.positions[:, 2].clamp_min(0).cpu() + 1e-3)

    monkeypatch.setitem(ESTIMATORS, "test-height", height)
    monkeypatch.setitem(METHODS, "height-nbv", MethodSpec("height-nbv", "test-height", "top-k", "highest views"))
    _, train, candidates = scene
    selection = select_views("height-nbv", None, train, candidates, 3, torch.Generator().manual_seed(0))
    z = candidates.positions[:, 2]
    assert selection.indices.tolist() == torch.argsort(z, descending=True)[:3].tolist()


def test_unknown_estimators_and_selectors_are_one_error_listing_the_known_ones():
    from nerfaug.selection.registry import ESTIMATORS, SELECTORS, get_estimator, get_selector

    with pytest.raises(ValueError, match="unknown estimator 'bayes'; choose one of: combined, entropy"):
        get_estimator("bayes")
    with pytest.raises(ValueError, match="unknown selector 'best'; choose one of: sampling, top-k"):
        get_selector("best")
    assert set(ESTIMATORS) == {"combined", "entropy", "distance", "none", "fisher"}
    assert set(SELECTORS) == {"sampling", "top-k", "uniform", "farthest", "greedy-fisher", "batch-sampling"}


def test_estimates_are_typed_and_name_their_components(scene):
    """What an estimator hands a selector is read by attribute: a misspelt name fails at once."""
    from nerfaug.selection.estimators import combined
    from nerfaug.selection.interface import Estimate, Request

    model, train, candidates = scene
    estimate = combined(Request("ours", model, train, candidates, 3, None, FAST))
    assert estimate.terms is not None and estimate.terms.weights == (1.0, 1.0)
    assert estimate.fisher is None and estimate.exponent is None
    assert list(estimate.components()) == ["entropy", "distance"]
    with pytest.raises(AttributeError):
        estimate.entropy  # noqa: B018 (the term is estimate.terms.entropy)
    with pytest.raises(dataclasses.FrozenInstanceError):
        estimate.scores = torch.ones(3)
    sharpened = Estimate(torch.tensor([1.0, 0.25]), uncertainty=torch.tensor([2.0, 1.0]), exponent=2.0)
    assert list(sharpened.components()) == ["uncertainty", "exponent"]
    assert sharpened.components()["exponent"].tolist() == [2.0, 2.0]


def test_method_specs_are_checked():
    from nerfaug.selection import MethodSpec

    with pytest.raises(ValueError, match="unknown estimator"):
        MethodSpec("x", "bayes", "top-k", "")
    with pytest.raises(ValueError, match="needs the estimator fisher"):
        MethodSpec("x", "combined", "greedy-fisher", "")
    with pytest.raises(ValueError, match="needs the estimator combined or distance"):
        MethodSpec("x", "fisher", "batch-sampling", "")
    with pytest.raises(ValueError, match="unknown SelectionConfig settings"):
        MethodSpec("x", "combined", "top-k", "", settings={"entropy_resolutoin": 3})
    with pytest.raises(ValueError, match="sharpness"):
        SelectionConfig(sharpness=1.5).checked()
    with pytest.raises(ValueError, match="^entropy_resolutoin 3: unknown field"):
        SelectionConfig.from_dict({"entropy_resolutoin": 3})
    assert SelectionConfig.from_dict(json.loads(json.dumps(FAST.authors_variant().to_dict()))) == FAST.authors_variant()


def test_families_name_registered_methods_and_experiments_share_them():
    from nerfaug.experiment import config as experiment_config
    from nerfaug.selection import FAMILIES, STUDY_METHODS, TABLE_I, TABLE_I_ROWS, TABLE_II, TABLE_II_ROWS, method_label

    for family, names in FAMILIES.items():
        assert names and set(names) <= set(METHODS), family
    assert TABLE_I == tuple(m for _, m in TABLE_I_ROWS) and set(TABLE_II) == {m for _, _, m in TABLE_II_ROWS}
    assert {"ours", "ours-authors", "uniform", "entropy", "fisherrf", "furthest"} <= set(STUDY_METHODS)
    assert any(METHODS[m].selector == "batch-sampling" for m in STUDY_METHODS)
    assert experiment_config.TABLE_I is TABLE_I and experiment_config.STUDY_METHODS is STUDY_METHODS
    assert len({method_label(m) for m in METHODS}) == len(METHODS)  # labels tell methods apart


def seed_one() -> torch.Generator:
    return torch.Generator().manual_seed(1)


def test_a_sampler_with_too_few_positive_scores_fills_uniformly_and_says_so(scene):
    """A NeRF that renders nothing gives FisherRF's gain 0 to every candidate: the sampling
    variant still returns n distinct views (drawn uniformly), warns, and records how many."""
    _, train, candidates = scene
    empty = BlobNerf()
    with torch.no_grad():
        empty.log_density.fill_(-math.inf)  # density 0 everywhere: no gradient, no information
    with pytest.warns(UniformFill, match="0 of 60 eligible candidates score above 0, fewer than the 4 views"):
        selection = select_views(
            "fisherrf-sampling", empty, train, candidates, 4, torch.Generator().manual_seed(1), FAST
        )
    assert (selection.scores == 0).all()
    assert selection.uniform_fill == 4 and len(set(selection.indices.tolist())) == 4
    record = selection.to_dict()
    assert record["uniform_fill"] == 4 and Selection.from_dict(json.loads(json.dumps(record))).uniform_fill == 4


def test_a_sampler_with_enough_positive_scores_records_no_fill(scene):
    model, train, candidates = scene
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        selection = select_views(
            "fisherrf-sampling", model, train, candidates, 4, torch.Generator().manual_seed(1), FAST
        )
    assert selection.uniform_fill == 0 and "uniform_fill" not in selection.to_dict()


def test_each_method_says_what_its_scores_are_and_in_which_unit():
    from nerfaug.selection import METHODS, Selection

    assert METHODS["ours"].score_label().splitlines()[0] == "uncertainty U = H′ + D′ (no unit; ′: min-max scaled)"
    raw = METHODS["ours-paper-sum"].score_label()
    assert raw.startswith("uncertainty U = H + D (bits + rad²)") and "min-max" not in raw
    assert METHODS["distance"].score_label(SelectionConfig(distance_weight=3.0)).startswith("uncertainty U = D′")
    assert METHODS["fisherrf"].score_label() == "FisherRF information gain (no unit)"
    assert METHODS["uniform"].score_label().startswith("no score")
    sharpened = Selection(torch.zeros(1), torch.ones(3), {"exponent": torch.full((3,), 2.5)}, "ours")
    assert sharpened.score_label().endswith("raised to the power 2.5 (the sampler's 1/T)")
