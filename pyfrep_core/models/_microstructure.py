"""The paper's fitting example (section 5.4, Figs. 7-8): a half sphere filled with a graded grid of rods.

The rods are the intersections of slabs ``sin(s x) > c``; their scale ``s`` and threshold ``c``
(the paper's "frequency") are blended between an outer and an inner value by the field of a
sphere of radius 10, so the rods get finer and thinner towards the shell.
"""

from __future__ import annotations

import torch

from ..model import Param, model
from ..operations import blendUnion, difference, intersection, union

__all__ = ["microstructure"]

RADIUS = 10.0  # the sphere whose field grades the rods
SHELL = 0.15  # thickness of the shell, in units of the sphere's field


@model(
    bounds=((-10.5, -0.5, -10.5), (10.5, 10.5, 10.5)),
    scale1=Param(9.0, 1.0, 10.0, label="rod scale near the shell"),
    scale2=Param(3.0, 1.0, 10.0, label="rod scale at the centre"),
    freq1=Param(0.75, 0.1, 2.0, label="slab threshold near the shell"),
    freq2=Param(0.85, 0.1, 2.0, label="slab threshold at the centre"),
)
def microstructure(x: torch.Tensor, scale1, scale2, freq1, freq2) -> torch.Tensor:
    """Half sphere (y >= 0) of radius 10: a shell plus a graded grid of rods (paper Fig. 8).

    With ``t = 1 - |x|^2 / 100`` (1 at the centre, 0 on the sphere), the rods use
    ``scale = scale1 (1 - t) + scale2 t`` and ``c = freq1 (1 - t) + freq2 t``; slabs are
    ``sin(scale x_k) - c`` and rods the R-intersections of two slabs.  The defaults are
    the parameters of the paper's experiment.  Parameters may be (B, 1) tensors (the Model
    reshapes (B,) batches): the result is then (B, N).

    Examples
    --------
    >>> import torch
    >>> x = torch.tensor([[0.0, 9.6, 0.0], [0.0, 5.0, 0.0], [0.0, -1.0, 0.0]])
    >>> microstructure(x) > 0  # in the shell, between rods, below the cut
    tensor([ True, False, False])
    >>> microstructure(x, scale1=torch.tensor([2.0, 9.0, 5.0])).shape
    torch.Size([3, 3])
    """
    x0, x1, x2 = x[..., 0], x[..., 1], x[..., 2]
    sp = 1.0 - (x0 * x0 + x1 * x1 + x2 * x2) / (RADIUS * RADIUS)
    shell = difference(sp, sp - SHELL)
    t = sp
    scale = scale1 * (1.0 - t) + scale2 * t
    c = freq1 * (1.0 - t) + freq2 * t
    xslabs = torch.sin(x0 * scale) - c
    yslabs = torch.sin(x1 * scale) - c
    zslabs = torch.sin(x2 * scale) - c
    xrods = intersection(yslabs, zslabs)
    yrods = intersection(xslabs, zslabs)
    zrods = intersection(xslabs, yslabs)
    grid = union(blendUnion(xrods, zrods, 1.0, 3.0, 3.0), yrods)
    return intersection(union(shell, intersection(sp, grid)), x1)
