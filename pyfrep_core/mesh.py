"""Grids, chunked evaluation, marching cubes with vertices moved onto f = 0, and the Mesh type.

``polygonize`` evaluates f on a regular grid (float32, in cache-sized chunks), runs
scikit-image's marching cubes, then moves every vertex onto f = 0 in float64: along its
marching-cubes edge by bracketed root finding (the edge's two grid values bracket the
root), with Newton steps along grad f (:func:`pyfrep_core.diff.project_to_surface`) for
the few vertices that do not lie strictly inside an edge.  Normals are -grad f.

``polygonize(..., sparse=True)`` evaluates f exactly only in blocks near the surface (coarse
corners first; see :func:`_sparse_grid` for what it assumes) and gives the dense grid's mesh
on every shape of the test suite, 1.2-1.5x faster on the Fig. 1 part (it falls back to the
dense grid where the surface is everywhere, as in lattices).  It is the shape panel's mode;
plain ``polygonize`` stays dense, since a heuristic that can miss a steep bump narrower than
a block should not decide an export.  On the CPU the chunks run one after the other on one
intra-op thread (:func:`_map`): faster here than two threads, and a busy neighbour core cannot
stall it.

>>> from pyfrep_core import sphere
>>> m = polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 64)
>>> round(m.volume(), 2)
4.19
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from skimage.measure import marching_cubes

from . import _array
from ._array import available_memory, check_option, validated_inputs
from ._threads import intra_op_threads
from .diff import project_to_surface, value_and_grad
from .evaluate import budget_points, evaluate, name_of
from .model import check_bounds

__all__ = [
    "Mesh",
    "GridTooLargeError",
    "polygonize",
    "evaluate_grid",
    "grid_axes",
    "grid_memory",
    "available_memory",
]

# points per call of f on the CPU: the temporaries stay in cache (see _map)
CHUNK_POINTS = 1 << 15
CHUNK_POINTS_GPU = 1 << 22
ROOT_CHUNK = 1 << 14  # vertices per float64 evaluation while projecting (CPU; chunks run in parallel)
SPARSE_STEP = 4  # fine cells per coarse block edge in the sparse evaluation
SPARSE_GUARD = 0.5  # blocks whose corners come within this many block diagonals (|f| / |grad f|) are checked
SPARSE_MAX_FRACTION = 0.5  # evaluate densely when more of the blocks than this need exact values
GiB = float(1 << 30)
GRID_DTYPES = (torch.float32, torch.float64)


class GridTooLargeError(ValueError, MemoryError):
    """A grid that would not fit in memory (a ValueError for bad input, and a MemoryError)."""


@dataclass
class Mesh:
    """A triangle mesh in world coordinates.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64, counter-clockwise seen from outside (normals by the right-hand rule point out)
    normals : (V, 3) float64 outward unit normals (from -grad f at the vertices), or None
    point_data : name -> (V,) or (V, k) arrays carried along (curvatures, residuals ...)
    gradient : (V, 3) float64 grad f at the vertices where :func:`polygonize` computed it
        (the normals are -gradient / |gradient|), so that callers need no second autograd
        pass (the shape panel's sensitivity -(df/dp) / |grad f|), or None.  Not written to files.

    Examples
    --------
    >>> import numpy as np
    >>> tet = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]),
    ...            np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    >>> round(tet.volume(), 6), tet.n_vertices, tet.n_faces
    (0.166667, 4, 4)
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    point_data: dict[str, np.ndarray] = field(default_factory=dict)
    gradient: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.vertices = _as_array(self.vertices, np.float64, "vertices")
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError(f"vertices must have shape (V, 3), got {self.vertices.shape}")
        if not np.isfinite(self.vertices).all():
            raise ValueError("vertices contain NaN or inf")
        faces = np.asarray(self.faces)
        if faces.size == 0:
            faces = faces.reshape(0, 3)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must have shape (F, 3), got {faces.shape}")
        if faces.dtype.kind not in "iu":
            if faces.dtype.kind != "f" or not np.array_equal(faces, np.round(faces)):
                raise ValueError(f"faces must hold integer vertex indices, got dtype {faces.dtype}")
        self.faces = faces.astype(np.int64, copy=False)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError(
                f"faces index vertices {self.faces.min()}..{self.faces.max()}, "
                f"but there are {len(self.vertices)} vertices"
            )
        if self.normals is not None:
            self.normals = _as_array(self.normals, np.float64, "normals")
            if self.normals.shape != self.vertices.shape:
                raise ValueError(f"normals must have shape {self.vertices.shape}, got {self.normals.shape}")
        if self.gradient is not None:
            self.gradient = _as_array(self.gradient, np.float64, "gradient")
            if self.gradient.shape != self.vertices.shape:
                raise ValueError(f"gradient must have shape {self.vertices.shape}, got {self.gradient.shape}")
        data = {}
        for name, values in dict(self.point_data).items():
            arr = np.asarray(values)
            if arr.ndim == 0 or arr.shape[0] != len(self.vertices):
                raise ValueError(f"point_data[{name!r}] must have one row per vertex, got shape {arr.shape}")
            data[name] = arr
        self.point_data = data

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def is_empty(self) -> bool:
        return self.n_faces == 0

    def volume(self) -> float:
        """Enclosed volume by the divergence theorem (exact for a closed, outward-oriented mesh)."""
        if self.is_empty():
            return 0.0
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)

    def area(self) -> float:
        """Total surface area."""
        if self.is_empty():
            return 0.0
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    def to_pyvista(self) -> Any:
        """A ``pyvista.PolyData`` with the normals and point data attached."""
        import pyvista as pv

        faces = np.hstack([np.full((self.n_faces, 1), 3, dtype=np.int64), self.faces.astype(np.int64)])
        poly = pv.PolyData(self.vertices, faces.ravel())
        if self.normals is not None:
            poly.point_data["Normals"] = self.normals
        for name, values in self.point_data.items():
            poly.point_data[name] = values
        return poly

    def save(self, path: str | os.PathLike) -> None:
        """Write the mesh to ``path``; the format follows the extension: ``save_mesh(self, path)``.

        See :func:`pyfrep_core.io.save_mesh` for the formats and what each keeps.  It takes no
        other arguments (an unknown keyword is a TypeError).
        """
        from .io import save_mesh

        save_mesh(self, path)


def _as_array(values: Any, dtype: type, name: str) -> np.ndarray:
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().numpy()
    try:
        return np.asarray(values, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a numeric array: {err}") from None


def _device(device: Any, fn: str) -> torch.device:
    """``torch.device(device)``, with an error naming the option."""
    try:
        return torch.device(device)
    except (RuntimeError, TypeError) as err:
        raise ValueError(
            f"{fn}: device must be a torch device or its name ('cpu', 'cuda'), got {device!r}: {err}"
        ) from None


def _resolution(resolution: Any, dim: int) -> tuple[int, ...]:
    """Validate samples per axis: an integer >= 2, or one per axis."""
    values = (resolution,) * dim if np.ndim(resolution) == 0 else tuple(resolution)
    if len(values) != dim:
        raise ValueError(f"resolution must be one integer or {dim} integers, got {resolution!r}")
    out = []
    for r in values:
        ok = isinstance(r, int | np.integer | float | np.floating) and not isinstance(r, bool | np.bool_)
        if not ok or not math.isfinite(r) or int(r) != r or r < 2:
            raise ValueError(f"resolution must be an integer >= 2 per axis, got {resolution!r}")
        out.append(int(r))
    return tuple(out)


def grid_axes(bounds: Any, resolution: int | tuple[int, ...], dim: int = 3) -> list[np.ndarray]:
    """Sample positions along each axis: ``resolution`` points from lower to upper bound inclusive.

    Examples
    --------
    >>> grid_axes(((0, 0, 0), (1, 2, 1)), 3)[1]
    array([0., 1., 2.])
    """
    dim = check_option(dim, "dim", "grid_axes", "int", positive=True)
    lo, hi = check_bounds(bounds, dim)
    res = _resolution(resolution, dim)
    return [np.linspace(a, b, r) for a, b, r in zip(lo, hi, res)]


def grid_memory(resolution: int | tuple[int, ...], dtype: torch.dtype = torch.float32) -> int:
    """Estimated peak bytes to evaluate and mesh a grid of ``resolution`` samples per axis.

    The grid itself (4 or 8 bytes a sample; marching cubes needs a float32 copy of a
    float64 grid) and a quarter more for marching cubes, 256 MiB for the temporaries of the
    chunked evaluation and autograd passes, and 400 bytes a vertex for the projection and
    the mesh's arrays (measured: 390-430 bytes a vertex from 5e4 to 1e6 vertices).

    Marching cubes puts one vertex on each grid edge the surface crosses.  A closed part
    spanning the box crosses about 2/3 of the grid lines along each axis, twice each (a
    sphere inscribed in a cube: pi/4 of them), but a line of ``n`` samples has only ``n - 1``
    edges: the count is ``2/3 sum_a min(2, n_a - 1) N / n_a`` for N samples, 4 n^2 for a cube
    of n^3 (n >= 3) and one crossing per line across a slab two samples thick (a face of the
    part lying in the slab).  A lattice has more.

    Examples
    --------
    >>> round(grid_memory(512) / 2**30, 2)
    1.27
    >>> round(grid_memory((4096, 4096, 2)) / 2**30, 2)  # 11.2 million vertices at most
    4.58
    """
    res = _resolution(resolution, 3)
    dtype = check_option(dtype, "dtype", "grid_memory", "choice", choices=GRID_DTYPES)
    per_sample = 4 if dtype == torch.float32 else 8 + 4
    n = math.prod(res)
    vertices = 2 * sum(min(2, r - 1) * (n // r) for r in res) // 3
    return int(n * per_sample * 1.25) + (256 << 20) + 400 * vertices


def _check_memory(resolution: tuple[int, ...], dtype: torch.dtype) -> None:
    need = grid_memory(resolution, dtype)
    have = _array.available_memory()
    if have is not None and need > have:
        shown = resolution[0] if len(set(resolution)) == 1 else resolution
        raise GridTooLargeError(
            f"resolution {shown} needs about {need / GiB:.3g} GiB for the grid and marching cubes, "
            f"but only {have / GiB:.3g} GiB of memory is available; lower the resolution"
        )


# --------------------------------------------------------------------------- chunked evaluation


def _map(fn: Callable, items: list, device: torch.device) -> list:
    """``[fn(item) for item in items]``: chunks one after the other.

    On the CPU, polygonize runs them on one intra-op thread (see :func:`polygonize`): chunks of
    2^15 points stay in cache, and at that size the cost is torch's per-operation dispatch,
    which holds the GIL, so neither torch's second thread nor a pool of workers made the 2-core
    machine faster (measured: 0.37 s one thread vs 0.71 s two workers for the 256^3 grid).
    """
    return [fn(item) for item in items]


def _chunk_points(f: Callable, default: int) -> int:
    """Points per call: ``default``, or the ``chunk_points`` that f (or the model a
    ``functools.partial`` binds) declares (a compiled model's fused loop wants larger chunks)."""
    while isinstance(f, functools.partial):
        f = f.func
    hint = getattr(f, "chunk_points", None)
    return max(default, int(hint)) if isinstance(hint, int) and hint > 0 else default


def _grid_chunks(shape: tuple[int, int, int], max_points: int):
    """Blocks (i, kx, j, ky) of whole z-rows with at most ``max_points`` points (at least one row)."""
    nx, ny, nz = shape
    if ny * nz <= max_points:
        kx = max(1, max_points // (ny * nz))
        for i in range(0, nx, kx):
            yield i, min(kx, nx - i), 0, ny
    else:
        ky = max(1, max_points // nz)
        for i in range(nx):
            for j in range(0, ny, ky):
                yield i, 1, j, min(ky, ny - j)


def _call(f: Callable, pts: torch.Tensor) -> tuple[torch.Tensor, float, float]:
    """f on component-first points (3, ...) (so that x[:, 0] etc. are contiguous), its min and max.

    f is handed the points flattened to (N, 3) (the model contract); the values come back in
    the block's shape.  Raises ValueError for a wrong output shape (naming f, the input and the
    output shapes) or a non-finite value (naming the point).
    """
    shape = tuple(pts.shape[1:])
    with torch.no_grad():
        # f sees the block as a list of points (N, 3): a view, x[:, 0] etc. still contiguous
        points = pts.reshape(3, -1).t()
        with validated_inputs():  # grid points from checked bounds: the primitives of f need not read them
            vals = evaluate(f, points, chunk=points.shape[0], label=name_of(f))
        _check_values_dtype(f, vals, pts.dtype)
        vals = vals.reshape(shape)
        lo, hi = torch.aminmax(vals)
        lo, hi = float(lo), float(hi)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            bad = tuple(int(t) for t in torch.nonzero(~torch.isfinite(vals))[0])
            where = pts[(slice(None), *bad)].tolist()
            raise ValueError(f"f is not finite at x = {tuple(where)}: {float(vals[bad])}")
    return vals, lo, hi


def _check_values_dtype(f: Callable, values: torch.Tensor, dtype: torch.dtype) -> None:
    """Refuse values that are not floating point: an integer or boolean f has no gradient, so
    neither the vertices' projection onto f = 0 nor the normals (-grad f) exist."""
    if not values.is_floating_point():
        raise TypeError(
            f"f ({name_of(f)}) returned {str(values.dtype).removeprefix('torch.')} values for "
            f"{str(dtype).removeprefix('torch.')} points; a defining function must return floating-point "
            "values (meshing needs its gradient: the normals, and the vertices' projection onto f = 0)"
        )


def _check_grid_options(fn: str, f: Any, dtype: Any) -> torch.dtype:
    """f callable and the grid dtype float32 or float64 (an integer grid rounds f and loses its zero set)."""
    if not callable(f):
        raise TypeError(f"{fn}: f must be callable (points (N, 3) -> values (N,)), got {type(f).__name__}")
    return check_option(dtype, "dtype", fn, "choice", choices=GRID_DTYPES)


def _evaluate_grid(
    f: Callable, axes: list[np.ndarray], dtype: torch.dtype, device: Any, max_points: int | None
) -> tuple[np.ndarray, float, float]:
    """f on the grid of ``axes`` plus its min and max; raises on a non-finite value."""
    device = torch.device(device)
    if max_points is None:  # cache-sized on the CPU, and never above the memory budget of one call
        default = _chunk_points(f, CHUNK_POINTS if device.type == "cpu" else CHUNK_POINTS_GPU)
        max_points = min(default, budget_points(dtype, len(axes)))
    shape = tuple(len(a) for a in axes)
    out = np.empty(shape, dtype=np.float32 if dtype == torch.float32 else np.float64)
    gx, gy, gz = (torch.as_tensor(a, dtype=dtype, device=device) for a in axes)

    def chunk(block: tuple[int, int, int, int]) -> tuple[float, float]:
        i, kx, j, ky = block
        pts = torch.empty((3, kx, ky, shape[2]), dtype=dtype, device=device)
        pts[0] = gx[i : i + kx, None, None]
        pts[1] = gy[j : j + ky, None]
        pts[2] = gz
        vals, lo, hi = _call(f, pts)
        out[i : i + kx, j : j + ky] = vals.cpu().numpy()
        return lo, hi

    ranges = _map(chunk, list(_grid_chunks(shape, max_points)), device)
    return out, min(r[0] for r in ranges), max(r[1] for r in ranges)


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


def evaluate_grid(
    f: Callable,
    bounds: Any,
    resolution: int | tuple[int, int, int],
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    max_points: int | None = None,
) -> np.ndarray:
    """f on a regular 3-D grid, evaluated in chunks of at most ``max_points`` points.

    Parameters
    ----------
    f : callable, torch points (N, 3) -> values (N,) (a Model too).
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)); the grid's end points lie on them.
    resolution : samples per axis (>= 2), or one per axis.
    dtype : torch.float32 (fast) or torch.float64.
    max_points : points per call of f (default 2^15 on the CPU, 2^22 on accelerators, at most
        :func:`pyfrep_core.evaluate.budget_points`: the memory budget of one call).  f gets
        them as a list of points (N, 3), never as a grid block.

    Returns
    -------
    (nx, ny, nz) numpy array of ``dtype``: ``values[i, j, k] = f(x_i, y_j, z_k)``.

    Raises
    ------
    ValueError (GridTooLargeError) before allocating when the grid cannot fit in memory;
    ValueError naming the point where f is NaN or inf.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> v = evaluate_grid(lambda x: sphere(x, r=1.0), ((-1, -1, -1), (1, 1, 1)), 3)
    >>> v.shape, float(v[1, 1, 1]), float(v[0, 0, 0])
    ((3, 3, 3), 1.0, -2.0)
    """
    dtype = _check_grid_options("evaluate_grid", f, dtype)
    max_points = check_option(max_points, "max_points", "evaluate_grid", "int", positive=True, none=True)
    device = _device(device, "evaluate_grid")
    res = _resolution(resolution, 3)
    _check_memory(res, dtype)
    axes = grid_axes(bounds, res)
    return _evaluate_grid(f, axes, dtype, device, max_points)[0]


def polygonize(
    f: Callable,
    bounds: Any = None,
    resolution: int | tuple[int, int, int] = 128,
    project: bool = True,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    sparse: bool = False,
    tol: float | None = None,
) -> Mesh:
    """Mesh the surface f = 0 inside ``bounds`` with marching cubes, vertices moved onto f = 0.

    Parameters
    ----------
    f : callable (N, 3) -> (N,) on torch tensors, or a Model (its default bounds are used when
        ``bounds`` is None).  f is only ever called with lists of points (N, 3), in chunks.
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)); the grid's end points lie on them.
    resolution : grid samples per axis (an integer >= 2, or three).
    project : move the vertices onto f = 0 in float64 (root finding along each marching-cubes
        edge, Newton steps along grad f where that does not apply), to a first-order distance
        |f| / |grad f| below 100 ulp of the largest coordinate (2.4e-14 in [-1.1, 1.1]^3);
        False keeps marching cubes' linear interpolation.  Normals come from -grad f either way.
    dtype : dtype of the grid evaluation (float32 is fast; vertices are float64 either way).
    device : where f is evaluated.
    sparse : evaluate f exactly only near the surface (coarse-to-fine, blocks of
        ``SPARSE_STEP``^3 cells; see :func:`_sparse_grid` for what it assumes); the mesh is
        the dense grid's whenever that assumption holds (tested on the paper's shapes).
    tol : distance to f = 0 (length units) at which a projected vertex is accepted; None (the
        default) is the 100-ulp tolerance above.  A display-grade value (e.g. 1e-3 of a cell,
        as the workbench uses while a slider moves) saves most of the root-finding steps.

    Returns
    -------
    Mesh with vertices (V, 3) float64 in world coordinates, faces (F, 3) int64 oriented
    outward, unit normals (V, 3).  Empty (with a RuntimeWarning) when f does not change
    sign inside the bounds.  Vertices whose projection does not converge keep their
    marching-cubes position; their number is given in a RuntimeWarning.

    Raises
    ------
    ValueError for bad bounds or resolution, for a grid that cannot fit in memory (before
    allocating; the message gives the GiB needed), and where f is NaN or inf.

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part
    >>> m = polygonize(fig1_part, resolution=64)      # the model's default bounds
    >>> abs(m.volume() - 0.98879) < 0.01, m.vertices.dtype, m.faces.shape[1]
    (True, dtype('float64'), 3)
    """
    dtype = _check_grid_options("polygonize", f, dtype)
    project = check_option(project, "project", "polygonize", "bool")
    sparse = check_option(sparse, "sparse", "polygonize", "bool")
    tol = check_option(tol, "tol", "polygonize", positive=True, none=True)
    cpu = _device(device, "polygonize").type == "cpu"
    # one intra-op thread on the CPU: at 2^15-point chunks torch's dispatch, not arithmetic, is the cost
    # (the Fig. 1 part at 256^3: 0.91 s on one thread, 1.29 s on two)
    with intra_op_threads(1 if cpu else None):
        return _polygonize(f, bounds, resolution, project, dtype, device, sparse, tol)


def _polygonize(
    f: Callable,
    bounds: Any = None,
    resolution: int | tuple[int, int, int] = 128,
    project: bool = True,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    sparse: bool = False,
    tol: float | None = None,
) -> Mesh:
    if bounds is None:
        bounds = getattr(f, "bounds", None)
        if bounds is None:
            raise ValueError("bounds must be given for a function without default bounds")
    dim = getattr(f, "dim", None)  # None: not declared (a plain function, a normalized one)
    if dim is not None and dim != 3:
        raise ValueError(f"polygonize meshes 3-D models; this one has dim={dim}")
    res = _resolution(resolution, 3)
    lo, hi = check_bounds(bounds, 3)
    _check_memory(res, dtype)
    axes = grid_axes((lo, hi), res)
    grid = _sparse_grid(f, axes, dtype, device, SPARSE_STEP, SPARSE_GUARD) if sparse else None
    if grid is not None:
        values, vmin, vmax, mask, evaluated = grid
    else:
        values, vmin, vmax = _evaluate_grid(f, axes, dtype, device, None)
        mask = None
    empty = vmin >= 0.0 or vmax <= 0.0
    if not empty:
        try:
            index_verts, faces, _, _ = marching_cubes(values, level=0.0, gradient_direction="descent", mask=mask)
        except RuntimeError:  # skimage: "No surface found" (f > 0 nowhere next to f <= 0 in a cell)
            empty = True
    if empty:
        warnings.warn("polygonize: f does not change sign inside the bounds; empty mesh", RuntimeWarning, stacklevel=2)
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)))
    # skimage orients faces so that the right-hand normal points toward increasing f (inward here)
    faces = np.ascontiguousarray(faces[:, ::-1], dtype=np.int64)
    origin = np.asarray(lo)
    spacing = np.array([a[1] - a[0] for a in axes])
    if project:
        if grid is not None:
            _exact_neighbours(f, values, index_verts, evaluated, SPARSE_STEP, axes, dtype, device)
        verts, gradient, n_failed = _project_vertices(f, values, index_verts, origin, spacing, (lo, hi), device, tol)
        if n_failed:
            warnings.warn(
                f"polygonize: {n_failed} of {len(verts)} vertices could not be moved onto f = 0; "
                "they keep their marching-cubes position",
                RuntimeWarning,
                stacklevel=2,
            )
    else:
        verts = origin + index_verts.astype(np.float64) * spacing
        gradient = _value_and_grad(f, verts, device)[1]
    verts, faces, gradient = _collapse_coincident(verts, faces, gradient)
    return Mesh(verts, faces, _normals(gradient, verts, faces), gradient=gradient)


def _edge_counts(faces: np.ndarray) -> np.ndarray:
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1], return_counts=True)[1]


def _collapse_coincident(
    verts: np.ndarray, faces: np.ndarray, gradient: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge the vertices of a face that landed on the same point; drop the faces that collapse.

    Newton steps (the fallback of the projection) can move two vertices of a triangle next to
    a sharp crease onto the same point: a zero-area triangle, which STL readers drop (VTK's
    merges points, leaving a hole).  Collapsing such an edge removes the two triangles that
    share it and keeps the mesh closed, unless the collapse would pinch it (an edge then in
    more than two faces, or a changed border): then the mesh is returned unchanged.
    """
    if len(faces) == 0:
        return verts, faces, gradient
    # coincident vertices have equal keys (a hash of the coordinates' bits, -0.0 as 0.0): only the
    # faces with two equal keys (few or none) are compared coordinate by coordinate
    bits = (verts + 0.0).view(np.int64)
    key = bits[:, 0] * _HASH[0] ^ bits[:, 1] * _HASH[1] ^ bits[:, 2]  # wraps around: a hash
    k = [key[faces[:, i]] for i in range(3)]
    suspect = faces[(k[0] == k[1]) | (k[1] == k[2]) | (k[2] == k[0])]
    corners = [verts[suspect[:, i]] for i in range(3)]
    pairs = [suspect[(corners[i] == corners[j]).all(axis=1)][:, [i, j]] for i, j in ((0, 1), (1, 2), (2, 0))]
    pairs = np.concatenate(pairs)
    if len(pairs) == 0:
        return verts, faces, gradient
    label = np.arange(len(verts))
    while True:  # every vertex of a coincident cluster points to the cluster's smallest index
        low = np.minimum(label[pairs[:, 0]], label[pairs[:, 1]])
        new = label.copy()
        np.minimum.at(new, pairs[:, 0], low)
        np.minimum.at(new, pairs[:, 1], low)
        new = new[new]
        if np.array_equal(new, label):
            break
        label = new
    merged = label[faces]
    keep = (merged[:, 0] != merged[:, 1]) & (merged[:, 1] != merged[:, 2]) & (merged[:, 2] != merged[:, 0])
    merged = merged[keep]
    before, after = _edge_counts(faces), _edge_counts(merged)
    if after.max() > 2 or (after == 1).sum() != (before == 1).sum():
        return verts, faces, gradient  # a collapse would pinch the surface: keep the zero-area triangles
    used = np.unique(merged)
    index = np.full(len(verts), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return verts[used], index[merged], gradient[used]


_HASH = (6364136223846793005, 1442695040888963407)  # odd 64-bit multipliers (Knuth's MMIX LCG)


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


def _f64(f: Callable, x: np.ndarray, device: Any) -> np.ndarray:
    """f at points x (N, 3) in float64, forward only, in chunks (in parallel on the CPU)."""
    out = np.empty(len(x))
    device = torch.device(device)
    size = _chunk_points(f, ROOT_CHUNK)

    def chunk(s: int) -> None:
        t = torch.as_tensor(x[s : s + size], dtype=torch.float64, device=device)
        with torch.no_grad(), validated_inputs():  # points on grid edges: finite, not read again per primitive
            out[s : s + size] = evaluate(f, t, chunk=size).cpu().numpy()

    _map(chunk, list(range(0, len(x), size)), device)
    return out


def _value_and_grad(f: Callable, x: np.ndarray, device: Any) -> tuple[np.ndarray, np.ndarray]:
    """f and grad f at points x (N, 3) in float64 (numpy out; diff's chunked, parallel passes)."""
    if len(x) == 0:
        return np.zeros(0), np.zeros((0, 3))
    t = torch.as_tensor(x, dtype=torch.float64, device=device)
    hint = _chunk_points(f, 0)  # a compiled model's chunk size, else diff's default
    value, gradient = value_and_grad(f, t, chunk=hint or None)
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
    root = np.full(len(sel), np.nan)
    # the rows still moving: their points, where their coordinate along the edge starts, edge
    # lengths and axes.  A point start + c * edge differs from start only along the edge, as c
    # stays finite (in [0, 1]: a step that leaves the bracket is replaced by regula falsi's,
    # c - fc (c - a) / (fc - fa) with fc, fa of opposite signs, which lies between c and a)
    rows, x, xa, hs, ax = np.arange(len(sel)), start.copy(), start_axis, h, axis
    a = fa = p = fp = None  # bracket end opposite to c, and the previous iterate
    for _ in range(max_iter):
        x.reshape(-1)[np.arange(len(rows)) * 3 + ax] = xa + c * hs
        fc = _f64(f, x, device)
        positive = fc > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            if a is None:  # the bracket: the grid end whose value has the other sign
                same = positive == (f0 > 0)
                a = same.astype(np.float64)
                fa = np.where(same, f1, f0)
                nxt = c - fc / slope  # Newton with the cubic's slope
            else:  # the bracket becomes [previous iterate, c] when the sign changed
                flip = positive != (fp > 0)
                np.copyto(a, p, where=flip)
                np.copyto(fa, fp, where=flip)
                secant = c - p  # secant: c - fc (c - p) / (fc - fp)
                secant *= fc
                secant /= fc - fp
                nxt = c - secant
            move = nxt - c
            outside = np.flatnonzero(~((nxt - a) * move < 0))
            if len(outside):  # regula falsi: inside
                co, fo = c[outside], fc[outside]
                nxt[outside] = co - fo * (co - a[outside]) / (fo - fa[outside])
                move[outside] = nxt[outside] - co
        finished = np.abs(move) * hs <= step_tol  # False for NaN
        exact = fc == 0
        finished_rows = np.flatnonzero(finished)
        root[rows[finished_rows]] = nxt[finished_rows]
        if exact.any():
            root[rows[exact]] = c[exact]
        go = np.flatnonzero(~(finished | exact) & np.isfinite(fc))
        if len(go) == len(rows):
            p, fp, c = c, fc, nxt
            continue
        rows, p, fp, c, a, fa = rows[go], c[go], fc[go], nxt[go], a[go], fa[go]
        if len(rows) == 0:
            break
        x, xa, hs, ax = np.take(x, go, axis=0), xa[go], hs[go], ax[go]
    found = np.flatnonzero(np.isfinite(root))
    # start + t * edge: across the edge the grid node's coordinates, which marching cubes' vertex has
    moving = sel * 3 + axis  # the coordinate along the edge in verts.reshape(-1)
    verts.reshape(-1)[moving[found]] = start_axis[found] + root[found] * h[found]
    verts.reshape(-1)[moving[rows]] = start_axis[rows] + c * h[rows]  # not done yet: the best estimate
    done[sel[found]] = True
    return verts, done


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


def _normals(gradient: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit outward normals -grad f / |grad f|; the area-weighted face normal where grad f vanishes."""
    length = _row_norms(gradient)
    good = np.isfinite(length) & (length > 0)
    if good.all():
        normals = np.negative(gradient)
        normals /= length[:, None]
        return normals
    normals = np.zeros_like(verts)
    normals[good] = -gradient[good] / length[good, None]
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
