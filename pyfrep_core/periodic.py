"""Periodic operations on coordinates: repeat a unit cell (paper section 3, "Periodic functions").

These functions act on coordinates, not on field values: compose them *inside* a primitive.
``sphere(rep(x, 1.0), r=0.3)`` is an infinite lattice of spheres, one per unit cell centred on
the integer points; ``sphere(triangleWave(x, 1.0), r=0.3)`` is the same lattice built from a
mirror-symmetric cell.  Clip the infinite pattern with a solid (R-intersection with a block or a
sphere) to get a printable part.

Conventions (period ``p``, applied to every coordinate, or per axis when ``p`` has 3 values):

- ``sawtooth(x, p)``: ``x`` wrapped into the centred cell [-p/2, p/2): slope 1, jumps of -p at
  ``x = p/2 + k p``.  A shape inside the cell [-p/2, p/2)^3 is repeated; a shape that crosses
  the cell faces is cut there (the field jumps).
- ``triangleWave(x, p)``: ``|sawtooth(x, p)|`` in [0, p/2]: continuous, kinks at ``x = k p / 2``.
  A shape is mirrored at every cell face, so the field is continuous everywhere; a shape that is
  symmetric about the cell centre (``sphere`` at the origin) is repeated exactly, without kinks.
- ``rep(x, p)``: the point operation ``(..., 3) -> (..., 3)`` of the reference code, a sawtooth
  on each coordinate.
- A tensor period of shape (B, 1) or (B, 3) (B parameter sets, as ``@model`` passes them) maps
  points (N, 3) to (B, N, 3), so that a primitive composed with it gives (B, N) values.
- ``sawtoothFourier``, ``triangleWaveFourier``: truncated Fourier series, smooth (C-infinity)
  everywhere, so gradients and curvatures of the composed field exist everywhere.  The truncated
  sawtooth has the Gibbs overshoot (see :func:`sawtoothFourier`); the triangle wave converges
  uniformly.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from ._array import check_param, check_points, frep

Period = float | Sequence[float] | torch.Tensor

__all__ = [
    "rep",
    "sawtooth",
    "triangleWave",
    "sawtoothFourier",
    "triangleWaveFourier",
]


def _period(period: Period, like: torch.Tensor, fn: str) -> float | torch.Tensor:
    """A float, or a tensor on ``like``'s device/dtype; checked (> 0, finite; tensors outside tracing)."""
    if isinstance(period, torch.Tensor):
        check_param(period, "period", fn, positive=True)  # a period 0 would divide by 0: NaN
        p = period.to(device=like.device, dtype=like.dtype)
        if p.ndim == 2 and like.ndim >= 2:  # a batch (B, 1) or (B, 3) against points (..., 3)
            p = p.reshape(p.shape[0], *([1] * (like.ndim - 1)), p.shape[-1])
        return p
    values = [period] if isinstance(period, int | float) else list(period)
    for v in values:
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"period must be positive and finite, got {period!r}")
    if isinstance(period, int | float):
        return float(period)
    return torch.as_tensor(values, dtype=like.dtype, device=like.device)


def _n_terms(n_terms: int) -> int:
    if isinstance(n_terms, bool) or int(n_terms) != n_terms or n_terms < 1:
        raise ValueError(f"n_terms must be a positive integer, got {n_terms!r}")
    return int(n_terms)


@frep
def sawtooth(x: torch.Tensor, period: Period = 1.0) -> torch.Tensor:
    """Centred sawtooth wave: ``x`` wrapped into [-period/2, period/2).

    ``sawtooth(x, p) = x - p * floor(x / p + 1/2)``; equal to ``x`` on (-p/2, p/2), jumps at
    ``p/2 + k p``; derivative 1 away from the jumps.

    Parameters
    ----------
    x : coordinates of any shape, e.g. (..., 3) points.
    period : p > 0, a number, or one value per coordinate (broadcast against the last axis).

    Returns
    -------
    Same shape as ``x``, values in [-p/2, p/2).

    Examples
    --------
    >>> import torch
    >>> sawtooth(torch.tensor([0.2, 0.7, -1.2, 2.5]), 1.0)
    tensor([ 0.2000, -0.3000, -0.2000, -0.5000])
    """
    p = _period(period, x, "sawtooth")
    return torch.remainder(x + 0.5 * p, p) - 0.5 * p


@frep
def triangleWave(x: torch.Tensor, period: Period = 1.0) -> torch.Tensor:
    """Triangle wave ``|sawtooth(x, period)|``: continuous, values in [0, period/2].

    Equal to ``|x|`` on [-p/2, p/2], even and p-periodic, kinks (slope +-1) at ``x = k p / 2``.
    Used as a coordinate map it mirrors the unit cell at its faces.

    Parameters
    ----------
    x : coordinates of any shape.
    period : p > 0, a number or one value per coordinate.

    Returns
    -------
    Same shape as ``x``.

    Examples
    --------
    >>> import torch
    >>> triangleWave(torch.tensor([0.2, 0.7, -1.2, 2.5]), 1.0)
    tensor([0.2000, 0.3000, 0.2000, 0.5000])
    """
    _period(period, x, "triangleWave")
    return torch.abs(sawtooth(x, period))


@frep
def rep(x: torch.Tensor, period: Period = 1.0) -> torch.Tensor:
    """Repeat the unit cell [-p/2, p/2)^3 centred on the origin over all of space.

    A point operation: ``rep(x, p)`` maps each point to its position in its cell (a sawtooth on
    every coordinate), so ``f(rep(x, p))`` repeats the part of the solid f inside the cell.

    Parameters
    ----------
    x : (..., 3) points.
    period : cell size, a number or (px, py, pz).

    Returns
    -------
    (..., 3) points in the cell.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> x = torch.tensor([[2.1, -3.0, 0.05], [2.5, 0.0, 0.0]])
    >>> sphere(rep(x, 1.0), r=0.3) > 0          # a lattice of spheres of radius 0.3
    tensor([ True, False])
    """
    check_points(x, empty=True)  # no points give no values
    _period(period, x, "rep")
    return sawtooth(x, period)


@frep
def sawtoothFourier(x: torch.Tensor, period: Period = 1.0, n_terms: int = 10) -> torch.Tensor:
    """Truncated Fourier series of :func:`sawtooth`, smooth everywhere.

    ``S_n(x) = (p / pi) sum_{k=1..n} (-1)^(k+1) sin(2 pi k x / p) / k``.

    Away from the jumps ``S_n`` converges to the sawtooth with an error O(p^2 / (n d)) at a
    distance d from the nearest jump.  Near a jump the series overshoots (Gibbs phenomenon):
    the maximum tends to about 0.5895 p instead of p/2, i.e. 9 % of the jump p on each side,
    however large n is; increasing ``n_terms`` only squeezes the overshoot closer to the jump
    (within about p / (2 n)) and makes the fall at the jump steeper: the derivative there is
    exactly -2 n.  Few terms give a smooth, gently varying map (large features stay round);
    many terms follow the sawtooth closely but with steep, wiggly transitions.

    Parameters
    ----------
    x : coordinates of any shape.
    period : p > 0, a number or one value per coordinate.
    n_terms : number n of harmonics (>= 1).

    Returns
    -------
    Same shape as ``x``.

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([0.1, 0.5], dtype=torch.float64)
    >>> torch.round(sawtoothFourier(x, 1.0, n_terms=200), decimals=3)  # 0 at the jump
    tensor([0.1000, 0.0000], dtype=torch.float64)
    """
    p = _period(period, x, "sawtoothFourier")
    n = _n_terms(n_terms)
    theta = (2.0 * math.pi) * x / p
    total = torch.zeros_like(theta)
    for k in range(1, n + 1):  # a loop over harmonics, each on the whole array
        total = total + ((-1) ** (k + 1) / k) * torch.sin(k * theta)
    return (p / math.pi) * total


@frep
def triangleWaveFourier(x: torch.Tensor, period: Period = 1.0, n_terms: int = 10) -> torch.Tensor:
    """Truncated Fourier series of :func:`triangleWave`, smooth everywhere.

    ``T_n(x) = p/4 - (2 p / pi^2) sum_{j=0..n-1} cos(2 pi (2j+1) x / p) / (2j+1)^2`` (odd
    harmonics only).  Converges uniformly, without overshoot: ``|T_n - T| <= p / (2 pi^2 n)``.
    The kinks of the triangle wave become rounded over a width ~ p / n.

    Parameters
    ----------
    x : coordinates of any shape.
    period : p > 0, a number or one value per coordinate.
    n_terms : number n of (odd) harmonics (>= 1).

    Returns
    -------
    Same shape as ``x``.

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([0.2, 0.5], dtype=torch.float64)
    >>> triangleWaveFourier(x, 1.0, n_terms=500)
    tensor([0.2000, 0.4999], dtype=torch.float64)
    """
    p = _period(period, x, "triangleWaveFourier")
    n = _n_terms(n_terms)
    theta = (2.0 * math.pi) * x / p
    total = torch.zeros_like(theta)
    for j in range(n):
        k = 2 * j + 1
        total = total + torch.cos(k * theta) / (k * k)
    return 0.25 * p - (2.0 * p / math.pi**2) * total
