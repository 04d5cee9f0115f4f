"""Starting points for the Model tab: the paper's shapes written as a user writes a model in a cell.

Each template is complete (imports, ``@model`` with bounds and ``Param``s, the function) and
gives the same values as its model in :mod:`pyfrep_core.models` where there is one
(tests/test_model_panel.py checks it).
"""

from __future__ import annotations

__all__ = ["TEMPLATES"]

FIG1_PART = """\
import torch
from pyfrep_core import *


# The paper's Fig. 1 part: a sphere cut by a cube, drilled by three cylinders of
# radius r.
@model(
    bounds=((-1.1,) * 3, (1.1,) * 3),
    r=Param(0.5, 0.2, 0.8, label="cylinder radius"),
)
def my_part(x, r):
    sp1 = sphere(x, center=(0, 0, 0), r=1)
    b1 = block(x, vertex=(-0.75, -0.75, -0.75), dx=1.5, dy=1.5, dz=1.5)
    t1 = intersection(sp1, b1)
    c1 = cylX(x, center=(0, 0, 0), r=r)
    c2 = cylY(x, center=(0, 0, 0), r=r)
    c3 = cylZ(x, center=(0, 0, 0), r=r)
    t2 = difference(t1, c1)
    t3 = difference(t2, c2)
    return difference(t3, c3)
"""

PAWN = """\
import torch
from pyfrep_core import *


# The chess pawn of Figs. 5-6: polynomial pieces joined by R-functions, standing
# on z = -1.
@model(
    bounds=((-1.0, -1.0, -1.2), (1.0, 1.0, 1.3)),
    head_radius=Param(0.3, 0.2, 0.4, label="head radius"),
    neck_radius=Param(0.17, 0.1, 0.24, label="neck (waist) radius"),
    base_radius=Param(0.62, 0.45, 0.75, label="base radius"),
    collar_radius=Param(0.36, 0.25, 0.45, label="collar radius"),
)
def my_pawn(x, head_radius, neck_radius, base_radius, collar_radius):
    z = x[:, 2]
    head = sphere(x, center=(0.0, 0.0, 0.72), r=head_radius)
    c = collar_radius
    collar = ellipsoid(x, center=(0.0, 0.0, 0.45), a=c, b=c, c=0.07)
    # the body: a hyperboloid of one sheet, narrowest (neck_radius) under the
    # collar, cut by a slab
    waist = neck_radius**2 + (0.33 * (z - 0.45)) ** 2 - x[:, 0] ** 2 - x[:, 1] ** 2
    body = intersection(waist, (z + 0.7) * (0.45 - z))
    r = 0.8 * base_radius
    ring = ellipsoid(x, center=(0.0, 0.0, -0.68), a=r, b=r, c=0.08)
    b = base_radius
    foot = ellipsoid(x, center=(0.0, 0.0, -0.88), a=b, b=b, c=0.3)
    base = intersection(foot, z + 1.0)
    return union(union(union(union(base, ring), body), collar), head)
"""

GYROID_BALL = """\
import torch
from pyfrep_core import *


# A gyroid sheet lattice (a triply periodic minimal surface thickened) inside a ball.
@model(
    bounds=((-1.1,) * 3, (1.1,) * 3),
    cells=Param(1.5, 0.75, 3.0, label="cells per unit length"),
    wall=Param(0.4, 0.1, 0.9, label="wall: |gyroid| below it"),
    radius=Param(1.0, 0.6, 1.05, label="ball radius"),
)
def my_gyroid_ball(x, cells, wall, radius):
    # sin X cos Y + ..., X = 2 pi cells x
    g = gyroid(x, alpha=cells, beta=cells, gamma=cells)
    sheet = wall - torch.abs(g)  # >= 0 within the wall around the gyroid surface
    return intersection(sphere(x, r=radius), sheet)
"""

PAPER_STYLE = """\
import torch
from pyfrep_core import *


# The paper's own style: coordinates as p[:, 0], p[:, 1], p[:, 2]; f >= 0 inside.
@model(
    bounds=((-1.2,) * 3, (1.2,) * 3),
    r=Param(0.8, 0.3, 1.1, label="ball radius"),
    hole=Param(0.3, 0.1, 0.6, label="hole radius"),
)
def my_drilled_ball(p, r, hole):
    x0, x1, x2 = p[:, 0], p[:, 1], p[:, 2]
    ball = r**2 - x0**2 - x1**2 - x2**2
    drill = hole**2 - x0**2 - x1**2  # a cylinder along z
    return difference(ball, drill)
"""

TEMPLATES: dict[str, str] = {
    "Fig. 1 part": FIG1_PART,
    "pawn (Figs. 5-6)": PAWN,
    "gyroid lattice in a ball": GYROID_BALL,
    "the paper's p[:, i] style": PAPER_STYLE,
}
