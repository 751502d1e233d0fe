"""Encodings of positions and directions: multiresolution hash grid, K-planes tri-planes, and
real spherical harmonics.

A position encoding is an `nn.Module` mapping points (n, 3) in the unit cube [0, 1]^3 to features
(n, output_dim), with an `output_dim` attribute and a `from_config(NerfConfig)` constructor; the
registry (`nerfaug.nerf.registry.ENCODINGS`) names them.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os

import torch
import torch.nn.functional as F
from torch import Tensor, nn

# Instant-NGP's spatial hash primes (the first is 1 so that x alone is not scrambled).
HASH_PRIMES = (1, 2654435761, 805459861)


def hash_resolutions(num_levels: int, base_resolution: int, max_resolution: int) -> list[int]:
    """Grid resolution of each level, growing geometrically from `base` to `max` (Instant-NGP).

    Example:
        >>> hash_resolutions(3, 16, 64)
        [16, 32, 64]
    """
    if num_levels == 1:
        return [base_resolution]
    growth = math.exp((math.log(max_resolution) - math.log(base_resolution)) / (num_levels - 1))
    return [int(math.floor(base_resolution * growth**level + 1e-6)) for level in range(num_levels)]


def hash_grid_indices(corners: Tensor, resolutions: Tensor, table_size: int) -> Tensor:
    """Row of each grid vertex in its level's table.

    A level whose (resolution + 1)^3 vertices fit in the table is indexed densely (no
    collisions); finer levels use Instant-NGP's XOR-of-primes hash. The low bits of a product
    do not depend on wrap-around, so int64 arithmetic gives the same rows as Instant-NGP's uint32.

    Args:
        corners: Tensor with shape (..., 3), integer vertex coordinates in [0, resolution].
        resolutions: integer Tensor broadcastable to shape (...), each vertex's level resolution.
        table_size: entries per level, a power of two.

    Returns:
        Tensor with shape (...), integer in [0, table_size).
    """
    side = resolutions + 1
    dense = corners[..., 0] + side * (corners[..., 1] + side * corners[..., 2])
    x, y, z = corners.unbind(-1)
    hashed = (x * HASH_PRIMES[0]) ^ (y * HASH_PRIMES[1]) ^ (z * HASH_PRIMES[2])
    hashed = hashed & (table_size - 1)
    return torch.where(side**3 <= table_size, dense, hashed)


@functools.cache
def triton_available() -> bool:
    """Whether Triton is installed (for `HashEncoding`'s fused kernels)."""
    return importlib.util.find_spec("triton") is not None


# Types as wide as a table row (4, 8 or 16 bytes: 1, 2 or 4 float32 features), to gather it as one element.
_ROW_TYPES = {4: torch.int32, 8: torch.int64, 16: torch.complex128}


def _gather_rows(table: Tensor, rows: Tensor) -> Tensor:
    """`table[rows]` for a table (m, F) and rows (k,) -> (k, F), bit for bit.

    A row of a few float32 features is gathered as one element of its width: `index_select`
    moves the 8-byte elements of a 1-D array 5x faster than the rows of an (m, 2) table, and a
    copy moves the bits unchanged.
    """
    row_type = _ROW_TYPES.get(table.shape[1] * table.element_size())
    if row_type is None or not table.is_contiguous():
        return table.index_select(0, rows)
    return table.view(row_type).reshape(-1).index_select(0, rows).view(table.dtype).reshape(-1, table.shape[1])


class _HashInterpolation(torch.autograd.Function):
    """Trilinear interpolation of table rows, with a hand-written backward.

    The values are those of the autograd composition it replaces (per channel: gather, multiply
    by the weights, sum over the 8 corners), computed by the same arithmetic in the same order,
    so every output and every table gradient is bit for bit the same. What it saves is layout:
    autograd's product of the expanded output gradient with the weights ran over a
    (levels, 8, n) tensor with a zero stride, element by element, then was copied and scattered
    into a zero table per channel before the channels were added.
    """

    @staticmethod
    def forward(ctx, table: Tensor, rows: Tensor, weights: Tensor) -> Tensor:
        levels, _, n = weights.shape
        features = table.shape[1]
        # Sizes spelled out, not -1: a render pass whose rays lost every sample brings n = 0 points.
        gathered = _gather_rows(table, rows.reshape(-1)).reshape(*weights.shape, features)  # (L, 8, n, F)
        channels = [(gathered[..., f] * weights).sum(dim=1) for f in range(features)]  # each (L, n)
        ctx.save_for_backward(table, rows, weights)
        return torch.stack(channels, dim=-1).transpose(0, 1).reshape(n, levels * features)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor | None, None, Tensor | None]:
        table, rows, weights = ctx.saved_tensors
        levels, _, n = weights.shape
        features = table.shape[1]
        flat = rows.reshape(-1)
        per_channel = grad.reshape(n, levels, features)
        grad_table = torch.zeros_like(table) if ctx.needs_input_grad[0] else None
        grad_weights = torch.zeros_like(weights) if ctx.needs_input_grad[2] else None
        for f in range(features):
            g = per_channel[:, :, f].T.contiguous()[:, None, :]  # (L, 1, n)
            if grad_table is not None:
                grad_table[:, f].index_add_(0, flat, (g * weights).reshape(-1))
            if grad_weights is not None:
                grad_weights += g * table[:, f].index_select(0, flat).reshape(weights.shape)
        return grad_table, None, grad_weights


class HashEncoding(nn.Module):
    """Multiresolution hash encoding (Mueller et al. 2022), all levels in one vectorised pass.

    Output feature of a point: for each level, the trilinear interpolation of the features
    stored at the 8 vertices of its grid cell, concatenated over levels. Rows are those of
    `hash_grid_indices`: each vertex coordinate is multiplied by its level's factor per axis
    (row-major strides for dense levels, primes for hashed ones), and the three terms are summed
    (dense) or XOR-ed (hashed) over the 2 x 2 x 2 corners by broadcasting. The low bits of a
    product and of an XOR depend only on the operands' low bits, so masking each term gives
    Instant-NGP's uint32 rows; the level's offset in the flat table is added to the z term
    alone, which an XOR leaves in place since it lies above the mask.

    `kernel` picks how: "torch" (PyTorch operations, the reference: bit for bit the same on
    every run), "triton" (`nerfaug.nerf.hash_triton`'s fused kernels: one launch per pass
    instead of ~25, gradients summed by atomic adds in no fixed order), "cpu"
    (`nerfaug.nerf.hash_cpu`'s C loop on float32 CPU tensors, where a C compiler built it:
    deterministic, about twice a training step's speed on one core), or "auto" (Triton on CUDA
    tensors where Triton is installed, the C loop on CPU tensors where it is built, else
    PyTorch; the default, `default_kernel`, which the environment variable
    `NERFAUG_HASH_KERNEL` or a benchmark may set for the whole process). Points that need
    gradients of their own always take the PyTorch path.
    """

    KERNELS = ("auto", "torch", "triton", "cpu")
    default_kernel = os.environ.get("NERFAUG_HASH_KERNEL") or "auto"

    def __init__(
        self,
        num_levels: int = 16,
        features_per_level: int = 2,
        log2_table_size: int = 19,
        base_resolution: int = 16,
        max_resolution: int = 2048,
        init_scale: float = 1e-4,
        kernel: str | None = None,
    ):
        super().__init__()
        where = "kernel" if kernel is not None else "the hash encoding's kernel (NERFAUG_HASH_KERNEL)"
        kernel = self.default_kernel if kernel is None else kernel
        if kernel not in self.KERNELS:
            raise ValueError(f"{where} must be one of {', '.join(self.KERNELS)}, got {kernel!r}")
        self.kernel = kernel
        if (max_resolution + 1) * 2**log2_table_size >= 2**31:
            raise ValueError(
                f"max_resolution {max_resolution} with a 2^{log2_table_size} table overflows int32 hashing"
            )
        self.num_levels, self.features_per_level = num_levels, features_per_level
        self.table_size = 2**log2_table_size
        resolutions = torch.tensor(hash_resolutions(num_levels, base_resolution, max_resolution))
        side = resolutions + 1
        dense = side**3 <= self.table_size
        # Resolutions grow with the level, so the dense levels are the first ones.
        self.dense_levels = int(dense.sum())
        # Per level and axis, the factor a vertex coordinate is multiplied by: row-major strides
        # for dense levels (summed), masked primes for hashed ones (XOR-ed).
        strides = torch.stack([torch.ones_like(side), side, side * side], dim=-1)
        primes = torch.tensor(HASH_PRIMES) & (self.table_size - 1)
        factors = torch.where(dense[:, None], strides, primes)
        self.register_buffer("resolutions", resolutions.int(), persistent=False)
        self.register_buffer("factors", factors.int(), persistent=False)
        offsets = torch.arange(num_levels, dtype=torch.int32) * self.table_size
        self.register_buffer("level_offsets", offsets, persistent=False)
        # Small uniform init as Instant-NGP: the field starts almost constant.
        self.table = nn.Parameter(
            torch.empty(num_levels * self.table_size, features_per_level).uniform_(-init_scale, init_scale)
        )

    @classmethod
    def from_config(cls, config) -> HashEncoding:
        """The field's hash grid as a `NerfConfig` whose encoding is a `HashGridConfig` describes it."""
        grid = config.field.encoding
        return cls(
            grid.levels, grid.features_per_level, grid.log2_table_size, grid.base_resolution, grid.max_resolution
        )

    @property
    def output_dim(self) -> int:
        return self.num_levels * self.features_per_level

    def corners(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Table rows and trilinear weights of the 8 cell vertices around each point, per level.

        Points are the last (contiguous) dimension: on a CPU, elementwise ops broadcast over
        trailing dimensions of size 2 run element by element, which made the earlier
        (levels, n, 2, 2, 2) layout 3x slower for the whole encoding (forward + backward).

        Args:
            x: Tensor with shape (n, 3) in [0, 1].

        Returns:
            rows: int32 Tensor with shape (levels, 8, n), rows of the flat table.
            weights: Tensor with shape (levels, 8, n), summing to 1 over the 8 vertices.
        """
        n, levels, dense = x.shape[0], self.num_levels, self.dense_levels
        resolutions = self.resolutions[:, None, None]
        scaled = resolutions.to(x.dtype) * x.T[None]  # (L, 3, n)
        floor = scaled.floor()
        frac = scaled - floor
        # int32 rows: int64 products have no vector instruction on AVX2 CPUs, and the rows are
        # the largest tensor of the encoding, written once and read three times.
        # terms (L, 3, 2, n): each axis's low and high vertex coordinate, then its term of the row.
        terms = scaled.new_empty((levels, 3, 2, n), dtype=torch.int32)
        low, high = terms.unbind(2)
        low.copy_(floor)
        # x == 1 lands on vertex res + 1; clamping keeps it on the last cell's far face.
        torch.minimum(low + 1, resolutions, out=high)
        terms *= self.factors[:, :, None, None]
        terms[dense:] &= self.table_size - 1
        terms[:, 2] += self.level_offsets[:, None, None]
        # Vertex order: z slowest, x fastest.
        tx, ty, tz = terms[:, 0, None, None], terms[:, 1, None, :, None], terms[:, 2, :, None, None]
        rows = terms.new_empty((levels, 2, 2, 2, n))
        torch.add(tx[:dense] + ty[:dense], tz[:dense], out=rows[:dense])
        torch.bitwise_xor(tx[dense:] ^ ty[dense:], tz[dense:], out=rows[dense:])
        w = torch.stack([1.0 - frac, frac], dim=2)  # (L, 3, 2, n)
        weights = w[:, 0, None, None] * w[:, 1, None, :, None] * w[:, 2, :, None, None]
        return rows.reshape(levels, 8, n), weights.reshape(levels, 8, n)

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (n, 3) in [0, 1]. Returns: Tensor with shape (n, output_dim).

        Level-major rows keep the backward's scatter inside one level's table at a time
        (cache-friendly)."""
        if self.fused(x):
            from nerfaug.nerf.hash_triton import FusedHashInterpolation  # needs Triton, an optional package

            return FusedHashInterpolation.apply(x, self.table, self)
        if self.cpu_fused(x):
            from nerfaug.nerf.hash_cpu import CpuHashInterpolation

            return CpuHashInterpolation.apply(x, self.table, self)
        rows, weights = self.corners(x)
        return _HashInterpolation.apply(self.table, rows, weights)

    def fused(self, x: Tensor) -> bool:
        """Whether `forward(x)` runs the Triton kernels (see `kernel`)."""
        if self.kernel in ("torch", "cpu") or x.requires_grad:
            return False
        return self.kernel == "triton" or (x.is_cuda and triton_available())

    @classmethod
    def cpu_loop_selected(cls) -> bool:
        """Whether an encoding of the default kernel runs the fused C loop on float32 CPU points:
        the default ("auto" or "cpu", `default_kernel`) and the loop built (a C compiler present)."""
        from nerfaug.nerf import hash_cpu

        return cls.default_kernel in ("auto", "cpu") and hash_cpu.available()

    def cpu_fused(self, x: Tensor) -> bool:
        """Whether `forward(x)` runs the fused C loop (see `kernel`): float32 CPU points without
        gradients of their own, where the loop is built; else the PyTorch path."""
        if self.kernel not in ("auto", "cpu"):
            return False
        from nerfaug.nerf import hash_cpu

        return hash_cpu.supports(x, self.table)


class KPlanesEncoding(nn.Module):
    """Factorised grid (K-planes, Fridovich-Keil et al. 2023, static case): at each scale, three
    feature planes (xy, xz, yz) sampled bilinearly and multiplied elementwise.

    Bilinear lookups in 2-D planes are one `grid_sample` call per scale, an order of magnitude
    faster on a CPU than gathering 8 vertices from 16 hash levels.
    """

    def __init__(self, resolutions: tuple[int, ...] = (64, 256), features: int = 8):
        super().__init__()
        self.features = features
        # K-planes' init: positive planes so the product starts away from zero in every channel.
        self.planes = nn.ParameterList(
            [nn.Parameter(torch.empty(3, features, r, r).uniform_(0.1, 0.5)) for r in resolutions]
        )

    @classmethod
    def from_config(cls, config) -> KPlanesEncoding:
        """The field's tri-planes as a `NerfConfig` whose encoding is a `PlanesConfig` describes them."""
        return cls(config.field.encoding.resolutions, config.field.encoding.features)

    @property
    def output_dim(self) -> int:
        return self.features * len(self.planes)

    def forward(self, x: Tensor) -> Tensor:
        """Args: x: Tensor with shape (n, 3) in [0, 1]. Returns: Tensor with shape (n, output_dim)."""
        coords = 2.0 * x - 1.0  # grid_sample's [-1, 1]; its (u, v) index (width, height)
        grid = torch.stack([coords[:, [0, 1]], coords[:, [0, 2]], coords[:, [1, 2]]])[:, :, None, :]
        outputs = []
        for planes in self.planes:
            sampled = F.grid_sample(planes, grid, mode="bilinear", align_corners=True)  # (3, C, n, 1)
            # unbind and explicit products: indexing and prod() have much slower backwards.
            xy, xz, yz = sampled[..., 0].unbind(0)
            outputs.append((xy * xz * yz).T)
        return torch.cat(outputs, dim=-1)


def spherical_harmonics(directions: Tensor, levels: int = 4) -> Tensor:
    """Real spherical harmonics basis Y_lm evaluated at unit directions, l < levels.

    Args:
        directions: Tensor with shape (n, 3), unit length.
        levels: 1 to 4; the output has levels**2 components.

    Returns:
        Tensor with shape (n, levels**2), orthonormal on the sphere
        (the integral of Y_i Y_j over the sphere is delta_ij).
    """
    if not 1 <= levels <= 4:
        raise ValueError(f"levels must be 1 to 4, got {levels}")
    x, y, z = directions.unbind(-1)
    terms = [torch.full_like(x, 0.28209479177387814)]
    if levels > 1:
        terms += [0.4886025119029199 * y, 0.4886025119029199 * z, 0.4886025119029199 * x]
    if levels > 2:
        xx, yy, zz = x * x, y * y, z * z
        terms += [
            1.0925484305920792 * x * y,
            1.0925484305920792 * y * z,
            0.9461746957575601 * zz - 0.31539156525251999,
            1.0925484305920792 * x * z,
            0.5462742152960396 * (xx - yy),
        ]
    if levels > 3:
        terms += [
            0.5900435899266435 * y * (3 * xx - yy),
            2.890611442640554 * x * y * z,
            0.4570457994644658 * y * (5 * zz - 1),
            0.3731763325901154 * z * (5 * zz - 3),
            0.4570457994644658 * x * (5 * zz - 1),
            1.445305721320277 * z * (xx - yy),
            0.5900435899266435 * x * (xx - 3 * yy),
        ]
    return torch.stack(terms, dim=-1)
