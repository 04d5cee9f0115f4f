"""Points where a model is looked at: clouds on its surface, and planes through its box.

The synthetic data of the paper's fitting experiment (section 5.4): n points on the zero set of
any model at chosen parameters, optionally with Gaussian noise (area-weighted mesh samples
projected onto f = 0).  And the grid of a slice (:func:`plane_points`), where the workbench's
slice views evaluate f and the fields built on it.

>>> from pyfrep_core import model, Param, sphere
>>> @model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(0.8, 0.5, 1.0))
... def ball(x, r):
...     return sphere(x, r=r)
>>> pts = sample_surface(ball, 500, params={"r": 0.9}, seed=0)
>>> pts.shape, bool(abs(np.linalg.norm(pts, axis=1) - 0.9).max() < 1e-12)
((500, 3), True)
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import torch

from ._array import check_memory, check_option
from .diff import project_to_surface
from .meshing import Mesh, polygonize
from .model import Model, check_bounds

__all__ = ["sample_surface", "sample_mesh", "plane_points"]

# Peak bytes per sampled point, measured (peak RSS, a sphere, n = 1e5 to 3e6): 370 to 480 (the
# drawn faces and barycentric coordinates, the projection's float64 tensors and gradients,
# the result).  Rounded up to 600; the marching-cubes grid is checked by polygonize itself.
SAMPLE_BYTES_PER_POINT = 600


def sample_mesh(mesh: Mesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points uniformly distributed over the area of a triangle mesh, (n, 3) float64.

    Faces are drawn with probability proportional to their area, then a point is drawn
    uniformly inside each (barycentric coordinates ``1 - sqrt(r1)``, ``sqrt(r1) (1 - r2)``,
    ``sqrt(r1) r2``).

    Examples
    --------
    >>> m = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    >>> p = sample_mesh(m, 1000, np.random.default_rng(0))
    >>> bool((p[:, 0] + p[:, 1] <= 1).all() and (p[:, 2] == 0).all())
    True
    """
    n = check_option(n, "n", "sample_mesh", "int", positive=True)
    if mesh.is_empty():
        raise ValueError("sample_mesh: cannot sample an empty mesh")
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    total = area.sum()
    if not total > 0:
        raise ValueError("sample_mesh: cannot sample a mesh of zero area")
    face = rng.choice(len(area), size=n, p=area / total)
    r1 = np.sqrt(rng.random((n, 1)))
    r2 = rng.random((n, 1))
    return (1.0 - r1) * a[face] + r1 * (1.0 - r2) * b[face] + r1 * r2 * c[face]


def _field(model: Callable, params: Mapping[str, Any] | None) -> Callable:
    if isinstance(model, Model):
        values = model.check(**dict(params or {}))
        return lambda x: model(x, **values)
    if params:
        raise TypeError("params can only be given for a Model (declared with @model)")
    if not callable(model):
        raise TypeError(f"model must be callable, got {type(model).__name__}")
    return model


def sample_surface(
    model: Callable,
    n: int,
    params: Mapping[str, float] | None = None,
    noise: float = 0.0,
    seed: int | None = None,
    bounds: Any = None,
    resolution: int = 128,
    max_rounds: int = 20,
) -> np.ndarray:
    """``n`` points on the surface f = 0 of a model, as an (n, 3) float64 array.

    Marching cubes (:func:`pyfrep_core.meshing.polygonize`) gives a mesh of the surface; points
    are drawn on it by area, then moved onto f = 0 by Newton steps
    (:func:`pyfrep_core.diff.project_to_surface`, float64, at most one grid cell).  Points that
    do not converge are dropped and redrawn, never kept, so every returned point (before
    noise) satisfies ``|f| / |grad f| < 100 eps max|x|``.

    Parameters
    ----------
    model : a Model (its default bounds are used) or any callable (N, 3) -> (N,) with ``bounds``.
    n : number of points (>= 1).
    params : parameter values of a Model (defaults for the others); checked against the ranges.
    noise : standard deviation of the isotropic Gaussian noise added to each coordinate, in
        length units (0 for exact surface points).
    seed : seed of the random generator (faces, barycentric coordinates and noise).
    bounds : box ((xmin, ymin, zmin), (xmax, ymax, zmax)) to mesh; default ``model.bounds``.
    resolution : marching-cubes samples per axis; fine enough to resolve the thinnest features.
    max_rounds : redraw rounds for points that failed to project before giving up (RuntimeError).

    Returns
    -------
    (n, 3) float64 numpy array; save it as XYZ or PLY with :func:`pyfrep_core.io.save_points`.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> p = sample_surface(lambda x: sphere(x, r=1.0), 100, noise=0.01, seed=1, bounds=((-1.1,) * 3, (1.1,) * 3))
    >>> p.shape, bool(abs(np.linalg.norm(p, axis=1) - 1).max() < 0.06)
    ((100, 3), True)
    """
    n = check_option(n, "n", "sample_surface", "int", positive=True)
    noise = check_option(noise, "noise", "sample_surface", minimum=0.0)
    max_rounds = check_option(max_rounds, "max_rounds", "sample_surface", "int", positive=True)
    seed = check_option(seed, "seed", "sample_surface", "int", minimum=0, none=True)
    check_memory(
        SAMPLE_BYTES_PER_POINT * n + (256 << 20), "sample_surface", f"n={n}", "draw fewer points, in several samples"
    )
    f = _field(model, params)
    if bounds is None:
        bounds = getattr(model, "bounds", None)
        if bounds is None:
            raise ValueError("bounds must be given for a function without default bounds")
    lo, hi = check_bounds(bounds, 3)
    rng = np.random.default_rng(seed)
    mesh = polygonize(f, (lo, hi), resolution, project=False)
    if mesh.is_empty():
        raise ValueError("the surface does not cross the bounds: nothing to sample")
    cell = float(np.linalg.norm((np.asarray(hi) - np.asarray(lo)) / (resolution - 1)))
    kept: list[np.ndarray] = []
    missing = n
    for _ in range(max_rounds):
        # draw a little more than missing so one round usually suffices
        draw = missing + max(16, missing // 10)
        raw = torch.from_numpy(sample_mesh(mesh, draw, rng))
        proj = project_to_surface(f, raw, max_step=cell, max_distance=cell, warn=False)
        good = proj.points[proj.converged].numpy()[:missing]
        kept.append(good)
        missing -= len(good)
        if missing == 0:
            break
    else:
        raise RuntimeError(
            f"sample_surface: only {n - missing} of {n} points converged onto f = 0 in {max_rounds} rounds; "
            "raise the resolution"
        )
    points = np.concatenate(kept)
    if noise > 0:
        points = points + rng.normal(0.0, noise, size=points.shape)
    return points


def plane_points(bounds: Any, axis: int, offset: float, n: int, dim: int = 3) -> tuple[np.ndarray, list[np.ndarray]]:
    """Points on the plane ``x[axis] = offset`` across ``bounds``, and the plane's two axes.

    Parameters
    ----------
    bounds : ((lo, ...), (hi, ...)) with ``dim`` values each, the box of the model.
    axis : the axis normal to the plane, 0, 1 or 2 (a planar model, ``dim`` 2: its whole box,
        ``axis`` and ``offset`` unused).
    offset : where the plane cuts ``axis`` (length units).
    n : samples along each of the plane's axes, >= 2.
    dim : 3, or 2 for a planar model.

    Returns
    -------
    points : (n, n, dim) float64; ``points[j, i]`` lies at ``(u[i], v[j])`` (rows follow v, as an
        image's), with ``u`` and ``v`` along the other axes in increasing order.
    axes : [u, v], each (n,) float64, the sample positions from the lower to the upper bound.

    Examples
    --------
    >>> pts, (u, v) = plane_points(((-1, -1, -1), (1, 1, 1)), axis=0, offset=0.25, n=3)
    >>> pts.shape, pts[..., 0].min(), pts[..., 0].max(), u.tolist()
    ((3, 3, 3), 0.25, 0.25, [-1.0, 0.0, 1.0])
    >>> plane_points(((-1, -1, -1), (1, 1, 1)), axis=3, offset=0.0, n=3)
    Traceback (most recent call last):
    ...
    ValueError: plane_points: axis must be 0, 1 or 2, got 3
    """
    if dim not in (2, 3):
        raise ValueError(f"plane_points: dim must be 2 or 3, got {dim!r}")
    lo, hi = check_bounds(bounds, dim)
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
        raise ValueError(f"plane_points: n must be an integer >= 2, got {n!r}")
    n = int(n)
    if dim == 2:
        u, v = np.linspace(lo[0], hi[0], n), np.linspace(lo[1], hi[1], n)
        uu, vv = np.meshgrid(u, v, indexing="xy")
        return np.stack([uu, vv], axis=-1), [u, v]
    if isinstance(axis, bool) or axis not in (0, 1, 2):
        raise ValueError(f"plane_points: axis must be 0, 1 or 2, got {axis!r}")
    if not np.isfinite(offset):
        raise ValueError(f"plane_points: offset must be finite, got {offset!r}")
    first, second = (i for i in range(3) if i != axis)
    u, v = np.linspace(lo[first], hi[first], n), np.linspace(lo[second], hi[second], n)
    uu, vv = np.meshgrid(u, v, indexing="xy")
    points = np.empty((n, n, 3))
    points[..., first], points[..., second], points[..., axis] = uu, vv, float(offset)
    return points, [u, v]
