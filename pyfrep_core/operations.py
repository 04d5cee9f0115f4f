"""Operations on defining functions: R-function Booleans, min/max, blends (paper section 3.1).

All functions take field values ``f1, f2`` (tensors of any broadcastable shape, e.g. (N,))
and return a tensor of the broadcast shape.  Convention: f >= 0 inside.
"""

from __future__ import annotations

import torch

from ._array import frep, safe_sqrt

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


@frep
def union_m(f1: torch.Tensor, f2: torch.Tensor, m: float = 1.0) -> torch.Tensor:
    """R_m union: ``(f1 + f2 + sqrt(f1^2 + f2^2)) * (f1^2 + f2^2)^(m/2)`` (C^m on the plane).

    Examples
    --------
    >>> import torch
    >>> union_m(torch.tensor([3.0]), torch.tensor([4.0]), m=2)
    tensor([300.])
    """
    s = f1 * f1 + f2 * f2
    return (f1 + f2 + safe_sqrt(s)) * s ** (0.5 * m)


@frep
def intersection_m(f1: torch.Tensor, f2: torch.Tensor, m: float = 1.0) -> torch.Tensor:
    """R_m intersection: ``(f1 + f2 - sqrt(f1^2 + f2^2)) * (f1^2 + f2^2)^(m/2)``.

    Examples
    --------
    >>> import torch
    >>> intersection_m(torch.tensor([3.0]), torch.tensor([4.0]), m=2)
    tensor([50.])
    """
    s = f1 * f1 + f2 * f2
    return (f1 + f2 - safe_sqrt(s)) * s ** (0.5 * m)


@frep
def difference_m(f1: torch.Tensor, f2: torch.Tensor, m: float = 1.0) -> torch.Tensor:
    """R_m difference: ``intersection_m(f1, -f2, m)``.

    Examples
    --------
    >>> import torch
    >>> difference_m(torch.tensor([3.0]), torch.tensor([-4.0]), m=2)
    tensor([50.])
    """
    return intersection_m(f1, -f2, m)


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
