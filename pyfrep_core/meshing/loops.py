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

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")  # x / 0: inf or NaN, as in NumPy


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

    Each block's classes are read once into bits; a block of one class (the bounds kept it, the
    samples show no crossing) is passed over, and a cell's configuration joins the four-corner
    codes of its two z-faces (each face is shared by the cells below and above it).
    """
    k = v.shape[0]
    n0, n1, n2 = shape[0], shape[1], shape[2]
    c1, c2 = n1 - 1, n2 - 1
    n_nodes = n0 * n1 * n2
    cell_keys = np.empty(k * s * s * s, dtype=np.int64)
    configs = np.empty(k * s * s * s, dtype=np.uint8)
    edge_keys = np.empty(3 * k * s * (s + 1) * (s + 1), dtype=np.int64)
    f0 = np.empty(3 * k * s * (s + 1) * (s + 1))
    f1 = np.empty(3 * k * s * (s + 1) * (s + 1))
    bits = np.empty((s + 1, s + 1, s + 1), dtype=np.uint8)
    nc = 0
    ne = 0
    for b in range(k):
        bx, by, bz = part[b, 0] * s, part[b, 1] * s, part[b, 2] * s
        # the block's last node inside the grid, per axis (the rest is padding)
        ni, nj, nm = min(s, n0 - 1 - bx), min(s, n1 - 1 - by), min(s, n2 - 1 - bz)
        first = v[b, 0, 0, 0] > 0
        mixed = False
        for i in range(ni + 1):
            for j in range(nj + 1):
                for m in range(nm + 1):
                    inside = v[b, i, j, m] > 0
                    bits[i, j, m] = inside
                    mixed |= inside != first
        if not mixed:
            continue
        # the edges from each node along +x, +y, +z whose ends differ in class
        for i in range(ni + 1):
            for j in range(nj + 1):
                node = ((bx + i) * n1 + by + j) * n2 + bz
                for m in range(nm + 1):
                    here = bits[i, j, m]
                    if i < ni and bits[i + 1, j, m] != here:
                        edge_keys[ne], f0[ne], f1[ne] = node + m, v[b, i, j, m], v[b, i + 1, j, m]
                        ne += 1
                    if j < nj and bits[i, j + 1, m] != here:
                        edge_keys[ne], f0[ne], f1[ne] = node + m + n_nodes, v[b, i, j, m], v[b, i, j + 1, m]
                        ne += 1
                    if m < nm and bits[i, j, m + 1] != here:
                        edge_keys[ne], f0[ne], f1[ne] = node + m + 2 * n_nodes, v[b, i, j, m], v[b, i, j, m + 1]
                        ne += 1
        # the cells: corners (0, 0, 0) .. (1, 1, 0) are bits 0-3, the face above bits 4-7
        for i in range(ni):
            for j in range(nj):
                below = bits[i, j, 0] | bits[i + 1, j, 0] << 1 | bits[i, j + 1, 0] << 2 | bits[i + 1, j + 1, 0] << 3
                cell = ((bx + i) * c1 + by + j) * c2 + bz
                for m in range(nm):
                    above = (
                        bits[i, j, m + 1]
                        | bits[i + 1, j, m + 1] << 1
                        | bits[i, j + 1, m + 1] << 2
                        | bits[i + 1, j + 1, m + 1] << 3
                    )
                    config = below | above << 4
                    below = above
                    if config != 0 and config != 255:
                        cell_keys[nc] = cell + m
                        configs[nc] = config
                        nc += 1
    return cell_keys[:nc].copy(), configs[:nc].copy(), edge_keys[:ne].copy(), f0[:ne].copy(), f1[:ne].copy()


@_jit
def _block_points(part: np.ndarray, s: int, ax: np.ndarray, ay: np.ndarray, az: np.ndarray) -> np.ndarray:
    """The nodes (3, k, s + 1, s + 1, s + 1) of blocks (k, 3) of ``s``^3 cells, component-first (as
    compiled kernels read points), from the grid's sample positions per axis (``ax``, ``ay``,
    ``az``; their dtype); nodes past the grid's last one repeat it (padding)."""
    k = part.shape[0]
    out = np.empty((3, k, s + 1, s + 1, s + 1), dtype=ax.dtype)
    for b in range(k):
        for i in range(s + 1):
            x = ax[min(part[b, 0] * s + i, ax.shape[0] - 1)]
            for j in range(s + 1):
                y = ay[min(part[b, 1] * s + j, ay.shape[0] - 1)]
                for m in range(s + 1):
                    out[0, b, i, j, m] = x
                    out[1, b, i, j, m] = y
                    out[2, b, i, j, m] = az[min(part[b, 2] * s + m, az.shape[0] - 1)]
    return out


@_jit
def _distinct_edges(
    key: np.ndarray, order: np.ndarray, f0: np.ndarray, f1: np.ndarray, shape: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The edges of sorted keys ``key[order]`` (E,) (flat start node + axis * nodes, as
    :func:`_classify_blocks` gives them, with f at their ends ``f0``, ``f1`` in the unsorted order),
    each once: start nodes (D, 3) int64, axes (D,) int64 and end values (D,), in key order."""
    n = key.shape[0]
    n1, n2 = shape[1], shape[2]
    n_nodes = shape[0] * n1 * n2
    node = np.empty((n, 3), dtype=np.int64)
    axis = np.empty(n, dtype=np.int64)
    g0 = np.empty(n)
    g1 = np.empty(n)
    d = 0
    for t in range(n):
        e = order[t]
        if t > 0 and key[e] == key[order[t - 1]]:
            continue  # an edge on a face shared by two blocks: the same values from both
        axis[d], flat = divmod(key[e], n_nodes)
        node[d, 0], rest = divmod(flat, n1 * n2)
        node[d, 1], node[d, 2] = divmod(rest, n2)
        g0[d], g1[d] = f0[e], f1[e]
        d += 1
    return node[:d].copy(), axis[:d].copy(), g0[:d].copy(), g1[:d].copy()


@_jit
def _unravel_cells(key: np.ndarray, ncell: np.ndarray) -> np.ndarray:
    """Cells (C, 3) int64 of flat keys (C,) over a grid of ``ncell`` (3,) cells."""
    out = np.empty((key.shape[0], 3), dtype=np.int64)
    for t in range(key.shape[0]):
        out[t, 0], rest = divmod(key[t], ncell[1] * ncell[2])
        out[t, 1], out[t, 2] = divmod(rest, ncell[2])
    return out


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
    for q in range(4):  # one corner at a time: its cells' keys come in ascending order within an axis
        db = 1 if q == 0 or q == 3 else 0  # (1, 1), (0, 1), (0, 0), (1, 0)
        dc = 1 if q < 2 else 0
        at = 0
        for e in range(n):
            a = edge_axis[e]
            b, c = (a + 1) % 3, (a + 2) % 3
            cell[0], cell[1], cell[2] = edge_node[e, 0], edge_node[e, 1], edge_node[e, 2]
            cell[b] -= db
            cell[c] -= dc
            if cell[b] < 0 or cell[c] < 0 or cell[0] >= ncell[0] or cell[1] >= ncell[1] or cell[2] >= ncell[2]:
                continue
            key = (cell[0] * ncell[1] + cell[1]) * ncell[2] + cell[2]
            if at > 0 and keys[at - 1] >= key:  # keys went down (the next axis): binary search
                low, high = 0, at
                while low < high:
                    mid = (low + high) >> 1
                    if keys[mid] < key:
                        low = mid + 1
                    else:
                        high = mid
                at = low
            while at < size and keys[at] < key:  # the first key >= key, walking up
                at += 1
            if at < size and keys[at] == key:
                comp = component[config[at], 4 * a + db + 2 * dc]
                if comp >= 0:
                    out[e, q] = base[at] + comp
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
def _unbias_requests(
    quads: np.ndarray,
    points: np.ndarray,
    point_gradient: np.ndarray,
    x: np.ndarray,
    gradient: np.ndarray,
    total: np.ndarray,
    count: np.ndarray,
) -> None:
    """What the triangles (crossing, q_i, q_i+1) of quads (Q, 4) whose two cell vertices are both
    smooth (finite ``gradient``) ask of them, added to ``total`` (V,) (length units, > 0: inward) and
    their number to ``count`` (V,): each asks both its vertices for 9/8 of its centroid's depth (> 0:
    inside).  The depth of the midpoint of a chord p q of a surface with unit inward normals m_p, m_q
    is (q - p) . (m_p - m_q) / 8 to leading order; the chord error of a triangle is the quadratic
    a l1 l2 + b l2 l3 + c l3 l1 in barycentric coordinates, 4 times that at each edge's midpoint, so
    (a + b + c) / 9 at the centroid.  Summed in the quads' order."""
    unit = np.empty((5, 3))  # the quad's four vertices' unit normals, then the crossing's
    for q in range(quads.shape[0]):
        for k in range(5):
            g = point_gradient[q] if k == 4 else gradient[quads[q, k]]
            inverse = 1.0 / np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
            for d in range(3):
                unit[k, d] = g[d] * inverse  # NaN: not smooth; inf or NaN: no gradient at the crossing
        for half in range(4):
            i, j = half, (half + 1) % 4
            a, b = quads[q, i], quads[q, j]
            chords = 0.0  # the sum over the triangle's edges of (q - p) . (m_p - m_q)
            for d in range(3):
                chords += (x[a, d] - points[q, d]) * (unit[4, d] - unit[i, d])
                chords += (x[b, d] - x[a, d]) * (unit[i, d] - unit[j, d])
                chords += (points[q, d] - x[b, d]) * (unit[j, d] - unit[4, d])
            if not np.isfinite(chords):
                continue
            ask = 1.125 * 4.0 / 9.0 * chords / 8.0
            total[a] += ask
            total[b] += ask
            count[a] += 1.0
            count[b] += 1.0


@_jit
def _unbias_scale(total: np.ndarray, count: np.ndarray, gradient: np.ndarray) -> np.ndarray:
    """The mean request per vertex in units of grad f, from the requests of W parts of the quads
    (``total``, ``count`` (W, V), :func:`_unbias_requests`), summed in the parts' order: the move is
    ``scale * gradient`` (V,) (> 0: inward)."""
    n = gradient.shape[0]
    scale = np.zeros(n)
    for v in range(n):
        asked, times = 0.0, 0.0
        for w in range(total.shape[0]):
            asked += total[w, v]
            times += count[w, v]
        if times > 0:
            g = gradient[v]
            scale[v] = asked / times / np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    return scale


@_jit
def _take_rows(source: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """out[k] = source[rows[k]] for rows (K,) of ``source`` (N, 3), into ``out`` (K, 3) (no temporaries)."""
    for k in range(rows.shape[0]):
        for d in range(3):
            out[k, d] = source[rows[k], d]


@_jit
def _gather_rows(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """x[rows] (K, 3), component-first (as compiled kernels read points)."""
    out = np.empty((3, rows.shape[0])).T
    _take_rows(x, rows, out)
    return out


@_jit
def _inner_cell(cell: np.ndarray, lo: np.ndarray, hi: np.ndarray, spacing: np.ndarray, margin: float, d: int) -> tuple:
    """Axis d's bounds of cell (3,) of the grid from ``lo`` to ``hi``, less ``margin`` of a cell on each side."""
    cell_lo = lo[d] + cell[d] * spacing[d]
    cell_hi = min(cell_lo + spacing[d], hi[d])
    return cell_lo + margin * spacing[d], cell_hi - margin * spacing[d]


@_jit
def _symmetric_eigen3(a: np.ndarray, w: np.ndarray, u: np.ndarray) -> None:
    """Eigenvalues ``w`` (3,) ascending and unit eigenvectors ``u`` (3, 3) (columns) of the symmetric
    3 x 3 matrix ``a`` (overwritten), by cyclic Jacobi rotations (a few sweeps; accurate to
    rounding; no LAPACK call and no allocation per cell)."""
    for r in range(3):
        for c in range(3):
            u[r, c] = 1.0 if r == c else 0.0
    for _ in range(32):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        if off == 0.0 or off <= 1e-36 * (a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]):
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if a[p, q] == 0.0:
                continue
            theta = 0.5 * (a[q, q] - a[p, p]) / a[p, q]
            t = 1.0 / (abs(theta) + np.sqrt(1.0 + theta * theta))  # the smaller root of t^2 + 2 theta t = 1
            if theta < 0:
                t = -t
            c = 1.0 / np.sqrt(1.0 + t * t)
            s = t * c
            for k in range(3):  # A J
                akp, akq = a[k, p], a[k, q]
                a[k, p], a[k, q] = c * akp - s * akq, s * akp + c * akq
            for k in range(3):  # J^T (A J)
                apk, aqk = a[p, k], a[q, k]
                a[p, k], a[q, k] = c * apk - s * aqk, s * apk + c * aqk
            for k in range(3):
                ukp, ukq = u[k, p], u[k, q]
                u[k, p], u[k, q] = c * ukp - s * ukq, s * ukp + c * ukq
    for d in range(3):
        w[d] = a[d, d]
    for p, q in ((0, 1), (1, 2), (0, 1)):  # sort ascending, columns along
        if w[q] < w[p]:
            w[p], w[q] = w[q], w[p]
            for k in range(3):
                u[k, p], u[k, q] = u[k, q], u[k, p]


@_jit
def _solve_qefs(
    sums: np.ndarray,
    cell: np.ndarray,
    shared: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    margin: float,
    cutoff: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each vertex's QEF minimiser (V, 3) about its mass point, kept in its cell; the mass points
    (V, 3); the number of directions kept (V,) int64 (0 where ``shared``: the vertex is its mass point).

    sums : (V, 13) from :func:`_qef_sums`; cell : (V, 3) each vertex's cell, whose bounds less ``margin``
    of a cell bound the vertex; cutoff : relative eigenvalue below which a direction is free.

    A smooth patch (one direction) needs no eigendecomposition: power iteration from the largest
    column gives the top eigenpair; its Rayleigh quotient q <= l1, so trace - q >= l2 + l3 bounds
    l2.  Otherwise the pseudo-inverse from the eigendecomposition.  A crease (two directions
    kept) leaves a line of minimisers: where the one nearest the mass point lies outside the
    cell, the line's point nearest to it inside the cell is taken (the crease only clips the
    cell); only where the line misses the cell is the point clamped.
    """
    n = sums.shape[0]
    x = np.empty((n, 3))
    mass = np.empty((n, 3))
    rank = np.ones(n, dtype=np.int64)
    ata = np.empty((3, 3))
    rhs = np.empty(3)
    w = np.empty(3)
    u = np.empty((3, 3))
    box_lo = np.empty(3)
    box_hi = np.empty(3)
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for i in range(n):
        count = max(sums[i, 12], 1.0)
        for d in range(3):
            box_lo[d], box_hi[d] = _inner_cell(cell[i], lo, hi, spacing, margin, d)
            mass[i, d] = min(max(sums[i, 9 + d] / count, box_lo[d]), box_hi[d])
            x[i, d] = mass[i, d]
        if shared[i]:  # a cell crossed by two sheets: the QEF's point could cross the other one
            rank[i] = 0
            continue
        # (scalars, not arrays: they stay in registers)
        a00, a01, a02, a11, a12, a22 = sums[i, 0], sums[i, 1], sums[i, 2], sums[i, 3], sums[i, 4], sums[i, 5]
        m0, m1, m2 = mass[i, 0], mass[i, 1], mass[i, 2]
        r0 = sums[i, 6] - (a00 * m0 + a01 * m1 + a02 * m2)
        r1 = sums[i, 7] - (a01 * m0 + a11 * m1 + a12 * m2)
        r2 = sums[i, 8] - (a02 * m0 + a12 * m1 + a22 * m2)
        column, largest = 0, a00  # power iteration from the column of the largest diagonal entry
        if a11 > largest:
            column, largest = 1, a11
        if a22 > largest:
            column = 2
        if column == 0:
            v0, v1, v2 = a00, a01, a02
        elif column == 1:
            v0, v1, v2 = a01, a11, a12
        else:
            v0, v1, v2 = a02, a12, a22
        for _ in range(4):
            w0 = a00 * v0 + a01 * v1 + a02 * v2
            w1 = a01 * v0 + a11 * v1 + a12 * v2
            w2 = a02 * v0 + a12 * v1 + a22 * v2
            scale = 1.0 / max(np.sqrt(w0 * w0 + w1 * w1 + w2 * w2), 1e-300)
            v0, v1, v2 = w0 * scale, w1 * scale, w2 * scale
        q = v0 * (a00 * v0 + a01 * v1 + a02 * v2) + v1 * (a01 * v0 + a11 * v1 + a12 * v2)
        q += v2 * (a02 * v0 + a12 * v1 + a22 * v2)
        if (a00 + a11 + a22) - q <= cutoff * q and q > 0:
            t = (v0 * r0 + v1 * r1 + v2 * r2) / q
            x[i, 0] = min(max(m0 + v0 * t, box_lo[0]), box_hi[0])
            x[i, 1] = min(max(m1 + v1 * t, box_lo[1]), box_hi[1])
            x[i, 2] = min(max(m2 + v2 * t, box_lo[2]), box_hi[2])
            continue
        for k in range(6):
            r, c = pairs[k]
            ata[r, c] = ata[c, r] = sums[i, k]
        rhs[0], rhs[1], rhs[2] = r0, r1, r2
        _symmetric_eigen3(ata, w, u)
        kept = 0
        for j in range(3):
            if w[j] > cutoff * w[2]:
                kept += 1
                coef = (u[0, j] * rhs[0] + u[1, j] * rhs[1] + u[2, j] * rhs[2]) / w[j]
                for d in range(3):
                    x[i, d] += u[d, j] * coef
        rank[i] = kept
        outside = False
        for d in range(3):
            outside |= x[i, d] < box_lo[d] or x[i, d] > box_hi[d]
        if kept == 2 and outside:  # slide along the crease (the dropped eigenvalue's eigenvector) into the cell
            t_min, t_max = -np.inf, np.inf
            for d in range(3):
                line, start = u[d, 0], x[i, d]
                if abs(line) > 1e-12:
                    t1, t2 = (box_lo[d] - start) / line, (box_hi[d] - start) / line
                    t_min, t_max = max(t_min, min(t1, t2)), min(t_max, max(t1, t2))
                elif start < box_lo[d] or start > box_hi[d]:
                    t_min, t_max = np.inf, -np.inf
            if t_min <= t_max:
                t = min(max(0.0, t_min), t_max)
                for d in range(3):
                    x[i, d] += t * u[d, 0]
        for d in range(3):
            x[i, d] = min(max(x[i, d], box_lo[d]), box_hi[d])
    return x, mass, rank


@_jit
def _move_in_cells(
    x: np.ndarray,
    rows: np.ndarray,
    scale: np.ndarray,
    gradient: np.ndarray,
    cell: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    margin: float,
    slack: float,
) -> None:
    """x[rows[k]] -= scale[k] gradient[k] (in place), clipped to the vertex's cell ``cell[rows[k]]`` less
    ``margin`` of a cell (the grid from ``lo`` to ``hi``); skipped where ``scale`` is 0 or not finite,
    and, with ``slack`` >= 0, where the move would leave that box by more than ``slack`` cells."""
    for k in range(rows.shape[0]):
        s = scale[k]
        if s == 0.0 or not np.isfinite(s):
            continue
        i = rows[k]
        ok = True
        for d in range(3):
            y = x[i, d] - s * gradient[k, d]
            inner_lo, inner_hi = _inner_cell(cell[i], lo, hi, spacing, margin, d)
            if slack >= 0.0:
                ok &= np.isfinite(y) and inner_lo - slack * spacing[d] <= y <= inner_hi + slack * spacing[d]
        if ok:
            for d in range(3):
                inner_lo, inner_hi = _inner_cell(cell[i], lo, hi, spacing, margin, d)
                x[i, d] = min(max(x[i, d] - s * gradient[k, d], inner_lo), inner_hi)


@_jit
def _unit_rows(gradient: np.ndarray, sign: float, normals: np.ndarray, good: np.ndarray) -> None:
    """In place: ``normals`` (V, 3) = ``sign`` grad f / |grad f| per row of ``gradient`` (V, 3), and ``good``
    (V,) whether |grad f| was finite and nonzero (the row is left as it was where not)."""
    for i in range(gradient.shape[0]):
        g0, g1, g2 = gradient[i, 0], gradient[i, 1], gradient[i, 2]
        length = np.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        good[i] = np.isfinite(length) and length > 0
        if good[i]:
            scale = sign / length
            normals[i, 0], normals[i, 1], normals[i, 2] = g0 * scale, g1 * scale, g2 * scale


@_jit
def _unit_normals(gradient: np.ndarray, sign: float) -> tuple[np.ndarray, np.ndarray]:
    """``sign`` grad f / |grad f| per row of ``gradient`` (V, 3) (-1: outward normals), and whether
    |grad f| was finite and nonzero (V,) (the normal is 0 where not)."""
    normals = np.zeros((gradient.shape[0], 3))
    good = np.empty(gradient.shape[0], dtype=np.bool_)
    _unit_rows(gradient, sign, normals, good)
    return normals, good


@_jit
def _mark_used(faces: np.ndarray, index: np.ndarray) -> None:
    """``index[v] = 0`` for every vertex v that ``faces`` (F, 3) use (rows of faces may be marked from
    several threads at once: they write the same value)."""
    for i in range(faces.shape[0]):
        for k in range(3):
            index[faces[i, k]] = 0


@_jit
def _number_used(index: np.ndarray) -> np.ndarray:
    """The marked vertices (``index`` 0, others -1) numbered in order, in place; returns them (U,)."""
    used = 0
    for v in range(index.shape[0]):
        if index[v] == 0:
            index[v] = used
            used += 1
    kept = np.empty(used, dtype=np.int64)
    for v in range(index.shape[0]):
        if index[v] >= 0:
            kept[index[v]] = v
    return kept


@_jit
def _renumber(faces: np.ndarray, index: np.ndarray) -> None:
    """``faces`` (F, 3) renumbered in place through ``index`` (V,)."""
    for i in range(faces.shape[0]):
        for k in range(3):
            faces[i, k] = index[faces[i, k]]


@_jit
def _edge_points(
    rows: np.ndarray, start: np.ndarray, axis: np.ndarray, start_axis: np.ndarray, h: np.ndarray, c: np.ndarray
) -> np.ndarray:
    """Points (K, 3) at ``c[r]`` (edge units) along edges ``rows`` (K,): ``start[r]`` (3,) moved to
    ``start_axis[r] + c[r] h[r]`` along axis ``axis[r]``."""
    out = np.empty((3, rows.shape[0]))  # component-first, as compiled kernels read points: no copy there
    for k in range(rows.shape[0]):
        r = rows[k]
        for d in range(3):
            out[d, k] = start[r, d]
        out[axis[r], k] = start_axis[r] + c[r] * h[r]
    return out.T


@_jit
def _secant_step(
    rows: np.ndarray,
    fc: np.ndarray,
    first: bool,
    f0: np.ndarray,
    f1: np.ndarray,
    slope: np.ndarray,
    h: np.ndarray,
    c: np.ndarray,
    a: np.ndarray,
    fa: np.ndarray,
    p: np.ndarray,
    fp: np.ndarray,
    falsi: np.ndarray,
    step_tol: float,
    root: np.ndarray,
) -> np.ndarray:
    """One step of Dekker's safeguarded secant on the edges ``rows`` (K,), f at their estimates
    ``fc`` (K,); the rows still moving come back.

    Per edge r (in edge units; state updated in place): ``c`` the estimate, ``a``, ``fa`` the bracket's
    other end, ``p``, ``fp`` the previous iterate, ``falsi`` whether the last step was regula falsi's.
    The first step sets the bracket from the end values ``f0``, ``f1`` and takes Newton's step with
    ``slope``; the next ones take the secant through the last two iterates, after moving the
    bracket's end to the previous iterate when the sign changed.  A step that leaves the bracket is
    replaced by regula falsi's (inside it).  An edge is done (``root[r]`` set) when the step is below
    ``step_tol`` (length units) or f is 0.

    Where f bends sharply in the bracket (a kink of min/max near the root), regula falsi keeps one
    end and creeps toward the root from the other by a fixed fraction a step.  So, as in the
    Illinois method, when a regula falsi step is followed by one that keeps the same end, that
    end's value is halved: the next estimate lands on the far side and the bracket closes from both.
    """
    moving = np.empty(rows.shape[0], dtype=np.int64)
    m = 0
    for k in range(rows.shape[0]):
        r = rows[k]
        fck, ck = fc[k], c[r]
        if first:  # the bracket: the grid end whose value has the other sign
            same = (fck > 0) == (f0[r] > 0)
            a[r] = 1.0 if same else 0.0
            fa[r] = f1[r] if same else f0[r]
            nxt = ck - fck / slope[r]  # Newton with the cubic's slope
            falsi[r] = False
        else:  # the bracket becomes [previous iterate, c] when the sign changed
            if (fck > 0) != (fp[r] > 0):
                a[r], fa[r] = p[r], fp[r]
            elif falsi[r]:  # the same end kept after a regula falsi step (Illinois)
                fa[r] *= 0.5
            nxt = ck - fck * (ck - p[r]) / (fck - fp[r])
        move = nxt - ck
        falsi[r] = not ((nxt - a[r]) * move < 0)
        if falsi[r]:  # regula falsi: inside
            nxt = ck - fck * (ck - a[r]) / (fck - fa[r])
            move = nxt - ck
        finished = abs(move) * h[r] <= step_tol  # False for NaN
        if finished:
            root[r] = nxt
        if fck == 0:
            root[r] = ck
        elif not finished and np.isfinite(fck):
            p[r], fp[r], c[r] = ck, fck, nxt
            moving[m] = r
            m += 1
    return moving[:m]


@_jit
def _section_points(
    rows: np.ndarray,
    start: np.ndarray,
    axis: np.ndarray,
    start_axis: np.ndarray,
    h: np.ndarray,
    a: np.ndarray,
    p: np.ndarray,
    m: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``m`` evenly spaced interior points of the brackets [a[r], p[r]] (edge units, either
    order) of edges ``rows`` (K,): their positions t (K m,) in edge units, row by row, and the points
    (K m, 3) component-first (as :func:`_edge_points`)."""
    t = np.empty(rows.shape[0] * m)
    out = np.empty((3, rows.shape[0] * m))
    for k in range(rows.shape[0]):
        r = rows[k]
        for j in range(m):
            q = k * m + j
            t[q] = a[r] + (p[r] - a[r]) * (j + 1) / (m + 1)
            for d in range(3):
                out[d, q] = start[r, d]
            out[axis[r], q] = start_axis[r] + t[q] * h[r]
    return t, out.T


@_jit
def _section_step(
    rows: np.ndarray,
    t: np.ndarray,
    ft: np.ndarray,
    m: int,
    a: np.ndarray,
    fa: np.ndarray,
    p: np.ndarray,
    fp: np.ndarray,
    last: bool,
    root: np.ndarray,
) -> np.ndarray:
    """One multisection step on the brackets [a, p] (values fa, fp of opposite classes f > 0 / f <= 0)
    of edges ``rows`` (K,), f ``ft`` at their ``m`` interior points ``t`` (K m,) (:func:`_section_points`);
    the rows still moving come back.

    Each bracket becomes the first pair of neighbours, from ``a``, among a, the m points and p whose
    classes differ: (m + 1) times narrower, whatever the shape of f.  A point where f is 0 is the
    root; on the ``last`` step the root is regula falsi's in the narrowed bracket (inside it, also where
    ``fa`` is still Illinois's halved value of :func:`_secant_step`).  A row with a non-finite value is
    dropped without a root (NaN).
    """
    moving = np.empty(rows.shape[0], dtype=np.int64)
    n = 0
    for k in range(rows.shape[0]):
        r = rows[k]
        x0, g0, x1, g1 = a[r], fa[r], p[r], fp[r]
        finite, exact = True, False
        for j in range(m):
            v = ft[k * m + j]
            if not np.isfinite(v):
                finite = False
                break
            if v == 0:
                root[r] = t[k * m + j]
                exact = True
                break
            if (v > 0) != (g0 > 0):
                x1, g1 = t[k * m + j], v
                break
            x0, g0 = t[k * m + j], v
        if not finite or exact:
            continue
        a[r], fa[r], p[r], fp[r] = x0, g0, x1, g1
        if last:
            root[r] = x0 - g0 * (x1 - x0) / (g1 - g0)
        else:
            moving[n] = r
            n += 1
    return moving[:n]


@_jit
def _quad_halves(quads: np.ndarray, first_crossing: int) -> np.ndarray:
    """The four triangles (crossing, q_i, q_i+1) (4 Q, 3) of each quad (Q, 4), quad by quad; quad k's
    crossing is vertex ``first_crossing + k``."""
    nq = quads.shape[0]
    out = np.empty((4 * nq, 3), dtype=np.int64)
    for k in range(nq):
        for i in range(4):
            out[4 * k + i, 0] = first_crossing + k
            out[4 * k + i, 1] = quads[k, i]
            out[4 * k + i, 2] = quads[k, (i + 1) % 4]
    return out


@_jit
def _owned_quads(
    vert: np.ndarray,
    edge_node: np.ndarray,
    edge_axis: np.ndarray,
    f0: np.ndarray,
    points: np.ndarray,
    point_gradient: np.ndarray,
    first: int,
    end: int,
    ncell: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The quads of a slab's crossing edges that start in its cell layers [first, end) along x and
    have all four cells (``vert`` (E, 4) >= 0), oriented outward (toward f <= 0: reversed where f > 0
    at the edge's end), with the flat key of each edge's end with f > 0 among the grid's nodes, its
    crossing (Q, 3) and grad f there (Q, 3)."""
    keep = np.empty(vert.shape[0], dtype=np.int64)
    nq = 0
    for e in range(vert.shape[0]):
        if (
            first <= edge_node[e, 0] < end
            and vert[e, 0] >= 0
            and vert[e, 1] >= 0
            and vert[e, 2] >= 0
            and vert[e, 3] >= 0
        ):
            keep[nq] = e
            nq += 1
    quads = np.empty((nq, 4), dtype=np.int64)
    corner = np.empty(nq, dtype=np.int64)
    crossing = np.empty((nq, 3))
    crossing_gradient = np.empty((nq, 3))
    positive = np.empty(3, dtype=np.int64)
    for k in range(nq):
        e = keep[k]
        inside_start = f0[e] > 0
        for q in range(4):
            quads[k, q] = vert[e, q] if inside_start else vert[e, 3 - q]
        for d in range(3):
            positive[d] = edge_node[e, d]
            crossing[k, d] = points[e, d]
            crossing_gradient[k, d] = point_gradient[e, d]
        if not inside_start:
            positive[edge_axis[e]] += 1
        corner[k] = (positive[0] * (ncell[1] + 1) + positive[1]) * (ncell[2] + 1) + positive[2]
    return quads, corner, crossing, crossing_gradient


@_jit
def _cell_pairs(
    face: np.ndarray,
    key: np.ndarray,
    own: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    faces: np.ndarray,
    changed: np.ndarray,
) -> np.ndarray:
    """Codes ``min * F + max`` (with repeats) of the pairs of faces that share a cell and may meet.

    The (face, cell) entries ``face``, ``key``, ``own`` (K,) are sorted by cell, the entries that
    do not hold the cell's only vertex (``own`` False) first; each of those is paired with the
    entries after it in its cell.  A pair is kept when one of its faces is ``changed`` (F,), their
    bounding boxes ``lo``, ``hi`` (3, F) overlap and they share no vertex (``faces`` (F, 3)).
    """
    n = face.shape[0]
    nf = faces.shape[0]
    out = np.empty(max(16, n), dtype=np.int64)
    m = 0
    end = n
    for i in range(n - 1, -1, -1):
        if i < n - 1 and key[i] != key[i + 1]:
            end = i + 1
        if own[i]:
            continue
        a = face[i]
        for j in range(i + 1, end):
            b = face[j]
            if not (changed[a] or changed[b]):
                continue
            if (
                lo[0, a] > hi[0, b]
                or lo[0, b] > hi[0, a]
                or lo[1, a] > hi[1, b]
                or lo[1, b] > hi[1, a]
                or lo[2, a] > hi[2, b]
                or lo[2, b] > hi[2, a]
            ):
                continue
            shared = False
            for u in range(3):
                for w in range(3):
                    if faces[a, u] == faces[b, w]:
                        shared = True
            if shared:
                continue
            if m == out.shape[0]:
                grown = np.empty(2 * m, dtype=np.int64)
                grown[:m] = out
                out = grown
            out[m] = min(a, b) * nf + max(a, b)
            m += 1
    return out[:m].copy()
