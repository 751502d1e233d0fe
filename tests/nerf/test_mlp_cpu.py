"""The fields' MLPs in one C pass (`nerfaug.nerf.mlp_cpu`, part of engine version cpu-fused-3)
against PyTorch's layers: outputs and every gradient within float32 rounding for random widths,
depths and point counts (hypothesis; counts that are not multiples of the 64-point block, and
none); ReLU's NaN and zero as torch's; the same bits from the AVX2 build and the build for any
machine, and from two calls; where the loop runs and where it does not."""

from __future__ import annotations

import ctypes
import shutil
import subprocess

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from nerfaug.nerf import hash_cpu, mlp_cpu, sampler_cpu
from nerfaug.nerf.config import NerfConfig
from nerfaug.nerf.encoding import HashEncoding
from nerfaug.nerf.field import DensityField, NerfField, mlp
from nerfaug.nerf.registry import build_field

pytestmark = pytest.mark.skipif(
    not (mlp_cpu.available() and sampler_cpu.available() and hash_cpu.available()),
    reason="no C compiler built the fused CPU loops",
)


@pytest.fixture(name="fused")
def fused_fixture(monkeypatch):
    """This process on cpu-fused-3 for one test."""
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    monkeypatch.setattr(sampler_cpu, "MODE", "fused")


def network_and_data(seed: int, n: int, widths: list[int]):
    """`field.mlp(widths[0], widths[1], widths[-1], len(widths) - 2)` (hidden layers of one width)
    with random parameters, points x (n, in) that need a gradient, and an output gradient."""
    torch.manual_seed(seed)
    network = mlp(widths[0], widths[1], widths[-1], len(widths) - 2)
    with torch.no_grad():
        for p in network.parameters():
            p.normal_(0.0, 0.5)  # biases too: some ReLUs closed, some open
    x = torch.randn(n, widths[0]).requires_grad_()
    return network, x, torch.randn(n, widths[-1])


def outputs_and_gradients(network, x, grad, through_c: bool):
    out = mlp_cpu.run(network, x, fused=True) if through_c else network(x)
    grads = torch.autograd.grad((out * grad).sum(), [x, *network.parameters()]) if x.shape[0] else ()
    return out, grads


def close(got: torch.Tensor, want: torch.Tensor) -> bool:
    """Equal within float32 rounding of sums of up to a few thousand terms (another order, fused
    multiply-adds), relative to the tensor's largest entry."""
    scale = float(want.detach().abs().max()) if want.numel() else 1.0
    return got.shape == want.shape and bool(torch.allclose(got, want, rtol=1e-4, atol=1e-5 * (scale + 1e-6)))


# The fixture only chooses the loops for this process: the same for every example.
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    seed=st.integers(0, 10**6),
    n=st.sampled_from([0, 1, 7, 63, 64, 65, 200, 1000]),
    inputs=st.integers(1, 40),
    hidden=st.integers(1, 40),
    outputs=st.integers(1, 20),
    hidden_layers=st.integers(1, 3),
)
def test_outputs_and_gradients_match_pytorchs_layers(fused, seed, n, inputs, hidden, outputs, hidden_layers):
    network, x, grad = network_and_data(seed, n, [inputs] + [hidden] * hidden_layers + [outputs])
    want_out, want_grads = outputs_and_gradients(network, x, grad, through_c=False)
    got_out, got_grads = outputs_and_gradients(network, x, grad, through_c=True)
    assert close(got_out, want_out)
    assert len(got_grads) == len(want_grads)
    for got, want in zip(got_grads, want_grads):
        assert close(got, want)


def test_relu_keeps_nan_and_closes_at_zero_as_torch_does(fused):
    """An input NaN reaches the outputs (no ReLU hides it), and a unit whose input is exactly zero
    passes no gradient (torch's threshold_backward), in both paths alike."""
    network = mlp(2, 3, 1, 1)
    with torch.no_grad():
        network[0].weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))
        network[0].bias.zero_()
        network[2].weight.fill_(1.0)
        network[2].bias.zero_()
    x = torch.tensor([[float("nan"), 1.0], [0.0, 0.0], [2.0, -1.0]], requires_grad=True)
    want_out, want_grads = outputs_and_gradients(network, x, torch.ones(3, 1), through_c=False)
    got_out, got_grads = outputs_and_gradients(network, x, torch.ones(3, 1), through_c=True)
    assert torch.isnan(got_out[0, 0]) and torch.isnan(want_out[0, 0])
    assert torch.equal(got_out[1:], want_out[1:])
    assert torch.equal(got_grads[0][1:], want_grads[0][1:])  # zero inputs: closed units, as torch


def _build(tmp_path, one_version: bool) -> ctypes.CDLL:
    """mlp_cpu.c built as the engine builds it, or with only the version for any machine."""
    compiler = shutil.which("cc") or shutil.which("gcc")
    target = tmp_path / ("one.so" if one_version else "two.so")
    extra = ["-DNERFAUG_ONE_VERSION"] if one_version else []
    subprocess.run(
        [compiler, *hash_cpu._FLAGS, *extra, "-o", str(target), str(mlp_cpu._SOURCE), "-lm"],
        check=True,
        capture_output=True,
    )
    library = ctypes.CDLL(str(target))
    library.mlp_forward.argtypes = mlp_cpu._library().mlp_forward.argtypes
    library.mlp_backward.argtypes = mlp_cpu._library().mlp_backward.argtypes
    return library


def _call(library, network, x, grad, keep: bool):
    """Outputs and all gradients through `library`'s loops (as `CpuMlp` calls them), the hidden
    activations kept by the forward for the backward or computed again by it."""
    linears = mlp_cpu.linear_layers(network)
    weights = [layer.weight.detach().contiguous() for layer in linears]
    biases = [layer.bias.detach().contiguous() for layer in linears]
    dims = (ctypes.c_int * (len(weights) + 1))(x.shape[1], *(w.shape[0] for w in weights))
    out = torch.empty(x.shape[0], weights[-1].shape[0])
    blocks = -(-x.shape[0] // 64)
    kept = torch.empty(blocks * sum(w.shape[0] for w in weights[:-1]) * 64)  # alive until the backward
    hidden = kept.data_ptr() if keep else None
    grad_x = torch.empty_like(x)
    grad_w, grad_b = [torch.empty_like(w) for w in weights], [torch.empty_like(b) for b in biases]
    p = mlp_cpu._pointers
    n, layers = x.shape[0], len(weights)
    assert library.mlp_forward(x.data_ptr(), n, layers, dims, p(weights), p(biases), out.data_ptr(), hidden) == 0
    assert (
        library.mlp_backward(
            *(x.data_ptr(), n, layers, dims, p(weights), p(biases), hidden),
            *(grad.data_ptr(), grad_x.data_ptr(), p(grad_w), p(grad_b)),
        )
        == 0
    )
    return [out, grad_x, *grad_w, *grad_b]


@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler")
def test_the_build_for_any_machine_computes_the_same_bits_as_the_fast_one(tmp_path):
    """Fused multiply-adds by the instruction (AVX2 machines) and by the C library's fmaf (any
    machine) round alike, and every sum keeps its order: the same bits, so a run's numbers do not
    depend on the machine's vector instructions. Two calls give the same bits, and so does a
    backward that computes the hidden activations again instead of reading the forward's."""
    network, x, grad = network_and_data(3, 1000, [31, 32, 32, 3])
    x = x.detach()
    fast, plain = _build(tmp_path, one_version=False), _build(tmp_path, one_version=True)
    first = _call(fast, network, x, grad, keep=True)
    assert all(torch.equal(a, b) for a, b in zip(first, _call(plain, network, x, grad, keep=True)))
    assert all(torch.equal(a, b) for a, b in zip(first, _call(fast, network, x, grad, keep=True)))
    assert all(torch.equal(a, b) for a, b in zip(first, _call(fast, network, x, grad, keep=False)))


def test_the_loop_runs_for_engines_with_proposal_networks_only_when_chosen(monkeypatch, fused):
    """Chosen, on float32 CPU tensors of a proposal engine's field and proposal networks: the loop;
    an occupancy-grid engine's field, float64, autocast or the choice "hash": PyTorch's layers."""
    calls = []
    real = mlp_cpu.CpuMlp.apply
    monkeypatch.setattr(mlp_cpu.CpuMlp, "apply", lambda *a: calls.append(1) or real(*a))
    proposal_engine = NerfConfig.preset("nerfacto-cpu")
    field, proposal_network = build_field(proposal_engine), DensityField(proposal_engine, 64)
    assert isinstance(field, NerfField) and field.fused_mlps
    points, directions = torch.rand(100, 3), torch.nn.functional.normalize(torch.randn(100, 3), dim=-1)

    def every_network():
        _, geometry = field.density(points)
        field.color(geometry, directions)
        proposal_network(points)

    every_network()
    assert len(calls) == 3
    assert not build_field(NerfConfig.preset("cpu")).fused_mlps  # K-planes, occupancy grid
    network, x, _ = network_and_data(0, 10, [4, 8, 2])
    mlp_cpu.run(network.double(), x.double(), fused=True)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        mlp_cpu.run(network.float(), x, fused=True)
    assert len(calls) == 3
    monkeypatch.setattr(sampler_cpu, "MODE", "hash")
    every_network()
    assert len(calls) == 3


def test_without_the_mlp_loop_no_run_records_the_fused_version(monkeypatch, fused):
    """Where the MLP loop is not built, the fused loops are not chosen at all: a run computes and
    records hash-cpu-1, never a cpu-fused-3 without its MLPs."""
    from nerfaug.experiment.config import ExperimentConfig
    from nerfaug.nerf.config import CPU_FUSED_ENGINE_VERSION, HASH_CPU_ENGINE_VERSION

    study = ExperimentConfig(device="cpu", engine="nerfacto-cpu")
    assert study.engine_version() == CPU_FUSED_ENGINE_VERSION
    monkeypatch.setattr(mlp_cpu, "available", lambda: False)
    assert not sampler_cpu.selected()
    assert study.engine_version() == HASH_CPU_ENGINE_VERSION
