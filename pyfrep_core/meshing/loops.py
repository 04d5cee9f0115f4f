"""Compiled loops of dual contouring over edges, cells and triangles (numba).

Dual contouring's passes gather and scatter per edge, cell and triangle: the QEF of a cell sums
the terms of its up to twelve edges, a vertex's unbiasing the requests of its triangles.  Written
as NumPy passes, each is several full-size temporaries (their page faults cost as much as the
arithmetic), sparse products and binary searches over the whole slab; here each is one loop
in machine code over the arrays it reads, with no temporaries.  The loops are serial and release
the GIL (safe from any thread); numba caches their machine code next to this file.

The model is never called from here: f is evaluated by the callers (torch) between the loops.

>>> import numpy as np
>>> v = np.zeros((1, 2, 2, 2)); v[0, 0, 0, 0] = 1.0  # one cell, f > 0 at its first corner only
>>> keys, config, edges, f0, f1 = _classify_blocks(v, np.zeros((1, 3), dtype=np.int64), 1, np.array([2, 2, 2]))
>>> keys.tolist(), config.tolist(), edges.tolist()   # the cell, its configuration, its 3 crossing edges
([0], [1], [0, 8, 16])
"""

from __future__ import annotations

import numba
import numpy as np

_jit = numba.njit(cache=True, nogil=True)


@_jit
def _classify_blocks(
    v: np.ndarray, part: np.ndarray, s: int, shape: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mixed cells and crossing edges of blocks of ``s``^3 cells from f at their nodes.

    v : (k, s + 1, s + 1, s + 1) f at the blocks' nodes (node index ``part * s + local``, clipped to
    the grid: samples past the grid's last node are padding); part : (k, 3) int64 block indices;
    shape : (3,) nodes per axis.  Classes: f > 0 / f <= 0.

    Returns the mixed cells' flat keys (C,) int64 and configurations (C,) uint8 (bit c: corner
    (c & 1, c >> 1 & 1, c >> 2 & 1) has f > 0), the crossing edges' keys (E,) int64 (flat start
    node + axis * nodes) and f at their start and end (E,) float64, block by block.  Edges on
    faces shared by two blocks come once from each.
    """
    k = v.shape[0]
    n1, n2 = shape[1], shape[2]
    c1, c2 = n1 - 1, n2 - 1
    n_nodes = shape[0] * n1 * n2
    cell_keys = np.empty(k * s * s * s, dtype=np.int64)
    configs = np.empty(k * s * s * s, dtype=np.uint8)
    edge_keys = np.empty(3 * k * s * (s + 1) * (s + 1), dtype=np.int64)
    f0 = np.empty(3 * k * s * (s + 1) * (s + 1))
    f1 = np.empty(3 * k * s * (s + 1) * (s + 1))
    nc = 0
    ne = 0
    for b in range(k):
        bx, by, bz = part[b, 0] * s, part[b, 1] * s, part[b, 2] * s
        for i in range(s + 1):
            gx = bx + i
            if gx > shape[0] - 1:
                break
            for j in range(s + 1):
                gy = by + j
                if gy > n1 - 1:
                    break
                for m in range(s + 1):
                    gz = bz + m
                    if gz > n2 - 1:
                        break
                    here = v[b, i, j, m]
                    inside = here > 0
                    node = (gx * n1 + gy) * n2 + gz
                    # the edges from this node along +x, +y, +z
                    if i < s and gx < shape[0] - 1 and (v[b, i + 1, j, m] > 0) != inside:
                        edge_keys[ne], f0[ne], f1[ne] = node, here, v[b, i + 1, j, m]
                        ne += 1
                    if j < s and gy < n1 - 1 and (v[b, i, j + 1, m] > 0) != inside:
                        edge_keys[ne], f0[ne], f1[ne] = node + n_nodes, here, v[b, i, j + 1, m]
                        ne += 1
                    if m < s and gz < n2 - 1 and (v[b, i, j, m + 1] > 0) != inside:
                        edge_keys[ne], f0[ne], f1[ne] = node + 2 * n_nodes, here, v[b, i, j, m + 1]
                        ne += 1
                    # the cell with this node as its lower corner
                    if i < s and j < s and m < s and gx < shape[0] - 1 and gy < c1 and gz < c2:
                        config = 0
                        for c in range(8):
                            if v[b, i + (c & 1), j + (c >> 1 & 1), m + (c >> 2 & 1)] > 0:
                                config |= 1 << c
                        if config != 0 and config != 255:
                            cell_keys[nc] = (gx * c1 + gy) * c2 + gz
                            configs[nc] = config
                            nc += 1
    return cell_keys[:nc].copy(), configs[:nc].copy(), edge_keys[:ne].copy(), f0[:ne].copy(), f1[:ne].copy()


@_jit
def _edge_vertices(
    keys: np.ndarray,
    config: np.ndarray,
    base: np.ndarray,
    edge_node: np.ndarray,
    edge_axis: np.ndarray,
    ncell: np.ndarray,
    component: np.ndarray,
) -> np.ndarray:
    """The vertex (E, 4) int64 of each crossing edge's component in the four cells around it,
    counter-clockwise about +axis (-1: the cell is outside the grid or not among ``keys``).

    keys : (C,) sorted flat keys of the mixed cells; config : (C,) their configurations; base : (C,)
    their first vertex; edge_node : (E, 3) start nodes; edge_axis : (E,); ncell : (3,) cells per
    axis; component : (256, 12) int8 component of each edge per configuration (-1: no crossing).
    """
    n = edge_node.shape[0]
    out = np.full((n, 4), -1, dtype=np.int64)
    size = keys.shape[0]
    cell = np.empty(3, dtype=np.int64)
    for e in range(n):
        a = edge_axis[e]
        b, c = (a + 1) % 3, (a + 2) % 3
        for q in range(4):
            db = 1 if q == 0 or q == 3 else 0  # (1, 1), (0, 1), (0, 0), (1, 0)
            dc = 1 if q < 2 else 0
            cell[0], cell[1], cell[2] = edge_node[e, 0], edge_node[e, 1], edge_node[e, 2]
            cell[b] -= db
            cell[c] -= dc
            if cell[b] < 0 or cell[c] < 0 or cell[0] >= ncell[0] or cell[1] >= ncell[1] or cell[2] >= ncell[2]:
                continue
            key = (cell[0] * ncell[1] + cell[1]) * ncell[2] + cell[2]
            low, high = 0, size
            while low < high:  # the first key >= key
                mid = (low + high) >> 1
                if keys[mid] < key:
                    low = mid + 1
                else:
                    high = mid
            if low < size and keys[low] == key:
                comp = component[config[low], 4 * a + db + 2 * dc]
                if comp >= 0:
                    out[e, q] = base[low] + comp
    return out


@_jit
def _qef_sums(vert: np.ndarray, normal: np.ndarray, points: np.ndarray, offset: int, n_vert: int) -> np.ndarray:
    """Per vertex (n_vert, 13): A^T A (entries 00 01 02 11 12 22), A^T b, the sum of its crossings
    and their number, from the crossing edges' (E, 3) points and unit normals into the vertices
    ``vert`` (E, 4) (global indices; those below ``offset`` are not this slab's and are skipped)."""
    sums = np.zeros((n_vert, 13))
    for e in range(vert.shape[0]):
        nx, ny, nz = normal[e, 0], normal[e, 1], normal[e, 2]
        px, py, pz = points[e, 0], points[e, 1], points[e, 2]
        d = nx * px + ny * py + nz * pz
        for q in range(4):
            w = vert[e, q] - offset
            if vert[e, q] < 0 or w < 0:
                continue
            row = sums[w]
            row[0] += nx * nx
            row[1] += nx * ny
            row[2] += nx * nz
            row[3] += ny * ny
            row[4] += ny * nz
            row[5] += nz * nz
            row[6] += nx * d
            row[7] += ny * d
            row[8] += nz * d
            row[9] += px
            row[10] += py
            row[11] += pz
            row[12] += 1.0
    return sums


@_jit
def _triangle_centroids(
    quads: np.ndarray, points: np.ndarray, point_length: np.ndarray, x: np.ndarray, length: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The triangles (crossing, q_i, q_i+1) of quads (Q, 4) whose two cell vertices are both smooth
    (finite ``length`` = |grad f|): their centroids (T, 3), their two vertices (T,) each, and the mean
    |grad f| of their corners (T,); half i of every quad first, then half i + 1 (as the quads' columns)."""
    nq = quads.shape[0]
    centroid = np.empty((4 * nq, 3))
    first = np.empty(4 * nq, dtype=np.int64)
    second = np.empty(4 * nq, dtype=np.int64)
    mean_length = np.empty(4 * nq)
    t = 0
    for half in range(4):
        for q in range(nq):
            a, b = quads[q, half], quads[q, (half + 1) % 4]
            if not (np.isfinite(length[a]) and np.isfinite(length[b])):
                continue
            for d in range(3):
                centroid[t, d] = (points[q, d] + x[a, d] + x[b, d]) / 3.0
            first[t], second[t] = a, b
            mean_length[t] = (point_length[q] + length[a] + length[b]) / 3.0
            t += 1
    return centroid[:t], first[:t], second[:t], mean_length[:t]


@_jit
def _add_requests(first: np.ndarray, second: np.ndarray, ask: np.ndarray, total: np.ndarray, count: np.ndarray) -> None:
    """Each triangle's request ``ask`` (T,) added to both its vertices' ``total``, and 1 to their ``count``."""
    for t in range(ask.shape[0]):
        total[first[t]] += ask[t]
        total[second[t]] += ask[t]
        count[first[t]] += 1.0
        count[second[t]] += 1.0


@_jit
def _move_inside(
    x: np.ndarray,
    gradient: np.ndarray,
    step: np.ndarray,
    cell: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    margin: float,
) -> None:
    """x[v] -= step[v] grad f[v] (in place) where ``step`` is finite and nonzero, clipped to the vertex's cell
    ``cell`` (V, 3) less ``margin`` of a cell on each side (the grid from ``lo`` to ``hi``)."""
    for v in range(x.shape[0]):
        if step[v] == 0.0 or not np.isfinite(step[v]):
            continue
        for d in range(3):
            cell_lo = lo[d] + cell[v, d] * spacing[d]
            cell_hi = min(cell_lo + spacing[d], hi[d])
            inner_lo, inner_hi = cell_lo + margin * spacing[d], cell_hi - margin * spacing[d]
            moved = x[v, d] - step[v] * gradient[v, d]
            x[v, d] = min(max(moved, inner_lo), inner_hi)
