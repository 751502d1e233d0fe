"""Position and direction encodings, and the field's activations."""

import math

import pytest
import torch

from nerfaug.nerf.encoding import (
    HASH_PRIMES,
    HashEncoding,
    KPlanesEncoding,
    hash_grid_indices,
    hash_resolutions,
    spherical_harmonics,
)
from nerfaug.nerf.field import density_activation, trunc_exp


def test_hash_resolutions_grow_geometrically_from_base_to_max():
    resolutions = hash_resolutions(16, 16, 2048)
    assert resolutions[0] == 16 and resolutions[-1] == 2048
    assert all(b > a for a, b in zip(resolutions, resolutions[1:]))
    ratios = [b / a for a, b in zip(resolutions, resolutions[1:])]
    assert max(ratios) - min(ratios) < 0.05


def test_hashed_rows_are_in_the_table_and_coarse_levels_are_dense(generator):
    table_size = 2**12
    resolutions = torch.tensor([8, 2048])
    corners = torch.randint(0, 2049, (1000, 2, 3), generator=generator)
    corners[:, 0] = corners[:, 0] % 9
    rows = hash_grid_indices(corners, resolutions, table_size)
    assert rows.min() >= 0 and rows.max() < table_size
    # Level 0 has 9^3 = 729 <= 4096 vertices: dense, collision-free indexing.
    all_vertices = torch.stack(torch.meshgrid(*[torch.arange(9)] * 3, indexing="ij"), -1).reshape(-1, 3)
    dense_rows = hash_grid_indices(all_vertices, torch.tensor(8), table_size)
    assert dense_rows.unique().numel() == 729
    # Level 1 uses Instant-NGP's hash (uint32 products, XOR, low bits).
    c = corners[0, 1].tolist()
    products = [(c[k] * HASH_PRIMES[k]) % 2**32 for k in range(3)]
    expected = (products[0] ^ products[1] ^ products[2]) % table_size
    assert rows[0, 1].item() == expected


def _naive_hash_encoding(encoding: HashEncoding, x: torch.Tensor) -> torch.Tensor:
    """Level by level, corner by corner: the reference the vectorised encoding must match."""
    out = []
    for level, resolution in enumerate(encoding.resolutions.tolist()):
        scaled = x * resolution
        base = scaled.floor().long()
        frac = scaled - base
        feature = 0
        for dx in (0, 1):
            for dy in (0, 1):
                for dz in (0, 1):
                    vertex = (base + torch.tensor([dx, dy, dz])).clamp(max=resolution)
                    row = hash_grid_indices(vertex, torch.tensor(resolution), encoding.table_size)
                    w = (
                        (frac[:, 0] if dx else 1 - frac[:, 0])
                        * (frac[:, 1] if dy else 1 - frac[:, 1])
                        * (frac[:, 2] if dz else 1 - frac[:, 2])
                    )
                    feature = feature + w[:, None] * encoding.table[row + level * encoding.table_size]
        out.append(feature)
    return torch.cat(out, dim=-1)


def test_hash_encoding_matches_a_per_level_reference_and_passes_gradients(generator):
    torch.manual_seed(0)
    encoding = HashEncoding(
        num_levels=4, features_per_level=2, log2_table_size=10, base_resolution=4, max_resolution=64
    )
    with torch.no_grad():
        encoding.table.normal_()
    x = torch.rand(257, 3, generator=generator)
    x[0] = 1.0  # the far corner of the cube stays in range
    features = encoding(x)
    assert features.shape == (257, 8)
    assert torch.allclose(features, _naive_hash_encoding(encoding, x), atol=1e-5)
    features.square().sum().backward()
    touched = (encoding.table.grad.abs().sum(-1) > 0).sum().item()
    assert 0 < touched <= 257 * 4 * 8
    # Each level sees a different resolution: the finest varies within a coarse cell.
    a, b = torch.tensor([[0.50, 0.5, 0.5]]), torch.tensor([[0.51, 0.5, 0.5]])
    with torch.no_grad():
        assert not torch.allclose(encoding(a)[:, 6:], encoding(b)[:, 6:])


def _autograd_interpolation(table: torch.Tensor, rows: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """The interpolation as the engine composed it from autograd operations before it had a
    backward of its own: the reference its outputs and gradients must equal bit for bit."""
    n = weights.shape[-1]
    flat = rows.reshape(-1).long()
    channels = [
        (table[:, f].index_select(0, flat).reshape(weights.shape) * weights).sum(dim=1) for f in range(table.shape[1])
    ]
    return torch.stack(channels, dim=-1).transpose(0, 1).reshape(n, -1)


@pytest.mark.parametrize(
    "levels, features, log2_size, base, finest",
    [(6, 2, 14, 16, 256), (3, 2, 12, 16, 64), (4, 3, 10, 4, 64), (2, 1, 12, 8, 2048)],
)
def test_hash_encoding_equals_the_autograd_composition_bit_for_bit(
    levels, features, log2_size, base, finest, generator
):
    encoding = HashEncoding(levels, features, log2_size, base, finest, kernel="torch")
    with torch.no_grad():
        encoding.table.normal_(generator=generator)
    x = torch.rand(3000, 3, generator=generator)
    x[:3] = torch.tensor([[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.5, 0.0]])
    grad = torch.randn(3000, levels * features, generator=generator)
    rows, weights = encoding.corners(x)
    table = encoding.table.detach().clone().requires_grad_()
    expected = _autograd_interpolation(table, rows, weights)
    expected.backward(grad)
    got = encoding(x)
    got.backward(grad)
    assert torch.equal(got, expected)
    assert torch.equal(encoding.table.grad, table.grad)
    assert 0 < (table.grad.abs().sum(-1) > 0).sum() < table.shape[0]


def test_hash_encoding_passes_gradients_to_the_positions_too():
    encoding = HashEncoding(2, 2, 8, 4, 16).double()
    x = torch.rand(20, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    x = (x * 0.98 + 0.01).requires_grad_()  # off the cell faces, where trilinear weights have kinks
    # d/dx of the features against the autograd composition of the same rows and weights.
    rows, weights = encoding.corners(x)
    expected = torch.autograd.grad(_autograd_interpolation(encoding.table, rows, weights).sum(), x)[0]
    got = torch.autograd.grad(encoding(x).sum(), x)[0]
    assert torch.allclose(got, expected, rtol=1e-12, atol=1e-12)
    assert got.abs().sum() > 0


def test_hash_encoding_is_exact_at_grid_vertices():
    encoding = HashEncoding(num_levels=1, features_per_level=3, log2_table_size=12, base_resolution=8, max_resolution=8)
    with torch.no_grad():
        encoding.table.normal_()
    vertex = torch.tensor([[3, 5, 2]])
    row = hash_grid_indices(vertex, torch.tensor(8), encoding.table_size)
    assert torch.allclose(encoding(vertex / 8.0), encoding.table[row])


def test_kplanes_features_multiply_the_three_planes_and_reach_every_scale(generator):
    encoding = KPlanesEncoding(resolutions=(4, 8), features=3)
    x = torch.rand(100, 3, generator=generator)
    features = encoding(x)
    assert features.shape == (100, 6)
    features.sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in encoding.planes)
    # At a texel centre with align_corners, bilinear lookup returns the texel.
    with torch.no_grad():
        point = torch.tensor([[1 / 3, 2 / 3, 1.0]])  # texels (1, 2), (1, 3), (2, 3) of a 4x4 plane
        planes = encoding.planes[0]
        expected = planes[0, :, 2, 1] * planes[1, :, 3, 1] * planes[2, :, 3, 2]
        assert torch.allclose(encoding(point)[0, :3], expected, atol=1e-6)


def test_spherical_harmonics_are_orthonormal_on_the_sphere():
    # Fibonacci points: near-uniform on the sphere, so the mean approximates the integral / 4 pi.
    n = 20000
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = (1 - z * z).sqrt()
    directions = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
    basis = spherical_harmonics(directions, 4)
    assert basis.shape == (n, 16)
    gram = 4 * math.pi * basis.T @ basis / n
    assert torch.allclose(gram, torch.eye(16, dtype=torch.float64), atol=1e-3)


def test_trunc_exp_clamps_the_gradient_and_densities_start_at_the_average():
    x = torch.tensor([0.0, 20.0], requires_grad=True)
    trunc_exp(x).sum().backward()
    assert x.grad[0].item() == pytest.approx(1.0)
    assert x.grad[1].item() == pytest.approx(math.exp(15.0), rel=1e-5)
    zero = torch.zeros(3)
    for kind in ("trunc_exp", "softplus"):
        assert torch.allclose(density_activation(zero, kind, 0.01), torch.full((3,), 0.01), rtol=1e-4)


def test_hash_encoding_kernel_is_checked_and_the_cpu_takes_no_triton_kernel():
    with pytest.raises(ValueError, match=r"kernel must be one of auto, torch, triton, cpu, got 'cuda'"):
        HashEncoding(2, 2, 8, 4, 16, kernel="cuda")
    x = torch.rand(5, 3)
    assert not HashEncoding(2, 2, 8, 4, 16).fused(x)  # "auto": Triton on CUDA tensors only
    assert HashEncoding(2, 2, 8, 4, 16, kernel="triton").fused(x)
    assert not HashEncoding(2, 2, 8, 4, 16, kernel="triton").fused(x.requires_grad_())  # positions' gradients


@pytest.mark.parametrize("levels", [6, 16])
def test_no_points_encode_to_no_rows_and_backpropagate(levels):
    # a render pass whose rays lost every sample (all background) hands the encoding 0 points
    encoding = HashEncoding(num_levels=levels, log2_table_size=12, max_resolution=256)
    for needs_grad in (False, True):
        points = torch.rand(0, 3, requires_grad=needs_grad)
        features = encoding(points)
        assert features.shape == (0, levels * 2)
        features.sum().backward()
        assert encoding.table.grad is not None and not encoding.table.grad.any()
