"""Jupyter workbench: ipywidgets panels composing pyfrep_core calls (no geometry here).

``workbench.app()`` shows every panel in tabs; ``workbench.shape_panel(model)`` gives live
sliders for any parametric model; each other panel has its builder (``curvature_panel``,
``slice_panel``, ``redistance_panel``, ``fitting_panel``).

>>> import workbench
>>> callable(workbench.shape_panel) and callable(workbench.app)
True
"""

from .app import App, app, paper_models
from .curvature_panel import CurvaturePanel, curvature_panel
from .fitting_panel import FittingPanel, fitting_panel
from .redistance_panel import RedistancePanel, redistance_panel
from .shape_panel import ShapePanel, shape_panel
from .slice_panel import SlicePanel, slice_panel
from .view import MeshView

__all__ = [
    "App",
    "CurvaturePanel",
    "FittingPanel",
    "MeshView",
    "RedistancePanel",
    "ShapePanel",
    "SlicePanel",
    "app",
    "curvature_panel",
    "fitting_panel",
    "paper_models",
    "redistance_panel",
    "shape_panel",
    "slice_panel",
]
