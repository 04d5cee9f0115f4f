"""How far is an approximate distance from the true one? (paper section 5.3, Figs. 5-6).

The true signed distance to the zero set of f is computed from dense samples of the surface
itself: marching cubes, points drawn inside the triangles and projected onto f = 0 by Newton
steps, a KD-tree (scipy ``cKDTree``) over them, then a few *closest-point* steps on the
surface from the nearest sample (each accepted step moves to a surface point closer to the
query).  Every candidate is a point of {f = 0}, so the result is never below the true
distance, and where the steps converge it equals it to the projection tolerance.  The sign is
the sign of f (positive inside, the HyperFun convention).

:func:`distance_error` measures any approximate distance (a normalized f, a redistanced
network, :func:`fmm_distance`'s grid) against it on a regular grid: mean and max absolute
error, overall and in a band |d| < band.

>>> from pyfrep_core import sphere
>>> ball = lambda x: sphere(x, r=1.0)
>>> d = true_distance(ball, ((-1.5,) * 3, (1.5,) * 3), resolution=32)
>>> d(np.array([[0.0, 0.0, 0.2], [0.0, 1.5, 0.0]])).round(6)
array([ 0.8, -0.5])
>>> err = distance_error(lambda x: ball(x) / 2.0, ball, ((-1.5,) * 3, (1.5,) * 3), resolution=16, reference=d)
>>> 0.1 < err.mean < 0.5
True
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import cKDTree

from ._array import as_tensor, check_finite, check_option, check_points
from .diff import grad, project_to_surface
from .evaluate import evaluate
from .meshing import Mesh, evaluate_grid, grid_axes, polygonize
from .model import check_bounds
from .progress import StopFlag
from .sampling import sample_surface

__all__ = [
    "SurfaceSamples",
    "TrueDistance",
    "DistanceError",
    "SurfaceDistance",
    "FMMDistance",
    "surface_samples",
    "true_distance",
    "distance_error",
    "surface_distance",
    "fmm_distance",
]

CHUNK = 1 << 16  # query points per refinement pass: bounds memory
MAX_RESOLUTION = 512  # grid samples per axis; 512^3 doubles are already 1 GiB
MAX_COORDINATE = 1e150  # |x| beyond: squared distances (~|x|^2) overflow float64


def _check_coordinates(t: torch.Tensor, name: str) -> None:
    """Refuse coordinates whose squared distances overflow float64 (the KD-tree then finds no sample)."""
    big = t.abs() > MAX_COORDINATE
    if bool(big.any()):
        idx = tuple(int(i) for i in torch.nonzero(big)[0])
        raise ValueError(
            f"TrueDistance: {name} has a coordinate {t[idx].item()!r} at index {idx}; the distance is "
            f"computed in float64 for coordinates up to {MAX_COORDINATE:g} in magnitude"
        )


def _check_callable(f: Any, name: str = "f") -> None:
    if not callable(f):
        raise TypeError(f"{name} must be callable (points (N, 3) -> values (N,)), got {type(f).__name__}")


def _check_resolution(resolution: Any, fn: str) -> int:
    return check_option(resolution, "resolution", fn, "int", minimum=2, maximum=MAX_RESOLUTION)


@dataclass
class SurfaceSamples:
    """Points on f = 0 (M, 3) float64 with unit outward normals (M, 3) and the mean spacing."""

    points: np.ndarray
    normals: np.ndarray
    spacing: float


def _triangle_samples(mesh: Mesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points uniform on the mesh (area-weighted triangle choice, uniform barycentrics)."""
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    tri = rng.choice(len(area), size=n, p=area / area.sum())
    u = rng.random((n, 2))
    flip = u.sum(1) > 1.0
    u[flip] = 1.0 - u[flip]
    return a[tri] + u[:, :1] * (b - a)[tri] + u[:, 1:] * (c - a)[tri]


def surface_samples(
    f: Callable,
    bounds: Any,
    resolution: int = 96,
    n_points: int | None = None,
    seed: int | None = 0,
) -> SurfaceSamples:
    """Dense points on the surface f = 0 inside ``bounds``, projected onto it.

    Marching cubes at ``resolution`` (vertices projected onto f = 0 by :func:`polygonize`),
    plus ``n_points`` points drawn uniformly inside the triangles and projected onto f = 0
    by Newton steps (float64).  Points whose projection does not converge are dropped.

    Parameters
    ----------
    f : callable (N, 3) -> (N,)
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax))
    resolution : marching-cubes grid samples per axis.
    n_points : extra points drawn inside triangles; default 4 per mesh vertex.
    seed : random seed of the triangle samples.

    Returns
    -------
    SurfaceSamples ; ``spacing`` = sqrt(area / number of points), a typical sample distance.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> s = surface_samples(lambda x: sphere(x, r=1.0), ((-1.5,) * 3, (1.5,) * 3), 24)
    >>> bool(np.allclose(np.linalg.norm(s.points, axis=1), 1.0))
    True
    """
    _check_callable(f)
    bounds = check_bounds(bounds, 3)
    resolution = _check_resolution(resolution, "surface_samples")
    n_points = check_option(n_points, "n_points", "surface_samples", "int", minimum=0, none=True)
    seed = check_option(seed, "seed", "surface_samples", "int", minimum=0, none=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an empty mesh is reported below
        mesh = polygonize(f, bounds, resolution)
    if mesh.is_empty():
        raise ValueError("f has no zero set inside bounds (it does not change sign there): no surface to sample")
    n_points = 4 * mesh.n_vertices if n_points is None else n_points
    rng = np.random.default_rng(seed)
    extra = _triangle_samples(mesh, n_points, rng)
    # half of them pushed off the surface first: Newton steps from outside a sharp edge or
    # corner (an R-function's Boolean) end near it, where marching cubes cuts the solid
    cell = float(np.linalg.norm([(b - a) / (resolution - 1) for a, b in zip(*bounds)]))
    half = n_points // 2
    extra[:half] += rng.normal(scale=3.0 * cell, size=(half, 3))
    proj = project_to_surface(f, torch.as_tensor(extra, dtype=torch.float64), max_iter=20, warn=False)
    ok = proj.converged.numpy()
    points = np.concatenate([mesh.vertices, proj.points.numpy()[ok]])
    g = np.concatenate([-mesh.normals, proj.gradient.numpy()[ok]])
    lo, hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    inside = np.all((points >= lo) & (points <= hi), axis=1)
    points, g = points[inside], g[inside]
    normals = -g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), np.finfo(np.float64).tiny)
    spacing = float(np.sqrt(mesh.area() / max(len(points), 1)))
    return SurfaceSamples(points, normals, spacing)


def _tangent(x: torch.Tensor, y: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Component of x - y in the tangent plane at y (normal direction g)."""
    n = g / g.norm(dim=1, keepdim=True).clamp_min(torch.finfo(g.dtype).tiny)
    r = x - y
    return r - (r * n).sum(1, keepdim=True) * n


def _closest_point_steps(
    f: Callable,
    x: torch.Tensor,
    y: torch.Tensor,
    best: torch.Tensor,
    steps: int,
    tol: float = 1e-10,
    stop: StopFlag | None = None,
) -> None:
    """Move surface points ``y`` (in place) toward the closest points of f = 0 to ``x``.

    At the closest point, x - y is normal to the surface: the tangent part t of x - y
    vanishes.  A step goes to ``project(y + alpha t)``; alpha is a secant (quasi-Newton)
    estimate of 1 / (1 - d kappa) from how t changed over the previous step, so the
    iteration converges fast on curved surfaces, where the plain step (alpha = 1)
    overshoots.  A step is kept only if it lands on a closer surface point (``best`` never
    increases), else alpha is halved.  A set ``stop`` flag ends the steps early (checked
    before each).
    """
    active = torch.arange(len(x))
    t0 = _tangent(x, y, grad(f, y))
    alpha = torch.ones_like(best)
    for _ in range(steps):
        if stop is not None and stop.is_set():
            break
        moving = t0.norm(dim=1) > tol
        active, t0, alpha = active[moving], t0[moving], alpha[moving]
        if active.numel() == 0:
            break
        xa = x[active]
        proj = project_to_surface(f, y[active] + alpha[:, None] * t0, max_iter=8, warn=False)
        t1 = _tangent(xa, proj.points, proj.gradient)
        d = (xa - proj.points).norm(dim=1)
        better = proj.converged & (d < best[active])
        # secant estimate of the Newton step length along t0
        change = (t0 * (t0 - t1)).sum(1)
        newton = alpha * (t0 * t0).sum(1) / change.clamp_min(torch.finfo(x.dtype).tiny)
        newton = torch.where(change > 0, newton.clamp(0.02, 4.0), alpha)
        idx = active[better]
        y[idx] = proj.points[better]
        best[idx] = d[better]
        t0 = torch.where(better[:, None], t1, t0)
        alpha = torch.where(better, newton, torch.minimum(0.5 * alpha, newton))


@dataclass
class TrueDistance:
    """Signed distance to the zero set of ``f`` from surface samples (see :func:`true_distance`).

    Calling it on points (..., 3), numpy or torch, gives the signed distance (...), positive
    where f > 0, same kind as the input (torch results are float64 on the input's device).
    """

    f: Callable
    samples: SurfaceSamples
    tree: cKDTree
    refine_steps: int = 8
    max_points: int = 1 << 24

    def __post_init__(self) -> None:
        _check_callable(self.f)
        self.refine_steps = check_option(self.refine_steps, "refine_steps", "TrueDistance", "int", minimum=0)
        self.max_points = check_option(self.max_points, "max_points", "TrueDistance", "int", positive=True)

    def unsigned(self, points: np.ndarray, stop: StopFlag | None = None) -> np.ndarray:
        """Unsigned distance (N,) float64 for points (N, 3) float64.

        ``stop`` (an object with ``is_set()``) ends the closest-point steps early once set: the
        distances are then those of fewer ``refine_steps`` (still never below the true one).
        """
        _check_coordinates(torch.as_tensor(points), "points")
        out = np.empty(len(points))
        for i in range(0, len(points), CHUNK):
            q = points[i : i + CHUNK]
            d, j = self.tree.query(q, workers=-1)
            if self.refine_steps > 0:
                x = torch.as_tensor(q, dtype=torch.float64)
                y = torch.as_tensor(self.samples.points[j], dtype=torch.float64).clone()
                best = torch.as_tensor(d, dtype=torch.float64).clone()
                _closest_point_steps(self.f, x, y, best, self.refine_steps, stop=stop)
                d = best.numpy()
            out[i : i + CHUNK] = d
        return out

    def __call__(self, points: Any) -> Any:
        t, was_numpy = as_tensor(points, "points")
        check_points(t, 3, "points")
        check_finite(t, "points")
        _check_coordinates(t, "points")
        shape = t.shape[:-1]
        q = t.detach().reshape(-1, 3).to(dtype=torch.float64, device="cpu")
        if q.shape[0] > self.max_points:
            raise ValueError(f"points: {q.shape[0]} points exceed max_points={self.max_points}")
        dist = torch.as_tensor(self.unsigned(q.numpy()))
        with torch.no_grad():
            sign = torch.sign(evaluate(self.f, q))
        d = (sign * dist).reshape(shape)
        return d.numpy() if was_numpy else d.to(t.device)


def true_distance(
    f: Callable,
    bounds: Any,
    resolution: int = 96,
    n_points: int | None = None,
    refine_steps: int = 8,
    seed: int | None = 0,
) -> TrueDistance:
    """The signed distance to {f = 0}, as a callable, from dense projected surface samples.

    Parameters
    ----------
    f : callable (N, 3) -> (N,), f >= 0 inside.
    bounds : the box whose part of the surface is sampled (the distance is to that part).
    resolution : marching-cubes resolution of the sampling mesh.
    n_points : extra samples inside triangles (default 4 per mesh vertex).
    refine_steps : closest-point steps after the KD-tree query; 0 gives the plain distance
        to the nearest sample, which overestimates by at most the samples' covering radius.
    seed : random seed of the samples.

    Returns
    -------
    TrueDistance : call it on points (..., 3) for the signed distance (positive inside).

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> d = true_distance(lambda x: sphere(x, r=1.0), ((-1.5,) * 3, (1.5,) * 3), 24)
    >>> float(d(np.array([[0.3, 0.4, 0.0]]))[0])  # 1 - 0.5
    0.5
    """
    _check_callable(f)
    refine_steps = check_option(refine_steps, "refine_steps", "true_distance", "int", minimum=0)
    samples = surface_samples(f, bounds, resolution, n_points, seed)
    return TrueDistance(f, samples, cKDTree(samples.points), refine_steps)


@dataclass
class DistanceError:
    """Absolute error |approx - true| on a grid: overall and in the band |true| < band.

    ``errors`` and ``reference`` are (n, n, n) grids (``axes`` gives their coordinates);
    band statistics are NaN when no band was asked for.
    """

    mean: float
    max: float
    band: float | None
    band_mean: float
    band_max: float
    n_band: int
    resolution: int
    errors: np.ndarray = field(repr=False)
    reference: np.ndarray = field(repr=False)
    axes: list[np.ndarray] = field(repr=False)
    seconds: dict[str, float] = field(default_factory=dict)


def distance_error(
    approx: Callable,
    f: Callable,
    bounds: Any,
    resolution: int = 64,
    band: float | None = None,
    reference: TrueDistance | np.ndarray | None = None,
    dtype: torch.dtype = torch.float64,
) -> DistanceError:
    """Compare an approximate signed distance with the true one on a regular grid.

    Parameters
    ----------
    approx : callable on points (..., 3) (torch tensors of ``dtype``) -> (...): a normalized
        f, a redistanced network, an :class:`FMMDistance` ...
    f : the defining function whose zero set the distance is to.
    bounds : the box; the grid has ``resolution`` samples per axis, end points included.
    band : also report the error where |true distance| < band.
    reference : a :class:`TrueDistance` (or the true distance already on this grid, an
        (n, n, n) array) to reuse; computed with :func:`true_distance` when None.
    dtype : dtype the approximation is evaluated in.

    Returns
    -------
    DistanceError

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> ball = lambda x: sphere(x, r=1.0)
    >>> exact = lambda x: 1.0 - x.norm(dim=-1)
    >>> e = distance_error(exact, ball, ((-1.5,) * 3, (1.5,) * 3), resolution=12, band=0.2)
    >>> e.max < 1e-9, e.n_band > 0
    (True, True)
    """
    _check_callable(approx, "approx")
    _check_callable(f)
    bounds = check_bounds(bounds, 3)
    resolution = _check_resolution(resolution, "distance_error")
    band = check_option(band, "band", "distance_error", positive=True, none=True)
    dtype = check_option(dtype, "dtype", "distance_error", "choice", choices=(torch.float32, torch.float64))
    axes = grid_axes(bounds, resolution)
    timing: dict[str, float] = {}
    start = time.perf_counter()
    if isinstance(reference, np.ndarray):
        if reference.shape != (resolution,) * 3:
            raise ValueError(f"reference grid has shape {reference.shape}, expected {(resolution,) * 3}")
        ref = reference
    else:
        if reference is None:
            reference = true_distance(f, bounds)
        elif not isinstance(reference, TrueDistance):
            raise TypeError(f"reference must be a TrueDistance or an array, got {type(reference).__name__}")
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        ref = reference(grid.reshape(-1, 3)).reshape(grid.shape[:-1])
    timing["reference"] = time.perf_counter() - start
    start = time.perf_counter()
    values = evaluate_grid(approx, bounds, resolution, dtype=dtype, max_points=1 << 17).astype(np.float64)
    timing["approx"] = time.perf_counter() - start
    if not np.isfinite(values).all():
        raise ValueError("approx is not finite on the grid (NaN or inf values)")
    err = np.abs(values - ref)
    band_mean = band_max = float("nan")
    n_band = 0
    if band is not None:
        mask = np.abs(ref) < band
        n_band = int(mask.sum())
        if n_band:
            band_mean, band_max = float(err[mask].mean()), float(err[mask].max())
    return DistanceError(
        float(err.mean()), float(err.max()), band, band_mean, band_max, n_band, resolution, err, ref, axes, timing
    )


@dataclass
class SurfaceDistance:
    """How far apart two surfaces are (see :func:`surface_distance`), in length units.

    ``a_to_b`` (n,) are the distances from points spread uniformly over surface a to surface
    b, ``b_to_a`` the other way; ``chamfer`` is the mean of their two means, ``hausdorff`` the
    largest of all (a lower bound of the true Hausdorff distance, within the samples' spacing).
    """

    chamfer: float
    hausdorff: float
    a_to_b: np.ndarray = field(repr=False)
    b_to_a: np.ndarray = field(repr=False)


def surface_distance(
    a: Callable,
    b: Callable,
    bounds: Any,
    n_points: int = 5000,
    resolution: int = 64,
    refine_steps: int = 4,
    seed: int = 0,
) -> SurfaceDistance:
    """Chamfer and Hausdorff distances between the zero sets of two functions inside ``bounds``.

    ``n_points`` points are spread uniformly (by area) over each surface and projected onto it
    (:func:`pyfrep_core.sampling.sample_surface`); their distances to the other surface are
    :func:`true_distance`'s (nearest of ``n_points`` projected samples, then ``refine_steps``
    closest-point steps), exact where the steps converge.  The measure of a reconstruction
    (a fitted model, a free-form fit) against the surface it was sampled from.

    Parameters
    ----------
    a, b : callables (N, 3) -> (N,) (models), each with a zero set inside ``bounds``.
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)).
    n_points : sample points on each surface.
    resolution : marching-cubes resolution of the sampling meshes (fine enough for the
        thinnest feature of both surfaces).
    refine_steps : closest-point steps per distance (0: distance to the nearest sample).
    seed : seeds the samples.

    Returns
    -------
    SurfaceDistance

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> box = ((-1.5,) * 3, (1.5,) * 3)
    >>> d = surface_distance(lambda x: sphere(x, r=1.0), lambda x: sphere(x, r=1.1), box, 500, 32)
    >>> round(d.chamfer, 9), round(d.hausdorff, 9)
    (0.1, 0.1)
    """
    _check_callable(a, "a")
    _check_callable(b, "b")
    bounds = check_bounds(bounds, 3)
    n_points = check_option(n_points, "n_points", "surface_distance", "int", positive=True)
    resolution = _check_resolution(resolution, "surface_distance")
    refine_steps = check_option(refine_steps, "refine_steps", "surface_distance", "int", minimum=0)
    seed = check_option(seed, "seed", "surface_distance", "int", minimum=0)
    on_a = sample_surface(a, n_points, bounds=bounds, resolution=resolution, seed=seed)
    on_b = sample_surface(b, n_points, bounds=bounds, resolution=resolution, seed=seed + 1)
    to_a = true_distance(a, bounds, resolution, n_points=n_points, refine_steps=refine_steps, seed=seed + 2)
    to_b = true_distance(b, bounds, resolution, n_points=n_points, refine_steps=refine_steps, seed=seed + 3)
    a_to_b, b_to_a = to_b.unsigned(on_a), to_a.unsigned(on_b)
    chamfer = 0.5 * (float(a_to_b.mean()) + float(b_to_a.mean()))
    return SurfaceDistance(chamfer, float(max(a_to_b.max(), b_to_a.max())), a_to_b, b_to_a)


@dataclass
class FMMDistance:
    """scikit-fmm's signed distance on a grid, with trilinear interpolation between nodes.

    ``grid`` is (nx, ny, nz) float64 on ``axes``; calling it on points (..., 3) inside the
    bounds interpolates (numpy in -> numpy out, torch in -> torch out); outside -> ValueError.
    """

    grid: np.ndarray
    axes: list[np.ndarray]
    seconds: float
    interpolator: RegularGridInterpolator = field(repr=False)

    def __call__(self, points: Any) -> Any:
        t, was_numpy = as_tensor(points, "points")
        check_points(t, 3, "points")
        q = t.detach().reshape(-1, 3).to(dtype=torch.float64, device="cpu").numpy()
        try:
            v = self.interpolator(q)
        except ValueError as err:
            raise ValueError(f"points outside the FMM grid's bounds: {err}") from None
        v = v.reshape(tuple(t.shape[:-1]))
        return v if was_numpy else torch.as_tensor(v, dtype=t.dtype, device=t.device)


def fmm_distance(f: Callable, bounds: Any, resolution: int = 128) -> FMMDistance:
    """Grid redistancing of f by the fast marching method (``skfmm.distance``), a reference.

    f is sampled on the grid (float64) and ``skfmm.distance(values, dx=spacing)`` solves
    |grad d| = 1 from the interpolated zero crossing; first-order accurate, and only on the grid.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> d = fmm_distance(lambda x: sphere(x, r=1.0), ((-1.5,) * 3, (1.5,) * 3), 48)
    >>> abs(float(d(np.array([[0.5, 0.0, 0.0]]))[0]) - 0.5) < 0.05
    True
    """
    import skfmm

    _check_callable(f)
    bounds = check_bounds(bounds, 3)
    resolution = _check_resolution(resolution, "fmm_distance")
    axes = grid_axes(bounds, resolution)
    start = time.perf_counter()
    values = evaluate_grid(f, bounds, resolution, dtype=torch.float64)
    if not np.isfinite(values).all():
        raise ValueError("f is not finite on the grid (NaN or inf values)")
    if values.min() >= 0.0 or values.max() <= 0.0:
        raise ValueError("f has no zero set inside bounds (it does not change sign there)")
    dx = [float(a[1] - a[0]) for a in axes]
    grid = np.asarray(skfmm.distance(values, dx=dx), dtype=np.float64)
    seconds = time.perf_counter() - start
    interp = RegularGridInterpolator(axes, grid, method="linear", bounds_error=True)
    return FMMDistance(grid, axes, seconds, interp)
