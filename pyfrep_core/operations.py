"""Operations on defining functions: R-function Booleans, min/max, blends, offsets (paper section 3.1).

All functions take field values ``f1, f2`` (tensors of any broadcastable shape, e.g. (N,))
and return a tensor of the broadcast shape.  Convention: f >= 0 inside.
"""

from __future__ import annotations

import torch

from ._array import Scalar, check_param, frep, safe_sqrt

__all__ = [
    "union",
    "intersection",
    "negate",
    "difference",
    "union_m",
    "intersection_m",
    "difference_m",
    "union_min_max",
    "intersection_min_max",
    "difference_min_max",
    "blendUnion",
    "blendIntersection",
    "blendDifference",
    "boundBlendUnion",
    "boundBlendIntersection",
    "offset",
    "shell",
]


@frep
def union(f1: torch.Tensor, f2: torch.Tensor) -> torch.Tensor:
    """R-union (R_0 disjunction): ``f1 + f2 + sqrt(f1^2 + f2^2)``.

    Examples
    --------
    >>> import torch
    >>> union(torch.tensor([1.0, -1.0]), torch.tensor([-2.0, -3.0]))
    tensor([ 1.2361, -0.8377])
    """
    return f1 + f2 + safe_sqrt(f1 * f1 + f2 * f2)


@frep
def intersection(f1: torch.Tensor, f2: torch.Tensor) -> torch.Tensor:
    """R-intersection (R_0 conjunction): ``f1 + f2 - sqrt(f1^2 + f2^2)``.

    Examples
    --------
    >>> import torch
    >>> intersection(torch.tensor([3.0]), torch.tensor([4.0]))
    tensor([2.])
    """
    return f1 + f2 - safe_sqrt(f1 * f1 + f2 * f2)


@frep
def negate(f: torch.Tensor) -> torch.Tensor:
    """Complement: ``-f``.

    Examples
    --------
    >>> import torch
    >>> negate(torch.tensor([2.0]))
    tensor([-2.])
    """
    return -f


@frep
def difference(f1: torch.Tensor, f2: torch.Tensor) -> torch.Tensor:
    """R-difference: ``intersection(f1, -f2)``.

    Examples
    --------
    >>> import torch
    >>> difference(torch.tensor([3.0]), torch.tensor([-4.0]))
    tensor([2.])
    """
    return intersection(f1, -f2)


def _r_m(f1: torch.Tensor, f2: torch.Tensor, m: Scalar, sign: float, fn: str) -> torch.Tensor:
    # (f1 + f2 +- rho) rho^m with rho = safe_sqrt(f1^2 + f2^2): written with s^(m/2) instead,
    # d s^(m/2)/ds = inf at s = 0 meets ds/df = 0 and the gradient is NaN at f1 = f2 = 0
    check_param(m, "m", fn, nonnegative=True)
    rho = safe_sqrt(f1 * f1 + f2 * f2)
    # rho^m saturates at the dtype's largest value instead of overflowing: where operands near
    # sqrt(max) make it overflow, an exactly cancelled first factor still gives 0 (not 0 * inf = NaN)
    return (f1 + f2 + sign * rho) * (rho**m).clamp(max=torch.finfo(rho.dtype).max)


@frep
def union_m(f1: torch.Tensor, f2: torch.Tensor, m: float = 1.0) -> torch.Tensor:
    """R_m union: ``(f1 + f2 + sqrt(f1^2 + f2^2)) * (f1^2 + f2^2)^(m/2)`` (C^m on the plane).

    ``rho = sqrt(f1^2 + f2^2)`` is :func:`~pyfrep_core._array.safe_sqrt` and the factor is
    ``rho^m``, so value, gradient and Hessian are finite everywhere, also at f1 = f2 = 0:
    there the gradient is ``(grad f1 + grad f2) rho0^m`` with ``rho0 = safe_sqrt(0)`` (about
    1e-77 in float64), i.e. 0 to rounding, the exact derivative for m > 0 (the function is
    homogeneous of degree m + 1 in (f1, f2)); m = 0 is :func:`union` and its sub-gradient.

    Parameters
    ----------
    f1, f2 : field values (broadcastable shapes).
    m : smoothness order, finite and >= 0.

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> union_m(torch.tensor([3.0]), torch.tensor([4.0]), m=2)
    tensor([300.])
    """
    return _r_m(f1, f2, m, 1.0, "union_m")


@frep
def intersection_m(f1: torch.Tensor, f2: torch.Tensor, m: float = 1.0) -> torch.Tensor:
    """R_m intersection: ``(f1 + f2 - sqrt(f1^2 + f2^2)) * (f1^2 + f2^2)^(m/2)``.

    Finite value, gradient and Hessian everywhere, as for :func:`union_m`.

    Parameters
    ----------
    f1, f2 : field values (broadcastable shapes).
    m : smoothness order, finite and >= 0.

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> intersection_m(torch.tensor([3.0]), torch.tensor([4.0]), m=2)
    tensor([50.])
    """
    return _r_m(f1, f2, m, -1.0, "intersection_m")


@frep
def difference_m(f1: torch.Tensor, f2: torch.Tensor, m: float = 1.0) -> torch.Tensor:
    """R_m difference: ``intersection_m(f1, -f2, m)``.

    Parameters
    ----------
    f1, f2 : field values (broadcastable shapes); the solid of f2 is removed from f1's.
    m : smoothness order, finite and >= 0.

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> difference_m(torch.tensor([3.0]), torch.tensor([-4.0]), m=2)
    tensor([50.])
    """
    return _r_m(f1, -f2, m, -1.0, "difference_m")


@frep
def union_min_max(f1: torch.Tensor, f2: torch.Tensor) -> torch.Tensor:
    """Union by ``max(f1, f2)`` (same solid as :func:`union`, a different field).

    Examples
    --------
    >>> import torch
    >>> union_min_max(torch.tensor([1.0]), torch.tensor([2.0]))
    tensor([2.])
    """
    return torch.maximum(f1, f2)


@frep
def intersection_min_max(f1: torch.Tensor, f2: torch.Tensor) -> torch.Tensor:
    """Intersection by ``min(f1, f2)``.

    Examples
    --------
    >>> import torch
    >>> intersection_min_max(torch.tensor([1.0]), torch.tensor([2.0]))
    tensor([1.])
    """
    return torch.minimum(f1, f2)


@frep
def difference_min_max(f1: torch.Tensor, f2: torch.Tensor) -> torch.Tensor:
    """Difference by ``min(f1, -f2)``.

    Examples
    --------
    >>> import torch
    >>> difference_min_max(torch.tensor([1.0]), torch.tensor([2.0]))
    tensor([-2.])
    """
    return torch.minimum(f1, -f2)


def _check_extents(fn: str, **extents: Scalar) -> None:
    """a1, a2 (a3) divide the fields: 0 gives 0/0 = NaN on the surface f_i = 0 and a blend that jumps
    there (the limit a -> 0 is a0 / (1 + ...) on f_i = 0 and 0 beside it), so they must be nonzero.
    Their sign does not matter (they are squared); a0 = 0 is the plain operation."""
    for name, value in extents.items():
        check_param(value, name, fn, nonzero=name != "a0")


def _blend_displacement(f1: torch.Tensor, f2: torch.Tensor, a0: Scalar, a1: Scalar, a2: Scalar) -> torch.Tensor:
    # Pasko's displacement a0 / (1 + (f1/a1)^2 + (f2/a2)^2): a0 at the edge f1 = f2 = 0, -> 0 away from it
    return a0 / (1.0 + (f1 / a1) ** 2 + (f2 / a2) ** 2)


@frep
def blendUnion(
    f1: torch.Tensor, f2: torch.Tensor, a0: Scalar = 1.0, a1: Scalar = 1.0, a2: Scalar = 1.0
) -> torch.Tensor:
    """Blending union (HyperFun ``hfBlendUni``): ``union(f1, f2) + a0 / (1 + (f1/a1)^2 + (f2/a2)^2)``.

    The displacement adds material (a0 > 0) around the edge where both surfaces meet;
    a1 and a2 set how far along each solid the blend reaches.

    Parameters
    ----------
    f1, f2 : field values (broadcastable shapes, e.g. (N,)).
    a0 : blend amplitude (> 0 adds material).
    a1, a2 : blend extents along f1 and f2 (non-zero, in field units).

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> blendUnion(torch.tensor([0.0, 3.0]), torch.tensor([0.0, -4.0]), a0=1.0, a1=1.0, a2=2.0)
    tensor([1.0000, 4.0714])
    """
    _check_extents("blendUnion", a0=a0, a1=a1, a2=a2)
    return union(f1, f2) + _blend_displacement(f1, f2, a0, a1, a2)


@frep
def blendIntersection(
    f1: torch.Tensor, f2: torch.Tensor, a0: Scalar = 1.0, a1: Scalar = 1.0, a2: Scalar = 1.0
) -> torch.Tensor:
    """Blending intersection (HyperFun ``hfBlendInt``): ``intersection(f1, f2) + a0 / (1 + (f1/a1)^2 + (f2/a2)^2)``.

    Same sign convention as HyperFun: a0 > 0 adds material along the edge (fills a
    concave crease), a0 < 0 removes material (rounds a convex edge).

    Parameters
    ----------
    f1, f2 : field values (broadcastable shapes, e.g. (N,)).
    a0 : blend amplitude.
    a1, a2 : blend extents along f1 and f2 (non-zero).

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> blendIntersection(torch.tensor([0.0, 3.0]), torch.tensor([0.0, 4.0]), a0=-1.0, a1=1.0, a2=1.0)
    tensor([-1.0000,  1.9615])
    """
    _check_extents("blendIntersection", a0=a0, a1=a1, a2=a2)
    return intersection(f1, f2) + _blend_displacement(f1, f2, a0, a1, a2)


@frep
def blendDifference(
    f1: torch.Tensor, f2: torch.Tensor, a0: Scalar = 1.0, a1: Scalar = 1.0, a2: Scalar = 1.0
) -> torch.Tensor:
    """Blending difference: ``blendIntersection(f1, -f2, a0, a1, a2)``.

    Parameters
    ----------
    f1, f2 : field values (broadcastable shapes); the solid of f2 is removed from f1's.
    a0 : blend amplitude (> 0 adds material along the edge, < 0 rounds it off).
    a1, a2 : blend extents along f1 and f2 (non-zero).

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> blendDifference(torch.tensor([3.0]), torch.tensor([-4.0]), a0=-1.0)
    tensor([1.9615])
    """
    _check_extents("blendDifference", a0=a0, a1=a1, a2=a2)
    return blendIntersection(f1, -f2, a0, a1, a2)


def _bounded_displacement(
    f1: torch.Tensor, f2: torch.Tensor, f3: torch.Tensor, a0: Scalar, a1: Scalar, a2: Scalar, a3: Scalar
) -> torch.Tensor:
    # bounded blending (Pasko et al.): r1 = (f1/a1)^2 + (f2/a2)^2, r2 = (f3+/a3)^2, r = r1 / (r1 + r2),
    # displacement a0 (1 - r)^3 / (1 + r): a0 on the edge, 0 wherever the bounding solid f3 < 0
    # r1 and r2 saturate at half the dtype's largest value: their sum cannot overflow, so operands
    # whose squares overflow give r = 1/2 at worst instead of inf / inf = NaN
    big = torch.finfo(torch.result_type(f1, f2)).max / 2
    r1 = ((f1 / a1) ** 2 + (f2 / a2) ** 2).clamp(max=big)
    r2 = ((torch.clamp(f3, min=0.0) / a3) ** 2).clamp(max=big)
    total = r1 + r2
    has = total > 0
    r = torch.where(has, r1 / torch.where(has, total, torch.ones_like(total)), torch.zeros_like(total))
    return a0 * (1.0 - r) ** 3 / (1.0 + r)


@frep
def boundBlendUnion(
    f1: torch.Tensor,
    f2: torch.Tensor,
    f3: torch.Tensor,
    a0: Scalar = 1.0,
    a1: Scalar = 1.0,
    a2: Scalar = 1.0,
    a3: Scalar = 1.0,
) -> torch.Tensor:
    """Bounded blending union: the blend of :func:`blendUnion` confined to a bounding solid f3.

    ``union(f1, f2) + a0 (1 - r)^3 / (1 + r)`` with ``r1 = (f1/a1)^2 + (f2/a2)^2``,
    ``r2 = (max(f3, 0)/a3)^2`` and ``r = r1 / (r1 + r2)`` (0 where both vanish).  Outside
    the bounding solid (f3 <= 0) r = 1 and the result is the plain R-union; inside it the
    blend fades from a0 on the edge with ``a3`` setting how fast f3 lets it grow.

    Parameters
    ----------
    f1, f2 : field values of the two solids (broadcastable shapes).
    f3 : field values of the bounding solid.
    a0 : blend amplitude.
    a1, a2, a3 : extents along f1, f2 and f3 (non-zero).

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> f1, f2 = torch.tensor([1.0, 1.0]), torch.tensor([0.0, 0.0])
    >>> boundBlendUnion(f1, f2, torch.tensor([-1.0, 1.0]), a0=1.0)  # outside f3: plain union (2); inside: blended
    tensor([2.0000, 2.0833])
    """
    _check_extents("boundBlendUnion", a0=a0, a1=a1, a2=a2, a3=a3)
    return union(f1, f2) + _bounded_displacement(f1, f2, f3, a0, a1, a2, a3)


@frep
def boundBlendIntersection(
    f1: torch.Tensor,
    f2: torch.Tensor,
    f3: torch.Tensor,
    a0: Scalar = 1.0,
    a1: Scalar = 1.0,
    a2: Scalar = 1.0,
    a3: Scalar = 1.0,
) -> torch.Tensor:
    """Bounded blending intersection: :func:`boundBlendUnion`'s displacement on the R-intersection.

    a0 > 0 adds material along the edge inside the bounding solid f3, a0 < 0 removes it.

    Parameters
    ----------
    f1, f2 : field values of the two solids (broadcastable shapes).
    f3 : field values of the bounding solid.
    a0 : blend amplitude.
    a1, a2, a3 : extents along f1, f2 and f3 (non-zero).

    Returns
    -------
    field values of the broadcast shape.

    Examples
    --------
    >>> import torch
    >>> boundBlendIntersection(torch.tensor([0.0, 0.0]), torch.tensor([0.0, 0.0]), torch.tensor([-1.0, 1.0]), a0=-0.5)
    tensor([-0.5000, -0.5000])
    """
    _check_extents("boundBlendIntersection", a0=a0, a1=a1, a2=a2, a3=a3)
    return intersection(f1, f2) + _bounded_displacement(f1, f2, f3, a0, a1, a2, a3)


@frep
def offset(f: torch.Tensor, d: Scalar) -> torch.Tensor:
    """Offset: ``f + d``; the solid grows (d > 0) or shrinks (d < 0) to the level set f = -d.

    For a distance field this is an exact offset by d; for a general F-rep field the
    new surface is the level set ``f = -d`` (a uniform offset only where |grad f| = 1).

    Parameters
    ----------
    f : field values.
    d : offset in field units.

    Returns
    -------
    field values of f's shape.

    Examples
    --------
    >>> import torch
    >>> offset(torch.tensor([-0.25, 0.5]), 0.25)
    tensor([0.0000, 0.7500])
    """
    check_param(d, "d", "offset")
    return f + d


@frep
def shell(f: torch.Tensor, thickness: Scalar) -> torch.Tensor:
    """Shell (hollowing): the layer ``-t <= f <= t``, as ``intersection(f + t, t - f)``.

    Parameters
    ----------
    f : field values.
    thickness : half-thickness ``t`` of the layer in field units (> 0).

    Returns
    -------
    field values of f's shape, >= 0 inside the layer.

    Examples
    --------
    >>> import torch
    >>> shell(torch.tensor([0.0, 0.1, 1.0, -1.0]), 0.1)
    tensor([ 0.0586,  0.0000, -1.2213, -1.2213])
    """
    # t <= 0 leaves no layer: the field is negative everywhere (an empty solid)
    check_param(thickness, "thickness", "shell", positive=True)
    return intersection(f + thickness, thickness - f)
