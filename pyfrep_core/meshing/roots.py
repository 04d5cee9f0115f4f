"""Marching-cubes vertices moved onto f = 0 in float64, grad f there, and normals.

Every vertex is moved along its marching-cubes edge by bracketed root finding (the edge's
two grid values bracket the root), with Newton steps along grad f
(:func:`pyfrep_core.diff.project_to_surface`) for the few vertices that do not lie strictly
inside an edge.  Normals are -grad f.

>>> import numpy as np
>>> _normals(np.array([[0.0, 0.0, -2.0]]), np.zeros((1, 3)), np.zeros((0, 3), dtype=np.int64))
array([[-0., -0.,  1.]])
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from .._array import validated_inputs
from ..compiled import CompiledModel
from ..diff import project_to_surface, value_and_grad
from ..evaluate import call
from ..model import Model
from .grid import _chunk_points
from .loops import _edge_points, _secant_step, _section_points, _section_step, _unit_normals

ROOT_CHUNK = 1 << 14  # points per float64 call of f (larger where f declares chunk_points: a compiled model)
SECTION_POINTS = 32  # points per edge of a multisection step (_bracketed_roots' sections)
SECTION_ROWS = 1 << 13  # edges per multisection call (their points: 6 MB)


def _records(a: np.ndarray) -> np.ndarray:
    """A C-contiguous (N, k) array as N records of k values: whole rows gathered or scattered as one item
    (fancy indexing row by row costs 2-3x more)."""
    return a.view(np.dtype((np.void, a.dtype.itemsize * a.shape[1])))[:, 0]


def _row_norms(x: np.ndarray) -> np.ndarray:
    """|x| of each row of (N, 3) x: ``np.linalg.norm(x, axis=1)`` (same sums in the same order), column-wise."""
    return np.sqrt(x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1] + x[:, 2] * x[:, 2])


def _tolerance(lo: Any, hi: Any) -> float:
    """100 ulp of the largest coordinate (project_to_surface's default tolerance)."""
    return 100.0 * float(np.finfo(np.float64).eps) * max(1.0, float(np.abs([lo, hi]).max()))


def _bound(f: Callable, device: Any) -> Callable:
    """f for the mesher's own points, plain float64 (N, 3) tensors inside checked bounds: a 3-D
    Model's defining function with its parameters bound once, as 0-d tensors.

    A Model's call reads its points' shape and its parameters' values on every call (80 us of
    Python under the GIL, against 50 us for the fused kernel on a few hundred points: the root
    finder's last steps); the defining function gets the same points and parameters here.  Any
    other f, or a Model with a batch of parameters, comes back as it is.

    >>> from pyfrep_core.models import fig1_part
    >>> x = torch.tensor([[0.1, 0.2, 0.3], [0.9, 0.0, 0.0]], dtype=torch.float64)
    >>> torch.equal(_bound(fig1_part, "cpu")(x), fig1_part(x))
    True
    """
    if not isinstance(f, Model) or f.dim != 3:
        return f
    params = {k: torch.as_tensor(v, dtype=torch.float64, device=device) for k, v in f.check().items()}
    if any(v.ndim for v in params.values()):
        return f
    if isinstance(f, CompiledModel):  # the fused kernel without the model call's checks on every call
        return f.values_kernel(**params)
    fn = f.fn

    def bound(x: torch.Tensor) -> torch.Tensor:
        return fn(x, **params)

    bound.chunk_points = getattr(f, "chunk_points", None)  # the chunks that suit f (_chunk_points)
    bound.__name__ = f.__name__
    return bound


def _f64(f: Callable, x: np.ndarray, device: Any) -> np.ndarray:
    """f at points x (N, 3) in float64, forward only, in chunks.

    Each chunk goes to f as a tensor of its own (not a view), in x's layout: a compiled model's kernel
    (:func:`_bound`) takes the component-first points of the root finders as they are.
    """
    if len(x) == 0:
        return np.zeros(0)
    device = torch.device(device)
    size = _chunk_points(f, ROOT_CHUNK)
    parts = []
    with torch.no_grad(), validated_inputs():  # points on grid edges: finite, not read again per primitive
        for s in range(0, len(x), size):
            parts.append(call(f, torch.as_tensor(x[s : s + size], dtype=torch.float64, device=device)))
    out = parts[0] if len(parts) == 1 else torch.cat(parts)
    return np.asarray(out.numpy() if out.device.type == "cpu" else out.cpu().numpy(), dtype=np.float64)


def _value_and_grad(f: Callable, x: np.ndarray, device: Any) -> tuple[np.ndarray, np.ndarray]:
    """f and grad f at points x (N, 3) in float64 (numpy out, grad f in x's layout): a bound compiled
    model's fused first-order kernel (:func:`_bound`), in chunks of its size, component-first; diff's
    chunked, parallel passes otherwise."""
    if len(x) == 0:
        return np.zeros(0), np.zeros((0, 3))
    fused = None if isinstance(f, Model) else getattr(f, "value_and_grad", None)
    if fused is not None:
        size, parts = _chunk_points(f, ROOT_CHUNK), []
        for s in range(0, len(x), size):
            t = torch.as_tensor(x[s : s + size], dtype=torch.float64, device=device)
            if t.stride() != (1, t.shape[0]):  # as the kernel takes them
                t = torch.empty_strided(t.shape, (1, t.shape[0]), dtype=t.dtype, device=t.device).copy_(t)
            parts.append(fused(t))
        if all(part is not None for part in parts):
            values, gradients = zip(*parts)
            value = (values[0] if len(values) == 1 else torch.cat(values)).cpu().numpy()
            gradient = (gradients[0] if len(gradients) == 1 else torch.cat(gradients)).cpu().numpy()
            # in x's layout, as diff's passes give it (the compiled loops that read it are compiled for it)
            if x.flags.c_contiguous:
                return value, np.ascontiguousarray(gradient)
            return value, np.asfortranarray(gradient) if x.flags.f_contiguous else gradient
    t = torch.as_tensor(x, dtype=torch.float64, device=device)
    hint = _chunk_points(f, 0)  # a compiled model's chunk size, else diff's default
    # a compiled model differentiates through its fused kernel (diff's passes find it): not bound
    g = f if isinstance(f, CompiledModel) else _bound(f, device)
    with validated_inputs():  # vertices and roots in their cells: finite, not read again
        value, gradient = value_and_grad(g, t, chunk=hint or None)
    return value.cpu().numpy(), gradient.cpu().numpy()


def _project_vertices(
    f: Callable,
    values: np.ndarray,
    index_verts: np.ndarray,
    origin: np.ndarray,
    spacing: np.ndarray,
    bounds: Any,
    device: Any,
    tol: float | None = None,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Vertices on f = 0 (float64), grad f there, and how many could not be moved.

    A vertex counts as on the surface when its first-order distance |f| / |grad f| is below
    100 ulp of the largest coordinate (project_to_surface's tolerance; 2.4e-14 in [-1.1, 1.1]^3).
    """
    if tol is not None and not tol > 0:
        raise ValueError(f"tol must be a positive distance, got {tol!r}")
    accept = _tolerance(*bounds) if tol is None else max(float(tol), _tolerance(*bounds))
    step_tol = 1e-11 * float(spacing.min()) if tol is None else accept
    # iterate until the next step is below step_tol; every result is then checked against `accept`
    verts, done = _roots_on_edges(f, values, index_verts, origin, spacing, step_tol, device)
    gradient = np.empty_like(verts)
    on_edge = np.flatnonzero(done)
    if len(on_edge):
        points = verts if len(on_edge) == len(verts) else _records(verts)[on_edge].view(np.float64).reshape(-1, 3)
        value, grad_on_edge = _value_and_grad(f, points, device)
        _records(gradient)[on_edge] = _records(np.ascontiguousarray(grad_on_edge))
        # an edge whose float32 grid signs were wrong in float64 has no root: check the residual
        # |f| / |grad f| (|grad f| at least the median, so that f = 0 where grad f vanishes passes)
        length = _row_norms(grad_on_edge)
        distance = np.abs(value) / np.maximum(length, np.median(length))
        done[on_edge[~(distance <= accept)]] = False
    rest = np.flatnonzero(~done)
    n_failed = 0
    if len(rest):
        # vertices on a grid node, slow on their edge, or failing the check: Newton along grad f
        cell = float(np.linalg.norm(spacing))
        start = torch.as_tensor(verts[rest], dtype=torch.float64, device=device)
        proj = project_to_surface(f, start, tol=accept, max_step=cell, max_distance=cell, warn=False)
        points, converged = proj.points.cpu().numpy(), proj.converged.cpu().numpy()
        ok = converged & np.all((points >= bounds[0]) & (points <= bounds[1]), axis=1)
        verts[rest[ok]] = points[ok]
        gradient[rest] = proj.gradient.cpu().numpy()
        failed = rest[~ok]
        n_failed = len(failed)
        if n_failed:  # back to where marching cubes put them
            verts[failed] = origin + index_verts[failed].astype(np.float64) * spacing
            gradient[failed] = _value_and_grad(f, verts[failed], device)[1]
    return verts, gradient, n_failed


# the bits of a marching-cubes vertex's coordinates that lie between grid nodes (x: 1, y: 2,
# z: 4) -> the axis of its grid edge; -1: not strictly inside one edge (on a node, or Lewiner's
# vertex inside a cell)
_EDGE_AXIS = np.array([-1, 0, 1, -1, 2, -1, -1, -1], dtype=np.int8)


def _grid_edges(index_verts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The marching-cubes vertices strictly inside one grid edge, and their edges.

    Returns their rows (K,), the edge's axis (K,), its grid node at t = 0 (K, 3) int64 (the
    other end is one step along the axis) and the vertex's position t in (0, 1) on it (K,)
    float64 (exact: t = index - floor(index) in the index's own float type).
    """
    index_verts = np.ascontiguousarray(index_verts)
    base = np.floor(index_verts)
    between = (index_verts != base).view(np.uint8)
    axis = _EDGE_AXIS[between[:, 0] | (between[:, 1] << 1) | (between[:, 2] << 2)]
    rows = np.flatnonzero(axis >= 0)
    axis = axis[rows].astype(np.intp)
    node = np.take(base, rows, axis=0)
    along = np.arange(len(rows)) * 3 + axis
    t = np.take(index_verts, rows, axis=0).reshape(-1)[along] - node.reshape(-1)[along]
    return rows, axis, node.astype(np.int64), t.astype(np.float64)


def _grid_points(index: np.ndarray, origin: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """World positions ``origin + index * spacing`` (N, 3) float64 of grid indices (N, 3), column by
    column (the same operations; a broadcast over rows of three runs 3x slower)."""
    points = np.array(index, dtype=np.float64, order="C")  # a copy
    for d in range(3):
        column = points[:, d]
        column *= spacing[d]
        column += origin[d]
    return points


def _flat_index(node: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Index in ``values.reshape(-1)`` (C order) of grid nodes (K, 3)."""
    return (node[:, 0] * shape[1] + node[:, 1]) * shape[2] + node[:, 2]


def _roots_on_edges(
    f: Callable,
    values: np.ndarray,
    index_verts: np.ndarray,
    origin: np.ndarray,
    spacing: np.ndarray,
    step_tol: float,
    device: Any,
    max_iter: int = 12,
) -> tuple[np.ndarray, np.ndarray]:
    """Move each marching-cubes vertex to the root of f on its grid edge (float64).

    A vertex lies on the edge from grid node ``i0`` to ``i0 + e_axis``; the grid values at
    the two nodes have opposite signs, so the edge brackets a root.  On the edge parameter
    t in [0, 1], starting from marching cubes' linear interpolation, secant steps (order
    1.6) are taken while they stay inside the bracket, regula falsi on the bracket
    otherwise (Dekker's safeguard).  A vertex is done when the next step is shorter than
    ``step_tol`` (length units; the step is then taken) or f is exactly 0; the caller
    checks |f| / |grad f| at the result.  The few vertices still moving after ``max_iter``
    steps (an edge that grazes the surface, where f has a near-double root, or one next to
    a sharp feature) are left to Newton steps along grad f.

    Returns the vertices (V, 3) in world coordinates (the current estimate, or marching
    cubes' position, where not done) and the (V,) bool ``done``.
    """
    index_verts = np.ascontiguousarray(index_verts)  # skimage's comes with reversed columns: slow to read
    verts = _grid_points(index_verts, origin, spacing)  # marching cubes' positions
    done = np.zeros(len(verts), dtype=bool)
    sel, axis, i0, t = _grid_edges(index_verts)
    flat = values.reshape(-1)  # grid values by flat index; along an edge: + step
    lin = _flat_index(i0, values.shape)
    step = np.array([values.shape[1] * values.shape[2], values.shape[2], 1])[axis]
    f0 = flat[lin].astype(np.float64)
    f1 = flat[lin + step].astype(np.float64)
    keep = np.flatnonzero(f0 * f1 < 0)
    if len(keep) < len(sel):
        sel, axis, i0, t, lin, step, f0, f1 = (v[keep] for v in (sel, axis, i0, t, lin, step, f0, f1))
    if len(sel) == 0:
        return verts, done
    start = _grid_points(i0, origin, spacing)  # world position of t = 0
    h = spacing[axis]  # edge length
    along = np.arange(len(sel)) * 3 + axis  # the moving coordinate in start.reshape(-1)
    start_axis = start.reshape(-1)[along]
    # first guess: root of the cubic through the grid values at t = -1, 0, 1, 2 (error O(h^4)
    # where f is smooth, against O(h^2) for marching cubes' linear interpolation)
    size = np.asarray(values.shape)[axis]
    c, slope = _cubic_root(flat, lin, step, i0.reshape(-1)[along], size, f0, f1, t)
    root, rows, c = _bracketed_roots(f, start, start_axis, h, axis, c, slope, f0, f1, step_tol, device, max_iter)
    found = np.flatnonzero(np.isfinite(root))
    # start + t * edge: across the edge the grid node's coordinates, which marching cubes' vertex has
    moving = sel * 3 + axis  # the coordinate along the edge in verts.reshape(-1)
    verts.reshape(-1)[moving[found]] = start_axis[found] + root[found] * h[found]
    verts.reshape(-1)[moving[rows]] = start_axis[rows] + c * h[rows]  # not done yet: the best estimate
    done[sel[found]] = True
    return verts, done


def _bracketed_roots(
    f: Callable,
    start: np.ndarray,
    start_axis: np.ndarray,
    h: np.ndarray,
    axis: np.ndarray,
    c: np.ndarray,
    slope: np.ndarray,
    f0: np.ndarray,
    f1: np.ndarray,
    step_tol: float,
    device: Any,
    max_iter: int = 12,
    sections: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roots of f on K axis-aligned edges that bracket one (float64; Dekker's safeguarded secant).

    Edge k runs from ``start[k]`` (K, 3) along axis ``axis[k]`` over length ``h[k]``; its end
    values ``f0[k]``, ``f1[k]`` have opposite signs; ``start_axis[k]`` is ``start[k, axis[k]]``.
    ``c`` is the first guess in (0, 1) and ``slope`` df/dt there (Newton's first step).  Secant
    steps are taken while they stay inside the bracket, regula falsi's otherwise (Illinois: the kept
    end's value halved after a regula falsi step that did not cross the root); an edge is done when
    the next step is below ``step_tol`` (length units) or f is exactly 0.

    ``sections``: the edges still moving after ``max_iter`` steps (f bends sharply in their bracket:
    a kink of min/max or of an R-function's corner, where the secant creeps) have their brackets
    narrowed that many times by multisection, each 1 / (SECTION_POINTS + 1) as wide whatever f is
    (:func:`.loops._section_step`; up to SECTION_ROWS edges in one call of f), and their root is
    regula falsi's in the last bracket: within 1 / (SECTION_POINTS + 1)^sections of the bracket
    after the secant steps, in ``sections`` calls instead of many more small ones.

    Returns ``root`` (K,) in edge units (NaN where not done), and the rows not done (after
    ``max_iter`` steps, and the sections) with their last estimates ``c``.
    """
    root = np.full(len(c), np.nan)
    c = np.array(c, dtype=np.float64)  # the estimates, per edge (updated in place by the steps)
    a, fa, p, fp = (np.zeros(len(c)) for _ in range(4))  # bracket end opposite to c, previous iterate
    falsi = np.zeros(len(c), dtype=np.bool_)
    h = np.ascontiguousarray(np.broadcast_to(h, c.shape), dtype=np.float64)
    rows = np.arange(len(c))
    f = _bound(f, device)
    for step in range(max_iter):
        fc = _f64(f, _edge_points(rows, start, axis, start_axis, h, c), device)
        rows = _secant_step(rows, fc, step == 0, f0, f1, slope, h, c, a, fa, p, fp, falsi, step_tol, root)
        if len(rows) == 0:
            break
    if sections and len(rows):  # the bracket [a, p] of each edge still moving, SECTION_ROWS edges at a time
        left = []
        for first in range(0, len(rows), SECTION_ROWS):
            part = rows[first : first + SECTION_ROWS]
            for k in range(sections):
                t, points = _section_points(part, start, axis, start_axis, h, a, p, SECTION_POINTS)
                ft = _f64(f, points, device)
                part = _section_step(part, t, ft, SECTION_POINTS, a, fa, p, fp, k == sections - 1, root)
            left.append(part)
        rows = np.concatenate(left)
    return root, rows, c[rows]


def _cubic_root(
    flat: np.ndarray,
    lin: np.ndarray,
    step: np.ndarray,
    coord: np.ndarray,
    size: np.ndarray,
    f0: np.ndarray,
    f1: np.ndarray,
    t: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Root in (0, 1) and slope there of the cubic through the grid values at t = -1, 0, 1, 2 of each edge.

    The edges start at ``flat[lin]`` and step by ``step`` (flat grid values), at grid index
    ``coord`` of ``size`` along their axis.  A missing neighbour (grid border) is replaced by
    the value that makes the third difference zero (a quadratic, or linear with both missing).
    Three Newton steps from ``t`` (marching cubes' estimate); where they leave the edge, ``t``
    is kept.
    """
    has_m, has_2 = coord >= 1, coord + 2 < size
    fm = flat.take(lin - step, mode="clip").astype(np.float64)
    f2 = flat.take(lin + 2 * step, mode="clip").astype(np.float64)
    if not (has_m.all() and has_2.all()):
        fm = np.where(has_m, fm, np.where(has_2, 3 * f0 - 3 * f1 + f2, 2 * f0 - f1))
        f2 = np.where(has_2, f2, 3 * f1 - 3 * f0 + fm)
    # P(t) = f0 + b1 t + b2 t^2 + b3 t^3 (Lagrange on -1, 0, 1, 2 in power form)
    half0, half1, sixth2 = f0 / 2, f1 / 2, f2 / 6
    b1 = -fm / 3 - half0 + f1 - sixth2
    b2 = fm / 2 - f0 + half1
    b3 = -fm / 6 + half0 - half1 + sixth2
    twice_b2 = 2 * b2
    r = t.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        for _ in range(3):
            value = r * b3  # f0 + r (b1 + r (b2 + r b3)), in place
            value += b2
            value *= r
            value += b1
            value *= r
            value += f0
            value /= _cubic_slope(r, b1, twice_b2, b3)
            r -= value
        slope = _cubic_slope(r, b1, twice_b2, b3)
        rise = f1 - f0
        good = (r > 0) & (r < 1) & np.isfinite(slope) & (slope * rise > 0)
    if good.all():
        return r, slope
    return np.where(good, r, t), np.where(good, slope, rise)


def _cubic_slope(r: np.ndarray, b1: np.ndarray, twice_b2: np.ndarray, b3: np.ndarray) -> np.ndarray:
    """b1 + r (2 b2 + 3 r b3), in place on one temporary."""
    slope = 3 * r
    slope *= b3
    slope += twice_b2
    slope *= r
    slope += b1
    return slope


def _normals(
    gradient: np.ndarray, verts: np.ndarray, faces: np.ndarray, unit: tuple[np.ndarray, np.ndarray] | None = None
) -> np.ndarray:
    """Unit outward normals -grad f / |grad f|; the area-weighted face normal where grad f vanishes.
    ``unit``: the first part, ``_unit_normals(gradient, -1.0)``, when the caller has it."""
    normals, good = _unit_normals(np.asarray(gradient, dtype=np.float64), -1.0) if unit is None else unit
    if good.all():
        return normals
    if len(faces):
        a, b, c = (verts[faces[:, i]] for i in range(3))
        face_n = np.cross(b - a, c - a)
        acc = np.zeros_like(verts)
        for k in range(3):
            for d in range(3):
                acc[:, d] += np.bincount(faces[:, k], weights=face_n[:, d], minlength=len(verts))
        bad = ~good
        norm = np.linalg.norm(acc[bad], axis=1, keepdims=True)
        normals[bad] = acc[bad] / np.where(norm > 0, norm, 1.0)
    return normals
