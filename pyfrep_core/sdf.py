"""Exact signed distance functions (SDF) and the operations on them (paper section 3, "Signed Distance Function").

Sign convention: **positive inside**, like the rest of the kernel.  Every primitive returns
``d = -(Inigo Quilez's sdf)``: ``d(x)`` is the Euclidean distance from ``x`` to the surface,
counted positive inside the solid and negative outside, so ``|grad d| = 1`` wherever the
nearest surface point is unique (everywhere but the medial axis) and ``grad d`` points inward.

The paper keeps SDF and non-SDF code apart, and so does this package: this module is not
star-imported into :mod:`pyfrep_core` (its ``sphere`` is ``r - |x - c|``, not ``r^2 - |x - c|^2``).
Write ``from pyfrep_core import sdf`` and ``sdf.sphere(x, ...)``.  Names, argument order and
conventions follow the paper's reference code (PyFRep ``sdf_primitives.py``/``sdf_ops.py``), so
ported models read the same; where this module differs, the docstring says so.

Shapes: points ``x`` are (..., 3) (torch tensor or numpy array; numpy in gives numpy out),
the result is (...).  Numeric arguments are floats or tensors (``requires_grad`` works, for
shape parameters); a scalar tensor of shape (B, 1), or a vector of shape (B, 3), gives (B, N)
values for B parameter sets and N points.  Only torch operations are used on ``x`` (no
``.item()``, no Python ``if`` on values), and every square root that can reach 0 is a
:func:`~pyfrep_core._array.safe_sqrt`, so gradients are finite everywhere: at a sphere's
center, on box edges and corners, on a torus's axis, on the surface itself.

Operations on distances: :func:`union` (max), :func:`intersection` (min), :func:`difference`,
:func:`negate`, :func:`smoothUnion`/:func:`smoothIntersection`/:func:`smoothDifference`
(polynomial smooth max/min of width ``k``), :func:`dilate`, :func:`erode`, :func:`shell`.
Union and intersection of SDFs give the exact distance outside (union) or inside
(intersection) only; the smooth operations give a bound, not a distance, inside the blend.
"""

from __future__ import annotations

from typing import Any

import torch

from . import primitives
from ._array import as_tensor, check_param, check_points, frep, param_array, safe_sqrt, shown, vec

Vector = tuple[float, float, float] | torch.Tensor
Scalar = float | torch.Tensor

__all__ = [
    "sphere",
    "plane",
    "box",
    "block",
    "roundedBox",
    "torus",
    "torusX",
    "torusY",
    "torusZ",
    "capsule",
    "cylinder",
    "cylinderX",
    "cylinderY",
    "cylinderZ",
    "cylX",
    "cylY",
    "cylZ",
    "coneX",
    "coneY",
    "coneZ",
    "cappedCylinder",
    "cappedCone",
    "frame",
    "superQuadric",
    "union",
    "intersection",
    "difference",
    "negate",
    "smoothUnion",
    "smoothIntersection",
    "smoothDifference",
    "dilate",
    "erode",
    "shell",
]

_AXES = {"x": 0, "y": 1, "z": 2, 0: 0, 1: 1, 2: 2}


# ----------------------------------------------------------------------------- helpers


def _checked_points(x: Any) -> torch.Tensor:
    """``x`` as a floating tensor of shape (..., 3); ValueError naming the shape otherwise."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"x must be a torch tensor or a numpy array, got {type(x).__name__}")
    t, _ = as_tensor(x, "x")
    check_points(t, 3, "x", empty=True)  # no points give no values, as for every primitive
    return t


def _vec3(v: Any, like: torch.Tensor, name: str) -> torch.Tensor:
    """A 3-vector (or a scalar, repeated on the three axes) as a tensor broadcasting against ``like``.

    A (B, 3) vector becomes (B, 1, 3); a (B, 1) scalar becomes (B, 1, 3) too.
    """
    if isinstance(v, int | float) or (isinstance(v, torch.Tensor) and (v.ndim == 0 or v.shape[-1] == 1)):
        t = torch.as_tensor(v, dtype=like.dtype, device=like.device)
        return t.unsqueeze(-1).expand(*t.shape, 3)
    return vec(v, like, name=name)


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(-1)


def _length(v: torch.Tensor) -> torch.Tensor:
    """|v| over the last axis, with a finite gradient at v = 0 (it is 0 there)."""
    return safe_sqrt(_dot(v, v))


def _box_distance(q: torch.Tensor) -> torch.Tensor:
    """Quilez's box distance (negative inside) from ``q = |p| - half_extents``, shape (..., k) -> (...).

    ``|max(q, 0)|`` outside, ``max_i q_i`` inside or on the surface.  Choosing with ``where`` (instead
    of adding ``min(max_i q_i, 0)``) keeps ``|grad| = 1`` on the faces themselves: the sum form
    splits the gradient of ``min(0, 0)`` in half there.
    """
    inside = q.amax(-1)
    outside = _length(q.clamp_min(0.0))
    return torch.where(inside > 0, outside, inside)


def _axis(axis: Any) -> int:
    if axis not in _AXES:
        raise ValueError(f"axis must be one of 'x', 'y', 'z', 0, 1, 2; got {axis!r}")
    return _AXES[axis]


def _radial_axial(d: torch.Tensor, axis: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(distance to the coordinate axis ``axis``, coordinate along it) of offsets ``d`` (..., 3)."""
    i, j = [k for k in range(3) if k != axis]
    return safe_sqrt(d[..., i] ** 2 + d[..., j] ** 2), d[..., axis]


def _segment_frame(x: torch.Tensor, a: Any, b: Any) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Radial distance to the line a-b, coordinate along it from a, and the length |b - a|."""
    va, vb = vec(a, x, name="a"), vec(b, x, name="b")
    pa, ba = x - va, vb - va
    length = _length(ba)
    h = _dot(pa, ba) / length
    rho = safe_sqrt((_dot(pa, pa) - h * h).clamp_min(0.0))
    return rho, h, length


def _distinct_points(a: Any, b: Any, fn: str) -> None:
    """ValueError naming ``fn``'s end points ``a``, ``b`` when they coincide (no axis: 0/0)."""
    check_param(a, "a", fn)
    check_param(b, "b", fn)
    pa, pb = param_array(a, "a", fn), param_array(b, "b", fn)
    if pa is not None and pb is not None and not (pb - pa != 0).reshape(-1, 3).any(-1).all():
        raise ValueError(f"{fn}: a and b must be distinct points, got {shown(a)!r} and {shown(b)!r}")


# ----------------------------------------------------------------------------- primitives


@frep
def sphere(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Sphere: ``d = r - |x - center|``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) or (B, 3) center.
    r : radius (float or tensor, e.g. (B, 1)), same length unit as x.

    Returns
    -------
    (...) signed distance, positive inside.  grad d is 0 (finite) at the center.

    Examples
    --------
    >>> import torch
    >>> sphere(torch.tensor([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]), r=1.0)
    tensor([ 1., -2.])
    """
    x = _checked_points(x)
    check_param(center, "center", "sdf.sphere")
    check_param(r, "r", "sdf.sphere", positive=True)
    return r - _length(x - vec(center, x))


@frep
def plane(x: torch.Tensor, normal: Vector = (0.0, 0.0, 1.0), point: Vector = (0.0, 0.0, 0.0)) -> torch.Tensor:
    """Half-space through ``point`` on the side ``normal`` points to: ``d = (x - point) . n / |n|``.

    As in the reference code the solid lies on the side of the normal (``grad d = n / |n|``
    points inward, as for every F-Rep solid); Quilez's ``sdPlane`` takes the opposite side.

    Parameters
    ----------
    x : (..., 3) points.
    normal : (3,) or (B, 3) direction, any nonzero length (it is normalized).
    point : (3,) or (B, 3) a point of the plane.

    Returns
    -------
    (...) signed distance, positive on the normal's side.

    Examples
    --------
    >>> import torch
    >>> plane(torch.tensor([[0.0, 0.0, 2.0], [5.0, 1.0, -1.0]]), normal=(0.0, 0.0, 2.0), point=(0.0, 0.0, 1.0))
    tensor([ 1., -2.])
    """
    x = _checked_points(x)
    check_param(normal, "normal", "sdf.plane", nonzero=True)
    check_param(point, "point", "sdf.plane")
    n = vec(normal, x, name="normal")
    return _dot(x - vec(point, x, name="point"), n) / _length(n)


@frep
def box(x: torch.Tensor, b: Vector | Scalar = (1.0, 1.0, 1.0), center: Vector = (0.0, 0.0, 0.0)) -> torch.Tensor:
    """Axis-aligned box of half-extents ``b`` (Quilez's ``sdBox``, exact inside and outside).

    Parameters
    ----------
    x : (..., 3) points.
    b : (3,) or (B, 3) half-extents (a scalar gives a cube); the box is ``|x - center|_i <= b_i``.
    center : (3,) or (B, 3) center.

    Returns
    -------
    (...) signed distance: ``-|max(q, 0)|`` outside, ``-max_i q_i`` inside, ``q = |x - c| - b``.

    Examples
    --------
    >>> import torch
    >>> box(torch.tensor([[0.0, 0.0, 0.0], [2.0, 2.0, 1.0], [3.0, 3.0, 3.0]]), b=(1.0, 1.0, 1.0))
    tensor([ 1.0000, -1.4142, -3.4641])
    """
    x = _checked_points(x)
    check_param(b, "b", "sdf.box", positive=True)
    check_param(center, "center", "sdf.box")
    return _box_distance_of(x, b, center)


def _box_distance_of(x: torch.Tensor, b: Any, center: Any) -> torch.Tensor:
    """Signed distance (positive inside) of the box of half-extents ``b`` (>= 0, unchecked here)."""
    q = (x - vec(center, x)).abs() - _vec3(b, x, "b")
    return -_box_distance(q)


@frep
def block(
    x: torch.Tensor, vertex: Vector = (0.0, 0.0, 0.0), dx: Scalar = 1.0, dy: Scalar = 1.0, dz: Scalar = 1.0
) -> torch.Tensor:
    """Axis-aligned box from corner ``vertex`` with edge lengths dx, dy, dz, as an exact distance.

    The HyperFun ``block`` arguments; the same solid as :func:`pyfrep_core.block`.  (The
    reference code passes the full edge lengths as half-extents, which doubles the box; here
    the box is ``[vertex, vertex + (dx, dy, dz)]`` as its name says.)

    Parameters
    ----------
    x : (..., 3) points.
    vertex : (3,) or (B, 3) the corner with the smallest coordinates.
    dx, dy, dz : edge lengths (floats or (B, 1) tensors).

    Returns
    -------
    (...) signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> block(torch.tensor([[0.5, 0.5, 0.5], [0.5, 0.5, 3.0]]), vertex=(0, 0, 0), dx=1, dy=1, dz=2)
    tensor([ 0.5000, -1.0000])
    """
    x = _checked_points(x)
    check_param(vertex, "vertex", "sdf.block")
    for name, value in (("dx", dx), ("dy", dy), ("dz", dz)):
        check_param(value, name, "sdf.block", positive=True)
    dims = torch.broadcast_tensors(*(torch.as_tensor(v, dtype=x.dtype, device=x.device) for v in (dx, dy, dz)))
    half = 0.5 * torch.stack(dims, dim=-1)
    return _box_distance_of(x, half, vec(vertex, x, name="vertex") + half)


@frep
def roundedBox(
    x: torch.Tensor, b: Vector | Scalar = (1.0, 1.0, 1.0), radius: Scalar = 0.1, center: Vector = (0.0, 0.0, 0.0)
) -> torch.Tensor:
    """Box of half-extents ``b`` with its edges and corners rounded by ``radius``: ``box + radius``.

    As in the reference code, the rounding is added outside: the solid is the set of points
    within ``radius`` of the box ``b``, so its half-extents are ``b + radius`` (Quilez's
    ``sdRoundBox`` subtracts ``radius`` from ``b`` first).  Exact, since the box is convex.

    Parameters
    ----------
    x : (..., 3) points.
    b : (3,) or (B, 3) half-extents of the inner (sharp) box, or a scalar.
    radius : rounding radius (>= 0).
    center : (3,) or (B, 3) center.

    Returns
    -------
    (...) signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> roundedBox(torch.tensor([[2.0, 2.0, 0.0], [0.0, 0.0, 0.0]]), b=1.0, radius=0.5)
    tensor([-0.9142,  1.5000])
    """
    # b = 0 with radius > 0 is the ball of that radius; both 0 (on an axis) is flat
    check_param(b, "b", "sdf.roundedBox", nonnegative=True)
    check_param(radius, "radius", "sdf.roundedBox", nonnegative=True)
    hb, hr = param_array(b, "b", "sdf.roundedBox"), param_array(radius, "radius", "sdf.roundedBox")
    if hb is not None and hr is not None and not (hb + hr > 0).all():
        raise ValueError(f"sdf.roundedBox: b + radius must be positive, got b={shown(b)!r}, radius={shown(radius)!r}")
    check_param(center, "center", "sdf.roundedBox")
    return _box_distance_of(_checked_points(x), b, center) + radius


@frep
def torus(
    x: torch.Tensor, R: Scalar = 1.0, r: Scalar = 0.25, center: Vector = (0.0, 0.0, 0.0), axis: str | int = "z"
) -> torch.Tensor:
    """Torus of major radius ``R`` and tube radius ``r`` around ``axis``: ``d = r - |(rho - R, h)|``.

    ``rho`` is the distance to the axis through ``center``, ``h`` the coordinate along it.  The
    reference code's ``torus(p, r1, r2)`` is this with the default center and axis.

    Parameters
    ----------
    x : (..., 3) points.
    R : distance from the axis to the tube's center line (R > r for a ring torus).
    r : tube radius.
    center : (3,) or (B, 3) center.
    axis : "x", "y", "z" (or 0, 1, 2), the axis of revolution.

    Returns
    -------
    (...) signed distance, positive inside the tube; finite gradients on the axis.

    Examples
    --------
    >>> import torch
    >>> torus(torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]), R=1.0, r=0.25)
    tensor([ 0.2500, -0.7500])
    """
    return _torus(x, R, r, center, _axis(axis), "sdf.torus")


def _torus(x: torch.Tensor, R: Scalar, r: Scalar, center: Vector, axis: int, fn: str) -> torch.Tensor:
    x = _checked_points(x)
    check_param(R, "R", fn, nonnegative=True)  # R = 0 is the ball of radius r; R < 0 is no torus
    check_param(r, "r", fn, positive=True)
    check_param(center, "center", fn)
    rho, h = _radial_axial(x - vec(center, x), axis)
    return r - safe_sqrt((rho - R) ** 2 + h * h)


@frep
def torusX(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), R: Scalar = 1.0, r: Scalar = 0.25) -> torch.Tensor:
    """Torus around the x axis (reference ``torusX(x, center, R, r0)``); see :func:`torus`.

    Examples
    --------
    >>> import torch
    >>> torusX(torch.tensor([[0.0, 1.0, 0.0]]), R=1.0, r=0.25)
    tensor([0.2500])
    """
    return _torus(x, R, r, center, 0, "sdf.torusX")


@frep
def torusY(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), R: Scalar = 1.0, r: Scalar = 0.25) -> torch.Tensor:
    """Torus around the y axis; see :func:`torus`.

    Examples
    --------
    >>> import torch
    >>> torusY(torch.tensor([[0.0, 0.0, 1.5]]), R=1.0, r=0.25)
    tensor([-0.2500])
    """
    return _torus(x, R, r, center, 1, "sdf.torusY")


@frep
def torusZ(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), R: Scalar = 1.0, r: Scalar = 0.25) -> torch.Tensor:
    """Torus around the z axis; see :func:`torus`.

    Examples
    --------
    >>> import torch
    >>> torusZ(torch.tensor([[1.0, 0.0, 0.1]]), R=1.0, r=0.25)
    tensor([0.1500])
    """
    return _torus(x, R, r, center, 2, "sdf.torusZ")


@frep
def capsule(
    x: torch.Tensor, a: Vector = (0.0, 0.0, -0.5), b: Vector = (0.0, 0.0, 0.5), radius: Scalar = 0.25
) -> torch.Tensor:
    """Capsule: points within ``radius`` of the segment a-b, ``d = radius - |x - closest(a, b)|``.

    With a == b the segment is a point and the capsule the sphere of that radius around it
    (exact distance ``radius - |x - a|``, finite gradients).

    Parameters
    ----------
    x : (..., 3) points.
    a, b : (3,) or (B, 3) end points of the segment (a == b allowed: a sphere).
    radius : radius.

    Returns
    -------
    (...) signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> capsule(torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0]]), a=(0, 0, -1), b=(0, 0, 1), radius=0.5)
    tensor([-0.5000, -0.5000])
    >>> capsule(torch.tensor([[0.0, 0.0, 2.0]]), a=(0, 0, 1), b=(0, 0, 1), radius=0.5)  # a sphere
    tensor([-0.5000])
    """
    x = _checked_points(x)
    va, vb = vec(a, x, name="a"), vec(b, x, name="b")
    pa, ba = x - va, vb - va
    # the closest point's parameter on the segment; a == b (a point, 0/0): t = 0, the closest point is a
    length2 = _dot(ba, ba)
    point = length2 == 0
    t = torch.where(point, 0.0, _dot(pa, ba) / torch.where(point, 1.0, length2)).clamp(0.0, 1.0)
    return radius - _length(pa - ba * t.unsqueeze(-1))


@frep
def cylinder(
    x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), u: Vector = (0.0, 0.0, 1.0), r: Scalar = 1.0
) -> torch.Tensor:
    """Infinite cylinder through ``center`` along direction ``u``: ``d = r - dist(x, line)``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) or (B, 3) a point of the axis.
    u : (3,) or (B, 3) axis direction, any nonzero length.
    r : radius.

    Returns
    -------
    (...) signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> cylinder(torch.tensor([[3.0, 1.0, 0.0], [0.0, 0.0, 7.0]]), u=(1.0, 0.0, 0.0), r=0.5)
    tensor([-0.5000, -6.5000])
    """
    x = _checked_points(x)
    check_param(center, "center", "sdf.cylinder")
    check_param(u, "u", "sdf.cylinder", nonzero=True)
    check_param(r, "r", "sdf.cylinder", positive=True)
    w = x - vec(center, x)
    n = vec(u, x, name="u")
    n = n / _length(n).unsqueeze(-1)
    return r - _length(w - n * _dot(w, n).unsqueeze(-1))


def _cyl_axis(x: torch.Tensor, center: Vector, r: Scalar, axis: int) -> torch.Tensor:
    x = _checked_points(x)
    fn = "sdf.cylinder" + "XYZ"[axis]
    check_param(center, "center", fn)
    check_param(r, "r", fn, positive=True)
    rho, _ = _radial_axial(x - vec(center, x), axis)
    return r - rho


@frep
def cylinderX(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Infinite cylinder along x: ``d = r - sqrt(dy^2 + dz^2)``.  Alias :func:`cylX`.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) or (B, 3) a point of the axis.
    r : radius.

    Examples
    --------
    >>> import torch
    >>> cylinderX(torch.tensor([[5.0, 0.0, 0.0], [0.0, 3.0, 4.0]]), r=1.0)
    tensor([ 1., -4.])
    """
    return _cyl_axis(x, center, r, 0)


@frep
def cylinderY(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Infinite cylinder along y: ``d = r - sqrt(dx^2 + dz^2)``.  Alias :func:`cylY`.

    Examples
    --------
    >>> import torch
    >>> cylinderY(torch.tensor([[3.0, 9.0, 4.0]]), r=1.0)
    tensor([-4.])
    """
    return _cyl_axis(x, center, r, 1)


@frep
def cylinderZ(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Infinite cylinder along z: ``d = r - sqrt(dx^2 + dy^2)``.  Alias :func:`cylZ`.

    Examples
    --------
    >>> import torch
    >>> cylinderZ(torch.tensor([[0.5, 0.0, -9.0]]), r=1.0)
    tensor([0.5000])
    """
    return _cyl_axis(x, center, r, 2)


cylX = cylinderX  # noqa: N816 (the kernel's name for it)
cylY = cylinderY  # noqa: N816 (the kernel's name for it)
cylZ = cylinderZ  # noqa: N816 (the kernel's name for it)


def _cone_axis(x: torch.Tensor, center: Vector, r: Scalar, axis: int) -> torch.Tensor:
    x = _checked_points(x)
    fn = "sdf.cone" + "XYZ"[axis]
    check_param(center, "center", fn)
    check_param(r, "r", fn, positive=True)
    rho, h = _radial_axial(x - vec(center, x), axis)
    # the cone's side makes the angle t = atan(r) with the axis; the distance to that line
    # in the (rho, |h|) half-plane is exact (the foot of the perpendicular never passes the apex)
    c = (1.0 + r * r) ** -0.5
    return h.abs() * (r * c) - rho * c


@frep
def coneX(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Infinite double cone along x with apex ``center`` and slope ``r`` (radius r at distance 1).

    ``d = |dx| sin t - sqrt(dy^2 + dz^2) cos t`` with ``t = atan(r)`` (reference ``coneX``).

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) or (B, 3) apex.
    r : slope, tangent of the half-opening angle (> 0).

    Examples
    --------
    >>> import torch
    >>> coneX(torch.tensor([[1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]), r=1.0)
    tensor([0.0000, 0.7071])
    """
    return _cone_axis(x, center, r, 0)


@frep
def coneY(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Infinite double cone along y; see :func:`coneX`.

    Examples
    --------
    >>> import torch
    >>> coneY(torch.tensor([[0.0, -2.0, 0.0]]), r=1.0)
    tensor([1.4142])
    """
    return _cone_axis(x, center, r, 1)


@frep
def coneZ(x: torch.Tensor, center: Vector = (0.0, 0.0, 0.0), r: Scalar = 1.0) -> torch.Tensor:
    """Infinite double cone along z; see :func:`coneX`.

    Examples
    --------
    >>> import torch
    >>> coneZ(torch.tensor([[2.0, 0.0, 0.0]]), r=1.0)
    tensor([-1.4142])
    """
    return _cone_axis(x, center, r, 2)


@frep
def cappedCylinder(
    x: torch.Tensor, a: Vector = (0.0, 0.0, -0.5), b: Vector = (0.0, 0.0, 0.5), radius: Scalar = 0.5
) -> torch.Tensor:
    """Cylinder of ``radius`` between the flat caps at ``a`` and ``b`` (exact, any orientation).

    In the meridian half-plane (distance ``rho`` to the line a-b, coordinate ``h`` along it from
    the midpoint) the solid is the rectangle ``rho <= radius, |h| <= L/2``; its 2-D box distance
    is the 3-D distance (Quilez's ``sdCappedCylinder``, written without ``sqrt(|d|)`` so the
    gradient on the surface is the unit normal, not 0).

    Parameters
    ----------
    x : (..., 3) points.
    a, b : (3,) or (B, 3) centers of the two caps (a != b).
    radius : radius.

    Returns
    -------
    (...) signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> cappedCylinder(torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 3.0]]), a=(0, 0, -1), b=(0, 0, 1), radius=1.0)
    tensor([ 1.0000, -2.2361])
    """
    x = _checked_points(x)
    _distinct_points(a, b, "sdf.cappedCylinder")
    check_param(radius, "radius", "sdf.cappedCylinder", positive=True)
    rho, h, length = _segment_frame(x, a, b)
    q = torch.stack(torch.broadcast_tensors(rho - radius, (h - 0.5 * length).abs() - 0.5 * length), dim=-1)
    return -_box_distance(q)


@frep
def cappedCone(
    x: torch.Tensor,
    a: Vector = (0.0, 0.0, -0.5),
    b: Vector = (0.0, 0.0, 0.5),
    ra: Scalar = 0.5,
    rb: Scalar = 0.25,
) -> torch.Tensor:
    """Truncated cone: radius ``ra`` at cap center ``a``, ``rb`` at cap center ``b`` (exact).

    In the meridian half-plane the solid is the trapezoid with corners (0, 0), (ra, 0), (rb, L),
    (0, L) (``rho`` across, ``h`` along a-b), mirrored over the axis: a convex polygon.  Inside,
    the distance is the largest signed distance to its three edge lines; outside, the distance
    to the nearest of its three edge segments (the same distance as Quilez's ``sdCappedCone``;
    choosing with ``where`` keeps the gradient a unit vector on the surface too).

    Parameters
    ----------
    x : (..., 3) points.
    a, b : (3,) or (B, 3) centers of the two caps (a != b).
    ra, rb : cap radii (>= 0; one may be 0 for a pointed cone).

    Returns
    -------
    (...) signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> cappedCone(torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 3.0]]), a=(0, 0, 0), b=(0, 0, 1), ra=1.0, rb=0.5)
    tensor([ 0.5000, -2.0000])
    """
    check_param(ra, "ra", "sdf.cappedCone", nonnegative=True)
    check_param(rb, "rb", "sdf.cappedCone", nonnegative=True)
    ha, hb = param_array(ra, "ra", "sdf.cappedCone"), param_array(rb, "rb", "sdf.cappedCone")
    if ha is not None and hb is not None and not (ha + hb > 0).all():
        raise ValueError(f"sdf.cappedCone: ra and rb must not both be 0, got {shown(ra)!r} and {shown(rb)!r}")
    x = _checked_points(x)
    _distinct_points(a, b, "sdf.cappedCone")
    rho, h, length = _segment_frame(x, a, b)
    dr = rb - ra
    side = safe_sqrt(dr * dr + length * length)
    # signed distances to the three edge lines (outward normals): caps at h = 0, h = L; the side
    caps = (h - 0.5 * length).abs() - 0.5 * length
    slant = ((rho - ra) * length - h * dr) / side
    inside = torch.maximum(caps, slant)
    # squared distances to the three edge segments: bottom cap, top cap, side
    d_bottom = (rho - ra).clamp_min(0.0) ** 2 + h * h
    d_top = (rho - rb).clamp_min(0.0) ** 2 + (h - length) ** 2
    f = (((rho - ra) * dr + h * length) / (side * side)).clamp(0.0, 1.0)
    d_side = (rho - ra - f * dr) ** 2 + (h - f * length) ** 2
    outside = safe_sqrt(torch.minimum(torch.minimum(d_bottom, d_top), d_side))
    return -torch.where(inside > 0, outside, inside)


@frep
def frame(
    x: torch.Tensor, side_length: Vector | Scalar = 1.0, thickness: Scalar = 0.1, center: Vector = (0.0, 0.0, 0.0)
) -> torch.Tensor:
    """The twelve edges of a box as square bars (Quilez's ``sdBoxFrame``, exact).

    As in the reference code, ``side_length`` is measured between the bars' center lines and
    the bars have a square cross-section of side ``thickness``: the frame's outer size is
    ``side_length + thickness``.

    Parameters
    ----------
    x : (..., 3) points.
    side_length : scalar (cube) or (3,) / (B, 3) side lengths between bar center lines.
    thickness : bar thickness (0 < thickness < side_length).
    center : (3,) or (B, 3) center.

    Returns
    -------
    (...) signed distance, positive inside the bars.

    Examples
    --------
    >>> import torch
    >>> frame(torch.tensor([[1.0, 1.0, 0.0], [0.0, 0.0, 0.0]]), side_length=2.0, thickness=0.2)
    tensor([ 0.1000, -1.2728])
    """
    x = _checked_points(x)
    check_param(side_length, "side_length", "sdf.frame", positive=True)
    check_param(thickness, "thickness", "sdf.frame", positive=True)
    check_param(center, "center", "sdf.frame")
    hs, ht = param_array(side_length, "side_length", "sdf.frame"), param_array(thickness, "thickness", "sdf.frame")
    if hs is not None and ht is not None and not (ht < hs).all():
        raise ValueError(
            f"sdf.frame: thickness must be below side_length, got {shown(thickness)!r} and {shown(side_length)!r}"
        )
    half = 0.5 * _vec3(side_length, x, "side_length") + 0.5 * thickness  # outer half-extents
    e = 0.5 * thickness
    p = (x - vec(center, x)).abs() - half
    q = (p + e).abs() - e
    px, py, pz = p.unbind(-1)
    qx, qy, qz = q.unbind(-1)
    bars = [  # the four bars along each axis, folded into one by the symmetry |x - c|
        _box_distance(torch.stack(torch.broadcast_tensors(px, qy, qz), -1)),
        _box_distance(torch.stack(torch.broadcast_tensors(qx, py, qz), -1)),
        _box_distance(torch.stack(torch.broadcast_tensors(qx, qy, pz), -1)),
    ]
    return -torch.minimum(torch.minimum(bars[0], bars[1]), bars[2])


@frep
def superQuadric(
    x: torch.Tensor,
    e: tuple[float, float] | torch.Tensor = (1.0, 1.0),
    a: Vector = (1.0, 1.0, 1.0),
    r: Vector = (0.0, 0.0, 0.0),
    t: Vector = (0.0, 0.0, 0.0),
) -> torch.Tensor:
    """Superquadric with the radial distance of Jaklic et al.: ``d = |x - t| (F^(-e1/2) - 1)``.

    ``F`` is the inside-outside function of :func:`pyfrep_core.superQuadric` (``F = 1 - f``,
    same arguments: exponents ``e``, semi-axes ``a``, Z-Y-X Euler angles ``r``, center ``t``).
    F is homogeneous of degree 2/e1 about the center, so ``d`` is the signed distance from x
    to the surface *along the ray from the center*: exact for a sphere (a1 = a2 = a3,
    e = (1, 1)), an approximation elsewhere (it over-estimates the distance where the ray
    meets the surface obliquely), positive inside.  Written as ``rho(n) - |x - t|`` with
    ``rho(n) = F(n)^(-e1/2)`` the center's distance to the surface in the direction
    ``n = (x - t) / |x - t|``, so it is finite everywhere; at the center itself ``n`` is
    taken along z.  (The reference code multiplies by the norm of the whole (N, 3) array
    of points instead of each point's, so its values depend on the batch; the surface is
    the same.)

    Parameters
    ----------
    x : (..., 3) points.
    e : (2,) exponents (e1 north-south, e2 east-west), > 0.
    a : (3,) semi-axes (> 0).
    r : (3,) Euler angles in radians: about z, then y, then x (R = Rz(r1) Ry(r2) Rx(r3)).
    t : (3,) center.

    Returns
    -------
    (...) radial signed distance, positive inside.

    Examples
    --------
    >>> import torch
    >>> p = torch.tensor([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 0.25]], dtype=torch.float64)
    >>> superQuadric(p, e=(1.0, 1.0), a=(2.0, 1.0, 0.5))  # an ellipsoid: exact along its axes
    tensor([ 0.5000, -1.0000,  0.2500], dtype=torch.float64)
    """
    x = _checked_points(x)
    check_param(e, "e", "sdf.superQuadric", positive=True)
    check_param(a, "a", "sdf.superQuadric", positive=True)
    check_param(r, "r", "sdf.superQuadric")
    check_param(t, "t", "sdf.superQuadric")
    center = vec(t, x, name="t")
    d = x - center
    rho = _length(d)
    at_center = _dot(d, d) == 0
    up = torch.tensor((0.0, 0.0, 1.0), dtype=x.dtype, device=x.device)
    n = torch.where(at_center[..., None], up, d / torch.where(at_center, 1.0, rho)[..., None])
    inside_outside = 1.0 - primitives.superQuadric(center + n, e=e, a=a, r=r, t=t)  # F(n) > 0
    e1 = vec(e, x, n=2, name="e")[..., 0]
    return inside_outside ** (-0.5 * e1) - rho


# ----------------------------------------------------------------------------- operations


@frep
def union(d1: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
    """Union ``max(d1, d2)`` (positive inside): exact outside, a lower bound inside.

    Parameters
    ----------
    d1, d2 : distances of broadcastable shapes, e.g. (N,).

    Examples
    --------
    >>> import torch
    >>> union(torch.tensor([1.0, -2.0]), torch.tensor([-1.0, -3.0]))
    tensor([ 1., -2.])
    """
    return torch.maximum(d1, d2)


@frep
def intersection(d1: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
    """Intersection ``min(d1, d2)``: exact inside, a bound outside.

    Examples
    --------
    >>> import torch
    >>> intersection(torch.tensor([1.0, -2.0]), torch.tensor([-1.0, -3.0]))
    tensor([-1., -3.])
    """
    return torch.minimum(d1, d2)


@frep
def difference(d1: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
    """Difference (d1 minus d2) ``min(d1, -d2)``.

    Examples
    --------
    >>> import torch
    >>> difference(torch.tensor([1.0, 1.0]), torch.tensor([-0.5, 0.5]))
    tensor([ 0.5000, -0.5000])
    """
    return torch.minimum(d1, -d2)


@frep
def negate(d: torch.Tensor) -> torch.Tensor:
    """Complement ``-d`` (an exact distance stays exact).

    Examples
    --------
    >>> import torch
    >>> negate(torch.tensor([2.0]))
    tensor([-2.])
    """
    return -d


def _smooth_weight(d1: torch.Tensor, d2: torch.Tensor, k: Scalar, fn: str) -> tuple[torch.Tensor, Any]:
    check_param(k, "k", fn, nonnegative=True)  # k = 0 is the sharp operation
    if isinstance(k, torch.Tensor):
        k = k.clamp_min(torch.finfo(k.dtype if k.is_floating_point() else d1.dtype).tiny)
    else:
        k = max(float(k), float(torch.finfo(d1.dtype).tiny))
    return (0.5 + 0.5 * (d1 - d2) / k).clamp(0.0, 1.0), k


@frep
def smoothUnion(d1: torch.Tensor, d2: torch.Tensor, k: Scalar = 0.1) -> torch.Tensor:
    """Smooth union: polynomial smooth maximum of width ``k`` (Quilez's ``opSmoothUnion``, negated).

    ``h = clamp(1/2 + (d1 - d2) / (2k), 0, 1)``, ``d = d2 + h (d1 - d2) + k h (1 - h)``: equal to
    ``max(d1, d2)`` where ``|d1 - d2| >= k``, and ``max + k/4`` where ``d1 = d2``.  ``k = 0`` gives
    the sharp union.

    Parameters
    ----------
    d1, d2 : distances of broadcastable shapes.
    k : blend width (>= 0), float or tensor (e.g. (B, 1)).

    Examples
    --------
    >>> import torch
    >>> smoothUnion(torch.tensor([0.0, 1.0]), torch.tensor([0.0, -1.0]), k=0.4)
    tensor([0.1000, 1.0000])
    """
    h, k = _smooth_weight(d1, d2, k, "sdf.smoothUnion")
    return d2 + h * (d1 - d2) + k * h * (1.0 - h)


@frep
def smoothIntersection(d1: torch.Tensor, d2: torch.Tensor, k: Scalar = 0.1) -> torch.Tensor:
    """Smooth intersection: polynomial smooth minimum of width ``k``.

    ``d = d1 + h (d2 - d1) - k h (1 - h)`` with ``h`` as in :func:`smoothUnion`: ``min(d1, d2)``
    where ``|d1 - d2| >= k``, ``min - k/4`` where ``d1 = d2``.

    Examples
    --------
    >>> import torch
    >>> smoothIntersection(torch.tensor([0.0, 1.0]), torch.tensor([0.0, -1.0]), k=0.4)
    tensor([-0.1000, -1.0000])
    """
    h, k = _smooth_weight(d1, d2, k, "sdf.smoothIntersection")
    return d1 + h * (d2 - d1) - k * h * (1.0 - h)


@frep
def smoothDifference(d1: torch.Tensor, d2: torch.Tensor, k: Scalar = 0.1) -> torch.Tensor:
    """Smooth difference: ``smoothIntersection(d1, -d2, k)``.

    Examples
    --------
    >>> import torch
    >>> smoothDifference(torch.tensor([0.0, 1.0]), torch.tensor([0.0, 1.0]), k=0.4)
    tensor([-0.1000, -1.0000])
    """
    check_param(k, "k", "sdf.smoothDifference", nonnegative=True)
    return smoothIntersection(d1, -d2, k)


@frep
def dilate(d: torch.Tensor, r: Scalar) -> torch.Tensor:
    """Offset outward by ``r``: ``d + r`` (exact for convex solids; for a sphere, radius + r).

    Examples
    --------
    >>> import torch
    >>> dilate(torch.tensor([-0.5]), 0.5)
    tensor([0.])
    """
    check_param(r, "r", "sdf.dilate")
    return d + r


@frep
def erode(d: torch.Tensor, r: Scalar) -> torch.Tensor:
    """Offset inward by ``r``: ``d - r`` (exact while r is below the smallest radius of curvature).

    Examples
    --------
    >>> import torch
    >>> erode(torch.tensor([0.5]), 0.5)
    tensor([0.])
    """
    check_param(r, "r", "sdf.erode")
    return d - r


@frep
def shell(d: torch.Tensor, e: Scalar) -> torch.Tensor:
    """Hollow shell of total thickness ``2 e`` centered on the surface: ``e - |d|`` (reference ``shell``).

    The solid is ``|d| <= e``: a point at distance ``e`` from the surface, on either side, lies
    on the shell's boundary.

    Parameters
    ----------
    d : distances, any shape.
    e : half-thickness (> 0; e = 0 would leave no solid).

    Examples
    --------
    >>> import torch
    >>> shell(torch.tensor([0.0, 0.1, -0.3]), 0.1)
    tensor([ 0.1000,  0.0000, -0.2000])
    """
    check_param(e, "e", "sdf.shell", positive=True)  # e = 0 leaves no solid (-|d| <= 0)
    return e - d.abs()
