"""Marching cubes on a regular grid, with vertices moved onto f = 0.

:func:`pyfrep_core.polygonize` (``method="mc"``) evaluates f on a regular grid (float32, in
cache-sized chunks; or sparsely: :mod:`pyfrep_core.meshing.sparse`), runs scikit-image's marching cubes, then moves
every vertex onto f = 0 in float64 (:mod:`pyfrep_core.meshing.roots`).  Normals are -grad f.  On
the CPU the chunks run one after the other on one intra-op thread (:func:`.grid._map`):
faster here than two threads, and a busy neighbour core cannot stall it.

>>> from pyfrep_core import sphere
>>> m = _polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 64)
>>> round(m.volume(), 2)
4.19
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from skimage.measure import marching_cubes

from ..model import check_bounds
from .grid import _check_memory, _evaluate_grid, _resolution, grid_axes
from .mesh_type import Mesh
from .repair import _collapse_coincident
from .roots import _normals, _project_vertices, _value_and_grad
from .sparse import SPARSE_GUARD, SPARSE_STEP, _exact_neighbours, _sparse_grid

__all__: list[str] = []  # polygonize (pyfrep_core.meshing.polygonize) calls _polygonize


def _polygonize(
    f: Callable,
    bounds: Any = None,
    resolution: int | tuple[int, int, int] = 128,
    project: bool = True,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    sparse: bool = False,
    tol: float | None = None,
    progress: Callable[[int], Any] | None = None,
) -> Mesh:
    """Marching cubes' mesh (the options as :func:`pyfrep_core.polygonize` checked them); ``progress(n)``
    gives the Progress of the grid's n chunks (dense grid only); raises ``grid.Stopped`` when stopped."""
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
        values, vmin, vmax = _evaluate_grid(f, axes, dtype, device, None, progress)
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
