"""Jupyter workbench: ipywidgets panels composing pyfrep_core calls (no geometry here).

``workbench.app()`` shows every panel in tabs; ``workbench.shape_panel(model)`` gives live
sliders for any parametric model.

>>> import workbench
>>> callable(workbench.shape_panel) and callable(workbench.app)
True
"""

from .app import App, app, paper_models
from .shape_panel import ShapePanel, shape_panel
from .view import MeshView

__all__ = ["App", "MeshView", "ShapePanel", "app", "paper_models", "shape_panel"]
