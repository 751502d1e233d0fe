import pytest
import torch
from torch import nn
from torch.autograd.functional import jacobian
from torch.func import functional_call

from nerfaug.cameras import Cameras
from nerfaug.hemisphere import BLENDER_CAMERA_ANGLE_X, sample_uniform_poses
from nerfaug.nerf.volrend import RenderOutput, composite, render_weights
from nerfaug.uncertainty.fisher import (
    fisher_diagonal,
    fisher_diagonal_groups,
    fisher_views,
    fisherrf_greedy,
    fisherrf_scores,
    fisherrf_view_scores,
    n_trainable,
    pixel_grid,
    sample_pixel_rays,
    stratified_pixel_rays,
    stratified_pixels,
)
from nerfaug.uncertainty.rays import views_rays


class TinyNerf(nn.Module):
    """A 2-layer MLP field with fixed stratified samples in [2, 6]: about 70 parameters."""

    def __init__(self, n_samples: int = 6, hidden: int = 6, seed: int = 0, skip_empty: bool = False):
        super().__init__()
        generator = torch.Generator().manual_seed(seed)
        self.hidden = nn.Linear(3, hidden)
        self.out = nn.Linear(hidden, 4)
        for p in self.parameters():
            nn.init.normal_(p, std=0.8, generator=generator)
        self.register_buffer("t", torch.linspace(2.0, 6.0, n_samples + 1))
        self.skip_empty = skip_empty

    def forward(self, origins, directions, background=None):
        n = origins.shape[0]
        t_starts, t_ends = self.t[:-1].expand(n, -1), self.t[1:].expand(n, -1)
        points = origins[:, None] + directions[:, None] * (0.5 * (t_starts + t_ends))[..., None]
        raw = self.out(torch.tanh(self.hidden(points.reshape(-1, 3))))
        if self.skip_empty:  # like NerfModel: data-dependent shapes, which vmap cannot batch
            keep = (points.reshape(-1, 3).norm(dim=-1) < 10.0).nonzero().squeeze(-1)
            raw = raw.new_zeros(raw.shape).index_put((keep,), raw[keep])
        raw = raw.reshape(n, -1, 4)
        weights, _ = render_weights(nn.functional.softplus(raw[..., 0]), t_ends - t_starts)
        rgb, acc, depth = composite(weights, torch.sigmoid(raw[..., 1:]), t_starts, t_ends, background)
        return RenderOutput(rgb, acc, depth, weights, t_starts, t_ends)


def rays(n: int, seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    origins = torch.tensor([0.0, 0.0, 4.0]) + 0.3 * torch.randn(n, 3, generator=generator)
    directions = torch.tensor([0.0, 0.0, -1.0]) + 0.3 * torch.randn(n, 3, generator=generator)
    return origins, directions / directions.norm(dim=-1, keepdim=True)


def full_jacobian_diagonal(model, origins, directions, background=None):
    """diag(J^T J) from the full Jacobian of every rendered colour w.r.t. every parameter."""
    names = [n for n, _ in model.named_parameters()]
    params = tuple(p.detach() for p in model.parameters())

    def colours(*values):
        out = functional_call(model, dict(zip(names, values)), (origins, directions), {"background": background})
        return out.rgb.reshape(-1)

    jac = jacobian(colours, params)
    jac = torch.cat([j.reshape(j.shape[0], -1) for j in jac], dim=1)  # (n_rays * 3, P)
    return (jac**2).sum(dim=0)


def test_exact_diagonal_equals_the_full_jacobian():
    model = TinyNerf()
    origins, directions = rays(12)
    expected = full_jacobian_diagonal(model, origins, directions, torch.ones(3))
    exact = fisher_diagonal(model, origins, directions, method="exact", background=torch.ones(3))
    assert exact.shape == (n_trainable(model),)
    assert torch.allclose(exact, expected, rtol=1e-4, atol=1e-7)
    assert expected.min() > 0  # every parameter matters, so the comparison is not vacuous


def test_exact_diagonal_without_vmap_falls_back_to_a_loop_with_a_warning():
    model = TinyNerf(skip_empty=True)
    origins, directions = rays(5)
    expected = full_jacobian_diagonal(model, origins, directions)
    with pytest.warns(UserWarning, match="vmap"):
        exact = fisher_diagonal(model, origins, directions, method="exact")
    assert torch.allclose(exact, expected, rtol=1e-4, atol=1e-7)


def test_random_sign_estimator_is_unbiased():
    model = TinyNerf()
    origins, directions = rays(10)
    expected = full_jacobian_diagonal(model, origins, directions)
    estimate = fisher_diagonal(
        model,
        origins,
        directions,
        method="random-sign",
        n_probes=1000,
        chunk=10,
        generator=torch.Generator().manual_seed(0),
    )
    # Relative error ~ sqrt(2 / n_probes) per entry; a bias (e.g. a missing 1 / n_probes or a
    # factor from the probe distribution) would show up far above this bound.
    relative = (estimate - expected).norm() / expected.norm()
    assert relative < 0.1
    few = fisher_diagonal(
        model,
        origins,
        directions,
        method="random-sign",
        n_probes=2,
        chunk=10,
        generator=torch.Generator().manual_seed(0),
    )
    assert (few - expected).norm() / expected.norm() > 0.3  # the bound above is not loose


def test_random_sign_with_one_ray_per_chunk_is_exact():
    # One ray and one channel per probe: (v J)^2 = J^2 whatever the sign.
    model = TinyNerf()
    origins, directions = rays(4)
    expected = full_jacobian_diagonal(model, origins, directions)
    per_ray = fisher_diagonal(
        model,
        origins,
        directions,
        method="random-sign",
        n_probes=1,
        chunk=1,
        generator=torch.Generator().manual_seed(1),
    )
    assert torch.allclose(per_ray, expected, rtol=1e-4, atol=1e-7)


def test_random_sign_is_deterministic_for_a_seed_and_keeps_eval_mode_temporary():
    model = TinyNerf().train()
    origins, directions = rays(8)
    first = fisher_diagonal(model, origins, directions, n_probes=3, generator=torch.Generator().manual_seed(5))
    second = fisher_diagonal(model, origins, directions, n_probes=3, generator=torch.Generator().manual_seed(5))
    assert torch.equal(first, second)
    assert model.training


def test_groups_split_the_diagonal_by_view():
    model = TinyNerf()
    origins, directions = rays(9)
    groups = torch.tensor([0, 1, 2, 0, 1, 2, 0, 1, 2])
    per_group = fisher_diagonal_groups(model, origins, directions, groups, 3, method="exact")
    for g in range(3):
        mask = groups == g
        assert torch.allclose(
            per_group[g], full_jacobian_diagonal(model, origins[mask], directions[mask]), rtol=1e-4, atol=1e-7
        )


def test_bad_arguments_are_refused():
    model = TinyNerf()
    origins, directions = rays(2)
    with pytest.raises(ValueError, match="random-sign"):
        fisher_diagonal(model, origins, directions, method="hutchinson")
    with pytest.raises(ValueError, match="n_probes"):
        fisher_diagonal(model, origins, directions, n_probes=0)


def test_scores_are_information_gain_over_the_training_diagonal():
    h_train = torch.tensor([1.0, 0.0, 4.0])
    h_candidates = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 4.0]])
    assert torch.allclose(fisherrf_scores(h_train, h_candidates, lam=1.0), torch.tensor([0.5, 1.0, 0.8]))


def test_greedy_picks_a_different_second_view_after_updating_h_train():
    # Views 0 and 1 see the same parameter; view 2 another, a little less informative.
    h_train = torch.tensor([0.1, 0.1, 1.0])
    h_candidates = torch.tensor([[10.0, 0.0, 0.0], [9.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, 0.0, 1.0]])
    scores = fisherrf_scores(h_train, h_candidates)
    assert torch.argsort(scores, descending=True)[:2].tolist() == [0, 1]  # what top-k would take
    indices, first = fisherrf_greedy(h_train, h_candidates, 2)
    assert indices.tolist() == [0, 2]
    assert torch.equal(first, scores)


def naive_greedy(h_train, h_candidates, k, lam):
    h, chosen = h_train.clone(), []
    for _ in range(k):
        scores = fisherrf_scores(h, h_candidates, lam)
        scores[chosen] = -torch.inf
        chosen.append(int(scores.argmax()))
        h += h_candidates[chosen[-1]]
    return chosen


def test_lazy_greedy_matches_rescoring_everything():
    generator = torch.Generator().manual_seed(3)
    for _ in range(20):
        h_candidates = torch.rand(40, 30, generator=generator) ** 4
        h_train = torch.rand(30, generator=generator) ** 4
        indices, _ = fisherrf_greedy(h_train, h_candidates, 8, lam=1e-3)
        assert indices.tolist() == naive_greedy(h_train, h_candidates, 8, 1e-3)
    with pytest.raises(ValueError, match="cannot pick"):
        fisherrf_greedy(h_train, h_candidates, 41)


def cameras(n: int, seed: int = 0) -> Cameras:
    poses = sample_uniform_poses(n, torch.Generator().manual_seed(seed), radius=4.0)
    return Cameras.from_fov(poses, BLENDER_CAMERA_ANGLE_X, 20, 20)


def test_view_scores_recompute_dropped_views_identically():
    model = TinyNerf()
    candidates = cameras(7)
    h_train = fisher_diagonal(model, *rays(16), n_probes=4, generator=torch.Generator().manual_seed(0))
    scores, h_of = fisherrf_view_scores(
        model,
        candidates,
        h_train,
        cache_floats=1,
        resolution=3,
        n_probes=2,
        generator=torch.Generator().manual_seed(1),
        views_per_batch=3,
    )
    for i in range(7):
        assert torch.allclose(fisherrf_scores(h_train, h_of(i)), scores[i], rtol=1e-5)
    exact_scores, _ = fisherrf_view_scores(
        model, candidates, h_train, resolution=3, method="exact", generator=torch.Generator().manual_seed(2)
    )
    dense = fisher_views(model, candidates, resolution=3, method="exact", generator=torch.Generator().manual_seed(2))
    assert torch.allclose(exact_scores, fisherrf_scores(h_train, dense), rtol=1e-5)


def test_pixel_subsample_is_seeded_and_inside_the_images():
    cams = cameras(3)
    o1, d1 = sample_pixel_rays(cams, 50, torch.Generator().manual_seed(0))
    o2, d2 = sample_pixel_rays(cams, 50, torch.Generator().manual_seed(0))
    assert torch.equal(d1, d2) and o1.shape == (50, 3)
    assert torch.allclose(d1.norm(dim=-1), torch.ones(50))


def test_stratified_pixels_weigh_each_pixel_by_the_inverse_of_its_inclusion_probability():
    # 7 x 5 pixels in a 3 x 2 grid: blocks of unequal sizes (2 or 3 columns, 2 or 3 rows).
    n_seeds = 4000
    generators = [torch.Generator().manual_seed(s) for s in range(n_seeds)]
    views, xs, ys, weights = stratified_pixels(n_seeds, 7, 5, 3, 2, generators)
    assert torch.equal(views, torch.arange(n_seeds).repeat_interleave(6))
    assert torch.allclose(weights.reshape(n_seeds, 6).sum(dim=1), torch.full((n_seeds,), 35.0, dtype=weights.dtype))
    assert xs.min() >= 0 and xs.max() <= 6 and ys.min() >= 0 and ys.max() <= 4
    # E[sum over draws of w * 1{pixel drawn}] = 1 for every pixel: the estimate of a sum is unbiased.
    per_pixel = torch.zeros(5, 7, dtype=torch.float64).index_put_((ys, xs), weights, accumulate=True) / n_seeds
    # Each count is binomial(n_seeds, 1 / area), area in {4, 6, 9}: std of per_pixel <= sqrt(9 / n_seeds).
    assert (per_pixel - 1).abs().max() < 5 * (9 / n_seeds) ** 0.5
    assert per_pixel.std() > 0  # random, not a fixed pattern


def test_a_grid_as_fine_as_the_image_takes_every_pixel_once():
    views, xs, ys, weights = stratified_pixels(2, 4, 3, 4, 3, [torch.Generator().manual_seed(i) for i in range(2)])
    assert torch.equal(weights, torch.ones(24, dtype=weights.dtype))
    assert sorted(zip(views.tolist(), ys.tolist(), xs.tolist())) == [
        (v, y, x) for v in range(2) for y in range(3) for x in range(4)
    ]
    assert pixel_grid(10**6, 4, 3) == (4, 3)
    assert pixel_grid(12, 40, 10) == (7, 2)  # about 12 blocks with the image's 4:1 aspect ratio
    with pytest.raises(ValueError, match="at least 1"):
        pixel_grid(0, 4, 3)
    with pytest.raises(ValueError, match="does not fit"):
        stratified_pixels(1, 4, 3, 5, 3, [torch.Generator()])


def full_image_diagonals(model, cams):
    """Per view, diag(J^T J) over every pixel of its image: the full Jacobian (torch reference)."""
    n_pixels = cams.width * cams.height
    origins, directions = views_rays(cams, list(range(len(cams))))
    return torch.stack(
        [
            full_jacobian_diagonal(
                model, origins[v * n_pixels : (v + 1) * n_pixels], directions[v * n_pixels : (v + 1) * n_pixels]
            )
            for v in range(len(cams))
        ]
    )


def test_whole_image_diagonal_equals_the_sum_over_every_pixel():
    model = TinyNerf()
    cams = cameras(2).resized(6, 5)
    expected = full_image_diagonals(model, cams)
    for method in ("exact", "random-sign"):  # the random-sign with chunk 1 is exact too
        whole = fisher_views(
            model, cams, resolution=6, method=method, chunk=1, generator=torch.Generator().manual_seed(0)
        )
        assert torch.allclose(whole, expected, rtol=1e-4, atol=1e-6), method
    # H_train over every pixel of the same views is on the same scale: the sum of the H_cand.
    origins, directions, weights = stratified_pixel_rays(cams, 10**6, torch.Generator().manual_seed(0))
    assert torch.equal(weights, torch.ones(60))
    h_train = fisher_diagonal(model, origins, directions, method="exact", weights=weights)
    assert torch.allclose(h_train, expected.sum(dim=0), rtol=1e-4, atol=1e-6)


def test_subsampled_diagonal_is_an_unbiased_estimate_of_the_whole_image():
    model = TinyNerf()
    cams = cameras(1).resized(12, 10)
    expected = full_image_diagonals(model, cams)[0]  # (P,) over all 120 pixels
    n_seeds = 300
    generator = torch.Generator().manual_seed(0)
    # 3 x 2 blocks of 4 x 5 pixels, one pixel each, weight 20; only the pixels are random ("exact").
    estimates = torch.stack(
        [fisher_views(model, cams, resolution=3, method="exact", generator=generator)[0] for _ in range(n_seeds)]
    )
    mean, standard_error = estimates.mean(dim=0), estimates.std(dim=0) / n_seeds**0.5
    z = (mean - expected) / standard_error
    assert z.abs().max() < 4.5  # about 70 parameters: a max |z| of 4.5 is a 1-in-1000 event
    # Their mean square is 1 in expectation, but the parameters' estimates are strongly correlated
    # (they share each drawn pixel), so it spreads far more than chi-square / P: bound it loosely.
    # A bias shows anyway: it grows with the seeds (measured: 300 -> 1200 seeds left max |z| ~2).
    assert z.pow(2).mean() < 3.0
    # Unweighted (no rescaling), the same pixels would be 20 times too small: far outside the bound.
    assert ((mean / 20 - expected) / standard_error).abs().max() > 10
    # Each estimate varies (the test is not of a deterministic pattern).
    assert estimates.std(dim=0).sum() > 0.05 * expected.sum()


def test_stratified_training_pixels_estimate_the_sum_over_all_training_images():
    model = TinyNerf()
    cams = cameras(2).resized(8, 8)
    expected = full_image_diagonals(model, cams).sum(dim=0)
    generator = torch.Generator().manual_seed(1)
    estimates = []
    for _ in range(150):
        origins, directions, weights = stratified_pixel_rays(cams, 8, generator)  # 2 x 2 blocks per view
        assert weights.shape == (8,) and float(weights.sum()) == 128.0
        estimates.append(fisher_diagonal(model, origins, directions, method="exact", weights=weights))
    estimates = torch.stack(estimates)
    z = (estimates.mean(dim=0) - expected) / (estimates.std(dim=0) / len(estimates) ** 0.5)
    assert z.abs().max() < 4.5


def test_random_sign_with_weights_is_unbiased_for_the_weighted_sum():
    model = TinyNerf()
    origins, directions = rays(6)
    weights = torch.tensor([1.0, 4.0, 0.5, 9.0, 2.0, 3.0])
    expected = fisher_diagonal(model, origins, directions, method="exact", weights=weights)
    reference = sum(
        w * full_jacobian_diagonal(model, origins[i : i + 1], directions[i : i + 1]) for i, w in enumerate(weights)
    )
    assert torch.allclose(expected, reference, rtol=1e-4, atol=1e-7)
    estimate = fisher_diagonal(
        model,
        origins,
        directions,
        method="random-sign",
        n_probes=2000,
        chunk=6,
        weights=weights,
        generator=torch.Generator().manual_seed(0),
    )
    assert (estimate - expected).norm() / expected.norm() < 0.1


def test_fisherrf_training_sum_is_on_the_candidates_whole_image_scale():
    """H_train in `fisherrf_candidates` estimates the sum over every pixel of the training views,
    the scale of the whole-image H_cand the greedy batch adds to it (not a subsample's sum)."""
    from nerfaug.selection import SelectionConfig, fisherrf_candidates

    model = TinyNerf()
    train, candidates = cameras(2).resized(6, 5), cameras(3, seed=1).resized(6, 5)
    expected = full_image_diagonals(model, train).sum(dim=0)
    config = SelectionConfig(fisher_method="exact", fisher_train_pixels=10**6, fisher_resolution=6)
    h_train, scores, h_of = fisherrf_candidates(model, train, candidates, config, torch.Generator().manual_seed(0))
    assert torch.allclose(h_train, expected, rtol=1e-4, atol=1e-6)
    # Subsampled (12 of 60 pixels), it is still an estimate of the same sum, not of a fifth of it.
    estimates = torch.stack(
        [
            fisherrf_candidates(
                model,
                train,
                candidates,
                SelectionConfig(fisher_method="exact", fisher_train_pixels=12, fisher_resolution=6),
                torch.Generator().manual_seed(seed),
            )[0]
            for seed in range(60)
        ]
    )
    ratio = estimates.mean(dim=0).sum() / expected.sum()
    assert 0.8 < ratio < 1.25, ratio
    assert torch.allclose(h_of(0), full_image_diagonals(model, candidates)[0], rtol=1e-4, atol=1e-6)
