"""The hash encoding's interpolation fused into Triton kernels: on a GPU, the PyTorch path's ~25
launches per encoding (index arithmetic, gather, products, sums) and as many in its backward
become one launch each way.

Forward: each program takes a block of points at one level, computes the rows and trilinear
weights of the cell's 8 vertices as `HashEncoding.corners` does (the same integer rows, the same
float32 weights), gathers the features and sums them over the vertices. Backward: the same rows
and weights, the output gradient scattered into the table with atomic adds (their order varies
between runs on a GPU, so gradients agree with the PyTorch path's to float rounding, not bit for
bit).

This module needs Triton; `HashEncoding` imports it only where Triton is installed (see
`HashEncoding.fused`). With `TRITON_INTERPRET=1` set before the import, the kernels run on the
CPU through Triton's interpreter, which is how the tests check them.
"""

from __future__ import annotations

import torch
import triton
import triton.language as tl
from torch import Tensor

# Points per program: a multiple of a GPU warp, small enough for the 8 vertices' registers.
BLOCK = 128


@triton.jit
def axis(scaled, res, factor, far: tl.constexpr):
    """One axis of a vertex: its coordinate's term of the row (int32) and its trilinear
    weight factor, for points `scaled` to the level's grid; the cell's near or far side."""
    floor = tl.floor(scaled)
    frac = scaled - floor
    low = floor.to(tl.int32)
    if far:
        return tl.minimum(low + 1, res) * factor, frac
    return low * factor, 1.0 - frac


@triton.jit
def vertex(sx, sy, sz, res, fx, fy, fz, dense, mask, offset, corner: tl.constexpr):
    """Row (int32) and trilinear weight of vertex `corner` (x fastest, z slowest) of the cells
    around points scaled to one level's grid (sx, sy, sz: floats in [0, res])."""
    tx, wx = axis(sx, res, fx, corner & 1)
    ty, wy = axis(sy, res, fy, corner & 2)
    tz, wz = axis(sz, res, fz, corner & 4)
    hashed = (tx & mask) ^ (ty & mask) ^ (tz & mask)
    row = tl.where(dense, tx + ty + tz, hashed) + offset
    return row, wx * wy * wz


@triton.jit
def level_setup(
    x_ptr, res_ptr, fac_ptr, n, dense_levels, table_size, per_run,
    LEVELS: tl.constexpr, F: tl.constexpr, F_BLOCK: tl.constexpr, BLOCK: tl.constexpr,
):  # fmt: skip
    """This program's points scaled to its level's grid, the level's constants (resolution,
    factors per axis, dense or not), each point's offset in the table: its run's tables (a trial
    batch's run k holds points k * per_run to (k + 1) * per_run - 1 and the k-th block of LEVELS
    tables), then the level's; the feature indices, which (point, feature) pairs are valid, and
    where each pair's value stands in the (n, LEVELS * F) output (and its gradient)."""
    level = tl.program_id(1)
    points = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    valid = points < n
    res = tl.load(res_ptr + level)
    scale = res.to(tl.float32)
    sx = scale * tl.load(x_ptr + points * 3, mask=valid, other=0.0)
    sy = scale * tl.load(x_ptr + points * 3 + 1, mask=valid, other=0.0)
    sz = scale * tl.load(x_ptr + points * 3 + 2, mask=valid, other=0.0)
    fx, fy, fz = tl.load(fac_ptr + level * 3), tl.load(fac_ptr + level * 3 + 1), tl.load(fac_ptr + level * 3 + 2)
    offset = ((points // per_run) * LEVELS + level) * table_size
    features = tl.arange(0, F_BLOCK)
    where = valid[:, None] & (features < F)[None, :]
    outputs = points[:, None] * (LEVELS * F) + level * F + features[None, :]
    return res, sx, sy, sz, fx, fy, fz, level < dense_levels, offset, features, where, outputs


@triton.jit
def forward_kernel(
    x_ptr, table_ptr, res_ptr, fac_ptr, out_ptr, n, dense_levels, table_size, mask, per_run,
    LEVELS: tl.constexpr, F: tl.constexpr, F_BLOCK: tl.constexpr, BLOCK: tl.constexpr,
):  # fmt: skip
    res, sx, sy, sz, fx, fy, fz, dense, offset, features, where, outputs = level_setup(
        x_ptr, res_ptr, fac_ptr, n, dense_levels, table_size, per_run, LEVELS, F, F_BLOCK, BLOCK
    )
    total = tl.zeros((BLOCK, F_BLOCK), dtype=tl.float32)
    for corner in tl.static_range(8):
        row, weight = vertex(sx, sy, sz, res, fx, fy, fz, dense, mask, offset, corner)
        value = tl.load(table_ptr + row[:, None] * F + features[None, :], mask=where, other=0.0)
        total += value * weight[:, None]
    tl.store(out_ptr + outputs, total, mask=where)


@triton.jit
def backward_kernel(
    x_ptr, grad_ptr, res_ptr, fac_ptr, grad_table_ptr, n, dense_levels, table_size, mask, per_run,
    LEVELS: tl.constexpr, F: tl.constexpr, F_BLOCK: tl.constexpr, BLOCK: tl.constexpr,
):  # fmt: skip
    res, sx, sy, sz, fx, fy, fz, dense, offset, features, where, outputs = level_setup(
        x_ptr, res_ptr, fac_ptr, n, dense_levels, table_size, per_run, LEVELS, F, F_BLOCK, BLOCK
    )
    grad = tl.load(grad_ptr + outputs, mask=where)
    for corner in tl.static_range(8):
        row, weight = vertex(sx, sy, sz, res, fx, fy, fz, dense, mask, offset, corner)
        tl.atomic_add(grad_table_ptr + row[:, None] * F + features[None, :], grad * weight[:, None], mask=where)


def _launch(kernel, x: Tensor, tensor: Tensor, out: Tensor, encoding, per_run: int | None = None) -> None:
    """Run `kernel` over every (block of points, level) with the encoding's constants; points
    `per_run` at a time belong to the successive runs of a stacked table (None: one run)."""
    levels, features = encoding.num_levels, encoding.features_per_level
    if x.shape[0] == 0:  # no points (no live sample in a batch): nothing to launch
        return
    per_run = x.shape[0] if per_run is None else per_run
    grid = (triton.cdiv(x.shape[0], BLOCK), levels)
    kernel[grid](
        x,
        tensor,
        encoding.resolutions,
        encoding.factors,
        out,
        x.shape[0],
        encoding.dense_levels,
        encoding.table_size,
        encoding.table_size - 1,
        max(per_run, 1),
        LEVELS=levels,
        F=features,
        F_BLOCK=triton.next_power_of_2(features),
        BLOCK=BLOCK,
    )


class FusedHashInterpolation(torch.autograd.Function):
    """`HashEncoding`'s features of points (n, 3) in [0, 1] -> (n, levels * features), through
    the Triton kernels. Gradients reach the table only (the positions' are not computed).

    With K runs' tables stacked into one (a batched GPU path; the engine trains each run through
    its own encoding today, `nerfaug.nerf.trainer`), `per_run` points at a time belong to the
    successive runs, each reading its own block of the table."""

    @staticmethod
    def forward(ctx, x: Tensor, table: Tensor, encoding, per_run: int | None = None) -> Tensor:
        x = x.contiguous().float()
        out = torch.empty(x.shape[0], encoding.output_dim, device=x.device, dtype=torch.float32)
        _launch(forward_kernel, x, table.contiguous(), out, encoding, per_run)
        ctx.save_for_backward(x)
        ctx.encoding, ctx.per_run = encoding, per_run
        return out

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[None, Tensor, None, None]:
        (x,) = ctx.saved_tensors
        encoding = ctx.encoding
        grad_table = torch.zeros_like(encoding.table)
        _launch(backward_kernel, x, grad.contiguous().float(), grad_table, encoding, ctx.per_run)
        return None, grad_table, None, None
