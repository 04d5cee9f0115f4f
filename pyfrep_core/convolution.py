"""Convolution surfaces with the Cauchy kernel, in closed form (McCormack & Sherstyuk 1998).

A skeleton (points, segments, polylines, triangles, meshes, circular arcs) is convolved with
the Cauchy kernel

    K(r) = 1 / (1 + S^2 r^2)^2,

where r is the distance to the skeleton and S > 0 controls the kernel width (larger S, thinner
surface).  The field is ``F(x) = sum over elements of the integral of K(|x - s|) ds`` (ds: arc
length for curves, area for triangles), and the solid is ``f = F - T >= 0`` for a threshold T.
Adding elements blends them smoothly: that is the appeal of convolution surfaces.

Argument conventions follow the paper's reference code: skeletons may be given flat
(``[x0, y0, z0, x1, y1, z1, ...]``) or as rows ((M, 3) points, (M, 3, 3) triangles); ``S`` is one
value per element (or one number for all); angles of :func:`convArc` are in degrees.  All
functions are vectorised over points *and* skeleton elements (broadcasting, evaluated in chunks
of points to bound memory) and differentiable with respect to x, S, T and the skeleton.  As for
the primitives, a (B, 1) tensor for ``S`` or ``T`` (and ``R`` of :func:`convLineR`) gives (B, N)
values for B parameter sets when called directly (``@model`` runs parameter sets through
``torch.func.vmap`` instead: these functions see 0-d parameters, and the value checks are
skipped while tracing, as :func:`pyfrep_core._array.check_param` does).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from ._array import check_points, frep, tracing

__all__ = [
    "convPoint",
    "convLine",
    "convLineR",
    "convCurve",
    "convTriangle",
    "convMesh",
    "convArc",
]

Skeleton = Sequence[float] | np.ndarray | torch.Tensor
PerElement = float | Sequence[float] | np.ndarray | torch.Tensor

# Elements of the (points x skeleton elements) temporaries per chunk (~4 MB each in float64).
_CHUNK = 1 << 19


def _tensor(v: Any, like: torch.Tensor, name: str) -> torch.Tensor:
    if isinstance(v, torch.Tensor):
        return v.to(device=like.device, dtype=like.dtype)
    try:
        arr = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be numeric, got {type(v).__name__}") from None
    return torch.as_tensor(arr, dtype=like.dtype, device=like.device)


def _rows(v: Any, like: torch.Tensor, width: int, name: str) -> torch.Tensor:
    """Skeleton coordinates, flat (width * M,), (M, ...) rows or one element's shape -> (M, width)."""
    t = _tensor(v, like, name)
    grouped = t.ndim == 1 or t.numel() == width or (t.ndim > 1 and t[0].numel() == width)
    if t.ndim == 0 or t.numel() == 0 or t.numel() % width != 0 or not grouped:
        raise ValueError(f"{name} must hold M groups of {width} coordinates, got shape {tuple(t.shape)}")
    if not tracing(t) and not bool(torch.isfinite(t).all()):
        raise ValueError(f"{name} contains a non-finite value")
    return t.reshape(-1, width)


def _per_element(v: Any, m: int, like: torch.Tensor, name: str, positive: bool = True) -> torch.Tensor:
    """One value per skeleton element: a number (shared) or M values -> (M,)."""
    t = _tensor(v, like, name).reshape(-1)
    if t.numel() == 1:
        t = t.expand(m)
    if t.numel() != m:
        raise ValueError(f"{name} must have 1 or {m} values (one per element), got {t.numel()}")
    if positive and not tracing(t) and not bool((t > 0).all()):
        raise ValueError(f"{name} must be positive, got {v!r}")
    return t


def _batchable(v: Any, m: int, like: torch.Tensor, name: str) -> torch.Tensor:
    """Like :func:`_per_element`, but a (B, 1) tensor (B parameter sets, for a direct call)
    becomes (B, 1, 1): it broadcasts over (points, elements) and gives (B, ...) values."""
    if isinstance(v, torch.Tensor) and v.ndim == 2 and v.shape[1] == 1:
        t = v.to(device=like.device, dtype=like.dtype)
        if not tracing(t) and not bool((t > 0).all()):
            raise ValueError(f"{name} must be positive, got {v!r}")
        return t.reshape(-1, 1, 1)
    return _per_element(v, m, like, name)


def _field(x: torch.Tensor, m: int, kernel: Callable[[torch.Tensor], torch.Tensor], batch: int = 1) -> torch.Tensor:
    """Sum over M elements of ``kernel(points (P, 1, 3)) -> ([B,] P, M)``, in chunks of points."""
    check_points(x, empty=True)  # no points give no values
    flat = x.reshape(-1, 3)
    chunk = max(1, _CHUNK // (m * batch))
    parts = [kernel(part[:, None, :]).sum(-1) for part in torch.split(flat, chunk)]
    out = torch.cat(parts, dim=-1)
    return out.reshape(*out.shape[:-1], *x.shape[:-1])


def _batch(*values: torch.Tensor) -> int:
    return max(v.shape[0] if v.ndim == 3 else 1 for v in values)


def _segment_integral(t: torch.Tensor, h2: torch.Tensor, length: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Integral over [0, l] of K at a point with axial coordinate t and squared distance h2 to the line.

    int du / (p^2 + S^2 u^2)^2 = u / (2 p^2 (p^2 + S^2 u^2)) + atan(S u / p) / (2 S p^3),
    with p^2 = 1 + S^2 h2, taken between u = -t and u = l - t.
    """
    s2 = s * s
    p2 = 1.0 + s2 * h2.clamp_min(0.0)
    p = torch.sqrt(p2)
    rest = length - t
    return (
        t / (2.0 * p2 * (p2 + s2 * t * t))
        + rest / (2.0 * p2 * (p2 + s2 * rest * rest))
        + (torch.atan(s * t / p) + torch.atan(s * rest / p)) / (2.0 * s * p2 * p)
    )


def _segments(
    x: torch.Tensor, begin: torch.Tensor, end: torch.Tensor, s: torch.Tensor, weight: torch.Tensor | None = None
) -> torch.Tensor:
    """Sum over segments of the closed-form line integral (times ``weight``); begin, end (M, 3), s (M,)."""
    axis = end - begin
    length = axis.norm(dim=-1)
    if not tracing(length) and not bool((length > 0).all()):
        raise ValueError("segments must have a positive length (begin != end)")
    unit = axis / length[:, None]

    def kernel(p: torch.Tensor) -> torch.Tensor:
        d = p - begin
        t = (d * unit).sum(-1)
        perp = d - t[..., None] * unit  # not |d|^2 - t^2: no cancellation far along the axis
        value = _segment_integral(t, (perp * perp).sum(-1), length, s)
        return value if weight is None else value * weight

    return _field(x, begin.shape[0], kernel, _batch(s) if weight is None else _batch(s, weight))


@frep
def convPoint(x: torch.Tensor, vect: Skeleton, S: PerElement, T: float | torch.Tensor) -> torch.Tensor:
    """Convolution surface of skeleton points: ``sum_i 1 / (1 + S_i^2 |x - c_i|^2)^2 - T``.

    Parameters
    ----------
    x : (..., 3) points.
    vect : M skeleton points, flat (3M,) or (M, 3).
    S : kernel width control, one number or (M,) values, > 0.
    T : threshold; a single point with ``T = 1 / (1 + S^2 R^2)^2`` gives a sphere of radius R.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> convPoint(torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), [0, 0, 0], S=1.0, T=0.25)
    tensor([0.7500, 0.0000])
    """
    centers = _rows(vect, x, 3, "vect")
    s = _batchable(S, centers.shape[0], x, "S")

    def kernel(p: torch.Tensor) -> torch.Tensor:
        r2 = ((p - centers) ** 2).sum(-1)
        return 1.0 / (1.0 + s * s * r2) ** 2

    return _field(x, centers.shape[0], kernel, _batch(s)) - T


@frep
def convLine(x: torch.Tensor, begin: Skeleton, end: Skeleton, S: PerElement, T: float | torch.Tensor) -> torch.Tensor:
    """Convolution surface of line segments (closed-form integral of the Cauchy kernel).

    For a segment of length l along the unit vector a from b, with t = (x - b) . a and
    p^2 = 1 + S^2 (|x - b|^2 - t^2) (squared distance to the line):

    ``F = t / (2 p^2 (1 + S^2 |x - b|^2)) + (l - t) / (2 p^2 q^2)
    + (atan(S t / p) + atan(S (l - t) / p)) / (2 S p^3)``, q^2 = 1 + S^2 |x - b - l a|^2.

    Parameters
    ----------
    x : (..., 3) points.
    begin, end : M segment end points, flat (3M,) or (M, 3).
    S : kernel width control, one number or (M,) values, > 0.
    T : threshold.

    Returns
    -------
    (...) field values ``sum F - T``.

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([[0.5, 0.0, 0.0], [0.5, 0.0, 3.0]], dtype=torch.float64)
    >>> convLine(x, begin=[0, 0, 0], end=[1, 0, 0], S=2.0, T=0.1) > 0
    tensor([ True, False])
    """
    b = _rows(begin, x, 3, "begin")
    e = _rows(end, x, 3, "end")
    if b.shape != e.shape:
        raise ValueError(f"begin and end must hold the same number of points, got {b.shape[0]} and {e.shape[0]}")
    return _segments(x, b, e, _batchable(S, b.shape[0], x, "S")) - T


@frep
def convCurve(x: torch.Tensor, vect: Skeleton, S: PerElement, T: float | torch.Tensor) -> torch.Tensor:
    """Convolution surface of a polyline through the points ``vect`` (N + 1 points, N segments).

    Parameters
    ----------
    x : (..., 3) points.
    vect : polyline vertices, flat (3(N+1),) or (N+1, 3), N >= 1.
    S : kernel width control, one number or (N,) values (one per segment), > 0.
    T : threshold.

    Returns
    -------
    (...) field values: the sum of :func:`convLine` fields of consecutive segments, minus T.

    Examples
    --------
    >>> import torch
    >>> pts = [0, 0, 0, 1, 0, 0, 1, 1, 0]            # an L-shaped polyline
    >>> convCurve(torch.tensor([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0]]), pts, S=3.0, T=0.2) > 0
    tensor([ True, False])
    """
    v = _rows(vect, x, 3, "vect")
    if v.shape[0] < 2:
        raise ValueError(f"vect must hold at least 2 points, got {v.shape[0]}")
    return _segments(x, v[:-1], v[1:], _batchable(S, v.shape[0] - 1, x, "S")) - T


@frep
def convLineR(x: torch.Tensor, begin: Skeleton, end: Skeleton, S: PerElement, R: PerElement) -> torch.Tensor:
    """Convolution segments with a radius: each segment's field is scaled so that f = 0 at distance R.

    ``f = sum_i F_i(x) / F_i(m_i + R_i n_i) - 1``: F_i is the :func:`convLine` field of segment
    i and ``m_i + R_i n_i`` a point at distance R_i from the segment's midpoint, perpendicular to
    it.  An isolated segment therefore gives a rounded rod whose radius at the middle is exactly
    R (thinner towards the ends, more so for small S); segments that meet blend smoothly.
    (The reference code instead sets S = 1/R when R < 1, calibrates at the end point and clamps
    the sum at 1; here S is kept as given and the field stays smooth.)

    Parameters
    ----------
    x : (..., 3) points.
    begin, end : M segment end points, flat (3M,) or (M, 3).
    S : kernel width control, one number or (M,) values, > 0.
    R : radius, one number or (M,) values, > 0.

    Returns
    -------
    (...) field values, 0 on the surface.

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([[0.5, 0.3, 0.0]], dtype=torch.float64)
    >>> convLineR(x, begin=[0, 0, 0], end=[1, 0, 0], S=2.0, R=0.3).abs() < 1e-12
    tensor([True])
    """
    b = _rows(begin, x, 3, "begin")
    e = _rows(end, x, 3, "end")
    if b.shape != e.shape:
        raise ValueError(f"begin and end must hold the same number of points, got {b.shape[0]} and {e.shape[0]}")
    m = b.shape[0]
    s = _batchable(S, m, x, "S")
    r = _batchable(R, m, x, "R")
    length = (e - b).norm(dim=-1)
    # F_i at distance R_i from the midpoint: t = l/2, squared distance to the line R^2
    at_radius = _segment_integral(0.5 * length, r * r, length, s)
    return _segments(x, b, e, s, weight=1.0 / at_radius) - 1.0


def _triangle_frames(tri: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Per-triangle frame of the closed form; tri (M, 3, 3) -> foot b, unit vectors u, v, h, a1, a2.

    The vertices are cycled so that the longest edge is a1-a2; then the foot b of the height from
    a3 lies strictly inside that edge, u points from b to a2, v from b to a3, h = |a3 - b|,
    a1 = |a1 - b| and a2 = |a2 - b|.
    """
    edges = (tri.roll(-1, dims=1) - tri).norm(dim=-1)  # |v1 - v0|, |v2 - v1|, |v0 - v2|
    first = edges.argmax(dim=1)
    order = (first[:, None] + torch.arange(3, device=tri.device)) % 3
    tri = torch.gather(tri, 1, order[:, :, None].expand(-1, -1, 3))
    p1, p2, p3 = tri[:, 0], tri[:, 1], tri[:, 2]
    e12 = p2 - p1
    t = ((p3 - p1) * e12).sum(-1) / (e12 * e12).sum(-1)
    foot = p1 + t[:, None] * e12
    height = (p3 - foot).norm(dim=-1)
    if not tracing(height) and not bool((height > 1e-12 * edges.max(dim=1).values).all()):
        raise ValueError("triangles must have a positive area (non-collinear vertices)")
    u = e12 / e12.norm(dim=-1, keepdim=True)
    v = (p3 - foot) / height[:, None]
    return foot, u, v, height, (p1 - foot).norm(dim=-1), (p2 - foot).norm(dim=-1)


def _triangles(x: torch.Tensor, tri: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Sum over triangles (M, 3, 3) of the closed-form area integral of the Cauchy kernel.

    In the frame of :func:`_triangle_frames` a point has coordinates (u, v) in the plane and w
    normal to it; with C^2 = 1/S^2 + v^2 + w^2 and q = 1/S^2 + w^2 the integral is a sum of
    three arctangent terms (McCormack & Sherstyuk 1998), one per edge.
    """
    foot, eu, ev, h, a1, a2 = _triangle_frames(tri)
    normal = torch.linalg.cross(eu, ev)

    def kernel(p: torch.Tensor) -> torch.Tensor:
        d = p - foot
        u = (d * eu).sum(-1)
        v = (d * ev).sum(-1)
        n = (d * normal).sum(-1)
        g = v - h
        q = 1.0 / (s * s) + n * n  # 1/S^2 + w^2 >= 1/S^2 > 0
        c2 = q + v * v
        c = torch.sqrt(c2)
        w = c2 - 2.0 * v * h + h * h
        base = h * h * (q + u * u)
        a = torch.sqrt(a1 * a1 * w + base - 2.0 * a1 * h * u * g)
        b = torch.sqrt(a2 * a2 * w + base + 2.0 * a2 * h * u * g)
        edge1 = (u * h - a1 * g) * (torch.atan((a1 * (a1 + u) + v * h) / a) + torch.atan((-a1 * u - g * h) / a)) / a
        edge2 = (a2 * g + u * h) * (torch.atan((-a2 * (a2 - u) - v * h) / b) + torch.atan((-a2 * u + g * h) / b)) / b
        edge3 = v * (torch.atan((a1 + u) / c) + torch.atan((a2 - u) / c)) / c
        # the reference code returns S^3 times this value (its thresholds scale accordingly)
        return (edge1 + edge2 + edge3) / (2.0 * q * s**4)

    return _field(x, tri.shape[0], kernel, _batch(s))


@frep
def convTriangle(x: torch.Tensor, vect: Skeleton, S: PerElement, T: float | torch.Tensor) -> torch.Tensor:
    """Convolution surface of triangles: the area integral of the Cauchy kernel, in closed form.

    Parameters
    ----------
    x : (..., 3) points.
    vect : M triangles, flat (9M,) as in the reference code, (M, 9) or (M, 3, 3) vertices.
    S : kernel width control, one number or (M,) values, > 0.
    T : threshold.

    Returns
    -------
    (...) field values ``sum_i int_{triangle i} K(|x - s|) dA(s) - T``.

    Notes
    -----
    The reference code's closed form returns S^3 times this integral; a threshold T_ref
    written for it corresponds to ``T = T_ref / S^3`` here.

    Examples
    --------
    >>> import torch
    >>> tri = [0, 0, 0, 1, 0, 0, 0, 1, 0]
    >>> convTriangle(torch.tensor([[0.3, 0.3, 0.0], [0.3, 0.3, 1.0]]), tri, S=4.0, T=0.05) > 0
    tensor([ True, False])
    """
    tri = _rows(vect, x, 9, "vect").reshape(-1, 3, 3)
    return _triangles(x, tri, _batchable(S, tri.shape[0], x, "S")) - T


@frep
def convMesh(
    x: torch.Tensor,
    vect: Skeleton,
    tri: Sequence[int] | np.ndarray | torch.Tensor,
    S: PerElement,
    T: float | torch.Tensor,
    base: int = 1,
) -> torch.Tensor:
    """Convolution surface of a triangle mesh given by vertices and vertex indices.

    Parameters
    ----------
    x : (..., 3) points.
    vect : V vertices, flat (3V,) or (V, 3).
    tri : M triangles as vertex indices, flat (3M,) or (M, 3).  Indices start at ``base``:
        1 as in the reference (HyperFun) code, pass ``base=0`` for 0-based faces such as
        ``Mesh.faces``.
    S : kernel width control, one number or (M,) values, > 0.
    T : threshold.
    base : index of the first vertex (0 or 1).

    Returns
    -------
    (...) field values, the :func:`convTriangle` field of the gathered triangles minus T.

    Examples
    --------
    >>> import torch
    >>> square = [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0]
    >>> convMesh(torch.tensor([[0.5, 0.5, 0.0], [0.5, 0.5, 1.0]]), square, [1, 2, 3, 1, 3, 4], S=4.0, T=0.05) > 0
    tensor([ True, False])
    """
    verts = _rows(vect, x, 3, "vect")
    if base not in (0, 1):
        raise ValueError(f"base must be 0 or 1, got {base!r}")
    index = tri.detach().cpu() if isinstance(tri, torch.Tensor) else torch.as_tensor(np.asarray(tri))
    # numpy integer faces arrive as float64 through @frep: integral values are accepted
    integral = not index.dtype.is_floating_point or bool((index == index.round()).all())
    if index.dtype == torch.bool or index.numel() == 0 or index.numel() % 3 or not integral:
        raise ValueError(f"tri must hold M triples of integer vertex indices, got {tri!r}")
    index = index.reshape(-1, 3).to(torch.int64) - base
    if int(index.min()) < 0 or int(index.max()) >= verts.shape[0]:
        lo, hi = int(index.min()) + base, int(index.max()) + base
        raise ValueError(
            f"tri indices must lie in [{base}, {verts.shape[0] - 1 + base}] (base={base}), got [{lo}, {hi}]"
            + ("; pass base=0 for 0-based faces" if base == 1 and lo == 0 else "")
        )
    triangles = verts[index.to(verts.device)]
    return _triangles(x, triangles, _batchable(S, triangles.shape[0], x, "S")) - T


def _rotations(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (M, 3, 3) by ``angle`` (radians) about unit ``axis`` (Rodrigues)."""
    k = axis / axis.norm(dim=-1, keepdim=True)
    zero = torch.zeros_like(k[:, 0])
    cross = torch.stack(
        [
            torch.stack([zero, -k[:, 2], k[:, 1]], -1),
            torch.stack([k[:, 2], zero, -k[:, 0]], -1),
            torch.stack([-k[:, 1], k[:, 0], zero], -1),
        ],
        -2,
    )
    eye = torch.eye(3, dtype=k.dtype, device=k.device)
    sin, cos = torch.sin(angle)[:, None, None], torch.cos(angle)[:, None, None]
    return eye + sin * cross + (1.0 - cos) * (cross @ cross)


@frep
def convArc(
    x: torch.Tensor,
    center: Skeleton,
    radius: PerElement,
    theta: PerElement,
    axis: Skeleton,
    angle: PerElement,
    S: PerElement,
    T: float | torch.Tensor,
) -> torch.Tensor:
    """Convolution surface of circular arcs (closed-form arc-length integral of the Cauchy kernel).

    Arc i lies in the local xy-plane: centre ``center_i``, radius ``radius_i``, from the local
    x-axis counter-clockwise over ``theta_i`` degrees (360 is a full circle); the plane is then
    rotated by ``angle_i`` degrees about ``axis_i`` (the reference code's convention).
    In local coordinates the kernel along the arc is ``1 / (B - P cos phi - Q sin phi)^2`` with
    B = 1 + S^2 (|x|^2 + r^2), P = 2 S^2 r x, Q = 2 S^2 r y, and
    ``F = r int_0^theta dphi / (B - P cos phi - Q sin phi)^2`` has a closed form (B^2 - P^2 - Q^2
    >= 1, so it is smooth everywhere, including on the arc's axis).  The reference code
    integrates over the angle phi instead of the arc length: its field is this one divided by
    the radius (a threshold T_ref corresponds to ``T = radius * T_ref`` here).

    Parameters
    ----------
    x : (..., 3) points.
    center : M arc centres, flat (3M,) or (M, 3).
    radius : arc radii, one number or (M,), > 0.
    theta : arc angles in degrees, in (0, 360].
    axis : rotation axes of the arcs' planes, flat (3M,) or (M, 3), non-zero.
    angle : rotation angles in degrees, one number or (M,).
    S : kernel width control, one number or (M,) values, > 0.
    T : threshold.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    >>> convArc(x, [0, 0, 0], 1.0, 360.0, [0, 0, 1], 0.0, S=3.0, T=0.1) > 0   # a torus
    tensor([ True, False,  True])
    """
    c = _rows(center, x, 3, "center")
    m = c.shape[0]
    r = _per_element(radius, m, x, "radius")
    arc = _per_element(theta, m, x, "theta")
    if not tracing(arc) and not bool((arc <= 360.0).all()):
        raise ValueError(f"theta must lie in (0, 360] degrees, got {theta!r}")
    ax = _rows(axis, x, 3, "axis")
    if ax.shape[0] == 1:
        ax = ax.expand(m, 3)
    if ax.shape[0] != m or (not tracing(ax) and not bool((ax.norm(dim=-1) > 0).all())):
        raise ValueError(f"axis must hold 1 or {m} non-zero vectors, got {tuple(ax.shape)}")
    rot = _rotations(ax, _per_element(angle, m, x, "angle", positive=False) * (math.pi / 180.0))
    s = _batchable(S, m, x, "S")
    half = arc * (math.pi / 360.0)  # theta / 2 in radians, in (0, pi]
    sin_t, cos_t = torch.sin(2.0 * half), torch.cos(2.0 * half)
    # sin(theta/2) >= 0 on (0, pi]; clamp the rounding of sin(pi) (negative in float32) so a full
    # circle sweeps +pi, not -pi
    sin_h, cos_h = torch.sin(half).clamp_min(0.0), torch.cos(half)

    def kernel(p: torch.Tensor) -> torch.Tensor:
        local = torch.einsum("mji,pmj->pmi", rot, p - c)  # R^T (x - c): the arc's frame
        s2 = s * s
        big_b = 1.0 + s2 * ((local * local).sum(-1) + r * r)
        big_p = 2.0 * s2 * r * local[..., 0]
        big_q = 2.0 * s2 * r * local[..., 1]
        bp = big_b + big_p
        d2 = (big_b - big_p) * bp - big_q * big_q  # B^2 - P^2 - Q^2 >= 1
        d = torch.sqrt(d2)
        # int_0^theta dphi / E = (2 / D) * (angle swept by M (cos s, sin s), s in [0, theta/2]),
        # M = [[D, 0], [-Q, B + P]]: atan2 of cross and dot products, continuous up to theta = 360.
        swept = torch.atan2(d * bp * sin_h, (d2 + big_q * big_q) * cos_h - big_q * bp * sin_h)
        j1 = 2.0 * swept / d
        end = big_b - big_p * cos_t - big_q * sin_t
        j2 = ((big_p * sin_t - big_q * cos_t) / end + big_q / (big_b - big_p) + big_b * j1) / d2
        return r * j2

    return _field(x, m, kernel, _batch(s)) - T
