"""The chess pawn of the paper's Figs. 5 and 6: polynomial primitives joined by R-functions.

The pawn stands on the plane z = -1 along the z axis: a flattened ellipsoid cut flat at the
bottom (the base), a thin flattened ellipsoid (the ring above it), a hyperboloid of one sheet
cut by a slab (the waisted body), a flattened ellipsoid (the collar) and a sphere (the head).
Every piece is a polynomial in x, y, z; the R-functions make f a non-distance field whose
redistancing section 5.3 shows.
"""

from __future__ import annotations

import torch

from ..model import Param, model
from ..operations import intersection, union
from ..primitives import ellipsoid, sphere

BOTTOM = -1.0  # the plane the pawn stands on
COLLAR_Z = 0.45  # height of the collar (top of the body)
BODY_BOTTOM = -0.7  # where the body's hyperboloid is cut


def _slab_z(x: torch.Tensor, lower: float, upper: float) -> torch.Tensor:
    """``(z - lower)(upper - z)``: >= 0 between the two planes (degree 2)."""
    z = x[..., 2]
    return (z - lower) * (upper - z)


def _hyperboloid_z(x: torch.Tensor, waist: torch.Tensor | float, z0: float, slope: float) -> torch.Tensor:
    """Hyperboloid of one sheet around the z axis: ``waist^2 + slope^2 (z - z0)^2 - x^2 - y^2``.

    Its radius at height z is sqrt(waist^2 + slope^2 (z - z0)^2): narrowest (``waist``) at z0.
    """
    return waist * waist + (slope * (x[..., 2] - z0)) ** 2 - x[..., 0] ** 2 - x[..., 1] ** 2


@model(
    bounds=((-1.0, -1.0, -1.2), (1.0, 1.0, 1.3)),
    head_radius=Param(0.3, 0.2, 0.4, label="head radius"),
    neck_radius=Param(0.17, 0.1, 0.24, label="neck (waist) radius"),
    base_radius=Param(0.62, 0.45, 0.75, label="base radius"),
    collar_radius=Param(0.36, 0.25, 0.45, label="collar radius"),
)
def pawn(
    x: torch.Tensor,
    head_radius: float = 0.3,
    neck_radius: float = 0.17,
    base_radius: float = 0.62,
    collar_radius: float = 0.36,
) -> torch.Tensor:
    """A chess pawn (Fig. 5), about 2 units high, standing on z = -1.

    Parameters
    ----------
    x : (..., 3) points.
    head_radius : radius of the spherical head, centered 0.27 above the collar.
    neck_radius : narrowest radius of the body, just under the collar.
    base_radius : radius of the base.
    collar_radius : radius of the collar under the head.

    Examples
    --------
    >>> import torch
    >>> pts = torch.tensor([[0.0, 0.0, 0.7], [0.0, 0.0, -0.95], [0.5, 0.0, 0.5], [0.0, 0.0, -1.1]])
    >>> pawn(pts) > 0  # head, base, beside the neck, under the base
    tensor([ True,  True, False, False])
    """
    head = sphere(x, center=(0.0, 0.0, COLLAR_Z + 0.27), r=head_radius)
    collar = ellipsoid(x, center=(0.0, 0.0, COLLAR_Z), a=collar_radius, b=collar_radius, c=0.07)
    # body: radius neck_radius at the collar, about 0.43 at its bottom
    body = intersection(_hyperboloid_z(x, neck_radius, COLLAR_Z, 0.33), _slab_z(x, BODY_BOTTOM, COLLAR_Z))
    ring = ellipsoid(x, center=(0.0, 0.0, -0.68), a=0.8 * base_radius, b=0.8 * base_radius, c=0.08)
    base = intersection(ellipsoid(x, center=(0.0, 0.0, -0.88), a=base_radius, b=base_radius, c=0.3), x[..., 2] - BOTTOM)
    return union(union(union(union(base, ring), body), collar), head)
