"""Primitive solids as defining functions (HyperFun convention: f >= 0 inside).

Every primitive takes points ``x`` of shape (..., 3) (torch tensor or numpy array) and
returns f of shape (...).  Numeric arguments may be floats or tensors with
``requires_grad`` (shape parameters, paper section 4); a tensor of shape (B, 1) gives
(B, N) values for B parameter sets at once.  Only torch operations on ``x`` are used
(no ``.item()``, no Python ``if`` on values).
"""

from __future__ import annotations

import torch

from ._array import frep, vec
from .operations import intersection

Center = tuple[float, float, float] | torch.Tensor


__all__ = [
    "sphere",
    "ellipsoid",
    "cylX",
    "cylY",
    "cylZ",
    "block",
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
