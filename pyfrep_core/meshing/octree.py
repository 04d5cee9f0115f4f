"""Certified octree: cells that interval bounds prove free of surface are never sampled.

The grid of ``n`` samples per axis (``n - 1`` cells, the voxel size of marching cubes at the
same ``resolution``) is covered by blocks of ``2^L`` x ``block`` cells.  Level by level, each
block's box gets guaranteed bounds ``[lo, hi]`` of f (:func:`pyfrep_core.interval.bounds`);
a block with ``lo > 0`` (all inside) or ``hi <= 0`` (all outside, in marching cubes' classes
f > 0 / f <= 0) holds no grid edge whose end points differ in class, hence no vertex of the
mesh, and is dropped with all its children; the others are split in eight.  Unlike the sparse
grid's heuristic (:mod:`pyfrep_core.meshing.sparse`) this misses nothing that the dense grid
would find: every edge with a sign change lies in the closed box of every block that holds one
of its cells, and the bounds enclose both end values.

The leaf blocks (``block``^3 cells) left are sampled exactly at all their nodes (in chunks of
blocks); the edges whose end points differ in class and the cells with mixed corners are what
dual contouring needs (:mod:`pyfrep_core.meshing.dual_contouring`).

>>> from pyfrep_core import sphere
>>> tree = prune(lambda x: sphere(x, r=1.0), (-1.2, -1.2, -1.2), (0.1, 0.1, 0.1), (24, 24, 24), 4)
>>> len(tree.blocks) < 6**3, tree.certified   # of 216 blocks, those near the sphere are kept
(True, True)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch

from ..interval import IntervalUnsupported, bounds
from .grid import CHUNK_POINTS, _call, _chunk_points
from .loops import _block_points, _classify_blocks, _distinct_edges, _unravel_cells

__all__ = ["Octree", "Samples", "prune", "sample_blocks"]

ROOT_BLOCKS = 16  # blocks per axis at the octree's coarsest level (a power of two)


class Octree(NamedTuple):
    """The pruning's result.

    blocks : (K, 3) int64 leaf blocks kept (index in units of ``block`` cells).
    block : cells per leaf block edge (the requested size, or twice it where surface is everywhere).
    certified : False when the model has no interval extension (every block is kept then).
    levels : per level, ``(size, origins (B, 3) int64 in cells, kept (B,) bool)`` of the blocks
        tested, coarse to fine (for drawing and counting).
    reason : why not certified ('' when certified).
    """

    blocks: np.ndarray
    block: int
    certified: bool
    levels: list[tuple[int, np.ndarray, np.ndarray]]
    reason: str = ""


class Samples(NamedTuple):
    """Crossing edges and mixed cells of the kept blocks.

    edge_node : (E, 3) int64 grid node at the edge's start; edge_axis : (E,) int64 (edges sorted by
    axis, then by node);
    f0, f1 : (E,) float64 values at the start and the end (opposite classes);
    cell : (C, 3) int64 cells (index of the lower corner node) with mixed corners, sorted by
        flat index; cell_key : (C,) int64 their flat index; config : (C,) uint8 the corners'
        classes (bit c set when corner ``(c & 1, c >> 1 & 1, c >> 2 & 1)`` has f > 0);
    n_points : points evaluated; vmin, vmax : min and max of f over them.
    """

    edge_node: np.ndarray
    edge_axis: np.ndarray
    f0: np.ndarray
    f1: np.ndarray
    cell: np.ndarray
    cell_key: np.ndarray
    config: np.ndarray
    n_points: int
    vmin: float
    vmax: float


def prune(
    f: Callable,
    origin: Any,
    spacing: Any,
    cells: tuple[int, int, int],
    block: int,
    stop: Any = None,
    crowded: float | None = 0.5,
) -> Octree:
    """Leaf blocks of ``block``^3 cells that may hold surface, by interval bounds from one root block down.

    Parameters
    ----------
    f : model or defining function (points (N, 3) -> (N,)).
    origin : (3,) world position of grid node (0, 0, 0); spacing : (3,) cell size per axis.
    cells : cells per axis (samples - 1).
    block : leaf block size in cells (>= 1).
    stop : an object with ``is_set()``; checked between levels (then the blocks of the level
        reached are returned, split to leaf size).
    crowded : when more than this fraction of all the grid's blocks of ``2 block`` cells is kept,
        they are the leaves (``Octree.block`` says which size came out); None: always split to ``block``.

    Returns
    -------
    Octree; when f has no interval extension (IntervalUnsupported) every leaf block, uncertified.
    """
    origin = np.asarray(origin, dtype=np.float64)
    spacing = np.asarray(spacing, dtype=np.float64)
    ncells = np.asarray(cells, dtype=np.int64)
    nb = -(-ncells // block)  # leaf blocks per axis
    # the root level: up to ROOT_BLOCKS^3 blocks (a call costs about 4 ms however few boxes it bounds: coarser
    # levels would cost more calls than the few blocks they drop)
    depth = max(0, math.ceil(math.log2(max(int(nb.max()), 1))) - int(math.log2(ROOT_BLOCKS)))
    size = block << depth
    count = -(-ncells // size)
    levels: list[tuple[int, np.ndarray, np.ndarray]] = []
    current = np.stack(np.meshgrid(*(np.arange(c) for c in count), indexing="ij"), axis=-1).reshape(-1, 3) * size
    certified, reason = True, ""
    while True:
        lo = origin + current * spacing
        hi = origin + np.minimum(current + size, ncells) * spacing
        try:
            flo, fhi = bounds(f, lo, hi)
        except IntervalUnsupported as err:
            certified, reason = False, str(err)
            break
        keep = ~((flo > 0) | (fhi <= 0))  # NaN bounds keep the block
        levels.append((size, current, keep))
        current = current[keep]
        if size == block or len(current) == 0 or (stop is not None and stop.is_set()):
            break
        if size == 2 * block and crowded is not None and len(current) > crowded * np.prod(-(-ncells // size)):
            # surface nearly everywhere (a lattice): the last split would drop few blocks, and
            # blocks twice as large share fewer nodes with their neighbours ((9/8)^3 vs (5/4)^3)
            return Octree(current // size, size, True, levels)
        size //= 2
        child = np.array([(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=np.int64) * size
        current = (current[:, None, :] + child[None]).reshape(-1, 3)
        current = current[(current < ncells).all(axis=1)]
    if not certified:  # every leaf block
        grid = np.stack(np.meshgrid(*(np.arange(c) for c in nb), indexing="ij"), axis=-1).reshape(-1, 3)
        return Octree(grid.astype(np.int64), block, False, levels, reason)
    if size > block and len(current):  # stopped early: split what is left down to leaf blocks
        k = size // block
        sub = np.stack(np.meshgrid(*(np.arange(k),) * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        current = (current[:, None, :] // block + sub[None]).reshape(-1, 3)
        return Octree(current[(current < nb).all(axis=1)], block, True, levels)
    return Octree(current // block, block, True, levels)


def sample_blocks(
    f: Callable,
    axes: list[np.ndarray],
    blocks: np.ndarray,
    block: int,
    dtype: torch.dtype,
    device: Any,
    progress: Any = None,
    first_step: int = 0,
) -> Samples | None:
    """f at every node of the leaf blocks (in chunks), their crossing edges and mixed cells.

    ``axes`` are the grid's sample positions per axis.  ``progress`` (a
    :class:`pyfrep_core.progress.Progress` or None) is advanced by one step per chunk (numbered
    from ``first_step``); when it asks to stop, None is returned.
    """
    s = int(block)
    shape = np.array([len(a) for a in axes], dtype=np.int64)
    ncell = shape - 1
    device = torch.device(device)
    grid = [np.asarray(a, dtype=np.float32 if dtype == torch.float32 else np.float64) for a in axes]
    per_chunk = max(1, _chunk_points(f, CHUNK_POINTS) // (s + 1) ** 3)
    edges_key, edges_f0, edges_f1, cells_key, cells_cfg = [], [], [], [], []
    n_points, vmin, vmax = 0, math.inf, -math.inf
    for step, first in enumerate(range(0, len(blocks), per_chunk)):
        part = blocks[first : first + per_chunk]
        pts = torch.from_numpy(_block_points(part, s, *grid)).to(device=device, dtype=dtype)
        vals, lo, hi = _call(f, pts)
        n_points += vals.numel()
        vmin, vmax = min(vmin, lo), max(vmax, hi)
        keys, config, edges, f0, f1 = _classify_blocks(vals.cpu().numpy(), part, s, shape)
        cells_key.append(keys)
        cells_cfg.append(config)
        edges_key.append(edges)
        edges_f0.append(f0)
        edges_f1.append(f1)
        if progress is not None and progress.update(first_step + step):
            return None
    key = np.concatenate(edges_key) if edges_key else np.zeros(0, dtype=np.int64)
    f0 = np.concatenate(edges_f0) if edges_f0 else np.zeros(0)
    f1 = np.concatenate(edges_f1) if edges_f1 else np.zeros(0)
    # the edges on faces shared by two blocks come twice, with the same values: keep one of each
    # (an unstable argsort: several times faster than np.unique's stable one)
    edge_node, axis, f0, f1 = _distinct_edges(key, np.argsort(key), f0, f1, shape)
    ckey = np.concatenate(cells_key) if cells_key else np.zeros(0, dtype=np.int64)
    cfg = np.concatenate(cells_cfg) if cells_cfg else np.zeros(0, dtype=np.uint8)
    order = np.argsort(ckey)  # the keys are distinct
    ckey, cfg = ckey[order], cfg[order]
    cell = _unravel_cells(ckey, ncell)
    return Samples(edge_node, axis, f0, f1, cell, ckey, cfg, n_points, vmin, vmax)
