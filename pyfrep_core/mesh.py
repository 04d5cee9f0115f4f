"""Grids, chunked evaluation, marching cubes with vertices projected onto f = 0, and the Mesh type.

>>> from pyfrep_core import sphere
>>> m = polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 64)
>>> round(m.volume(), 2)
4.19
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from skimage.measure import marching_cubes

from .diff import project_to_surface
from .model import check_bounds


@dataclass
class Mesh:
    """A triangle mesh in world coordinates.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64, counter-clockwise seen from outside (normals by the right-hand rule point out)
    normals : (V, 3) float64 outward unit normals (from -grad f at the vertices), or None
    point_data : name -> (V,) or (V, k) arrays carried along (curvatures, residuals ...)
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    point_data: dict[str, np.ndarray] = field(default_factory=dict)

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


def grid_axes(bounds: Any, resolution: int | tuple[int, int, int], dim: int = 3) -> list[np.ndarray]:
    """Sample positions along each axis: ``resolution`` points from lower to upper bound inclusive."""
    lo, hi = check_bounds(bounds, dim)
    res = (resolution,) * dim if np.isscalar(resolution) else tuple(resolution)
    for r in res:
        if int(r) != r or r < 2:
            raise ValueError(f"resolution must be an integer >= 2 per axis, got {resolution!r}")
    return [np.linspace(a, b, int(r)) for a, b, r in zip(lo, hi, res)]


def evaluate_grid(
    f: Callable,
    bounds: Any,
    resolution: int | tuple[int, int, int],
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    max_points: int = 1 << 20,
) -> np.ndarray:
    """f on a regular 3-D grid, evaluated in slabs of at most ``max_points`` points.

    Returns an (nx, ny, nz) numpy array (``dtype``); memory beyond the result stays
    below a few times ``max_points`` points.
    """
    axes = grid_axes(bounds, resolution)
    nx, ny, nz = (len(a) for a in axes)
    out = np.empty((nx, ny, nz), dtype=np.float32 if dtype == torch.float32 else np.float64)
    gx, gy, gz = (torch.as_tensor(a, dtype=dtype, device=device) for a in axes)
    yy, zz = torch.meshgrid(gy, gz, indexing="ij")
    slab = max(1, max_points // (ny * nz))
    with torch.no_grad():
        for i in range(0, nx, slab):
            k = min(slab, nx - i)
            pts = torch.empty((k, ny, nz, 3), dtype=dtype, device=device)
            pts[..., 0] = gx[i : i + k, None, None]
            pts[..., 1] = yy
            pts[..., 2] = zz
            vals = f(pts)
            if vals.shape != (k, ny, nz):
                raise ValueError(f"f must map points (..., 3) to values (...), got {tuple(vals.shape)}")
            out[i : i + k] = vals.cpu().numpy()
    return out


def polygonize(
    f: Callable,
    bounds: Any = None,
    resolution: int = 128,
    project: bool = True,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
) -> Mesh:
    """Mesh the surface f = 0 inside ``bounds`` with marching cubes, vertices projected onto f = 0.

    Parameters
    ----------
    f : callable (..., 3) -> (...), or a Model (its default bounds are used when ``bounds`` is None).
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)); the grid's end points lie on them.
    resolution : grid samples per axis (>= 2).
    project : move vertices onto f = 0 by Newton steps (float64) and take normals from grad f.
    dtype : dtype of the grid evaluation (float32 is fast; vertices are float64 either way).

    Returns
    -------
    Mesh ; empty (with a warning) when f does not change sign in the bounds.
    """
    if bounds is None:
        bounds = getattr(f, "bounds", None)
        if bounds is None:
            raise ValueError("bounds must be given for a function without default bounds")
    lo, hi = check_bounds(bounds, 3)
    axes = grid_axes(bounds, resolution)
    values = evaluate_grid(f, bounds, resolution, dtype=dtype, device=device)
    if not np.isfinite(values).all():
        raise ValueError("f is not finite on the grid (NaN or inf values)")
    if values.min() >= 0.0 or values.max() <= 0.0:
        warnings.warn("polygonize: f does not change sign inside the bounds; empty mesh", RuntimeWarning, stacklevel=2)
        return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)))
    spacing = tuple(float(a[1] - a[0]) for a in axes)
    verts, faces, _, _ = marching_cubes(values, level=0.0, spacing=spacing, gradient_direction="descent")
    verts = verts.astype(np.float64) + np.asarray(lo)
    # skimage orients faces so that the right-hand normal points toward increasing f (inward here)
    faces = faces[:, ::-1].astype(np.int64)
    x = torch.as_tensor(verts, dtype=torch.float64, device=device)
    f64 = f
    if project:
        cell = float(np.linalg.norm(spacing))
        proj = project_to_surface(f64, x, max_step=cell, max_distance=cell, warn=False)
        x, gradient = proj.points, proj.gradient
    else:
        from .diff import grad

        gradient = grad(f64, x)
    verts = x.cpu().numpy()
    g = gradient.cpu().numpy()
    normals = -g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), np.finfo(np.float64).tiny)
    verts = np.clip(verts, lo, hi)
    return Mesh(verts, faces, normals)
