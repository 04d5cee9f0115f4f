"""The paper's shapes as parametric models (``@model``): one file each, imported here.

Each is a :class:`pyfrep_core.model.Model` with named, bounded parameters and default bounds.
"""

from ._fig1 import fig1_part
from ._microstructure import microstructure

__all__ = ["fig1_part", "microstructure"]
