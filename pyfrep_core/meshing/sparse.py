"""Sparse grid evaluation: f exactly only in blocks of ``SPARSE_STEP``^3 cells near the surface.

``polygonize(..., sparse=True)`` evaluates f exactly only in blocks near the surface (coarse
corners first; see :func:`_sparse_grid` for what it assumes) and gives the dense grid's mesh
on every shape of the test suite, 1.2-1.5x faster on the Fig. 1 part (it falls back to the
dense grid where the surface is everywhere, as in lattices).  It is the shape panel's mode;
plain ``polygonize`` stays dense, since a heuristic that can miss a steep bump narrower than
a block should not decide an export.

>>> import torch
>>> from pyfrep_core import sphere
>>> from pyfrep_core.meshing.grid import grid_axes
>>> axes = grid_axes(((-1.2,) * 3, (1.2,) * 3), 65)
>>> ball = lambda x: sphere(x, r=1.0)
>>> values, lo, hi, mask, evaluated = _sparse_grid(ball, axes, torch.float32, "cpu", SPARSE_STEP, SPARSE_GUARD)
>>> values.shape, bool(evaluated.mean() < 0.5)  # exact values in fewer than half of the blocks
((65, 65, 65), True)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from ..diff import value_and_grad
from .grid import CHUNK_POINTS, _call, _check_values_dtype, _chunk_points, _map
from .roots import _flat_index, _grid_edges

SPARSE_STEP = 4  # fine cells per coarse block edge in the sparse evaluation

SPARSE_GUARD = 0.5  # blocks whose corners come within this many block diagonals (|f| / |grad f|) are checked

SPARSE_MAX_FRACTION = 0.5  # evaluate densely when more of the blocks than this need exact values


def _block_corners(a: np.ndarray) -> list[np.ndarray]:
    """The 8 corner values of every block from coarse node values (bx+1, by+1, bz+1) -> 8 x (bx, by, bz)."""
    nx, ny, nz = (n - 1 for n in a.shape)
    return [a[i : i + nx, j : j + ny, k : k + nz] for i in (0, 1) for j in (0, 1) for k in (0, 1)]


def _sparse_grid(
    f: Callable, axes: list[np.ndarray], dtype: torch.dtype, device: Any, step: int, guard: float
) -> tuple[np.ndarray, float, float, np.ndarray, np.ndarray] | None:
    """f on the grid of ``axes``, evaluated exactly only in blocks near the surface.

    The grid is cut into blocks of ``step``^3 cells; block (a, b, c) owns the nodes
    [a s, a s + s) x ... (the last blocks are shorter).  Steps:

    1. f and grad f at the blocks' corners (every s-th node, and the last one).
    2. A block is *marked* when its corners' signs differ (f > 0 against f <= 0, as marching
       cubes classes them); it is *suspect* when, without that, some corner's first-order
       distance |f| / |grad f| is below ``guard`` block diagonals.
    3. f is evaluated exactly at every node of the marked blocks (their own nodes, and the
       blocks b + {0, 1}^3 that own the rest of their closed nodes) and of the suspect blocks.
    4. Check: every block that is not marked must have all its exactly known nodes (its own
       when evaluated, and those of evaluated blocks on its closed faces) on its corners'
       side; one that has not holds surface after all (a surface leaving a marked block
       through a face shows a sign change on that face, whose nodes are known; or a small
       piece inside a suspect block): it is marked, and 3-4 repeat.
    5. Every other block gets the mean of its corners (their common sign: no crossing).

    Marching cubes then visits the cells of marked blocks only (``mask``), and
    :func:`_exact_neighbours` evaluates the few nodes next to crossing edges that are still
    fills (the root finder's cubic first guess reads them).  The mesh equals
    the dense grid's whenever no cell of an unmarked, unchecked block has a sign change at
    its nodes.  Surfaces that cross a block face at nodes are followed by step 4, so what
    this assumes is about *isolated* pieces, smaller than a block, that change no coarse
    corner's sign (a small ball, a thin closed shell, two bodies nearly touching): that
    some corner of their block sees them within ``guard`` block diagonals in first-order
    distance |f| / |grad f|.  With guard 0.5 that holds for a signed distance (the nearest
    corner of the block is at most half a diagonal from its centre) and for quadrics such as
    the catalogue's sphere (|f| / |grad f| = (d^2 - r^2) / (2 d) < d / 2); it fails for
    bumps narrower than a block on a flat background (a steep, narrow blobby or metaBall
    term far from other surface), whose corners see |grad f| ~ 0.  Pieces smaller than a
    fine cell are missed by the dense grid too.

    Returns None when more than ``SPARSE_MAX_FRACTION`` of the blocks would need exact values
    after step 2 (surface everywhere: a lattice; the dense evaluation is then cheaper),
    else the grid values, their exact min and max, the cell mask for marching cubes and the
    (bx, by, bz) blocks evaluated exactly.
    """
    device = torch.device(device)
    s = int(step)
    shape = tuple(len(a) for a in axes)
    nb = tuple(-(-n // s) for n in shape)  # blocks per axis
    padded = tuple(b * s for b in nb)
    corner_index = [np.minimum(np.arange(b + 1) * s, n - 1) for b, n in zip(nb, shape)]

    # 1. coarse values and gradients
    cx, cy, cz = (a[c] for a, c in zip(axes, corner_index))
    coarse = np.stack(np.meshgrid(cx, cy, cz, indexing="ij"), axis=-1).reshape(-1, 3)
    fc, gc = value_and_grad(f, torch.as_tensor(coarse, dtype=dtype, device=device))
    _check_values_dtype(f, fc, dtype)
    fc = fc.detach().cpu().numpy().astype(np.float64)
    if not np.isfinite(fc).all():
        bad = int(np.flatnonzero(~np.isfinite(fc))[0])
        raise ValueError(f"f is not finite at x = {tuple(coarse[bad].tolist())}: {fc[bad]}")
    fc = fc.reshape(len(cx), len(cy), len(cz))
    gn = np.linalg.norm(gc.detach().cpu().numpy().astype(np.float64), axis=1).reshape(fc.shape)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = np.abs(fc) / gn  # |f| / 0 = inf: an extremum, the other corners decide
    distance[~np.isfinite(gn) | np.isnan(distance)] = 0.0  # unknown slope, or f = 0 = grad f: mark

    # 2. blocks that may hold surface
    corners = _block_corners(fc)
    positive = [c > 0 for c in corners]
    any_pos = np.logical_or.reduce(positive)
    all_pos = np.logical_and.reduce(positive)
    nearest = np.minimum.reduce(_block_corners(distance))
    spacing = [a[1] - a[0] if len(a) > 1 else 0.0 for a in axes]
    extent = [np.diff(c) * h for c, h in zip(corner_index, spacing)]
    diagonal = np.sqrt(extent[0][:, None, None] ** 2 + extent[1][None, :, None] ** 2 + extent[2][None, None, :] ** 2)
    marked = (diagonal > 0) & any_pos & ~all_pos
    suspect = (diagonal > 0) & ~marked & (nearest < guard * diagonal)

    values = np.empty(padded, dtype=np.float32 if dtype == torch.float32 else np.float64)
    blocks = values.reshape(nb[0], s, nb[1], s, nb[2], s).transpose(0, 2, 4, 1, 3, 5)  # a view
    gx, gy, gz = (torch.as_tensor(a, dtype=dtype, device=device) for a in axes)
    local = np.arange(s)
    evaluated = np.zeros(nb, dtype=bool)
    vmin, vmax = float(fc.min()), float(fc.max())
    per_chunk = max(1, _chunk_points(f, CHUNK_POINTS) // s**3)

    def chunk(idx: np.ndarray) -> tuple[float, float]:
        ix, iy, iz = (np.minimum(idx[:, d, None] * s + local, shape[d] - 1) for d in range(3))
        k = len(idx)
        pts = torch.empty((3, k, s, s, s), dtype=dtype, device=device)
        pts[0] = gx[torch.as_tensor(ix, device=device)][:, :, None, None]
        pts[1] = gy[torch.as_tensor(iy, device=device)][:, None, :, None]
        pts[2] = gz[torch.as_tensor(iz, device=device)][:, None, None, :]
        vals, lo, hi = _call(f, pts)
        blocks[idx[:, 0], idx[:, 1], idx[:, 2]] = vals.cpu().numpy()
        return lo, hi

    while True:
        # 3. exact values in the marked blocks and their neighbours
        near = _upper_neighbours(marked) | suspect
        if not evaluated.any() and near.mean() > SPARSE_MAX_FRACTION:
            return None  # surface nearly everywhere (a lattice): the dense grid is cheaper
        todo = np.argwhere(near & ~evaluated)
        if len(todo):
            pieces = [todo[i : i + per_chunk] for i in range(0, len(todo), per_chunk)]
            for lo, hi in _map(chunk, pieces, device):
                vmin, vmax = min(vmin, lo), max(vmax, hi)
            evaluated |= near
        # 4. unmarked neighbours must have all their known nodes on their corners' side
        wrong = ~marked & _sides(blocks, evaluated, all_pos)
        if not wrong.any():
            break
        marked |= wrong

    # 5. the rest: the mean of the corners, of their common sign
    rest = ~evaluated
    blocks[rest] = (sum(corners) / 8.0)[rest][:, None, None, None]
    cells = np.broadcast_to(marked[:, None, :, None, :, None], (nb[0], s, nb[1], s, nb[2], s)).reshape(padded)
    # skimage visits the cell with origin (i, j, k) when mask[i + 1, j + 1, k + 1] is set
    mask = np.zeros(shape, dtype=bool)
    mask[1:, 1:, 1:] = cells[: shape[0] - 1, : shape[1] - 1, : shape[2] - 1]
    if padded != shape:
        values = np.ascontiguousarray(values[: shape[0], : shape[1], : shape[2]])
    return values, vmin, vmax, mask, evaluated


def _upper_neighbours(marked: np.ndarray) -> np.ndarray:
    """The marked blocks and the blocks b + o, o in {0, 1}^3, that own the rest of their closed nodes."""
    out = marked.copy()
    n = marked.shape
    for o in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1)):
        out[o[0] :, o[1] :, o[2] :] |= marked[: n[0] - o[0], : n[1] - o[1], : n[2] - o[2]]
    return out


def _exact_neighbours(
    f: Callable,
    values: np.ndarray,
    index_verts: np.ndarray,
    evaluated: np.ndarray,
    step: int,
    axes: list[np.ndarray],
    dtype: torch.dtype,
    device: Any,
) -> None:
    """Exact f at the nodes one step beyond each crossing edge (t = -1 and t = 2), where the sparse
    grid holds a fill value: the root finder's cubic first guess reads them (so the vertices
    are the dense grid's)."""
    _, axis, i0, _ = _grid_edges(index_verts)
    coord = i0.reshape(-1)[np.arange(len(i0)) * 3 + axis]
    size = np.asarray(values.shape)[axis]
    stride = np.array([values.shape[1] * values.shape[2], values.shape[2], 1])[axis]
    lin = _flat_index(i0, values.shape)
    # the node's block (flat index into `evaluated`), and the node's place in it along the axis
    block_of = i0 // step
    block = _flat_index(block_of, evaluated.shape)
    block_stride = np.array([evaluated.shape[1] * evaluated.shape[2], evaluated.shape[2], 1])[axis]
    offset = coord - block_of.reshape(-1)[np.arange(len(i0)) * 3 + axis] * step
    known = evaluated.reshape(-1)
    nodes = []
    for shift in (-1, 2):
        inside = (coord + shift >= 0) & (coord + shift < size)
        moved_block = block + (offset + shift) // step * block_stride  # (off the grid where not inside)
        k = np.flatnonzero(inside & ~known.take(moved_block, mode="clip"))
        nodes.append(lin[k] + shift * stride[k])
    nodes = np.unique(np.concatenate(nodes))  # C order: the nodes sorted as (i, j, k)
    if len(nodes) == 0:
        return
    nodes = np.stack(np.unravel_index(nodes, values.shape), axis=1)
    device = torch.device(device)
    grid = [torch.as_tensor(a, dtype=dtype, device=device) for a in axes]

    def chunk(lo: int) -> None:
        part = nodes[lo : lo + CHUNK_POINTS]
        pts = torch.stack([grid[d][torch.as_tensor(part[:, d], device=device)] for d in range(3)])
        vals, _, _ = _call(f, pts)
        values[part[:, 0], part[:, 1], part[:, 2]] = vals.cpu().numpy()

    _map(chunk, list(range(0, len(nodes), CHUNK_POINTS)), device)


def _sides(blocks: np.ndarray, evaluated: np.ndarray, positive: np.ndarray) -> np.ndarray:
    """Blocks with an exactly evaluated node (of the closed block) on the other side than ``positive`` says.

    Block b's closed node set is its own nodes plus the first layer of the blocks b + o,
    o in {0, 1}^3 \\ {0}, along the axes where o is 1.
    """
    nb = evaluated.shape
    idx = np.argwhere(evaluated)
    if len(idx) == 0:
        return np.zeros(nb, dtype=bool)
    s = blocks.shape[3:]
    pos = (blocks[idx[:, 0], idx[:, 1], idx[:, 2]] > 0).reshape(len(idx), -1)  # (K, s^3)
    # part o of a block: its nodes with local index 0 along the axes where o is 1; per part,
    # how many nodes are positive (one matrix product; the counts are exact in float32)
    local = np.indices(s).reshape(3, -1)
    part = np.array([np.all((local == 0) | (np.array(o)[:, None] == 0), axis=0) for o in _OFFSETS]).T
    count = pos.astype(np.float32) @ part.astype(np.float32)  # (K, 8)
    some_pos = np.zeros((*(n + 1 for n in nb), len(_OFFSETS)), dtype=bool)
    some_neg = np.zeros_like(some_pos)
    some_pos[idx[:, 0], idx[:, 1], idx[:, 2]] = count > 0
    some_neg[idx[:, 0], idx[:, 1], idx[:, 2]] = count < part.sum(axis=0)
    any_pos = np.zeros(nb, dtype=bool)
    any_neg = np.zeros(nb, dtype=bool)
    for k, o in enumerate(_OFFSETS):  # block b's closed nodes include part o of block b + o
        any_pos |= some_pos[o[0] : o[0] + nb[0], o[1] : o[1] + nb[1], o[2] : o[2] + nb[2], k]
        any_neg |= some_neg[o[0] : o[0] + nb[0], o[1] : o[1] + nb[1], o[2] : o[2] + nb[2], k]
    return np.where(positive, any_neg, any_pos)


_OFFSETS = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, 0, 1), (0, 1, 1), (1, 1, 1))
