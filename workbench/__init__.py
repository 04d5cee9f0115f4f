"""Jupyter workbench: ipywidgets panels composing pyfrep_core calls (no geometry here).

>>> import workbench
>>> callable(workbench.shape_panel)
True
"""

from .shape_panel import ShapePanel, shape_panel
from .view import MeshView

__all__ = ["MeshView", "ShapePanel", "shape_panel"]
