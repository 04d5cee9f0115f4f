"""Primitive solids as defining functions (HyperFun convention: f >= 0 inside).

Every primitive takes points ``x`` of shape (..., 3) (torch tensor or numpy array) and
returns f of shape (...).  Numeric arguments may be floats or tensors with
``requires_grad`` (shape parameters, paper section 4); a tensor of shape (B, 1) gives
(B, N) values for B parameter sets at once.  Only torch operations on ``x`` are used
(no ``.item()``, no Python ``if`` on values).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ._array import check_param, frep, safe_sqrt, vec
from .operations import intersection
from .transforms import rotate3DX, rotate3DY, rotate3DZ

Center = tuple[float, float, float] | torch.Tensor
Center2 = tuple[float, float] | torch.Tensor
Values = Sequence[float] | float | torch.Tensor


__all__ = [
    "sphere",
    "ellipsoid",
    "cylX",
    "cylY",
    "cylZ",
    "block",
    "torusX",
    "torusY",
    "torusZ",
    "circle",
    "ellipse",
    "rectangle",
    "ellCylX",
    "ellCylY",
    "ellCylZ",
    "coneX",
    "coneY",
    "coneZ",
    "ellConeX",
    "ellConeY",
    "ellConeZ",
    "superEll",
    "superQuadric",
    "mapBlob",
    "blobby",
    "metaBall",
    "soft",
    "noiseG",
]


@frep
def sphere(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), r: float = 1.0) -> torch.Tensor:
    """Sphere: ``r^2 - |x - center|^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) center.
    r : radius (> 0, same length unit as x).

    Examples
    --------
    >>> import torch
    >>> sphere(torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), r=1.0)
    tensor([ 1., -3.])
    """
    check_param(center, "center", "sphere")
    check_param(r, "r", "sphere", positive=True)
    d = x - vec(center, x)
    return r * r - (d * d).sum(-1)


@frep
def ellipsoid(
    x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0, c: float = 1.0
) -> torch.Tensor:
    """Ellipsoid: ``1 - (dx/a)^2 - (dy/b)^2 - (dz/c)^2`` with semi-axes a, b, c.

    Examples
    --------
    >>> import torch
    >>> ellipsoid(torch.tensor([[2.0, 0.0, 0.0]]), a=2.0, b=1.0, c=1.0)
    tensor([0.])
    """
    check_param(center, "center", "ellipsoid")
    for name, value in (("a", a), ("b", b), ("c", c)):
        check_param(value, name, "ellipsoid", positive=True)
    d = x - vec(center, x)
    return 1.0 - (d[..., 0] / a) ** 2 - (d[..., 1] / b) ** 2 - (d[..., 2] / c) ** 2


def _cyl(x: torch.Tensor, center: Center, r: float, axis: int) -> torch.Tensor:
    fn = "cyl" + "XYZ"[axis]
    check_param(center, "center", fn)
    check_param(r, "r", fn, positive=True)
    d = x - vec(center, x)
    i, j = [k for k in range(3) if k != axis]
    return r * r - d[..., i] ** 2 - d[..., j] ** 2


@frep
def cylX(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), r: float = 1.0) -> torch.Tensor:
    """Infinite cylinder along x: ``r^2 - dy^2 - dz^2``.

    Examples
    --------
    >>> import torch
    >>> cylX(torch.tensor([[5.0, 0.5, 0.0]]), r=0.5)
    tensor([0.])
    """
    return _cyl(x, center, r, 0)


@frep
def cylY(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), r: float = 1.0) -> torch.Tensor:
    """Infinite cylinder along y: ``r^2 - dx^2 - dz^2``.

    Examples
    --------
    >>> import torch
    >>> cylY(torch.tensor([[0.0, 5.0, 0.0]]), r=0.5)
    tensor([0.2500])
    """
    return _cyl(x, center, r, 1)


@frep
def cylZ(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), r: float = 1.0) -> torch.Tensor:
    """Infinite cylinder along z: ``r^2 - dx^2 - dy^2``.

    Examples
    --------
    >>> import torch
    >>> cylZ(torch.tensor([[1.0, 0.0, 3.0]]), r=0.5)
    tensor([-0.7500])
    """
    return _cyl(x, center, r, 2)


@frep
def block(
    x: torch.Tensor,
    vertex: Center = (0.0, 0.0, 0.0),
    dx: float = 1.0,
    dy: float = 1.0,
    dz: float = 1.0,
) -> torch.Tensor:
    """Axis-aligned box from ``vertex`` with edge lengths dx, dy, dz.

    The R-intersection of the three slabs ``(x - x0)(x0 + dx - x)``, then y, then z.

    Examples
    --------
    >>> import torch
    >>> block(torch.tensor([[0.5, 0.5, 0.5]]), vertex=(0, 0, 0), dx=1, dy=1, dz=1) > 0
    tensor([True])
    """
    check_param(vertex, "vertex", "block")
    for name, value in (("dx", dx), ("dy", dy), ("dz", dz)):
        check_param(value, name, "block", positive=True)
    v = vec(vertex, x, name="vertex")
    d = x - v
    sx = d[..., 0] * (dx - d[..., 0])
    sy = d[..., 1] * (dy - d[..., 1])
    sz = d[..., 2] * (dz - d[..., 2])
    return intersection(intersection(sx, sy), sz)


def _torus(x: torch.Tensor, center: Center, R: float, r: float, axis: int) -> torch.Tensor:
    fn = "torus" + "XYZ"[axis]
    check_param(center, "center", fn)
    check_param(R, "R", fn, nonnegative=True)  # R = 0 is the ball of radius r; R < 0 is no torus
    check_param(r, "r", fn, positive=True)
    d = x - vec(center, x)
    i, j = [k for k in range(3) if k != axis]
    # distance from the axis; safe_sqrt keeps grad finite on the axis itself
    rho = safe_sqrt(d[..., i] ** 2 + d[..., j] ** 2)
    return r * r - (d * d).sum(-1) - R * R + 2.0 * R * rho


@frep
def torusX(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), R: float = 1.0, r: float = 0.25) -> torch.Tensor:
    """Torus around the x axis: ``r^2 - |d|^2 - R^2 + 2 R sqrt(dy^2 + dz^2)``.

    Equal to ``r^2 - (rho - R)^2 - dx^2`` with ``rho = sqrt(dy^2 + dz^2)``: zero on the
    surface of the tube of radius ``r`` around the circle of radius ``R`` in the plane
    x = center[0].

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) center of the torus.
    R : radius of the tube's center circle (>= 0; R = 0 is the ball of radius r).
    r : radius of the tube (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> torusX(torch.tensor([[0.0, 1.0, 0.0], [0.0, 1.25, 0.0], [0.0, 0.0, 0.0]]), R=1.0, r=0.25)
    tensor([ 0.0625,  0.0000, -0.9375])
    """
    return _torus(x, center, R, r, 0)


@frep
def torusY(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), R: float = 1.0, r: float = 0.25) -> torch.Tensor:
    """Torus around the y axis: ``r^2 - |d|^2 - R^2 + 2 R sqrt(dx^2 + dz^2)``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) center of the torus.
    R : radius of the tube's center circle (>= 0; R = 0 is the ball of radius r).
    r : radius of the tube (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> torusY(torch.tensor([[0.0, 0.0, 1.25], [1.0, 0.0, 0.0]]), R=1.0, r=0.25)
    tensor([0.0000, 0.0625])
    """
    return _torus(x, center, R, r, 1)


@frep
def torusZ(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), R: float = 1.0, r: float = 0.25) -> torch.Tensor:
    """Torus around the z axis: ``r^2 - |d|^2 - R^2 + 2 R sqrt(dx^2 + dy^2)``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) center of the torus.
    R : radius of the tube's center circle (>= 0; R = 0 is the ball of radius r).
    r : radius of the tube (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> torusZ(torch.tensor([[0.75, 0.0, 0.0], [0.0, 1.0, 0.25]]), R=1.0, r=0.25)
    tensor([0., 0.])
    """
    return _torus(x, center, R, r, 2)


def _plane_offset(x: torch.Tensor, center: Center2, name: str) -> torch.Tensor:
    """(..., 2) offsets of the first two coordinates of ``x`` from a 2-D point."""
    if x.shape[-1] not in (2, 3):
        raise ValueError(f"x must have shape (N, 2) or (N, 3), got {tuple(x.shape)}")
    return x[..., :2] - vec(center, x[..., :2], n=2, name=name)


@frep
def circle(x: torch.Tensor, center: Center2 = (0.0, 0.0), r: float = 1.0) -> torch.Tensor:
    """2-D disc: ``r^2 - dx^2 - dy^2``.

    Parameters
    ----------
    x : (..., 2) points of the plane; (..., 3) points are accepted too (z is ignored,
        giving the infinite prism over the disc).
    center : (2,) center.
    r : radius.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> circle(torch.tensor([[0.0, 0.0], [0.0, 1.0], [2.0, 0.0]]), r=1.0)
    tensor([ 1.,  0., -3.])
    """
    check_param(center, "center", "circle")
    check_param(r, "r", "circle", positive=True)
    d = _plane_offset(x, center, "center")
    return r * r - (d * d).sum(-1)


@frep
def ellipse(x: torch.Tensor, center: Center2 = (0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """2-D ellipse: ``1 - (dx/a)^2 - (dy/b)^2`` with semi-axes a (along x) and b (along y).

    Parameters
    ----------
    x : (..., 2) points of the plane ((..., 3) accepted, z ignored).
    center : (2,) center.
    a, b : semi-axes (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellipse(torch.tensor([[2.0, 0.0], [0.0, 1.0], [0.0, 0.0]]), a=2.0, b=1.0)
    tensor([0., 0., 1.])
    """
    check_param(center, "center", "ellipse")
    check_param(a, "a", "ellipse", positive=True)
    check_param(b, "b", "ellipse", positive=True)
    d = _plane_offset(x, center, "center")
    return 1.0 - (d[..., 0] / a) ** 2 - (d[..., 1] / b) ** 2


@frep
def rectangle(x: torch.Tensor, vertex: Center2 = (0.0, 0.0), dx: float = 1.0, dy: float = 1.0) -> torch.Tensor:
    """2-D axis-aligned rectangle from ``vertex`` with side lengths dx, dy.

    The R-intersection of the two slabs ``(x - x0)(x0 + dx - x)`` and
    ``(y - y0)(y0 + dy - y)`` (like :func:`block`).

    Parameters
    ----------
    x : (..., 2) points of the plane ((..., 3) accepted, z ignored).
    vertex : (2,) corner with the smallest coordinates.
    dx, dy : side lengths (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> rectangle(torch.tensor([[0.5, 0.5], [1.0, 0.5], [2.0, 0.5]]), dx=1.0, dy=1.0)
    tensor([ 0.1464,  0.0000, -3.7656])
    """
    check_param(vertex, "vertex", "rectangle")
    check_param(dx, "dx", "rectangle", positive=True)
    check_param(dy, "dy", "rectangle", positive=True)
    d = _plane_offset(x, vertex, "vertex")
    sx = d[..., 0] * (dx - d[..., 0])
    sy = d[..., 1] * (dy - d[..., 1])
    return intersection(sx, sy)


def _ell_cyl(x: torch.Tensor, center: Center, a: float, b: float, axis: int) -> torch.Tensor:
    fn = "ellCyl" + "XYZ"[axis]
    check_param(center, "center", fn)
    check_param(a, "a", fn, positive=True)
    check_param(b, "b", fn, positive=True)
    d = x - vec(center, x)
    i, j = [k for k in range(3) if k != axis]
    return 1.0 - (d[..., i] / a) ** 2 - (d[..., j] / b) ** 2


@frep
def ellCylX(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """Infinite elliptic cylinder along x: ``1 - (dy/a)^2 - (dz/b)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) a point of the axis.
    a, b : semi-axes of the cross-section along y and z.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellCylX(torch.tensor([[7.0, 2.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]), a=2.0, b=1.0)
    tensor([0., 0., 1.])
    """
    return _ell_cyl(x, center, a, b, 0)


@frep
def ellCylY(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """Infinite elliptic cylinder along y: ``1 - (dx/a)^2 - (dz/b)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) a point of the axis.
    a, b : semi-axes of the cross-section along x and z.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellCylY(torch.tensor([[2.0, 7.0, 0.0], [0.0, 0.0, 2.0]]), a=2.0, b=1.0)
    tensor([ 0., -3.])
    """
    return _ell_cyl(x, center, a, b, 1)


@frep
def ellCylZ(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """Infinite elliptic cylinder along z: ``1 - (dx/a)^2 - (dy/b)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) a point of the axis.
    a, b : semi-axes of the cross-section along x and y.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellCylZ(torch.tensor([[0.0, 1.0, 5.0], [1.0, 0.0, 5.0]]), a=2.0, b=1.0)
    tensor([0.0000, 0.7500])
    """
    return _ell_cyl(x, center, a, b, 2)


def _ell_cone(x: torch.Tensor, center: Center, a: float, b: float, axis: int, fn: str) -> torch.Tensor:
    check_param(center, "center", fn)
    if fn.startswith("ellCone"):
        check_param(a, "a", fn, positive=True)
        check_param(b, "b", fn, positive=True)
    else:
        check_param(a, "R", fn, positive=True)
    d = x - vec(center, x)
    i, j = [k for k in range(3) if k != axis]
    return d[..., axis] ** 2 - (d[..., i] / a) ** 2 - (d[..., j] / b) ** 2


@frep
def coneX(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), R: float = 1.0) -> torch.Tensor:
    """Infinite double cone along x with apex ``center``: ``dx^2 - (dy/R)^2 - (dz/R)^2``.

    The cross-section at distance ``|dx|`` from the apex is a disc of radius ``R |dx|``
    (``R`` is the tangent of the half-angle).

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) apex.
    R : radius of the cross-section at unit distance from the apex (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> coneX(torch.tensor([[2.0, 1.0, 0.0], [-2.0, 0.0, 1.0], [1.0, 0.0, 0.0]]), R=0.5)
    tensor([0., 0., 1.])
    """
    return _ell_cone(x, center, R, R, 0, "coneX")


@frep
def coneY(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), R: float = 1.0) -> torch.Tensor:
    """Infinite double cone along y with apex ``center``: ``dy^2 - (dx/R)^2 - (dz/R)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) apex.
    R : radius of the cross-section at unit distance from the apex (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> coneY(torch.tensor([[1.0, 2.0, 0.0], [1.0, 0.0, 0.0]]), R=0.5)
    tensor([ 0., -4.])
    """
    return _ell_cone(x, center, R, R, 1, "coneY")


@frep
def coneZ(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), R: float = 1.0) -> torch.Tensor:
    """Infinite double cone along z with apex ``center``: ``dz^2 - (dx/R)^2 - (dy/R)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) apex.
    R : radius of the cross-section at unit distance from the apex (> 0).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> coneZ(torch.tensor([[0.0, 1.0, 2.0], [0.0, 0.0, 3.0]]), R=0.5)
    tensor([0., 9.])
    """
    return _ell_cone(x, center, R, R, 2, "coneZ")


@frep
def ellConeX(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """Infinite elliptic double cone along x: ``dx^2 - (dy/a)^2 - (dz/b)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) apex.
    a, b : semi-axes (along y and z) of the cross-section at unit distance from the apex.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellConeX(torch.tensor([[1.0, 2.0, 0.0], [1.0, 0.0, 1.0]]), a=2.0, b=1.0)
    tensor([0., 0.])
    """
    return _ell_cone(x, center, a, b, 0, "ellConeX")


@frep
def ellConeY(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """Infinite elliptic double cone along y: ``dy^2 - (dx/a)^2 - (dz/b)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) apex.
    a, b : semi-axes (along x and z) of the cross-section at unit distance from the apex.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellConeY(torch.tensor([[2.0, 1.0, 0.0], [0.0, 1.0, 0.0]]), a=2.0, b=1.0)
    tensor([0., 1.])
    """
    return _ell_cone(x, center, a, b, 1, "ellConeY")


@frep
def ellConeZ(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """Infinite elliptic double cone along z: ``dz^2 - (dx/a)^2 - (dy/b)^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) apex.
    a, b : semi-axes (along x and y) of the cross-section at unit distance from the apex.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellConeZ(torch.tensor([[2.0, 0.0, -1.0], [0.0, 2.0, 1.0]]), a=2.0, b=1.0)
    tensor([ 0., -3.])
    """
    return _ell_cone(x, center, a, b, 2, "ellConeZ")


def _pow0(t: torch.Tensor, p: float | torch.Tensor) -> torch.Tensor:
    """``t ** p`` for t >= 0 with value 0 and a finite (zero) gradient at t = 0.

    The double ``where`` keeps the unused branch away from 0 ** (negative) = inf, which
    would otherwise turn into NaN gradients (superellipsoids with exponents < 1).  A NaN
    stays NaN (a test ``t > 0`` would map it to 0, and a NaN point would read as inside).
    """
    nonzero = t != 0
    return torch.where(nonzero, torch.where(nonzero, t, torch.ones_like(t)) ** p, torch.zeros_like(t))


def _super_ellipsoid(u: torch.Tensor, v: torch.Tensor, w: torch.Tensor, s1: float, s2: float) -> torch.Tensor:
    # HyperFun hfSuperEll: 1 - (|u|^(2/s2) + |v|^(2/s2))^(s2/s1) - |w|^(2/s1), written on squares
    uv = _pow0(u * u, 1.0 / s2) + _pow0(v * v, 1.0 / s2)
    return 1.0 - _pow0(uv, s2 / s1) - _pow0(w * w, 1.0 / s1)


@frep
def superEll(
    x: torch.Tensor,
    center: Center = (0.0, 0.0, 0.0),
    a: float = 1.0,
    b: float = 1.0,
    c: float = 1.0,
    s1: float = 1.0,
    s2: float = 1.0,
) -> torch.Tensor:
    """Superellipsoid (HyperFun ``hfSuperEll``).

    ``1 - (|dx/a|^(2/s2) + |dy/b|^(2/s2))^(s2/s1) - |dz/c|^(2/s1)``.
    ``s1 = s2 = 1`` is the ellipsoid, exponents towards 0 give a box, 2 an octahedron,
    above 2 a star.  Gradients are finite everywhere, including on the coordinate
    planes through the center where a power with exponent < 1 is not differentiable.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) center.
    a, b, c : semi-axes along x, y, z (> 0).
    s1 : "north-south" exponent (z profile), > 0.
    s2 : "east-west" exponent (xy cross-section), > 0.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> p = torch.tensor([[2.0, 0.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.5, 0.5]])
    >>> superEll(p, a=2.0, b=1.0, c=1.0, s1=0.5, s2=0.5)
    tensor([0.0000, 0.0000, 0.8125])
    """
    check_param(center, "center", "superEll")
    for name, value in (("a", a), ("b", b), ("c", c), ("s1", s1), ("s2", s2)):
        check_param(value, name, "superEll", positive=True)
    d = x - vec(center, x)
    return _super_ellipsoid(d[..., 0] / a, d[..., 1] / b, d[..., 2] / c, s1, s2)


def _euler_local(x: torch.Tensor, r: Center, t: Center) -> torch.Tensor:
    """Local coordinates ``Rx(r3)^T Ry(r2)^T Rz(r1)^T (x - t)``: x = R local + t, R = Rz(r1) Ry(r2) Rx(r3)."""
    rv = vec(r, x, name="r")
    p = x - vec(t, x, name="t")
    return rotate3DX(rotate3DY(rotate3DZ(p, rv[..., 0]), rv[..., 1]), rv[..., 2])


@frep
def superQuadric(
    x: torch.Tensor,
    e: tuple[float, float] | torch.Tensor = (1.0, 1.0),
    a: Center = (1.0, 1.0, 1.0),
    r: Center = (0.0, 0.0, 0.0),
    t: Center = (0.0, 0.0, 0.0),
) -> torch.Tensor:
    """Superquadric (superellipsoid) in a general pose, the reference code's ``superQuadric``.

    ``1 - ((|u/a1|^(2/e2) + |v/a2|^(2/e2))^(e2/e1) + |w/a3|^(2/e1))`` where (u, v, w) are
    the local coordinates of x.  ``r = (r1, r2, r3)`` are Z-Y-X Euler angles, in the
    reference code's order (MATLAB's ``eul2rotm``): the solid is built at the origin, rotated
    by ``r3`` about x, then ``r2`` about y, then ``r1`` about z (radians, R = Rz(r1) Ry(r2)
    Rx(r3)), then translated by ``t``.  Equal to :func:`superEll` with ``s1 = e1, s2 = e2``
    when ``r = 0``.  (The reference code raises the signed local coordinates to the powers:
    NaN on their negative side unless 2/e is an even integer; here their absolute values.)

    Parameters
    ----------
    x : (..., 3) points.
    e : (2,) exponents (e1 north-south, e2 east-west), > 0.
    a : (3,) semi-axes (> 0).
    r : (3,) Euler angles in radians: about z, then y, then x (R = Rz(r1) Ry(r2) Rx(r3)).
    t : (3,) translation (the center of the solid).

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[1.0, 2.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    >>> f = superQuadric(p, e=(0.5, 0.5), a=(2.0, 1.0, 1.0), r=(math.pi / 2, 0.0, 0.0), t=(1.0, 0.0, 0.0))
    >>> f.round(decimals=12)
    tensor([0., 1.], dtype=torch.float64)
    """
    check_param(e, "e", "superQuadric", positive=True)
    check_param(a, "a", "superQuadric", positive=True)
    check_param(r, "r", "superQuadric")
    check_param(t, "t", "superQuadric")
    ev = vec(e, x, n=2, name="e")
    av = vec(a, x, name="a")
    q = _euler_local(x, r, t)
    return _super_ellipsoid(
        q[..., 0] / av[..., 0], q[..., 1] / av[..., 1], q[..., 2] / av[..., 2], ev[..., 0], ev[..., 1]
    )


def _per_center(like: torch.Tensor, **values: Values) -> list[torch.Tensor]:
    """The per-center arguments of a multi-center primitive as (K,) tensors on ``like``.

    Floats become length-1 vectors (they broadcast); tensors keep their graph.
    Raises ValueError naming the argument when the lengths disagree.
    """
    out, lengths = [], {}
    for name, v in values.items():
        if isinstance(v, torch.Tensor):
            t = v.to(device=like.device, dtype=like.dtype)
        elif isinstance(v, list | tuple) and any(isinstance(c, torch.Tensor) for c in v):
            t = torch.stack([torch.as_tensor(c, dtype=like.dtype, device=like.device) for c in v])
        else:
            t = torch.as_tensor(np.asarray(v, dtype=np.float64), dtype=like.dtype, device=like.device)
        t = t.reshape(-1) if t.ndim == 0 else t
        if t.ndim != 1:
            raise ValueError(f"{name} must be a number or a 1-D sequence, got shape {tuple(t.shape)}")
        if t.shape[0] != 1:
            lengths[name] = t.shape[0]
        out.append(t)
    if len(set(lengths.values())) > 1:
        raise ValueError(f"per-center arguments have different lengths: {lengths}")
    return out


def _sq_dist_to_centers(x: torch.Tensor, x0: torch.Tensor, y0: torch.Tensor, z0: torch.Tensor) -> torch.Tensor:
    """(..., K) squared distances from points (..., 3) to K centers."""
    return (x[..., 0, None] - x0) ** 2 + (x[..., 1, None] - y0) ** 2 + (x[..., 2, None] - z0) ** 2


@frep
def blobby(x: torch.Tensor, x0: Values, y0: Values, z0: Values, a: Values, b: Values, T: float = 0.5) -> torch.Tensor:
    """Blobby object (Blinn), HyperFun ``hfBlobby``: ``sum_i b_i exp(-a_i r_i^2) - T``.

    Parameters
    ----------
    x : (..., 3) points.
    x0, y0, z0 : (K,) coordinates of the K centers.
    a : (K,) decay rates (> 0), or one number for all.
    b : (K,) weights, or one number for all.
    T : threshold.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[0.0, 0.0, 0.0], [math.sqrt(math.log(2.0)), 0.0, 0.0]], dtype=torch.float64)
    >>> blobby(p, x0=[0.0], y0=[0.0], z0=[0.0], a=[1.0], b=[1.0], T=0.5)
    tensor([0.5000, 0.0000], dtype=torch.float64)
    """
    for name, value in (("x0", x0), ("y0", y0), ("z0", z0), ("b", b), ("T", T)):
        check_param(value, name, "blobby")
    check_param(a, "a", "blobby", positive=True)
    x0, y0, z0, a, b = _per_center(x, x0=x0, y0=y0, z0=z0, a=a, b=b)
    return (b * torch.exp(-a * _sq_dist_to_centers(x, x0, y0, z0))).sum(-1) - T


@frep
def metaBall(x: torch.Tensor, x0: Values, y0: Values, z0: Values, b: Values, d: Values, T: float = 0.5) -> torch.Tensor:
    """Metaballs (Nishimura), HyperFun ``hfMetaBall``: ``sum_i m_i(r_i) - T``.

    With r the distance to center i, ``m(r) = b (1 - 3 r^2 / d^2)`` for r <= d/3,
    ``1.5 b (1 - r/d)^2`` for d/3 < r <= d and 0 beyond (C^1, compact support d).

    Parameters
    ----------
    x : (..., 3) points.
    x0, y0, z0 : (K,) coordinates of the K centers.
    b : (K,) weights, or one number for all.
    d : (K,) radii of influence (> 0), or one number for all.
    T : threshold.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> p = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [2.0, 0.0, 0.0]], dtype=torch.float64)
    >>> metaBall(p, x0=[0.0], y0=[0.0], z0=[0.0], b=[1.0], d=[1.0], T=0.375)
    tensor([ 0.6250,  0.0000, -0.3750], dtype=torch.float64)
    """
    for name, value in (("x0", x0), ("y0", y0), ("z0", z0), ("b", b), ("T", T)):
        check_param(value, name, "metaBall")
    check_param(d, "d", "metaBall", positive=True)
    x0, y0, z0, b, d = _per_center(x, x0=x0, y0=y0, z0=z0, b=b, d=d)
    r2 = _sq_dist_to_centers(x, x0, y0, z0)
    r = safe_sqrt(r2)
    inner = b * (1.0 - 3.0 * r2 / (d * d))
    outer = 1.5 * b * torch.clamp(1.0 - r / d, min=0.0) ** 2  # 0 beyond d
    return torch.where(3.0 * r <= d, inner, outer).sum(-1) - T


@frep
def soft(x: torch.Tensor, x0: Values, y0: Values, z0: Values, d: Values, T: float = 0.5) -> torch.Tensor:
    """Soft objects (Wyvill), HyperFun ``hfSoft``: ``sum_i w(r_i) - T``.

    ``w(r) = 1 - 22 r^2 / (9 d^2) + 17 r^4 / (9 d^4) - 4 r^6 / (9 d^6)`` for r <= d and 0
    beyond (w(d) = 0, so the sum is continuous; C^1).

    Parameters
    ----------
    x : (..., 3) points.
    x0, y0, z0 : (K,) coordinates of the K centers.
    d : (K,) radii of influence (> 0), or one number for all.
    T : threshold.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> p = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [3.0, 0.0, 0.0]], dtype=torch.float64)
    >>> soft(p, x0=[0.0], y0=[0.0], z0=[0.0], d=[1.0], T=0.5)
    tensor([ 0.5000, -0.5000, -0.5000], dtype=torch.float64)
    """
    for name, value in (("x0", x0), ("y0", y0), ("z0", z0), ("T", T)):
        check_param(value, name, "soft")
    check_param(d, "d", "soft", positive=True)
    x0, y0, z0, d = _per_center(x, x0=x0, y0=y0, z0=z0, d=d)
    q = _sq_dist_to_centers(x, x0, y0, z0) / (d * d)  # (r/d)^2
    w = 1.0 - 22.0 / 9.0 * q + 17.0 / 9.0 * q * q - 4.0 / 9.0 * q * q * q
    return torch.where(q <= 1.0, w, torch.zeros_like(w)).sum(-1) - T


@frep
def mapBlob(
    x: torch.Tensor,
    fobj: float | torch.Tensor,
    x0: Values,
    y0: Values,
    z0: Values,
    fobj0: Values,
    sigma: Values,
) -> torch.Tensor:
    """Local dents (or bumps) in a field: ``fobj - sum_i fobj0_i / (1 + |x - c_i|^2 / sigma_i^2)``.

    The reference code's ``mapBlob``: each center ``c_i = (x0_i, y0_i, z0_i)`` lowers the field
    ``fobj`` of a solid by ``fobj0_i`` at the center, by half of it at distance ``sigma_i``, and
    by a Cauchy-like tail ``fobj0_i sigma_i^2 / r^2`` far away.  ``fobj0_i > 0`` carves a dent
    (material removed where ``fobj < fobj0_i``), ``fobj0_i < 0`` raises a bump.  (The reference
    adds 1e-9 to ``sigma_i^2`` against division by zero; here sigma must be positive: a
    relative difference of ``1e-9 / sigma^2``.)

    Parameters
    ----------
    x : (..., 3) points.
    fobj : (...) field values of the solid to deform at ``x`` (or a number).
    x0, y0, z0 : (K,) coordinates of the K centers.
    fobj0 : (K,) depths of the dents (field units), or one number for all.
    sigma : (K,) widths (> 0, length units), or one number for all.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([[1.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    >>> f = sphere(x, r=1.0)
    >>> mapBlob(x, f, x0=[1.0], y0=[0.0], z0=[0.0], fobj0=[0.5], sigma=[0.5])
    tensor([-0.5000, -1.5000,  0.9000], dtype=torch.float64)
    """
    for name, value in (("x0", x0), ("y0", y0), ("z0", z0), ("fobj0", fobj0)):
        check_param(value, name, "mapBlob")  # fobj: field values, read by frep (finite) like points
    check_param(sigma, "sigma", "mapBlob", positive=True)
    x0, y0, z0, fobj0, sigma = _per_center(x, x0=x0, y0=y0, z0=z0, fobj0=fobj0, sigma=sigma)
    r2 = _sq_dist_to_centers(x, x0, y0, z0)
    return fobj - (fobj0 / (1.0 + r2 / (sigma * sigma))).sum(-1)


@frep
def noiseG(x: torch.Tensor, amp: float = 1.0, freq: float = 1.0, phase: float = 0.0) -> torch.Tensor:
    """Deterministic "noise" of HyperFun's ``hfNoiseG``: a product of perturbed sines.

    With ``X = freq x`` (Y, Z likewise) and ``h(X, W) = amp sin X + amp/1.17 sin(X/1.35 + phase sin W)``,
    the value is ``h(X, Z) h(Y, X) h(Z, Y)``.  Not a solid by itself: add it to a
    defining function to roughen its surface (``sphere(x) + noiseG(x, 0.1, 8, 1)``).

    Parameters
    ----------
    x : (..., 3) points.
    amp : amplitude.
    freq : angular frequency (radians per length unit).
    phase : phase-coupling strength.

    Returns
    -------
    (...) values with ``|value| <= (|amp| (1 + 1/1.17))^3``.

    Examples
    --------
    >>> import math, torch
    >>> noiseG(torch.tensor([[0.0, 1.0, 2.0], [math.pi / 2, math.pi / 2, math.pi / 2]]), amp=1.0, freq=1.0, phase=0.0)
    tensor([0.0000, 5.6855])
    """
    for name, value in (("amp", amp), ("freq", freq), ("phase", phase)):
        check_param(value, name, "noiseG")
    sx, sy, sz = (torch.sin(freq * x[..., i]) for i in range(3))

    def series(coordinate: torch.Tensor, coupled_sine: torch.Tensor) -> torch.Tensor:
        return amp * torch.sin(freq * coordinate) + amp / 1.17 * torch.sin(
            freq * coordinate / 1.35 + phase * coupled_sine
        )

    # each coordinate's second sine is shifted by the sine of another one: x by z, y by x, z by y
    return series(x[..., 0], sz) * series(x[..., 1], sx) * series(x[..., 2], sy)
