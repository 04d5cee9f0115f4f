"""Residuals and robust losses for fitting a model to measured points.

Residual of a point x_i for parameters p:

- ``"algebraic"``: ``f(x_i; p)``, the paper's error of fit ``E(p) = mean f^2`` (paper eq. E(p));
  its size depends on how f is scaled (``r^2 - |x|^2`` grows like 2 r times the distance), so
  points on a large feature weigh more than on a small one;
- ``"geometric"``: Taubin's first-order distance ``f / |grad_x f|`` (the paper's delta_1, eq.
  delta1): a length in the points' units whatever the scaling of f, exact for a signed distance
  function and correct to first order near the surface for any f.  This is what measured data
  needs: its noise is a length.

Robust losses (``rho`` of the residual u = r / s for a scale s, so that ``rho(u) ~ u^2`` for small
u and l2 is unchanged): ``"l2"`` u^2; ``"huber"`` u^2 up to c = 1.345, linear beyond; ``"cauchy"``
``c^2 log(1 + u^2 / c^2)`` with c = 2.385 (both 95 % efficient for Gaussian noise);
``"trimmed"`` ``min(u^2, c^2)`` with c = 3 (points beyond 3 s are dropped).  Huber's pull of a
stray point does not fade with its distance (c s each), so stray points mostly on one side of a face
bias it; Cauchy's fades (as 1 / distance) and trimmed's vanishes: prefer those with outliers.  The scale s is the
noise level: given, or estimated as ``1.4826 * median |r|`` (the median absolute deviation about
0, consistent for Gaussian noise; half the points may be outliers before it breaks down).  A
point is an inlier when ``|r| <= 3 s``.  The least-squares weights of iteratively reweighted
least squares are ``w(u) = rho'(u) / (2 u)``.

>>> import torch
>>> r = torch.tensor([0.0, 0.5, 1.0, 10.0])
>>> weights(r, "huber", 0.5)
tensor([1.0000, 1.0000, 0.6725, 0.0673])
>>> weights(r, "trimmed", 0.5)
tensor([1., 1., 1., 0.])
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import torch

__all__ = [
    "RESIDUALS",
    "LOSSES",
    "INLIER_K",
    "geometric",
    "value_and_gradnorm",
    "rho",
    "weights",
    "slopes",
    "robust_scale",
    "objective",
    "inliers",
]

RESIDUALS = ("algebraic", "geometric")
LOSSES = ("l2", "huber", "cauchy", "trimmed")
TUNING = {"l2": math.inf, "huber": 1.345, "cauchy": 2.385, "trimmed": 3.0}
INLIER_K = 3.0  # |r| <= INLIER_K * scale: an inlier
MAD_TO_SIGMA = 1.4826  # 1 / Phi^-1(3/4): the median absolute value of N(0, s^2) is s / 1.4826


def value_and_gradnorm(fn: Callable, x: torch.Tensor, params: Mapping[str, Any]) -> tuple[torch.Tensor, torch.Tensor]:
    """f(x_i) (N,) and |grad_x f(x_i)| (N,) in one forward and one reverse pass (``torch.func.vjp``).

    Each point's value depends on its own coordinates only, so the vector-Jacobian product with
    ones gives every point's gradient at once.  Written with torch.func, it runs under ``vmap``
    (parameter sets) and lets gradients reach the parameters from outside.
    """
    f, pullback = torch.func.vjp(lambda y: fn(y, **params), x)
    (g,) = pullback(torch.ones_like(f))
    return f, torch.linalg.vector_norm(g, dim=-1)


def geometric(fn: Callable) -> Callable:
    """The geometric residual ``f / |grad f|`` (paper eq. delta1) of a defining function, as one.

    The result follows the model contract ((N, d) points, 0-d parameters, (N,) values), so the
    kernel evaluates it, batches parameter sets through it and differentiates it like a model.
    Where grad f = 0 the distance is unknown: the residual is then f / tiny (huge, an outlier to
    a robust loss), never NaN.

    Examples
    --------
    >>> import torch
    >>> def ball(x, r):
    ...     return r**2 - (x * x).sum(-1)        # algebraic: 2 r times the distance near the surface
    >>> d = geometric(ball)
    >>> d(torch.tensor([[0.0, 0.0, 2.1]], dtype=torch.float64), r=torch.tensor(2.0, dtype=torch.float64))
    tensor([-0.0976], dtype=torch.float64)
    """

    def residual(x: torch.Tensor, **params: Any) -> torch.Tensor:
        f, g = value_and_gradnorm(fn, x, params)
        return f / g.clamp_min(torch.finfo(g.dtype).tiny)

    residual.__name__ = getattr(fn, "__name__", "model")
    return residual


def _check(loss: str) -> float:
    if loss not in TUNING:
        raise ValueError(f"loss must be one of {', '.join(map(repr, LOSSES))}, got {loss!r}")
    return TUNING[loss]


def rho(u: torch.Tensor, loss: str) -> torch.Tensor:
    """The loss of the scaled residuals u = r / s (``rho(u) = u^2`` near 0), same shape.

    >>> import torch
    >>> rho(torch.tensor([1.0, 4.0]), "trimmed")
    tensor([1., 9.])
    """
    c = _check(loss)
    u2 = u * u
    if loss == "l2":
        return u2
    if loss == "huber":
        a = u.abs()
        return torch.where(a <= c, u2, 2.0 * c * a - c * c)
    if loss == "cauchy":
        return c * c * torch.log1p(u2 / (c * c))
    return u2.clamp_max(c * c)


def weights(r: torch.Tensor, loss: str, scale: float | torch.Tensor) -> torch.Tensor:
    """IRLS weights ``rho'(u) / (2 u)`` of the residuals r at scale s (1 for l2 and near 0).

    >>> import torch
    >>> weights(torch.tensor([0.0, 3.0]), "cauchy", 1.0)
    tensor([1.0000, 0.3872])
    """
    c = _check(loss)
    u = r / scale
    if loss == "l2":
        return torch.ones_like(u)
    a = u.abs()
    if loss == "huber":
        return torch.where(a <= c, torch.ones_like(a), c / a.clamp_min(c))
    if loss == "cauchy":
        return 1.0 / (1.0 + (u / c) ** 2)
    return (a <= c).to(u.dtype)


def slopes(r: torch.Tensor, loss: str, scale: float | torch.Tensor) -> torch.Tensor:
    """``rho''(u) / 2`` at u = r / s: the curvature of each point's loss, the M-estimator's "bread"
    weight in its sandwich covariance (the IRLS weight w is the secant slope ``rho'(u) / 2u``; they
    agree for l2, and for huber and trimmed within their threshold).

    >>> import torch
    >>> slopes(torch.tensor([0.0, 3.0]), "cauchy", 1.0)
    tensor([ 1.0000, -0.0873])
    """
    c = _check(loss)
    u = r / scale
    if loss == "l2":
        return torch.ones_like(u)
    if loss == "cauchy":
        q = (u / c) ** 2
        return (1.0 - q) / (1.0 + q) ** 2
    return (u.abs() <= c).to(u.dtype)


def robust_scale(r: torch.Tensor, floor: float = 0.0) -> torch.Tensor:
    """The noise level of residuals (..., N): ``1.4826 * median |r|`` over the last axis, (...).

    Never below ``floor`` (in the residuals' units) nor 0: exact data (points on the surface) has
    a median residual of rounding size, and a scale of that size would make ``r / s`` huge or
    infinite and most points outliers.  The caller gives the floor from the problem
    (:func:`pyfrep_core.fit` uses ``SCALE_FLOOR`` times the data's size).

    >>> import torch
    >>> robust_scale(torch.tensor([1.0, -1.0, 2.0, 100.0, -0.5]))
    tensor(1.4826)
    >>> robust_scale(torch.zeros(4), floor=1e-6)
    tensor(1.0000e-06)
    """
    med = r.detach().abs().median(dim=-1).values
    return (MAD_TO_SIGMA * med).clamp_min(max(float(floor), torch.finfo(r.dtype).tiny))


def objective(r: torch.Tensor, loss: str, scale: float | None, floor: float = 0.0) -> torch.Tensor:
    """Mean loss of residuals (..., N) over the last axis, in squared length units: ``s^2 mean rho(r/s)``.

    ``scale`` None: each row's own :func:`robust_scale` (held fixed for gradients, never below
    ``floor``).  For l2 this is
    ``mean r^2``, the paper's E(p) for algebraic residuals.

    >>> import torch
    >>> objective(torch.tensor([[1.0, -1.0, 3.0]]), "l2", None)
    tensor([3.6667])
    """
    if loss == "l2":
        return (r * r).mean(-1)
    s = robust_scale(r, floor) if scale is None else torch.as_tensor(scale, dtype=r.dtype, device=r.device)
    s = s.unsqueeze(-1) if s.ndim else s
    return (rho(r / s, loss) * s * s).mean(-1).reshape(r.shape[:-1])


def inliers(r: torch.Tensor, loss: str, scale: float) -> torch.Tensor:
    """Inlier mask (N,) bool: ``|r| <= 3 s`` for a robust loss; every point for l2.

    >>> import torch
    >>> inliers(torch.tensor([0.1, -0.2, 5.0]), "huber", 0.1)
    tensor([ True,  True, False])
    """
    if loss == "l2":
        return torch.ones_like(r, dtype=torch.bool)
    return r.abs() <= INLIER_K * scale
