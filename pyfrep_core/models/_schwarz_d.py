"""The Schwarz D surface of the paper's Fig. 3 (section 5.1): mean curvature on a minimal surface."""

from __future__ import annotations

import math

import torch

from ..lattices import SchwarzD
from ..model import Param, model

__all__ = ["schwarz_d"]

# the paper writes sin(x), cos(x) directly: frequency 1/(2 pi) in lattices.SchwarzD's convention
FREQUENCY = 1.0 / (2.0 * math.pi)


@model(
    bounds=((-4.0,) * 3, (4.0,) * 3),
    c=Param(0.0, -1.0, 1.0, label="iso-level offset"),
)
def schwarz_d(x: torch.Tensor, c: float) -> torch.Tensor:
    """``sin x sin y sin z + sin x cos y cos z + cos x sin y cos z + cos x cos y sin z + c``.

    The paper's formula as printed in section 5.1 (period 2 pi along each axis); the default
    box [-4, 4]^3 is that of the paper's example code (its faces miss the surface's grid-aligned
    points, so every marching-cubes vertex can be moved onto f = 0).  The zero set (c = 0) is
    the trigonometric (nodal) approximation of Schwarz's D minimal surface: the mean curvature
    is small compared with the principal curvatures but not zero (median |H| / max|k| = 0.025,
    at most 0.067, at every mesh resolution: see ``tests/test_curvature.py``).

    Examples
    --------
    >>> import math, torch
    >>> schwarz_d(torch.tensor([[0.0, 0.0, 0.0], [math.pi / 2, 0.0, 0.0]], dtype=torch.float64))
    tensor([0., 1.], dtype=torch.float64)
    """
    return SchwarzD(x, alpha=FREQUENCY, beta=FREQUENCY, gamma=FREQUENCY, c=c)
