"""Primitive solids as defining functions (HyperFun convention: f >= 0 inside).

Every primitive takes points ``x`` of shape (..., 3) (torch tensor or numpy array) and
returns f of shape (...).  Numeric arguments may be floats or tensors with
``requires_grad`` (shape parameters, paper section 4); a tensor of shape (B, 1) gives
(B, N) values for B parameter sets at once.  Only torch operations on ``x`` are used
(no ``.item()``, no Python ``if`` on values).
"""

from __future__ import annotations

import torch

from ._array import frep, safe_sqrt, vec
from .operations import intersection

Center = tuple[float, float, float] | torch.Tensor
Center2 = tuple[float, float] | torch.Tensor


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
]


@frep
def sphere(x: torch.Tensor, center: Center = (0.0, 0.0, 0.0), r: float = 1.0) -> torch.Tensor:
    """Sphere: ``r^2 - |x - center|^2``.

    Parameters
    ----------
    x : (..., 3) points.
    center : (3,) center.
    r : radius (same length unit as x).

    Examples
    --------
    >>> import torch
    >>> sphere(torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]), r=1.0)
    tensor([ 1., -3.])
    """
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
    d = x - vec(center, x)
    return 1.0 - (d[..., 0] / a) ** 2 - (d[..., 1] / b) ** 2 - (d[..., 2] / c) ** 2


def _cyl(x: torch.Tensor, center: Center, r: float, axis: int) -> torch.Tensor:
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
    v = vec(vertex, x, name="vertex")
    d = x - v
    sx = d[..., 0] * (dx - d[..., 0])
    sy = d[..., 1] * (dy - d[..., 1])
    sz = d[..., 2] * (dz - d[..., 2])
    return intersection(intersection(sx, sy), sz)


def _torus(x: torch.Tensor, center: Center, R: float, r: float, axis: int) -> torch.Tensor:
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
    R : radius of the tube's center circle.
    r : radius of the tube.

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
    R : radius of the tube's center circle.
    r : radius of the tube.

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
    R : radius of the tube's center circle.
    r : radius of the tube.

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
    d = _plane_offset(x, center, "center")
    return r * r - (d * d).sum(-1)


@frep
def ellipse(x: torch.Tensor, center: Center2 = (0.0, 0.0), a: float = 1.0, b: float = 1.0) -> torch.Tensor:
    """2-D ellipse: ``1 - (dx/a)^2 - (dy/b)^2`` with semi-axes a (along x) and b (along y).

    Parameters
    ----------
    x : (..., 2) points of the plane ((..., 3) accepted, z ignored).
    center : (2,) center.
    a, b : semi-axes.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> ellipse(torch.tensor([[2.0, 0.0], [0.0, 1.0], [0.0, 0.0]]), a=2.0, b=1.0)
    tensor([0., 0., 1.])
    """
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
    dx, dy : side lengths.

    Returns
    -------
    (...) field values, >= 0 inside.

    Examples
    --------
    >>> import torch
    >>> rectangle(torch.tensor([[0.5, 0.5], [1.0, 0.5], [2.0, 0.5]]), dx=1.0, dy=1.0)
    tensor([ 0.1464,  0.0000, -3.7656])
    """
    d = _plane_offset(x, vertex, "vertex")
    sx = d[..., 0] * (dx - d[..., 0])
    sy = d[..., 1] * (dy - d[..., 1])
    return intersection(sx, sy)
