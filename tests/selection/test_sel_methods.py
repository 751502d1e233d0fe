import json
import math

import pytest
import torch
from torch import nn

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, half_hemisphere_poses
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights
from nerfaug.selection import (
    METHODS, Selection, SelectionConfig, candidate_scores, hemisphere_candidates, select_views,
)

EXPECTED = {
    "ours", "ours-nbv", "uniform", "entropy", "entropy-sampling", "fisherrf", "fisherrf-sampling",
    "distance", "distance-nbv", "furthest",
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
    with pytest.raises(ValueError, match="entropy_mode"):
        SelectionConfig(entropy_mode="nats")


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
