"""Volume rendering against hand-computed rays, and sampling along rays."""

import math

import pytest
import torch

from nerfaug.nerf.sampling import ray_box_span, sample_pdf, stratified_edges
from nerfaug.nerf.volrend import composite, render_weights


def test_weights_colour_and_depth_of_a_hand_computed_ray():
    sigmas = torch.tensor([[0.0, 1.0, 2.0, 1e6]])
    t_starts = torch.tensor([[2.0, 3.0, 3.5, 4.0]])
    t_ends = torch.tensor([[3.0, 3.5, 4.0, 5.0]])
    rgbs = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0]]])
    weights, transmittance = render_weights(sigmas, t_ends - t_starts)

    # alpha_i = 1 - exp(-sigma_i delta_i); T_i = exp(-sum_{j<i} sigma_j delta_j).
    e = math.exp
    expected_t = [1.0, 1.0, e(-0.5), e(-1.5)]
    expected_w = [0.0, 1 - e(-0.5), e(-0.5) * (1 - e(-1.0)), e(-1.5)]
    assert transmittance[0].tolist() == pytest.approx(expected_t, abs=1e-6)
    assert weights[0].tolist() == pytest.approx(expected_w, abs=1e-6)

    rgb, accumulation, depth = composite(weights, rgbs, t_starts, t_ends, torch.tensor([0.5, 0.5, 0.5]))
    assert accumulation.item() == pytest.approx(1.0, abs=1e-6)  # the last sample is opaque
    w = expected_w
    assert rgb[0].tolist() == pytest.approx([w[0] + w[3], w[1] + w[3], w[2] + w[3]], abs=1e-6)
    mids = [2.5, 3.25, 3.75, 4.5]
    assert depth.item() == pytest.approx(sum(wi * m for wi, m in zip(w, mids)), abs=1e-5)


def test_background_shows_through_a_half_transparent_ray():
    sigmas = torch.tensor([[math.log(2.0)]])  # alpha = 1/2 over a unit interval
    weights, _ = render_weights(sigmas, torch.ones(1, 1))
    rgb, accumulation, _ = composite(weights, torch.zeros(1, 1, 3), torch.zeros(1, 1), torch.ones(1, 1), torch.ones(3))
    assert accumulation.item() == pytest.approx(0.5)
    assert rgb[0].tolist() == pytest.approx([0.5, 0.5, 0.5])


def test_weights_sum_to_accumulation_and_transmittance_decreases(generator):
    sigmas = torch.rand(64, 32, generator=generator) * 5
    deltas = torch.rand(64, 32, generator=generator) * 0.2
    weights, transmittance = render_weights(sigmas, deltas)
    _, accumulation, _ = composite(weights, torch.rand(64, 32, 3, generator=generator), torch.zeros(64, 32), deltas)
    assert torch.allclose(weights.sum(-1), accumulation)
    # The accumulation is 1 - the transmittance past the last sample.
    assert torch.allclose(accumulation, 1 - torch.exp(-(sigmas * deltas).sum(-1)), atol=1e-5)
    assert (transmittance[:, 1:] <= transmittance[:, :-1] + 1e-7).all()


def test_deep_samples_have_zero_transmittance_not_subnormal_floats():
    sigmas = torch.full((1, 60), 2.0)  # optical depth grows by 2 per sample, past 80 and 104
    weights, transmittance = render_weights(sigmas, torch.ones(1, 60))
    tiny = torch.finfo(torch.float32).tiny
    for values in (weights, transmittance):
        assert ((values == 0) | (values >= tiny)).all()
    assert transmittance[0, -1] == 0 and transmittance[0, 40] == pytest.approx(math.exp(-80.0))
    assert weights.sum().item() == pytest.approx(1.0)


def test_ray_box_span_clips_to_the_box_and_near_far():
    origins = torch.tensor([[0.0, 0.0, 4.0], [0.0, 0.0, 4.0], [5.0, 5.0, 4.0], [0.0, 0.0, 1.0]])
    directions = torch.tensor([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    t_min, t_max = ray_box_span(origins, directions, 1.5, 2.0, 6.0)
    assert t_min[0].item() == pytest.approx(2.5) and t_max[0].item() == pytest.approx(5.5)
    assert t_min[1] == t_max[1]  # looks away from the box
    assert t_min[2] == t_max[2]  # passes beside it
    # Starts inside the box: near clips the start, the box the end (z = -1.5 at t = 2.5).
    assert t_min[3].item() == pytest.approx(2.0) and t_max[3].item() == pytest.approx(2.5)


def test_stratified_edges_cover_the_span_and_jitter_is_seeded():
    t_min, t_max = torch.tensor([2.0, 3.0]), torch.tensor([4.0, 3.5])
    fixed = stratified_edges(t_min, t_max, 8)
    assert torch.allclose(fixed[:, 0], t_min) and torch.allclose(fixed[:, -1], t_max)
    assert torch.allclose(fixed[0, 1:] - fixed[0, :-1], torch.full((8,), 0.25))
    a = stratified_edges(t_min, t_max, 8, True, torch.Generator().manual_seed(3))
    b = stratified_edges(t_min, t_max, 8, True, torch.Generator().manual_seed(3))
    assert torch.equal(a, b) and not torch.equal(a, fixed)
    assert (a[:, 1:] >= a[:, :-1]).all()
    assert torch.allclose(a[:, 0], t_min) and torch.allclose(a[:, -1], t_max)


def test_sample_pdf_puts_samples_where_the_weight_is():
    edges = torch.linspace(0.0, 1.0, 11)[None]
    weights = torch.zeros(1, 10)
    weights[0, 7] = 1.0
    new = sample_pdf(edges, weights, 32, padding=1e-5)
    mids = 0.5 * (new[0, 1:] + new[0, :-1])
    assert ((mids >= 0.7) & (mids <= 0.8)).float().mean() > 0.9
    assert (new[0, 1:] >= new[0, :-1]).all()
