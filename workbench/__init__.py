"""Jupyter workbench: ipywidgets panels composing pyfrep_core calls (no geometry here)."""
