"""Manifold dual contouring from exact Hermite data: sharp edges and corners come out sharp.

Marching cubes puts its vertices on grid edges, so a crease of a CAD part that runs between
them is cut into a chamfer.  Dual contouring (Ju, Losasso, Schaefer and Warren 2002) puts one
vertex inside each cell the surface crosses, where the tangent planes of the crossings on the
cell's edges meet: for crossings p_i with unit normals n_i it minimises the quadratic error
function

    E(x) = sum_i (n_i . (x - p_i))^2 = x^T A^T A x - 2 x^T A^T b + b^T b,   (QEF)

rows n_i^T of A, b_i = n_i . p_i.  Here p_i is the root of f on the edge (bracketed root finding
in float64, :func:`.roots._bracketed_roots`) and n_i = grad f(p_i) / |grad f(p_i)| by autograd:
exact Hermite data.  The QEF is solved about the mass point m (the mean of the p_i) with the
pseudo-inverse of A^T A, eigenvalues below ``SINGULAR_CUTOFF`` of the largest set to zero, so
x = m + (A^T A)^+ (A^T b - A^T A m): on a flat or smooth patch (one significant direction) the
vertex moves from m along the normal only; along a crease (two) it lands on the crease; at a
corner (three) on the corner.  The vertex is clamped to its cell.

Manifold output (Schaefer, Ju and Warren 2007, "Manifold dual contouring"): a cell whose sign
configuration has several surface components (as marching cubes would triangulate it) gets one
vertex per component, each from its own edges; a face with four crossings joins them so that
the corners with f > 0 stay apart (the choice depends on the face's values only, so the two
cells sharing the face agree).  Every crossing edge then gives one quad, joining the vertices of
the four cells around it that hold its component; the quad is cut at its edge's crossing into
four triangles (crossing, v_i, v_i+1), so that the crossing, a point of f = 0, is a vertex too.

Smooth patches: a vertex whose QEF has one significant direction is moved onto f = 0 by a Newton
step along grad f (when it stays in its cell), so that spheres and TPMS come out at least as
accurate as projected marching cubes.

No self-intersections, proved where it can be and searched where it cannot: with every vertex
strictly inside its cell, the triangles' parts in a cell with one surface component and two
crossings per face form a cone over a simple polygon on the cell's boundary, which cannot meet
itself or its neighbours (:func:`_confined`).  Only faces with a vertex in the other cells
(sheets closer than a cell) are searched for intersecting pairs; there the cells involved fall
back to marching cubes' polygon, fanned from their mass points (:mod:`pyfrep_core.meshing.folds`).

Memory and time: the octree's leaf blocks are sampled and contoured in slabs along x, about
``SLAB_POINTS`` samples for all workers together, in equal shares (samples, Hermite data and QEFs
of those slabs only; a slab's last cell layer is carried to the next one's quads); what grows
with the surface is the mesh itself and the whole-mesh passes (unbiasing, folds).  On the CPU
``WORKERS`` threads take slabs side by side: the per-edge, per-cell and per-triangle passes are
compiled loops (:mod:`pyfrep_core.meshing.loops`) and a compiled model's kernels run without the
GIL, so the two overlap.  The mesh does not depend on how the slabs are cut or on the threads
(their sums are taken in order).

>>> from pyfrep_core import block
>>> m = dual_contour(lambda x: block(x, vertex=(-0.5, -0.5, -0.5), dx=1, dy=1, dz=1), ((-1.0,) * 3, (1.0,) * 3), 24)
>>> round(m.volume(), 12)   # the cube's corners and edges exactly: volume 1
1.0
"""

from __future__ import annotations

import contextlib
import threading
import warnings
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np
import torch

from .._threads import intra_op_threads
from ..model import check_bounds
from ..progress import Progress
from .folds import _without_folds
from .grid import CHUNK_POINTS, _check_memory, _chunk_points, _resolution, _return_freed_memory, grid_axes
from .loops import (
    _edge_points,
    _edge_vertices,
    _gather_rows,
    _mark_used,
    _move_in_cells,
    _number_used,
    _owned_quads,
    _qef_sums,
    _renumber,
    _solve_qefs,
    _take_rows,
    _unbias_requests,
    _unbias_scale,
    _unit_normals,
    _unit_rows,
)
from .mesh_type import Mesh
from .octree import Samples, prune, sample_blocks
from .roots import _bound, _bracketed_roots, _normals, _value_and_grad

__all__ = ["dual_contour", "SINGULAR_CUTOFF", "LEAF_BLOCK"]

SINGULAR_CUTOFF = 0.05  # relative eigenvalue of A^T A below which a direction is free (a crease of > 25 degrees stays)
# cells per leaf block edge: the octree's finest interval test.  Blocks of 4 cells would drop about
# a third of the samples of the 8-cell blocks around a surface, but at the price of a last level of
# bounds eight times larger, on one thread (interval arithmetic is torch's dispatch, under the GIL),
# while the samples are taken on all the workers: 8 is 0-15% faster from 128^3 to 1024^3, the same mesh
LEAF_BLOCK = 8
# samples taken and contoured at a time by all workers (about 200 MB; in points, not blocks: the
# octree's leaves are twice as large where the surface crowds them)
SLAB_POINTS = 1 << 21
WORKERS = 2  # threads meshing slabs side by side on the CPU
TRIM_QUADS = 1 << 21  # quads (about 400 MB of slab data) above which freed heap pages are handed back between passes
INTERIOR = 1e-6  # cells: vertices kept this far inside their cells, crossings this far from the edges' ends
# an edge's root: secant steps, then the few edges still moving (f bends sharply in their bracket: 4 %
# of the Fig. 1 part's after 6 steps at 128^3) narrowed twice by multisection, to 1/1089 of their bracket
# at most (in 2 calls of f, where 6 more secant steps left crossings up to 5e-3 cells off f = 0)
SECANT_STEPS = 6
SECTIONS = 2


# ----------------------------------------------------------------------------- cube tables

_CORNER = np.array([(c & 1, c >> 1 & 1, c >> 2 & 1) for c in range(8)], dtype=np.int64)


def _edge_corners() -> np.ndarray:
    """Corners (12, 2) of the cube's edges; edge ``4 a + db + 2 dc`` runs along axis a at offsets
    db, dc along the axes (a + 1) % 3, (a + 2) % 3."""
    out = np.zeros((12, 2), dtype=np.int64)
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for db in (0, 1):
            for dc in (0, 1):
                start = np.zeros(3, dtype=np.int64)
                start[b], start[c] = db, dc
                end = start.copy()
                end[a] = 1
                out[4 * a + db + 2 * dc] = (_corner_index(start), _corner_index(end))
    return out


def _corner_index(offset: np.ndarray) -> int:
    return int(offset[0] + 2 * offset[1] + 4 * offset[2])


_EDGE_CORNERS = _edge_corners()


def _components() -> tuple[np.ndarray, np.ndarray]:
    """Surface components per sign configuration: component (256, 12) of each crossing edge (-1: no
    crossing) and their number (256,).

    Crossing edges on a face are joined in pairs (the face's piece of the surface boundary): two
    crossings are one pair; four (an ambiguous face: diagonal corners alike) are paired around
    each corner with f > 0, which keeps those corners apart.  A component is a cycle of pairs.
    """
    comp = np.full((256, 12), -1, dtype=np.int8)
    count = np.zeros(256, dtype=np.int8)
    faces = []
    for a in range(3):
        for side in (0, 1):
            on = [e for e in range(12) if all(_CORNER[c][a] == side for c in _EDGE_CORNERS[e])]
            faces.append(on)
    for cfg in range(256):
        inside = [(cfg >> c) & 1 for c in range(8)]
        crossing = [inside[_EDGE_CORNERS[e][0]] != inside[_EDGE_CORNERS[e][1]] for e in range(12)]
        parent = list(range(12))

        def find(e: int, parent: list[int] = parent) -> int:
            while parent[e] != e:
                e = parent[e]
            return e

        for on in faces:
            cut = [e for e in on if crossing[e]]
            if len(cut) == 2:
                parent[find(cut[0])] = find(cut[1])
            elif len(cut) == 4:  # join the two edges that meet at each corner with f > 0
                for c in {int(x) for e in cut for x in _EDGE_CORNERS[e]}:
                    if inside[c]:
                        pair = [e for e in cut if c in _EDGE_CORNERS[e]]
                        parent[find(pair[0])] = find(pair[1])
        roots: dict[int, int] = {}
        for e in range(12):
            if crossing[e]:
                comp[cfg, e] = roots.setdefault(find(e), len(roots))
        count[cfg] = len(roots)
    return comp, count


_COMPONENT, _N_COMPONENTS = _components()


def _confined() -> np.ndarray:
    """(256,) whether a sign configuration's cell is proved free of folds: one surface component.

    Each quad is cut at its edge's crossing into four triangles (crossing, v_i, v_i+1); the segment
    from v_i to v_i+1 (in two cells sharing a face) meets that face at a point q inside it.  So
    the triangles' parts in a cell with one vertex v make the cone from v over a closed polygon on
    the cell's boundary: on each face a path crossing - q - crossing (or the straight segment
    crossing - crossing where a fan cuts the diamond).  On a face with two crossings that path is
    simple.  On a face with four, between two cells of one component each, the edge joining their
    vertices lies in four quads: both start fanned, and their paths there are marching cubes' two
    segments, which keep the corners with f > 0 apart and do not cross.  (Where the other cell has
    two components, the faces over the two paths hold its vertices, so the search below sees them.)
    The polygon is then simple, and the cone from a point strictly inside a convex cell over a
    simple curve on its boundary does not meet itself (each ray from v leaves the cell once).
    Neighbouring cells share only their common paths on their common faces.  Faces can therefore
    intersect only inside cells of two or more components: the fold search looks at faces with a
    vertex there only.
    """
    return _N_COMPONENTS == 1


_CONFINED = _confined()


# ----------------------------------------------------------------------------- the mesher


def dual_contour(
    f: Callable,
    bounds: Any,
    resolution: int | tuple[int, int, int] = 128,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    tol: float | None = None,
    block: int = LEAF_BLOCK,
    progress: Callable[[int], Progress] | None = None,
) -> Mesh:
    """Mesh f = 0 by octree dual contouring at the voxel size of a ``resolution``^3 grid.

    Parameters
    ----------
    f : callable (N, 3) -> (N,) on torch tensors, or a Model.
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)).
    resolution : samples per axis of the equivalent dense grid (cells: resolution - 1).
    dtype : dtype of the node samples (classes f > 0 / f <= 0); roots, normals and vertices are float64.
    device : where f is evaluated.
    tol : step length (length units) at which an edge's root is accepted; None: 1e-7 cells.
    block : cells per leaf block of the octree (the finest interval test).
    progress : ``progress(n)`` gives the :class:`pyfrep_core.progress.Progress` of the n chunks of
        samples (:func:`pyfrep_core.polygonize` builds it from its callback, stop and progress);
        stopped, an empty mesh comes back.

    Returns
    -------
    Mesh: vertices (V, 3) float64, faces (F, 3) int64 oriented outward, unit normals -grad f / |grad f|
    and ``gradient`` at the vertices.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> m = dual_contour(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 32)
    >>> abs(m.volume() - 4.18879) < 0.02
    True
    """
    res = _resolution(resolution, 3)
    lo, hi = check_bounds(bounds, 3)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    axes = grid_axes((lo, hi), res)
    spacing = np.array([a[1] - a[0] for a in axes])
    cells = tuple(r - 1 for r in res)
    tree = prune(f, lo, spacing, cells, int(block))
    block = tree.block
    if not tree.certified:
        _check_memory(res, dtype)  # every block is sampled: the dense grid's memory
    workers = WORKERS if torch.device(device).type == "cpu" else 1
    slabs = _slabs(tree.blocks, block, cells[0], max(1, SLAB_POINTS // ((block + 1) ** 3 * workers)), workers)
    per_chunk = max(1, _chunk_points(f, CHUNK_POINTS) // (block + 1) ** 3)  # sample_blocks' chunks
    n_chunks = sum(-(-len(part) // per_chunk) for part, _, _ in slabs)
    empty = Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)))
    # f at its parameters, bound once for the roots, gradients and vertices (a compiled model: its kernels,
    # called directly); the samples and bounds take the model as it is
    bound = _bound(f, device)
    with (
        progress(max(n_chunks, 1)) if progress is not None else contextlib.nullcontext() as bar,
        ThreadPoolExecutor(workers, thread_name_prefix="pyfrep-dc") as pool,
    ):
        counted = _Counted(bar) if bar is not None else None

        def on_worker(fn: Callable, *args: Any) -> Future:
            """fn(*args) on a worker (one torch thread each)."""

            def one() -> Any:
                with intra_op_threads(1 if workers > 1 else None):
                    return fn(*args)

            return pool.submit(one)

        # each slab of whole block layers along x is sampled and contoured by one worker, ``workers``
        # slabs at a time (the compiled loops and torch's kernels run without the GIL): the memory of
        # the samples and of their Hermite data stays bounded.  A slab's last cell layer (its
        # vertices) is carried to the next slab, and its vertices are numbered after those of the
        # slabs before it: ``ready[k]`` is slab k's (carry numbered from 0, vertex count) once it is
        # sampled (None: stopped), so a worker finds its Hermite data before it waits for the slabs
        # before it, and then waits for their samples only, never for their contouring
        ready: list[Future] = [Future() for _ in slabs]
        stopped = threading.Event()  # asked to stop: the slabs not yet begun return at once

        def slab(k: int) -> _Vertices | None:
            part, first, end = slabs[k]
            try:
                s = None if stopped.is_set() else sample_blocks(f, axes, part, block, dtype, device, counted)
                if s is None:
                    stopped.set()
                    ready[k].set_result(None)
                    return None
                ready[k].set_result(_last_layer(s, end))
                hermite = _hermite(bound, s, lo, spacing, device, tol) if len(s.f0) else None
                before = [r.result() for r in ready[:k]]  # submitted first: never wait on this one
            except BaseException as error:
                if not ready[k].done():
                    ready[k].set_exception(error)  # the next slabs raise it too, instead of waiting
                raise
            if any(b is None for b in before):
                return None
            if hermite is None:
                return _NO_SURFACE
            offset = sum(count for _, count in before)
            carry = _numbered(before[-1][0], offset - before[-1][1]) if k else None
            return _slab(s, hermite, carry, first, end, offset, lo, hi, spacing, cells, bound, device)

        # the slabs' vertices and quads joined in order by this thread while the workers go on
        joined = _Joined(len(slabs))
        for job in [on_worker(slab, k) for k in range(len(slabs))]:
            part = job.result()
            if part is None:
                return empty
            if part is not _NO_SURFACE:
                joined.append(part)
            del part
        if joined.quads == 0:
            warnings.warn(
                "polygonize: f does not change sign inside the bounds; empty mesh", RuntimeWarning, stacklevel=2
            )
            return empty
        return _contour(bound, joined.result(), lo, hi, spacing, device, on_worker, workers)


def _slabs(blocks: np.ndarray, block: int, ncell_x: int, limit: int, workers: int) -> list[tuple[np.ndarray, int, int]]:
    """The leaf blocks in slabs of whole layers along x, each with its first cell layer and the end of
    its cell layers: a multiple of ``workers`` slabs of about equal numbers of blocks (the slabs of a
    group end together), about ``limit`` blocks or fewer each (at least one layer).

    >>> blocks = np.array([(x, y, 0) for x in range(4) for y in range(x + 1)])  # 1, 2, 3, 4 blocks a layer
    >>> [(len(part), first, end) for part, first, end in _slabs(blocks, 4, 16, 100, 2)]
    [(6, 0, 12), (4, 12, 16)]
    """
    order = np.argsort(blocks[:, 0], kind="stable")
    blocks = blocks[order]
    layer, start = np.unique(blocks[:, 0], return_index=True)
    before = np.append(start, len(blocks))  # blocks before each layer, and all of them
    count = min(len(layer), -(-len(blocks) // (limit * workers)) * workers)
    # cut at the layer boundaries nearest to equal shares
    share = len(blocks) * np.arange(1, count) / count
    cut = np.clip(np.searchsorted(before, share), 1, len(layer))
    nearer_below = share - before[cut - 1] < before[cut] - share
    cut = np.unique(np.concatenate([[0], np.where(nearer_below, cut - 1, cut), [len(layer)]]))
    out = []
    for first, last in zip(cut[:-1], cut[1:]):
        part = blocks[before[first] : before[last]]
        out.append((part, int(layer[first]) * block, min(int(layer[last - 1] + 1) * block, ncell_x)))
    return out


def _hermite(
    f: Callable, s: Samples, lo: np.ndarray, spacing: np.ndarray, device: Any, tol: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roots of f on the crossing edges (E, 3), unit normals grad f / |grad f| there (E, 3) and
    grad f (E, 3), float64.  A root is kept ``INTERIOR`` of a cell from the edge's ends (a root on a
    grid node would touch the crossings of the other edges there)."""
    start = lo + s.edge_node * spacing
    h = spacing[s.edge_axis]
    rows = np.arange(len(start))
    start_axis = start[rows, s.edge_axis]
    with np.errstate(divide="ignore", invalid="ignore"):
        c = s.f0 / (s.f0 - s.f1)  # marching cubes' linear interpolation
    c = np.where(np.isfinite(c), np.clip(c, 0.0, 1.0), 0.5)
    step_tol = 1e-7 * float(spacing.min()) if tol is None else float(tol)
    slope = s.f1 - s.f0
    root, rest, c_rest = _bracketed_roots(
        f, start, start_axis, h, s.edge_axis, c, slope, s.f0, s.f1, step_tol, device, SECANT_STEPS, SECTIONS
    )
    root[rest] = c_rest  # f not finite in the bracket: the best estimate
    root = np.clip(np.where(np.isfinite(root), root, c), INTERIOR, 1.0 - INTERIOR)
    points = _edge_points(rows, start, s.edge_axis, start_axis, h, root)  # component-first (compiled kernels')
    _, g = _value_and_grad(f, points, device)
    normal, good = _unit_normals(g, 1.0)
    # no gradient there: the edge's own direction, toward increasing f
    bad = np.flatnonzero(~good)
    normal[bad, s.edge_axis[bad]] = np.sign(s.f1[bad] - s.f0[bad])
    return points, normal, g


class _Vertices(NamedTuple):
    """One slab's vertices and the quads of the crossing edges it owns (global vertex indices).

    x, mass, gradient (NaN where not smooth-projected) : (V, 3) per vertex; cell : (V, 3) int32 its cell;
    confined : (V,) bool its cell is proved free of folds (:func:`_confined`);
    quads : (Q, 4) int64 oriented outward (toward f <= 0); corner : (Q,) int64 flat key of the edge's
    end with f > 0 (it pairs the crossings on a face); points : (Q, 3) the edge's root; point_gradient :
    (Q, 3) grad f there.
    """

    x: np.ndarray
    mass: np.ndarray
    gradient: np.ndarray
    cell: np.ndarray
    confined: np.ndarray
    quads: np.ndarray
    corner: np.ndarray
    points: np.ndarray
    point_gradient: np.ndarray


def _slab(
    s: Samples,
    hermite: tuple[np.ndarray, np.ndarray, np.ndarray],
    carry: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    first: int,
    end: int,
    offset: int,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    cells: tuple[int, int, int],
    f: Callable,
    device: Any,
) -> _Vertices:
    """Vertices of the mixed cells of the slab of cell layers [first, end) along x, numbered from
    ``offset``, and the quads of the crossing edges that start in it (node x in [first, end)).

    ``s`` holds every edge of these cells (their blocks' nodes reach layer ``end``), ``hermite``
    their roots, unit normals and grad f (:func:`_hermite`); ``carry`` is the previous slab's last
    cell layer (flat keys, global first vertex, configuration), whose vertices the quads of edges on
    layer ``first`` need (:func:`_last_layer`).
    """
    points, normal, point_gradient = hermite
    ncell = np.asarray(cells, dtype=np.int64)
    # vertices: one per (cell, component)
    n_comp, first_vertex, n_vert = _numbering(s, offset)
    # the cells to look edges' neighbours up in: the carried layer (keys below the slab's), then the slab's
    if carry is None:
        carry = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.uint8))
    keys = np.concatenate([carry[0], s.cell_key])
    config = np.concatenate([carry[2], s.config])
    base = np.concatenate([carry[1], first_vertex])  # global first vertex of each cell
    # the up to four cells around each crossing edge, and the vertex of the edge's component there
    a = s.edge_axis
    vert = _edge_vertices(keys, config, base, s.edge_node, a, ncell, _COMPONENT)
    # QEF per vertex of the slab from its edges: A^T A (6 entries), A^T b, mass point (the carried
    # layer's QEFs are done)
    sums = _qef_sums(vert, normal, points, offset, n_vert)
    # the vertices' cells, less a margin: every vertex strictly inside its cell (see _confined); a
    # cell crossed by two or more sheets (a feature thinner than the cell): their QEF points, each
    # free in the whole cell, can cross the other sheet; their mass points stay between their own edges
    vcell = np.repeat(s.cell, n_comp, axis=0)
    shared = np.repeat(n_comp > 1, n_comp)
    x, mass, rank = _solve_qefs(sums, vcell, shared, lo, hi, spacing, INTERIOR, SINGULAR_CUTOFF)
    del sums
    x, smooth_gradient = _project_smooth(f, x, rank, vcell, lo, hi, spacing, device)
    # quads of the edges starting in the slab whose four cells lie in the grid
    quads = _owned_quads(vert, s.edge_node, a, s.f0, points, point_gradient, first, end, ncell)
    return _Vertices(x, mass, smooth_gradient, vcell.astype(np.int32), np.repeat(_CONFINED[s.config], n_comp), *quads)


def _last_layer(s: Samples, end: int) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], int]:
    """A slab's carry for the next one (its last cell layer ``end - 1``: flat keys, first vertex with the
    slab's vertices numbered from 0, configuration) and its number of vertices."""
    _, first_vertex, n_vert = _numbering(s, 0)
    last = s.cell[:, 0] == end - 1
    return (s.cell_key[last], first_vertex[last], s.config[last]), n_vert


def _numbered(
    carry: tuple[np.ndarray, np.ndarray, np.ndarray], offset: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A carry of :func:`_last_layer` with its slab's vertices numbered from ``offset``."""
    keys, first_vertex, config = carry
    return keys, first_vertex + offset, config


def _numbering(s: Samples, offset: int) -> tuple[np.ndarray, np.ndarray, int]:
    """A slab's vertices, one per surface component of each mixed cell: their number per cell (C,),
    each cell's first vertex numbered from ``offset`` (C,), and their count."""
    n_comp = _N_COMPONENTS[s.config].astype(np.int64)
    first_vertex = np.cumsum(n_comp) - n_comp + offset
    return n_comp, first_vertex, int(n_comp.sum())


_NO_SURFACE = object()  # a slab without crossing edges


class _Joined:
    """The slabs' :class:`_Vertices` appended in order, field by field, into buffers sized for all the
    slabs from the first one's share (one in ``slabs``, plus a margin) and grown by half when full:
    each slab's copy is freed once appended, so the whole mesh is never held twice.

    >>> parts = [_Vertices(*([np.full((n, 3), float(n))] * 5 + [np.arange(n)] * 4)) for n in (2, 1, 4)]
    >>> joined = _Joined(2)
    >>> for part in parts:
    ...     joined.append(part)
    >>> joined.result().x[:, 0].tolist(), joined.quads
    ([2.0, 2.0, 1.0, 4.0, 4.0, 4.0, 4.0], 7)
    """

    def __init__(self, slabs: int) -> None:
        self.slabs = slabs
        self.buffers: list[np.ndarray] = []
        self.sizes: list[int] = []
        self.quads = 0

    def append(self, part: _Vertices) -> None:
        if not self.buffers:
            self.buffers = [np.empty((int(len(a) * self.slabs * 1.1) + 16, *a.shape[1:]), a.dtype) for a in part]
            self.sizes = [0] * len(part)
        for i, a in enumerate(part):
            size, buffer = self.sizes[i], self.buffers[i]
            if size + len(a) > len(buffer):
                grown = np.empty((max(size + len(a), len(buffer) * 3 // 2), *a.shape[1:]), a.dtype)
                grown[:size] = buffer[:size]
                self.buffers[i] = buffer = grown
            buffer[size : size + len(a)] = a
            self.sizes[i] = size + len(a)
        self.quads += len(part.quads)

    def result(self) -> _Vertices:
        out = _Vertices(*[buffer[:size] for buffer, size in zip(self.buffers, self.sizes)])
        self.buffers = []
        return out


class _Counted:
    """A progress that counts the chunks done, whichever thread and slab they come from (in order)."""

    def __init__(self, bar: Progress) -> None:
        self.bar, self.done, self.lock = bar, 0, threading.Lock()

    def update(self, step: int) -> bool:
        with self.lock:
            self.done += 1
            return self.bar.update(self.done - 1)


def _contour(
    f: Callable,
    v: _Vertices,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    device: Any,
    on_worker: Callable[..., Future],
    workers: int,
) -> Mesh:
    """The mesh from all slabs' vertices and quads ``v`` (joined): each quad cut at its crossing
    into four triangles, unbiasing, folds, compaction, grad f (``on_worker(fn, *args)`` runs on
    one of the ``workers`` while this thread goes on)."""
    # freed pages go back to the system only for large meshes: it bounds the peak there, and costs
    # their page faults again (a sixth of the time at 256^3) where memory is no concern
    trim = _return_freed_memory if len(v.quads) > TRIM_QUADS else lambda: None
    trim()  # the slabs' copies
    n = len(v.x)
    # quads oriented outward (toward f <= 0); cut at their crossings (vertices n, n + 1, ...)
    quads = v.quads
    v = v._replace(quads=None)
    x = _unbias(v.x, v.points, quads, v.gradient, v.point_gradient, v.cell, lo, hi, spacing, on_worker, workers)
    # grad f at the vertices in cells, on the workers while the folds are searched here (the few
    # vertices that a fold moves to their mass points get theirs again after)
    ranges = _ranges(n, workers)
    cell_gradient = [on_worker(_value_and_grad, f, x[a:b], device) for a, b in ranges]
    v = v._replace(x=None, gradient=None, cell=None)  # not needed any more: memory for what follows
    # where faces of cells that are not confined intersect, the marching-cubes fans of the cells involved
    parts_left = (quads, v.corner, v.points, x, v.mass, v.confined)
    point_gradient = v.point_gradient
    del v, quads  # what the folds need is in parts_left, handed over
    faces, verts, fanned = _without_folds(*parts_left, lo, spacing)
    del parts_left
    trim()
    used = _compact(faces, len(verts), on_worker, workers)  # faces renumbered in place
    if used is None:  # every vertex used (the surface stays off the bounds, nothing dropped): as they are
        gradient = np.concatenate([job.result()[1] for job in cell_gradient] + [point_gradient])
        moved = fanned
    else:
        kept = np.empty((len(used), 3))
        _take_rows(verts, used, kept)
        verts = kept
        in_cell = int(np.searchsorted(used, n))  # vertices in cells sorted first, then crossings
        gradient = np.empty_like(verts)
        for (a, b), job in zip(ranges, cell_gradient):  # each part's rows among those kept (sorted)
            first, last = np.searchsorted(used[:in_cell], [a, b])
            _take_rows(job.result()[1], used[first:last] - a, gradient[first:last])
        _take_rows(point_gradient, used[in_cell:] - n, gradient[in_cell:])  # known at the crossings
        moved = np.zeros(0, dtype=np.int64)
        if len(fanned) and in_cell:  # the fanned vertices' rows after compaction, where they are used
            moved = np.searchsorted(used[:in_cell], fanned)
            moved = moved[(moved < in_cell) & (used[np.minimum(moved, in_cell - 1)] == fanned)]
    del cell_gradient, x, point_gradient, used
    if len(moved):  # grad f again where a fold moved them to their mass points
        gradient[moved] = _value_and_grad(f, verts[moved], device)[1]
    # -grad f / |grad f|, the rows in parts on the workers
    unit = (np.zeros_like(gradient), np.empty(len(gradient), dtype=np.bool_))
    ranges = _ranges(len(gradient), workers)
    for job in [on_worker(_unit_rows, gradient[a:b], -1.0, unit[0][a:b], unit[1][a:b]) for a, b in ranges]:
        job.result()
    return Mesh(verts, faces, _normals(gradient, verts, faces, unit), gradient=gradient)


def _compact(faces: np.ndarray, n_vertices: int, on_worker: Callable[..., Future], workers: int) -> np.ndarray | None:
    """The vertices (U,) that ``faces`` (F, 3) use, in order; ``faces`` renumbered to them in place (the
    passes over the faces in ``workers`` parts of rows, side by side).  None where they use every
    vertex (``faces`` unchanged).

    >>> faces = np.array([[5, 2, 7], [7, 2, 9]])
    >>> with ThreadPoolExecutor(2) as pool:
    ...     kept = _compact(faces, 10, pool.submit, 2)
    ...     every = _compact(faces, 4, pool.submit, 2)
    >>> kept.tolist(), faces.tolist(), every
    ([2, 5, 7, 9], [[1, 0, 2], [2, 0, 3]], None)
    """
    index = np.full(n_vertices, -1, dtype=np.int64)
    parts = [faces[a:b] for a, b in _ranges(len(faces), workers)]
    for job in [on_worker(_mark_used, part, index) for part in parts]:
        job.result()
    kept = _number_used(index)
    if len(kept) == n_vertices:
        return None
    for job in [on_worker(_renumber, part, index) for part in parts]:
        job.result()
    return kept


def _ranges(n: int, parts: int) -> list[tuple[int, int]]:
    """``parts`` contiguous row ranges [a, b) of about equal length covering n rows (empty ones left out).

    >>> _ranges(5, 2), _ranges(1, 2)
    ([(0, 2), (2, 5)], [(0, 1)])
    """
    ends = [n * k // parts for k in range(parts + 1)]
    return [(a, b) for a, b in zip(ends[:-1], ends[1:]) if b > a]


def _project_smooth(
    f: Callable,
    x: np.ndarray,
    rank: np.ndarray,
    cell: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    device: Any,
) -> tuple[np.ndarray, np.ndarray]:
    """Vertices on smooth patches (rank 1) moved (in place) onto f = 0 by a Newton step along grad f, where
    they stay in their cell (the QEF put them within O(h^2) of the surface; one step leaves
    O(h^4)); and grad f (V, 3) where it was evaluated (NaN elsewhere)."""
    smooth = np.flatnonzero(rank == 1)
    gradient = np.full_like(x, np.nan)
    if len(smooth) == 0:
        return x, gradient
    value, g = _value_and_grad(f, _gather_rows(x, smooth), device)
    g2 = np.einsum("ij,ij->i", g, g)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(g2 > 0, value / g2, 0.0)
    _move_in_cells(x, smooth, scale, g, cell, lo, hi, spacing, INTERIOR, 1e-9)  # Newton: only within the cell
    gradient[smooth] = g
    return x, gradient


def _unbias(
    x: np.ndarray,
    points: np.ndarray,
    quads: np.ndarray,
    gradient: np.ndarray,
    point_gradient: np.ndarray,
    cell: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    spacing: np.ndarray,
    on_worker: Callable[..., Future],
    workers: int,
) -> np.ndarray:
    """Smooth vertices (V, 3) moved in place along the normal so that the triangles' mean distance to f = 0
    vanishes (each kept inside its cell: ``cell`` (V, 3) indices into the grid from ``lo`` to ``hi``,
    cells ``spacing``).  The triangles are the quads' (Q, 4) halves (crossing, q_i, q_i+1), the
    crossings ``points`` (Q, 3) fixed on f = 0.

    Flat triangles with their corners on a curved surface lie on its concave side: the chord
    error e(x) is a quadratic vanishing at the corners, e = a l1 l2 + b l2 l3 + c l3 l1 in
    barycentric coordinates, whose mean over the triangle, (a + b + c) / 12, is 3/4 of its value
    at the centroid, (a + b + c) / 9.  A triangle moves by the mean of its corners' shifts, and
    the crossing stays: each of the two vertices is asked to move by 3/2 x 3/4 = 9/8 of the
    centroid's depth (triangles whose vertices are both smooth); a vertex moves by the mean of
    what its triangles ask.  The depth comes from the corners' normals, which are known (every
    corner is on f = 0 with its grad f), so f is not evaluated again (:func:`.loops._unbias_requests`;
    against f / |grad f| at the centroids it changes the Fig. 1 part's volume error at 256^3 by 1e-7
    of 3e-6).  This removes the bias that would otherwise make the volume err by O(h^2) (the
    cylinders' holes of the Fig. 1 part) and halves the largest distance to the surface.  The
    requests of the quads' ``workers`` parts are gathered through ``on_worker(fn, *args)``.
    """
    # the quads in ``workers`` parts, each part's requests in a row of its own (no shared sums)
    total, count = np.zeros((workers, len(x))), np.zeros((workers, len(x)))
    jobs = [
        on_worker(_unbias_requests, quads[a:b], points[a:b], point_gradient[a:b], x, gradient, t, c)
        for (a, b), t, c in zip(_ranges(len(quads), workers), total, count)
    ]
    for job in jobs:
        job.result()
    scale = _unbias_scale(total, count, gradient)
    del total, count
    _move_in_cells(x, np.arange(len(x)), scale, gradient, cell, lo, hi, spacing, INTERIOR, -1.0)  # outward: -grad f
    return x
