"""The paper's Fig. 1 part: a sphere cut by a cube, drilled by three cylinders."""

from __future__ import annotations

import torch

from ..model import Param, model
from ..operations import difference, intersection
from ..primitives import block, cylX, cylY, cylZ, sphere


@model(bounds=((-1.1,) * 3, (1.1,) * 3), r=Param(0.5, 0.2, 0.8, label="cylinder radius"))
def fig1_part(x: torch.Tensor, r: float) -> torch.Tensor:
    """The Fig. 1 program with ``r`` as the cylinders' radius (Fig. 2 shows r = 0.35, 0.5, 0.65).

    Examples
    --------
    >>> import torch
    >>> fig1_part(torch.tensor([[0.55, 0.55, 0.55], [0.0, 0.0, 0.0]])) > 0
    tensor([ True, False])
    """
    sp1 = sphere(x, center=(0, 0, 0), r=1)
    b1 = block(x, vertex=(-0.75, -0.75, -0.75), dx=1.5, dy=1.5, dz=1.5)
    t1 = intersection(sp1, b1)
    c1 = cylX(x, center=(0, 0, 0), r=r)
    c2 = cylY(x, center=(0, 0, 0), r=r)
    c3 = cylZ(x, center=(0, 0, 0), r=r)
    t2 = difference(t1, c1)
    t3 = difference(t2, c2)
    return difference(t3, c3)
