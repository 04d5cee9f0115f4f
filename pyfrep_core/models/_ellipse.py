"""The ellipse of the paper's Fig. 4 (section 5.2, normalization): semi-axes a = 5 and b = 2."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree

from ..model import Param, model
from ..primitives import ellipse as _ellipse

__all__ = ["ellipse", "ellipse_distance"]


@model(
    dim=2,
    bounds=((-7.0, -4.0), (7.0, 4.0)),
    a=Param(5.0, 1.0, 6.5, label="semi-axis along x"),
    b=Param(2.0, 0.5, 3.5, label="semi-axis along y"),
)
def ellipse(x: torch.Tensor, a: float, b: float) -> torch.Tensor:
    """``1 - (x/a)^2 - (y/b)^2`` on points of the plane (N, 2): f > 0 inside (paper Fig. 4).

    Not a distance: its level sets f = -0.5 ... 0.5 crowd near the ends of the major axis,
    which the normalizations of :mod:`pyfrep_core.normalization` correct near the curve.

    Examples
    --------
    >>> import torch
    >>> ellipse(torch.tensor([[5.0, 0.0], [0.0, 2.0], [0.0, 0.0]]))
    tensor([0., 0., 1.])
    """
    return _ellipse(x, a=a, b=b)


def ellipse_distance(x: np.ndarray, a: float = 5.0, b: float = 2.0, samples: int = 100_000) -> np.ndarray:
    """Exact signed distance (positive inside) from points (N, 2) to the ellipse with semi-axes a, b.

    The closest point ``(a cos t, b sin t)`` is found by Newton's method on
    ``d/dt |p - (a cos t, b sin t)|^2 = 0`` from the nearest of ``samples`` curve points
    (scipy ``cKDTree``); the result is exact to rounding.  The reference for the
    normalizations of Fig. 4.

    Examples
    --------
    >>> import numpy as np
    >>> ellipse_distance(np.array([[0.0, 0.0], [7.0, 0.0], [0.0, 3.0]]))
    array([ 2., -2., -1.])
    """
    p = np.asarray(x, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or not np.isfinite(p).all():
        raise ValueError(f"x must be finite points of shape (N, 2), got shape {p.shape}")
    if not (a > 0 and b > 0):
        raise ValueError(f"semi-axes must be positive, got a={a}, b={b}")
    t = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    _, nearest = cKDTree(np.column_stack([a * np.cos(t), b * np.sin(t)])).query(p)
    t = t[nearest]
    px, py = p[:, 0], p[:, 1]
    step_limit = 4.0 * np.pi / samples  # Newton refines within the sample spacing
    for _ in range(30):
        s, c = np.sin(t), np.cos(t)
        slope = (b * b - a * a) * s * c + a * px * s - b * py * c  # half the derivative of the squared distance
        curvature = (b * b - a * a) * (c * c - s * s) + a * px * c + b * py * s
        step = np.where(curvature > 0, slope / np.where(curvature > 0, curvature, 1.0), 0.0)
        t = t - np.clip(step, -step_limit, step_limit)
    d = np.hypot(a * np.cos(t) - px, b * np.sin(t) - py)
    return np.where(1.0 - (px / a) ** 2 - (py / b) ** 2 >= 0.0, d, -d)
