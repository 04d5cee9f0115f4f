"""The paper's shapes as parametric models (``@model``): one file each, imported here.

Each is a :class:`pyfrep_core.model.Model` with named, bounded parameters and default bounds.
"""

from ._ellipse import ellipse, ellipse_distance
from ._fig1 import fig1_part
from ._microstructure import microstructure
from ._pawn import pawn
from ._schwarz_d import schwarz_d

__all__ = ["ellipse", "ellipse_distance", "fig1_part", "microstructure", "pawn", "schwarz_d"]
