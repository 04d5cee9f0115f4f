"""Where dual contouring folds, the marching-cubes triangulation of the cells involved.

Dual contouring joins the vertices of the four cells around each crossing edge; where two sheets
pass within a cell of each other (thin rods, walls thinner than a cell) or a vertex sits far from
its crossings, these quads can pierce each other.  Marching cubes cannot, cell by cell: its
polygon in a cell joins the crossings on the cell's edges, so it lies in the cell.

Between the two lies a family of meshes.  Each mesh edge (v, w) of dual contouring crosses the
face shared by the cells of v and w between two crossings p, q of that face's edges (the
segment marching cubes draws on the face); (v, p, w, q) is a "diamond" around it.  Splitting
the quad of each edge e at its crossing p_e gives four half-diamonds (p_e, v_i, v_i+1); two
halves with the same (v, w) make a diamond, which can be cut along v w (dual contouring) or
along p q (marching cubes: the triangles (p, v, q) and (q, w, p), one in each cell).  A vertex
whose diamonds are all cut along p q is the fan of its cell's marching-cubes polygon; at its
mass point (the mean of those crossings, inside the cell) it lies in its cell.  Every choice
keeps the mesh watertight, manifold and oriented.

Dual contouring here always cuts its quads into half-diamonds (the crossing is a vertex), so the
mesh is the cone of each cell's vertex over a polygon on the cell's boundary; in cells with one
surface component and two crossings per face it cannot intersect itself
(``dual_contouring._confined``).  :func:`_unfold` finds the faces that intersect among those
with a vertex in the other cells (:func:`_intersecting_pairs`, an exact orientation test on the
pairs of faces that share a grid cell), turns their vertices into marching-cubes fans, and
repeats.

>>> import numpy as np
>>> v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, -0.5], [0.2, 0.2, 0.5], [0.3, 0.6, 0.0]])
>>> _intersecting_pairs(v, np.array([[0, 1, 2], [3, 4, 5]]), np.zeros(3), np.ones(3))  # the second pierces the first
array([[0, 1]])
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.ndimage import maximum_filter

from .loops import _cell_pairs, _quad_halves

UNFOLD_ROUNDS = 6  # rounds of "find intersecting faces, fan their vertices" (each grows the fanned set)
PAIR_CHUNK = 1 << 16  # candidate pairs tested at a time (temporaries stay in cache)
EPS = float(np.finfo(np.float64).eps)
# a corner this many ulps of |n| (|c| + |c - base|) from the other triangle's plane is in it: the rounding
# of n . (c - base), with n from differences of coordinates, is a few ulps of that
COPLANAR_ULPS = 64
SLAB_FACES = 1 << 18  # faces searched for intersecting pairs at a time (memory of the search)
DENSE_CELLS = 1 << 22  # cell grids up to this size (or 4 per queried cell) are dilated as grids (see _within)


def _largest_span(cell: np.ndarray, faces: np.ndarray) -> int:
    """The largest extent, in cells along one axis, of a face (F, 3) whose vertices lie in ``cell`` (V, 3).

    Axis by axis, 1-D gathers in chunks (a reduction over (F, 3, 3)'s middle axis costs several
    times more, and its memory grows with the faces).

    >>> _largest_span(np.array([[0, 0, 0], [2, 1, 0], [0, 3, 1]]), np.array([[0, 1, 2]]))
    3
    """
    reach = 0
    for d in range(3):
        column = np.ascontiguousarray(cell[:, d])
        for start in range(0, len(faces), SLAB_FACES):
            lo, hi = _corner_range(column, faces[start : start + SLAB_FACES])
            reach = max(reach, int((hi - lo).max(initial=0)))
    return reach


def _corner_range(column: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least and the greatest of a per-vertex value (V,) over each face's (F, 3) three corners.

    >>> _corner_range(np.array([4, 1, 7]), np.array([[0, 1, 2], [2, 0, 0]]))
    (array([1, 4]), array([7, 7]))
    """
    a, b, c = (column[faces[:, k]] for k in range(3))
    return np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b, out=a), c, out=b)


def _boxes(v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper corners (3, F) of the faces' (F, 3) bounding boxes, coordinates first.

    >>> lo, hi = _boxes(np.array([[0.0, 0, 0], [2, 1, 0], [0, 3, 1]]), np.array([[0, 1, 2]]))
    >>> lo.ravel().tolist(), hi.ravel().tolist()
    ([0.0, 0.0, 0.0], [2.0, 3.0, 1.0])
    """
    lo = np.empty((3, len(faces)))
    hi = np.empty((3, len(faces)))
    for d in range(3):
        lo[d], hi[d] = _corner_range(np.ascontiguousarray(v[:, d]), faces)
    return lo, hi


def _renumber(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The vertices (< n) that ``faces`` (F, k) use, ascending, and the faces in their numbering: what
    ``np.unique(faces, return_inverse=True)`` gives, by marking instead of sorting.

    >>> used, local = _renumber(np.array([[7, 2, 5], [5, 2, 9]]), 10)
    >>> used.tolist(), local.tolist()
    ([2, 5, 7, 9], [[2, 0, 1], [1, 0, 3]])
    """
    mark = np.zeros(n, dtype=bool)
    mark[faces.ravel()] = True
    used = np.flatnonzero(mark)
    index = np.empty(n, dtype=np.int64)
    index[used] = np.arange(len(used))
    return used, index[faces]


def _cells_of(
    faces: np.ndarray, subset: np.ndarray, cell: np.ndarray, dims: np.ndarray, alone: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(face, cell key, own) entries of the faces ``subset``: every grid cell [i, i + 1) h that the
    face's bounding box meets, and whether that cell's only vertex is one of the face's.

    ``cell`` (V, 3) is each vertex's cell, ``dims`` the key's extent, ``alone`` (V,) whether a
    vertex is the only one in its cell.  A point common to two faces lies in one half-open cell,
    which both faces' boxes meet (floor is monotone), so two intersecting faces share an entry.
    """
    f = faces[subset]
    corner = [cell[f[:, k]] for k in range(3)]
    first = np.minimum(np.minimum(corner[0], corner[1]), corner[2])
    span = np.maximum(np.maximum(corner[0], corner[1]), corner[2]) - first + 1
    vkey = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    fkey = [vkey[f[:, k]] for k in range(3)]
    falone = [alone[f[:, k]] for k in range(3)]
    base = (first[:, 0] * dims[1] + first[:, 1]) * dims[2] + first[:, 2]
    # boxes of at most 2 cells per axis (nearly all): one pass per corner offset of a 2 x 2 x 2 box
    wide = (span[:, 0] > 1) | (span[:, 1] > 1) << 1 | (span[:, 2] > 1) << 2
    small = np.flatnonzero((span <= 2).all(axis=1))
    rows, keys = [], []
    for need in range(8):
        r = small[(wide[small] & need) == need]
        rows.append(r)
        keys.append(base[r] + ((need & 1) * dims[1] + (need >> 1 & 1)) * dims[2] + (need >> 2 & 1))
    # the others: every cell of the box
    big = np.flatnonzero((span > 2).any(axis=1))
    count = span[big].prod(axis=1)
    r = np.repeat(big, count)
    k = np.arange(len(r)) - np.repeat(np.cumsum(count) - count, count)
    sy, sz = span[r, 1], span[r, 2]
    rows.append(r)
    keys.append(base[r] + ((k // (sy * sz)) * dims[1] + k // sz % sy) * dims[2] + k % sz)
    local, key = np.concatenate(rows), np.concatenate(keys)
    own = np.zeros(len(key), dtype=bool)
    for j in range(3):
        own |= (fkey[j][local] == key) & falone[j][local]
    return subset[local], key, own


def _candidate_pairs(
    v: np.ndarray, faces: np.ndarray, origin: np.ndarray, h: np.ndarray, changed: np.ndarray | None = None
) -> np.ndarray:
    """Pairs (P, 2) of faces, sharing no vertex, whose bounding boxes overlap within a common cell;
    with ``changed`` (a face mask), only the pairs with at least one changed face.

    Two faces holding the only vertex of a cell share it: in each cell only the pairs with a face
    that does not hold it are formed (those faces first, each paired with the ones after it).
    """
    cell = np.floor((v - origin) / h).astype(np.int64)
    cell -= cell.min(axis=0)
    dims = cell.max(axis=0) + 1
    vkey = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    used = np.zeros(len(v), dtype=bool)
    used[faces.ravel()] = True
    keys, inverse, count = np.unique(vkey[used], return_inverse=True, return_counts=True)
    alone = np.zeros(len(v), dtype=bool)
    alone[used] = count[inverse] == 1
    if changed is None:
        face, key, own = _cells_of(faces, np.arange(len(faces)), cell, dims, alone)
    else:
        # the faces whose boxes can meet a changed face's cells have a vertex within a box's span of them
        _, hot, _ = _cells_of(faces, np.flatnonzero(changed), cell, dims, alone)
        near = _within(hot, dims, _largest_span(cell, faces), vkey)
        face, key, own = _cells_of(faces, np.flatnonzero(near[faces].any(axis=1)), cell, dims, alone)
        keep = _within(hot, dims, 0, key)
        face, key, own = face[keep], key[keep], own[keep]
    order = np.argsort(2 * key + own)  # by cell, the faces that do not hold its only vertex first
    face, key, own = face[order], key[order], own[order]
    lo, hi = _boxes(v, faces)  # (3, F)
    if changed is None:
        changed = np.ones(len(faces), dtype=bool)
    pairs = np.unique(_cell_pairs(face, key, own, lo, hi, np.ascontiguousarray(faces), changed))
    return np.stack([pairs // len(faces), pairs % len(faces)], axis=1)


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Six times the signed volume of the tetrahedron (a, b, c, d): > 0 when d lies on the side of
    the plane (a, b, c) that its right-hand normal points to."""
    u, w, z = b - a, c - a, d - a  # (3, P): coordinates first
    return (u[1] * w[2] - u[2] * w[1]) * z[0] + (u[2] * w[0] - u[0] * w[2]) * z[1] + (u[0] * w[1] - u[1] * w[0]) * z[2]


def _orient2(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Twice the signed area of the triangles (a, b, c) in the plane, (2, P) each: > 0 counter-clockwise."""
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _overlap_in_plane(corner: np.ndarray, normal: np.ndarray, one: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Whether coplanar triangles ``one``, ``other`` (K,) (indices into ``corner`` (3, 3, F), normals
    (3, F)) meet, closed: seen along the largest component of the larger one's normal, an edge of one
    meets an edge of the other, or a corner of one lies in the other.

    >>> corner = np.array([[[0, 1], [0, 0], [0, 0]], [[1, 2], [0, 0], [0, 0]], [[0, 1], [1, 1], [0, 0]]], float)
    >>> normal = np.array([[0, 0], [0, 0], [1, 1]], float)
    >>> _overlap_in_plane(corner, normal, np.array([0]), np.array([1])).tolist()   # touching at (1, 0, 0)
    [True]
    >>> corner[:, 0, 1] -= 0.6   # the second moved -0.6 along x: it crosses the first's hypotenuse
    >>> _overlap_in_plane(corner, normal, np.array([0]), np.array([1])).tolist()
    [True]
    >>> corner[:, 1, 1] += 0.7   # and 0.7 along y: apart
    >>> _overlap_in_plane(corner, normal, np.array([0]), np.array([1])).tolist()
    [False]
    """
    # seen along the normal of the larger of the two (a sliver's normal is the rounding's)
    larger = np.where((normal[:, one] ** 2).sum(axis=0) >= (normal[:, other] ** 2).sum(axis=0), one, other)
    drop = np.abs(normal[:, larger]).argmax(axis=0)
    keep = np.stack([(drop + 1) % 3, (drop + 2) % 3])  # (2, K): the plane's coordinates
    p = [corner[i][keep, one[None]] for i in range(3)]  # (2, K) per corner
    q = [corner[i][keep, other[None]] for i in range(3)]
    meet = np.zeros(len(one), dtype=bool)
    for i in range(3):
        a, b = p[i], p[(i + 1) % 3]
        for j in range(3):
            c, d = q[j], q[(j + 1) % 3]
            o1, o2, o3, o4 = _orient2(a, b, c), _orient2(a, b, d), _orient2(c, d, a), _orient2(c, d, b)
            crossing = (o1 * o2 <= 0) & (o3 * o4 <= 0)
            collinear = (o1 == 0) & (o2 == 0)  # then the segments meet where their spans overlap
            span = np.all((np.minimum(a, b) <= np.maximum(c, d)) & (np.minimum(c, d) <= np.maximum(a, b)), axis=0)
            meet |= np.where(collinear, span, crossing)
    for s, t in ((p, q), (q, p)):  # a corner of one inside the other (it then meets no edge)
        area = _orient2(*t)
        inside = [np.sign(_orient2(t[i], t[(i + 1) % 3], s[0])) * np.sign(area) for i in range(3)]
        meet |= (area != 0) & (inside[0] >= 0) & (inside[1] >= 0) & (inside[2] >= 0)
    return meet


def _pairs_intersect(v: np.ndarray, faces: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Whether each pair (P, 2) of triangles intersects: two triangles that are not coplanar meet
    exactly when an edge of one meets the other (the ends of their common segment lie on edges).

    First each triangle must reach both sides of the other's plane (or touch it), with the planes
    computed once per face of a pair; the edge tests run on the pairs left.  Pairs where one's corners
    lie in the other's plane to within rounding (``COPLANAR_ULPS``) are tested in that plane
    (:func:`_overlap_in_plane`): there the signs of the edge tests would be the rounding's.
    """
    used, pairs = _renumber(pairs, len(faces))  # the faces of the pairs only
    corner = v[faces[used]].transpose(1, 2, 0)  # (corner, coordinate, face)
    e1, e2 = corner[1] - corner[0], corner[2] - corner[0]
    normal = np.stack([e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]])
    hit = np.zeros(len(pairs), dtype=bool)
    # rounding of a corner's side n . (c - base) over |n|: a few ulps of |c| + |c - base| <= 3 max |v|
    rounding = COPLANAR_ULPS * EPS * 3 * float(np.abs(corner).max(initial=0.0))
    for first in range(0, len(pairs), PAIR_CHUNK):
        part = pairs[first : first + PAIR_CHUNK]
        maybe = np.ones(len(part), dtype=bool)
        sides = []
        for one, other in ((part[:, 1], part[:, 0]), (part[:, 0], part[:, 1])):
            n, base = normal[:, one], corner[0][:, one]  # differences first: coplanar corners give exact zeros
            side = np.stack([np.einsum("cp,cp->p", n, corner[k][:, other] - base) for k in range(3)])
            maybe &= (side.min(axis=0) <= 0) & (side.max(axis=0) >= 0)
            sides.append(side)  # of ``other``'s corners to ``one``'s plane
        # coplanar to rounding (symmetric parts make them exactly so): the test above and those below
        # would read the rounding's signs; such pairs are tested in the plane instead
        flat = np.zeros(len(part), dtype=bool)  # the corners of one triangle in the other's plane
        for one, side in zip((part[:, 1], part[:, 0]), sides):
            flat |= np.abs(side).max(axis=0) <= rounding * np.sqrt((normal[:, one] ** 2).sum(axis=0))
        coplanar = np.flatnonzero(flat)
        if len(coplanar):
            hit[first + coplanar] = _overlap_in_plane(corner, normal, part[coplanar, 0], part[coplanar, 1])
        rows = np.flatnonzero(maybe & ~flat)
        found = np.zeros(len(rows), dtype=bool)
        for (one, other), side in zip(((part[:, 0], part[:, 1]), (part[:, 1], part[:, 0])), sides):
            # an edge of ``one`` that crosses ``other``'s plane meets ``other`` inside its three edges
            side = side[:, rows]
            for i, j in ((0, 1), (1, 2), (2, 0)):
                cross = np.flatnonzero((side[i] * side[j] <= 0) & ((side[i] != 0) | (side[j] != 0)) & ~found)
                p = corner[i][:, one[rows[cross]]]
                q = corner[j][:, one[rows[cross]]]
                a, b, c = (corner[k][:, other[rows[cross]]] for k in range(3))
                s1, s2, s3 = _orient(p, q, a, b), _orient(p, q, b, c), _orient(p, q, c, a)
                inside = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
                found[cross] = inside & ((s1 != 0) | (s2 != 0) | (s3 != 0))
        hit[first + rows] = found
    return hit


def _intersecting_pairs(
    v: np.ndarray, faces: np.ndarray, origin: np.ndarray, h: np.ndarray, changed: np.ndarray | None = None
) -> np.ndarray:
    """Pairs (P, 2) of faces that share no vertex and intersect; the grid (``origin``, cell ``h``)
    only buckets the search.  With ``changed``, only pairs with a changed face are tested.

    In slabs of cell layers along x holding at most ``SLAB_FACES`` faces each (and their vertices), so that the memory
    of the (face, cell) entries and candidate pairs stays bounded: two intersecting faces share a
    cell, and the slab of that cell's layer holds both (every face whose box meets its layers), so
    each such pair is found; pairs found twice (faces spanning two slabs) are merged.
    """
    if len(faces) <= SLAB_FACES:
        pairs = _candidate_pairs(v, faces, origin, h, changed)
        return pairs[_pairs_intersect(v, faces, pairs)]
    first, last = _corner_range(np.floor((v[:, 0] - origin[0]) / h[0]).astype(np.int64), faces)
    # layer boundaries such that at most SLAB_FACES faces start in each slab (at least one layer)
    start, count = np.unique(first, return_counts=True)
    bounds, total = [start[0]], 0
    for value, n in zip(start, count):
        if total and total + n > SLAB_FACES:
            bounds.append(value)
            total = 0
        total += n
    bounds.append(last.max() + 1)
    found = []
    for lo_layer, hi_layer in zip(bounds[:-1], bounds[1:]):
        subset = np.flatnonzero((first < hi_layer) & (last >= lo_layer))
        used, part = _renumber(faces[subset], len(v))  # the slab's vertices only
        near = v[used]
        pairs = _candidate_pairs(near, part, origin, h, None if changed is None else changed[subset])
        pairs = pairs[_pairs_intersect(near, part, pairs)]
        found.append(subset[pairs])
    pairs = np.unique(np.concatenate(found), axis=0)
    return pairs.reshape(-1, 2)


def _near(v: np.ndarray, faces: np.ndarray, watch: np.ndarray, origin: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Indices of the faces that may meet a face in ``watch`` (a face mask): those with a vertex within
    twice the largest face's span (in grid cells) of a watched face's vertex.

    Two faces that meet share a point, whose cell lies within each face's span of each of its
    vertices; so a vertex of the one lies within the sum of the spans of a vertex of the other.
    """
    cell = np.floor((v - origin) / h).astype(np.int64)
    cell -= cell.min(axis=0) - 1
    pad = 2 * _largest_span(cell, faces)
    cell += pad
    dims = cell.max(axis=0) + pad + 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    hit = _within(key[faces[watch]].ravel(), dims, pad, key)
    return np.flatnonzero(hit[faces].any(axis=1))


def _within(keys: np.ndarray, dims: np.ndarray, pad: int, query: np.ndarray) -> np.ndarray:
    """Whether each cell of ``query`` lies within ``pad`` cells, along every axis, of a cell of ``keys``
    (cells numbered ``(i dims[1] + j) dims[2] + k``, in [0, dims)).

    Where the grid of cells is not much larger than the query, the box dilation runs on it
    (``scipy.ndimage.maximum_filter``, separable); otherwise on the keys, axis by axis (a key
    shifted past a row's end marks a cell of the next row: a few more cells, never fewer).

    >>> dims = np.array([4, 4, 4])
    >>> _within(np.array([0]), dims, 1, np.array([21, 42])).tolist()  # cells (1, 1, 1) and (2, 2, 2)
    [True, False]
    """
    size = int(np.prod(dims))
    if size <= max(DENSE_CELLS, 4 * len(query)):
        grid = np.zeros(size, dtype=np.uint8)
        grid[keys] = 1
        if pad:
            grid = maximum_filter(grid.reshape(tuple(int(d) for d in dims)), size=2 * pad + 1, mode="constant").ravel()
        return grid.view(bool)[query]
    near = np.unique(keys)
    for stride in (dims[1] * dims[2], dims[2], 1):
        near = np.unique((near[:, None] + stride * np.arange(-pad, pad + 1)).ravel())
    return np.isin(query, near)


def _halves(quads: np.ndarray, corner: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The four half-diamonds (quad q_i, q_i+1) of each quad (4 Q,), their mesh edge's ends a, b and
    the partner half across each mesh edge (-1 at the border).

    A mesh edge lies in two quads, or in four where both its cells see two crossings of an
    ambiguous face in one component: there the halves pair up on the face's segments, whose two
    crossings share their corner with f > 0 (``corner`` (Q,), a key of that node per quad).
    """
    a = quads.ravel()
    b = quads[:, [1, 2, 3, 0]].ravel()
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    partner = np.full(len(a), -1, dtype=np.int64)
    _pair(partner, np.arange(len(a)), (lo, hi))
    crowded = np.flatnonzero(partner < 0)  # at the border, or among four
    _pair(partner, crowded, (lo[crowded], hi[crowded], np.repeat(corner, 4)[crowded]))
    return a, b, partner


def _pair(partner: np.ndarray, items: np.ndarray, keys: tuple) -> None:
    """Set ``partner`` of the items whose keys (a tuple of arrays) are shared by exactly one other."""
    order = np.lexsort(keys[::-1])
    same = np.ones(max(len(order) - 1, 0), dtype=bool)
    for k in keys:
        same &= k[order][1:] == k[order][:-1]
    start = np.flatnonzero(np.r_[True, ~same])
    size = np.diff(np.r_[start, len(order)])
    two = start[size == 2]
    i, j = items[order[two]], items[order[two + 1]]
    partner[i], partner[j] = j, i


def _hybrid(crossing: np.ndarray, fanned: np.ndarray, halves: tuple) -> np.ndarray:
    """Faces of the mesh whose vertices in ``fanned`` (a vertex mask) are marching-cubes fans.

    ``crossing`` (Q,) the vertex index of each quad's edge crossing, ``halves`` from :func:`_halves`.
    Every quad is cut at its crossing into four half-diamonds; two halves on the same mesh edge
    with a fanned end are cut along the crossings instead.
    """
    a, b, partner = halves
    c = np.repeat(crossing, 4)
    cut = (partner >= 0) & (fanned[a] | fanned[b])
    keep = ~cut
    faces = [np.stack([c[keep], a[keep], b[keep]], axis=1)]
    # the diamond (p, v, p', w) of the halves (p, v, w) and (p', w, v), cut along p p': each half
    # gives the triangle at its first end
    h = np.flatnonzero(cut)
    faces.append(np.stack([c[h], a[h], c[partner[h]]], axis=1))
    return np.concatenate(faces)


def _unfold(
    quads: np.ndarray,
    corner: np.ndarray,
    crossing_points: np.ndarray,
    x: np.ndarray,
    mass: np.ndarray,
    confined: np.ndarray,
    origin: np.ndarray,
    h: np.ndarray,
    rounds: int = UNFOLD_ROUNDS,
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """Faces and vertices with the vertices of intersecting faces turned into marching-cubes fans
    at their mass points, round by round; the number of intersecting pairs left, and the vertices
    fanned (moved to their mass points).

    ``quads`` (Q, 4) counter-clockwise seen from outside, ``corner`` as in :func:`_halves`;
    ``crossing_points`` (Q, 3) the roots on the quads' edges (appended to the vertices);
    ``x``, ``mass`` (V, 3) strictly inside their cells; ``confined`` (V,) whether a vertex's cell
    is proved free of folds (``dual_contouring._confined``): only pairs with a face holding a vertex
    of another cell are searched, and only the quads near those faces can change (the others'
    halves come out as they are).  The ends of a mesh edge in four quads start fanned (their fans
    hold no such edge: the mesh becomes manifold there).
    """
    n, nq = len(x), len(quads)
    verts = np.concatenate([x, crossing_points])
    plain = _quad_halves(quads, n)  # the halves (crossing, q_i, q_i+1) of every quad
    if confined.all():
        return plain, verts, 0, np.zeros(0, dtype=np.int64)
    exposed = np.concatenate([~confined, np.zeros(nq, dtype=bool)])
    # the region: quads with a vertex of a face that may meet a watched face (a watched face's
    # partners, the vertices that may be fanned, and the halves their fans cut all lie in it)
    near = _near(verts, plain, exposed[plain].any(axis=1), origin, h)
    candidate = np.zeros(n + nq, dtype=bool)
    candidate[plain[near].ravel()] = True
    del near
    inside = candidate[:n][quads].any(axis=1)
    outside = plain.reshape(nq, 4, 3)[~inside].reshape(-1, 3)
    del plain, candidate
    region = np.flatnonzero(inside)
    crossing = n + region
    halves = _halves(quads[region], corner[region])
    fanned = np.zeros(n, dtype=bool)
    a, b, partner = halves
    edge_key = np.minimum(a, b) * n + np.maximum(a, b)
    _, inverse, count = np.unique(edge_key, return_inverse=True, return_counts=True)
    crowded = count[inverse] > 2
    del edge_key, inverse, count
    fanned[a[crowded]] = fanned[b[crowded]] = True
    del crowded
    verts[fanned.nonzero()[0]] = mass[fanned]
    bad = np.zeros((0, 2), dtype=np.int64)
    for round_ in range(rounds + 1):
        faces = _hybrid(crossing, fanned, halves)
        watch = exposed[faces].any(axis=1)
        if not watch.any():
            break
        near = _near(verts, faces, watch, origin, h)  # on the faces near the watched ones, and their vertices only
        used, local = _renumber(faces[near], len(verts))
        bad = near[_intersecting_pairs(verts[used], local, origin, h, watch[near])]
        if len(bad) == 0 or round_ == rounds:
            break
        touched = np.unique(faces[bad.ravel()])
        touched = touched[touched < n]
        new = touched[~fanned[touched]]
        if len(new) == 0:
            break  # only fans left among the intersecting faces
        fanned[new] = True
        verts[new] = mass[new]
    return np.concatenate([outside, faces]), verts, len(bad), np.flatnonzero(fanned)


def _without_folds(
    quads: np.ndarray,
    corner: np.ndarray,
    crossing_points: np.ndarray,
    x: np.ndarray,
    mass: np.ndarray,
    confined: np.ndarray,
    origin: np.ndarray,
    h: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_unfold`'s faces and vertices, and the vertices moved to their mass points (fanned), with a
    warning when intersecting pairs are left."""
    faces, x, left, fanned = _unfold(quads, corner, crossing_points, x, mass, confined, origin, h)
    if left:
        warnings.warn(
            f"polygonize: {left} pairs of faces still intersect after {UNFOLD_ROUNDS} rounds of "
            "marching-cubes fallback (features thinner than a cell: a finer resolution separates them)",
            RuntimeWarning,
            stacklevel=4,
        )
    return faces, x, fanned
