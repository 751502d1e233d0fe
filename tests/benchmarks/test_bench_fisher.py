"""benchmarks/bench_fisher.py measures the estimator the study runs: its H_train and H_cand are the
ones `fisherrf_candidates` computes, draw for draw, for the same generator."""

from pathlib import Path

import pytest
import torch

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.model import NerfModel
from nerfaug.selection import SelectionConfig, fisherrf_candidates
from nerfaug.selection.estimators import fisher_train_rays
from nerfaug.uncertainty.fisher import fisher_diagonal, fisherrf_scores, sample_pixel_rays

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_fisher.py"


def cameras(n: int, seed: int, size: int = 10) -> Cameras:
    poses = sample_uniform_poses(n, torch.Generator().manual_seed(seed), radius=4.0)
    return Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, size, size)


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return NerfModel(NerfConfig.preset("test"))


@pytest.mark.filterwarnings("ignore:the model's forward does not run under torch.func.vmap")
@pytest.mark.parametrize("method", ["random-sign", "exact"])
def test_bench_draws_h_train_and_h_cand_as_the_estimator(bench, model, method):
    config = SelectionConfig(fisher_method=method, fisher_train_pixels=48, fisher_train_chunk=16, fisher_resolution=4)
    train, candidates = cameras(3, seed=0), cameras(4, seed=1)

    h_train, scores, h_of = fisherrf_candidates(model, train, candidates, config, torch.Generator().manual_seed(7))
    # The bench's two parts drawn in the estimator's order from one generator give its numbers.
    generator = torch.Generator().manual_seed(7)
    bench_train = bench.h_train_of(model, train, config, config.fisher_train_pixels, generator)
    bench_cand = bench.h_cand_of(model, candidates, config, config.fisher_resolution, generator)

    assert h_train.abs().sum() > 0
    assert torch.equal(bench_train, h_train)
    for i in range(len(candidates)):
        assert torch.allclose(bench_cand[i], h_of(i), rtol=1e-5, atol=1e-12)
    assert torch.allclose(fisherrf_scores(bench_train, bench_cand, config.fisher_lambda), scores, rtol=1e-5)


def test_bench_h_train_is_over_the_estimators_weighted_stratified_rays(bench, model):
    """Same rays and weights as the estimator's draw for the same generator, not uniform draws
    with replacement (`sample_pixel_rays`)."""
    config = SelectionConfig(fisher_train_pixels=60, fisher_train_chunk=16)
    train = cameras(3, seed=0)
    origins, directions, weights = fisher_train_rays(train, config, torch.Generator().manual_seed(3))
    assert weights.sum() == pytest.approx(3 * train.width * train.height)

    generator = torch.Generator().manual_seed(3)
    fisher_train_rays(train, config, generator)  # the pixel draw; the probes come next
    expected = fisher_diagonal(
        model,
        origins,
        directions,
        config.fisher_method,
        config.fisher_train_probes,
        generator,
        config.fisher_train_chunk,
        None,
        weights=weights,
    )
    measured = bench.h_train_of(model, train, config, 60, torch.Generator().manual_seed(3))
    assert torch.equal(measured, expected)

    uniform = fisher_diagonal(
        model,
        *sample_pixel_rays(train, 60, torch.Generator().manual_seed(3)),
        config.fisher_method,
        config.fisher_train_probes,
        torch.Generator().manual_seed(3),
        config.fisher_train_chunk,
    )
    assert not torch.allclose(measured, uniform)


def test_bench_reference_is_every_pixel_at_weight_one(bench):
    train = cameras(2, seed=0, size=6)
    config = SelectionConfig(fisher_train_pixels=bench.EVERY_PIXEL)
    _, _, weights = fisher_train_rays(train, config, torch.Generator().manual_seed(0))
    assert weights.shape == (2 * 6 * 6,)
    assert torch.equal(weights, torch.ones_like(weights))
