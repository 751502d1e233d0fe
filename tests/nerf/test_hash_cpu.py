"""The fused CPU hash-grid loop (`nerfaug.nerf.hash_cpu`) against the PyTorch path: features and
table gradients within float32 rounding on random points, points on cell borders and the cube's
faces, and points outside the cube (clamped onto it); the choice of kernel and the engine version
it records."""

from __future__ import annotations

import pytest
import torch

from nerfaug.experiment.config import ExperimentConfig
from nerfaug.nerf import hash_cpu
from nerfaug.nerf.config import HASH_CPU_ENGINE_VERSION
from nerfaug.nerf.encoding import HashEncoding

pytestmark = pytest.mark.skipif(not hash_cpu.available(), reason="no C compiler built the fused CPU loop")

# (levels, features, log2 table size, base, max resolution): nerfacto-cpu's field and proposal
# grids (dense and hashed levels), one with 1 and one with 4 features a row.
SIZES = [(6, 2, 14, 16, 256), (3, 2, 12, 16, 64), (4, 1, 10, 4, 64), (2, 4, 8, 4, 16)]


def pair(size, seed=0):
    """A PyTorch-path encoding and a fused one with the same table (random, not near zero)."""
    reference, fused = HashEncoding(*size, kernel="torch"), HashEncoding(*size, kernel="cpu")
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        reference.table.copy_(torch.rand(reference.table.shape, generator=generator) * 2 - 1)
        fused.table.copy_(reference.table)
    return reference, fused


def points(resolution: int, n: int = 3000, seed: int = 1) -> torch.Tensor:
    """Random points, points on the finest level's cell borders (coordinates k / resolution) and
    on the cube's faces and corners, shape (n + 2 * 64 + 8, 3)."""
    generator = torch.Generator().manual_seed(seed)
    random = torch.rand(n, 3, generator=generator)
    borders = torch.randint(0, resolution + 1, (64, 3), generator=generator).float() / resolution
    faces = torch.rand(64, 3, generator=generator)
    faces[torch.arange(64), torch.randint(0, 3, (64,), generator=generator)] = 1.0
    corners = torch.tensor([[i, j, k] for i in (0.0, 1.0) for j in (0.0, 1.0) for k in (0.0, 1.0)])
    return torch.cat([random, borders, faces, corners])


def features_and_gradient(encoding: HashEncoding, x: torch.Tensor, grad: torch.Tensor):
    encoding.table.grad = None
    out = encoding(x)
    out.backward(grad)
    return out.detach(), encoding.table.grad.clone()


@pytest.mark.parametrize("size", SIZES)
def test_features_and_table_gradients_match_the_pytorch_path(size):
    reference, fused = pair(size)
    assert fused.cpu_fused(torch.rand(2, 3)) and not reference.cpu_fused(torch.rand(2, 3))
    x = points(size[4])
    grad = torch.randn(x.shape[0], reference.output_dim, generator=torch.Generator().manual_seed(2))
    want_out, want_grad = features_and_gradient(reference, x, grad)
    got_out, got_grad = features_and_gradient(fused, x, grad)
    assert got_out.shape == want_out.shape
    torch.testing.assert_close(got_out, want_out, rtol=1e-5, atol=1e-6)
    # Gradients are sums of thousands of products in another order: within rounding of their scale.
    torch.testing.assert_close(got_grad, want_grad, rtol=1e-4, atol=1e-5 * want_grad.abs().max().item())
    assert want_grad.abs().sum() > 0 and (want_grad != 0).sum() == (got_grad != 0).sum()


def test_points_outside_the_cube_encode_as_the_nearest_points_on_it():
    size = SIZES[0]
    reference, fused = pair(size, seed=3)
    x = torch.rand(500, 3, generator=torch.Generator().manual_seed(4)) * 3 - 1  # in [-1, 2]^3
    assert ((x < 0) | (x > 1)).any(dim=1).sum() > 400
    grad = torch.randn(500, reference.output_dim, generator=torch.Generator().manual_seed(5))
    want_out, want_grad = features_and_gradient(reference, x.clamp(0, 1), grad)
    got_out, got_grad = features_and_gradient(fused, x, grad)
    torch.testing.assert_close(got_out, want_out, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(got_grad, want_grad, rtol=1e-4, atol=1e-5 * want_grad.abs().max().item())


def test_a_nan_point_reads_no_memory_outside_the_table():
    """A diverging run may hand the encoding NaN positions: the loop reads the origin's cell (the
    trainer then reports the divergence) instead of a row outside the table."""
    _, fused = pair(SIZES[0])
    x = torch.tensor([[float("nan"), 0.0, 0.0], [0.0, 0.0, 0.0], [float("nan")] * 3])
    out = fused(x)
    assert torch.equal(out[0], out[1]) and torch.equal(out[2], out[1])


def test_the_loop_is_deterministic_and_takes_no_points():
    _, fused = pair(SIZES[1])
    x = points(64)
    grad = torch.randn(x.shape[0], fused.output_dim, generator=torch.Generator().manual_seed(6))
    first, second = features_and_gradient(fused, x, grad), features_and_gradient(fused, x, grad)
    assert torch.equal(first[0], second[0]) and torch.equal(first[1], second[1])
    fused.table.grad = None
    empty = fused(torch.empty(0, 3))
    assert empty.shape == (0, fused.output_dim)
    empty.sum().backward()
    assert torch.count_nonzero(fused.table.grad) == 0


def test_points_with_gradients_or_other_dtypes_take_the_pytorch_path():
    _, fused = pair(SIZES[1])
    x = torch.rand(10, 3)
    assert fused.cpu_fused(x)
    assert not fused.cpu_fused(x.clone().requires_grad_())  # the loop computes no position gradients
    assert not fused.cpu_fused(x.double())
    assert not HashEncoding(*SIZES[1], kernel="triton").cpu_fused(x)


def test_the_environment_chooses_the_default_kernel_and_a_bad_name_is_refused(monkeypatch):
    monkeypatch.setattr(HashEncoding, "default_kernel", "gpu")
    with pytest.raises(ValueError, match=r"NERFAUG_HASH_KERNEL\) must be one of auto, torch, triton, cpu, got 'gpu'"):
        HashEncoding(*SIZES[1])


def test_the_engine_version_names_the_arithmetic(monkeypatch):
    """A hash-grid engine alone on the CPU records the fused loop's version; the reference path
    (NERFAUG_HASH_KERNEL=torch) and engines without a hash grid record none; a batch is no other arithmetic."""
    study = ExperimentConfig(device="cpu", engine="nerfacto-cpu")
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    assert study.engine_version() == HASH_CPU_ENGINE_VERSION
    assert study.fingerprinted()["engine_version"] == HASH_CPU_ENGINE_VERSION
    assert ExperimentConfig(device="cpu", engine="cpu").engine_version() is None  # K-planes, occupancy grid
    assert study.replace(batch=2).engine_version() == HASH_CPU_ENGINE_VERSION  # a batch computes each run as alone
    monkeypatch.setattr(HashEncoding, "default_kernel", "torch")
    assert study.engine_version() is None
    assert "engine_version" not in study.fingerprinted()


def test_without_a_c_compiler_runs_take_the_reference_path_and_record_it(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))  # no loop built before
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setattr(HashEncoding, "default_kernel", "auto")
    hash_cpu._library.cache_clear()
    try:
        assert not hash_cpu.available()
        reference, fused = pair(SIZES[1])
        x = points(64)
        assert not fused.cpu_fused(x)
        assert torch.equal(fused(x), reference(x))  # the PyTorch path, bit for bit
        assert ExperimentConfig(device="cpu", engine="nerfacto-cpu").engine_version() is None
    finally:
        hash_cpu._library.cache_clear()  # the next call builds with the real compiler


def _loop(library, name: str, x: torch.Tensor, tensor: torch.Tensor, out: torch.Tensor, encoding) -> torch.Tensor:
    """`library`'s loop `name` (hash_forward, hash_backward or their *_reference) on `x`, as
    `hash_cpu._call` calls it; returns `out`."""
    function = getattr(library, name)
    function.argtypes = hash_cpu._library().hash_forward.argtypes
    levels, features = encoding.num_levels, encoding.features_per_level
    function(
        *(x.data_ptr(), x.shape[0], tensor.data_ptr(), features, levels, encoding.resolutions.data_ptr()),
        *(encoding.factors.data_ptr(), encoding.dense_levels, encoding.table_size, out.data_ptr()),
    )
    return out


@pytest.mark.parametrize("size", SIZES)
def test_the_eight_point_loops_give_the_one_point_loops_bits_on_every_build(size, tmp_path):
    """Eight points at a time on vectors (AVX2 where the machine has it, and the build for any
    machine) and the one-point loop: the same features and table gradients to the last bit, for
    counts that are not multiples of 8, points outside the cube, on its faces and NaN."""
    import ctypes
    import shutil
    import subprocess

    _, fused = pair(size)
    x = torch.cat([points(size[-1], n=3001), torch.tensor([[float("nan"), 0.5, 0.5], [1.5, -0.5, 0.25]])])
    x[::97, 1] = float("nan")  # NaN lanes among valid ones
    table = fused.table.detach()
    grad = torch.randn(x.shape[0], fused.output_dim, generator=torch.Generator().manual_seed(3))
    compiler = shutil.which("cc") or shutil.which("gcc")
    plain = tmp_path / "plain.so"
    subprocess.run(
        [compiler, *hash_cpu._FLAGS, "-DNERFAUG_ONE_VERSION", "-o", str(plain), str(hash_cpu._SOURCE), "-lm"],
        check=True,
        capture_output=True,
    )
    for library in (hash_cpu._library(), ctypes.CDLL(str(plain))):
        features = {
            name: _loop(library, name, x, table, torch.empty(x.shape[0], fused.output_dim), fused)
            for name in ("hash_forward", "hash_forward_reference")
        }
        gradients = {
            name: _loop(library, name, x, grad, torch.zeros_like(table), fused)
            for name in ("hash_backward", "hash_backward_reference")
        }
        assert torch.equal(features["hash_forward"], features["hash_forward_reference"])
        assert torch.equal(gradients["hash_backward"], gradients["hash_backward_reference"])
