"""The proposal sampler's C loops (`nerfaug.nerf.sampler_cpu`, engine version cpu-fused-3) against
the PyTorch functions they replace: volume-rendering weights, the inverse-CDF resampling, the
interlevel and distortion losses, values and gradients within float32 rounding on random rays
(hypothesis) and on edge cases (opaque rays, empty histograms, edges that coincide); the choice of
path and the engine version it records; 12 training steps near the reference engine's recorded
losses, and the same numbers on a second run."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.nerf import hash_cpu, proposal, sampler_cpu
from nerfaug.nerf.config import CPU_FUSED_ENGINE_VERSION, HASH_CPU_ENGINE_VERSION, NerfConfig
from nerfaug.nerf.encoding import HashEncoding
from nerfaug.nerf.sampling import cdf_positions, sample_pdf, stratified_edges
from nerfaug.nerf.volrend import render_weights

from .test_recorded_numbers import RECORDED  # the reference engine's losses of 12 steps and two render sums

pytestmark = pytest.mark.skipif(
    not (sampler_cpu.available() and hash_cpu.available()), reason="no C compiler built the fused CPU loops"
)


@pytest.fixture(name="fused")
def fused_fixture(monkeypatch):
    """This process on cpu-fused-3 for one test."""
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    monkeypatch.setattr(sampler_cpu, "MODE", "fused")


def rays(seed: int, n_rays: int, n: int, scale: float = 1.0):
    """Jittered edges (n_rays, n + 1) over [2, 6] and a generator for more draws."""
    generator = torch.Generator().manual_seed(seed)
    t_min = 2.0 + torch.rand(n_rays, generator=generator)
    t_max = t_min + scale * (0.5 + 3.0 * torch.rand(n_rays, generator=generator))
    return stratified_edges(t_min, t_max, n, True, generator), generator


def close(got: torch.Tensor, want: torch.Tensor, scale: float = 1.0) -> bool:
    """Equal within float32 rounding of sums of tens of terms of size `scale`."""
    return got.shape == want.shape and bool(torch.allclose(got, want, rtol=1e-4, atol=1e-6 * scale))


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    n_rays=st.integers(1, 40),
    n=st.integers(1, 40),
    density=st.sampled_from([0.1, 3.0, 60.0]),
)
def test_weights_and_their_gradient_match_the_pytorch_function(seed, n_rays, n, density):
    """Densities up to 60 over spans up to 3.5 reach optical depths past the clamp at 80 (opaque rays)."""
    edges, generator = rays(seed, n_rays, n)
    deltas = edges[:, 1:] - edges[:, :-1]
    sigmas = (density * torch.rand(n_rays, n, generator=generator)).requires_grad_()
    grad_w, grad_t = torch.randn(n_rays, n, generator=generator), torch.randn(n_rays, n, generator=generator)
    want_w, want_t = render_weights(sigmas, deltas)
    (want_sigma,) = torch.autograd.grad((want_w * grad_w).sum() + (want_t * grad_t).sum(), sigmas)
    got_w, got_t = sampler_cpu.render_weights(sigmas, deltas)
    (got_sigma,) = torch.autograd.grad((got_w * grad_w).sum() + (got_t * grad_t).sum(), sigmas)
    assert close(got_w, want_w) and close(got_t, want_t)
    assert close(got_sigma, want_sigma, scale=float(want_sigma.abs().max()) + 1.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), n_rays=st.integers(1, 40), bins=st.integers(1, 40), samples=st.integers(1, 40))
def test_resampling_matches_sample_pdf_with_the_same_draws(seed, n_rays, bins, samples):
    edges, generator = rays(seed, n_rays, bins)
    weights = torch.rand(n_rays, bins, generator=generator) ** 3
    weights[0] = 0.0  # an empty histogram: the padding alone spreads the samples
    for jitter in (True, False):
        want = sample_pdf(edges, weights, samples, jitter, torch.Generator().manual_seed(seed))
        u = cdf_positions(n_rays, samples + 1, jitter, torch.Generator().manual_seed(seed), "cpu")
        got = sampler_cpu.sample_pdf(edges, weights, u, padding=0.01)
        assert close(got, want, scale=6.0)


def histograms(seed: int, n_rays: int, n: int, m: int):
    """A final histogram and two proposal ones on the same rays; some final edges on proposal
    edges exactly (where searchsorted's side matters)."""
    coarse, generator = rays(seed, n_rays, m)
    finer = sample_pdf(coarse, torch.rand(n_rays, m, generator=generator), m // 2 + 1, True, generator)
    final = sample_pdf(finer, torch.rand(n_rays, m // 2 + 1, generator=generator), n, True, generator)
    ties = min(n // 2, m) - 1
    final[:, 1 : 1 + ties] = coarse[:, 1 : 1 + ties].clamp(max=final[:, -1:])
    final = final.sort(dim=-1).values
    weights = torch.rand(n_rays, n, generator=generator) * 0.3
    p_weights = [torch.rand(n_rays, e.shape[1] - 1, generator=generator) * 0.1 for e in (coarse, finer)]
    return final, weights, [coarse, finer], [p.requires_grad_() for p in p_weights], generator


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), n_rays=st.integers(1, 30), n=st.integers(2, 24), m=st.integers(2, 40))
def test_interlevel_terms_and_proposal_gradients_match_the_pytorch_loss(seed, n_rays, n, m):
    edges, weights, p_edges, p_weights, generator = histograms(seed, n_rays, n, m)
    want = proposal.interlevel_loss(edges, weights, p_edges, p_weights)
    want_grads = torch.autograd.grad(want, p_weights)
    got = sum(sampler_cpu.FusedInterlevel.apply(edges, weights, e, w, 1e-7).mean() for e, w in zip(p_edges, p_weights))
    got_grads = torch.autograd.grad(got, p_weights)
    assert close(got, want)
    for g, w in zip(got_grads, want_grads):
        assert close(g, w, scale=float(w.abs().max()) + 1e-3)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), n_rays=st.integers(1, 30), n=st.integers(1, 40))
def test_distortion_and_its_gradient_match_the_pytorch_loss(seed, n_rays, n):
    edges, generator = rays(seed, n_rays, n)
    edges[0] = 3.0  # a ray of zero length: the span is clamped
    weights = (torch.rand(n_rays, n, generator=generator) / n).requires_grad_()
    grad = torch.randn(n_rays, generator=generator)
    want = proposal.distortion_per_ray(edges, weights)
    (want_grad,) = torch.autograd.grad((want * grad).sum(), weights)
    got = sampler_cpu.FusedDistortion.apply(edges, weights, 1e-7)
    (got_grad,) = torch.autograd.grad((got * grad).sum(), weights)
    assert close(got, want) and close(got_grad, want_grad, scale=float(want_grad.abs().max()) + 1e-3)


def test_the_sampler_takes_the_loops_only_when_chosen(monkeypatch, fused):
    """Chosen: the proposal functions run the loops (equal within rounding, so only a spy tells);
    not chosen, another dtype or the hash loop off: the PyTorch functions."""
    edges, generator = rays(0, 8, 16)
    weights = torch.rand(8, 16, generator=generator).requires_grad_()
    calls = []
    monkeypatch.setattr(sampler_cpu.FusedDistortion, "apply", lambda *a: calls.append(1) or torch.zeros(8))
    proposal.distortion_per_ray(edges, weights)
    assert calls == [1]
    proposal.distortion_per_ray(edges.double(), weights.double())
    monkeypatch.setattr(HashEncoding, "default_kernel", "torch")
    proposal.distortion_per_ray(edges, weights)
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    monkeypatch.setattr(sampler_cpu, "MODE", "hash")
    proposal.distortion_per_ray(edges, weights)
    assert calls == [1]


def test_the_engine_version_names_the_fused_loops_and_a_bad_choice_is_refused(monkeypatch, fused):
    study = ExperimentConfig(device="cpu", engine="nerfacto-cpu")
    assert study.engine_version() == CPU_FUSED_ENGINE_VERSION
    assert study.fingerprinted()["engine_version"] == CPU_FUSED_ENGINE_VERSION
    assert ExperimentConfig(device="cpu", engine="cpu").engine_version() is None  # K-planes, occupancy grid
    monkeypatch.setattr(HashEncoding, "default_kernel", "torch")  # no hash loop: the reference engine
    assert study.engine_version() is None
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    monkeypatch.setattr(sampler_cpu, "MODE", "hash")
    assert study.engine_version() == HASH_CPU_ENGINE_VERSION
    monkeypatch.setattr(sampler_cpu, "MODE", "all")
    with pytest.raises(ValueError, match=r"NERFAUG_CPU_KERNELS must be one of hash, fused, got 'all'"):
        study.engine_version()


@pytest.mark.rounding
def test_twelve_steps_stay_near_the_reference_engine_and_repeat_exactly(engine_numbers, fused):
    """Another summation order moves the losses by rounding, which 12 steps amplify little; the
    same seed gives the same numbers (one thread, a fixed order)."""
    first, _ = engine_numbers(NerfConfig.preset("nerfacto-cpu"), 12)
    second, _ = engine_numbers(NerfConfig.preset("nerfacto-cpu"), 12)
    assert first == pytest.approx([float.fromhex(x) for x in RECORDED["nerfacto-cpu"]], rel=1e-5)
    assert first == second
