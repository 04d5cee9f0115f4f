"""The workbench: every panel in a tab, the paper's shapes preloaded.

Tabs are built when first opened (a tab's panel may need seconds: a curvature mesh, a
distance field), so the page shows quickly.  A panel whose pyfrep_core module is missing
shows why instead of breaking the app.
"""

from __future__ import annotations

import html
import importlib
import traceback
from collections.abc import Callable
from typing import Any

import ipywidgets as widgets

from .help import help_box
from .user_models import offer, register

__all__ = ["App", "app", "paper_models"]

# (tab title, "module:function" building the panel)
TABS: tuple[tuple[str, str], ...] = (
    ("Shape", "workbench.shape_panel:paper_shape_panel"),
    ("Model", "workbench.model_panel:model_panel"),
    ("Curvature", "workbench.curvature_panel:curvature_panel"),
    ("Slices", "workbench.slice_panel:slice_panel"),
    ("Redistancing", "workbench.redistance_panel:redistance_panel"),
    ("Fitting", "workbench.fitting_panel:fitting_panel"),
)

PAPER_MODELS = ("fig1_part", "schwarz_d", "ellipse", "pawn", "microstructure")


def paper_models(dim: int | None = None) -> dict[str, Any]:
    """The paper's shapes available in ``pyfrep_core.models`` (name -> Model), optionally of one dimension,
    then the models the user wrote in the Model tab (:mod:`workbench.user_models`)."""
    from pyfrep_core import models

    from .user_models import user_models

    found = {}
    for name in PAPER_MODELS:
        m = getattr(models, name, None)
        if m is not None and (dim is None or getattr(m, "dim", 3) == dim):
            found[name] = m
    return {**found, **user_models(dim)}


def unavailable(what: str, err: BaseException) -> widgets.HTML:
    """What a tab shows when its panel cannot be built (a core module not there yet)."""
    return widgets.HTML(
        f"<p style='color:#a60'><b>{html.escape(what)}</b> not available yet: "
        f"{html.escape(type(err).__name__)}: {html.escape(str(err))}</p>"
        f"<details><summary>details</summary><pre>{html.escape(traceback.format_exc(limit=3))}</pre></details>"
    )


class App(widgets.Tab):
    """Tabs of panels, each built on first selection.

    Parameters
    ----------
    backend : 3-D view backend for every panel ("auto", "trame", "image").
    eager : build every tab now (tests, nbval) instead of on first selection.
    options : per-tab keyword arguments, e.g. ``{"Fitting": {"n_points": 500}}``.
    """

    def __init__(self, backend: str = "auto", eager: bool = False, options: dict[str, dict] | None = None):
        self.backend = backend
        self.options = options or {}
        self.panels: dict[str, Any] = {}
        self.user_model: Any = None  # the model last run in the Model tab, opened in every panel
        boxes = [widgets.VBox([widgets.HTML(f"<i>opening {title}...</i>")]) for title, _ in TABS]
        super().__init__(children=boxes)
        for i, (title, _) in enumerate(TABS):
            self.set_title(i, title)
        self.observe(self._selected, names="selected_index")
        self._build(0)
        if eager:
            for i in range(1, len(TABS)):
                self._build(i)

    def _selected(self, change: dict) -> None:
        if change["new"] is not None:
            self._build(change["new"])

    def _build(self, index: int) -> Any:
        title, target = TABS[index]
        if title in self.panels:
            return self.panels[title]
        module, func = target.split(":")
        try:
            builder: Callable = getattr(importlib.import_module(module), func)
            panel = builder(backend=self.backend, **self.options.get(title, {}))
        except Exception as err:  # the other tabs keep working
            panel = unavailable(title, err)
        self.panels[title] = panel
        self.children[index].children = (help_box(title), panel)  # what the tab shows, with the paper's eq./Fig.
        self._link()
        if hasattr(panel, "on_run"):  # the Model tab: a model run there opens in every panel
            panel.on_run.append(self.open_model)
        elif self.user_model is not None:
            offer(panel, self.user_model)
        return panel

    def open_model(self, model: Any) -> list[str]:
        """Offer ``model`` (a user's) in every panel's menu and open it in the panels built so far
        (the others open it when first shown); returns the titles of the tabs that opened it."""
        register(model)
        self.user_model = model
        return [title for title, panel in self.panels.items() if offer(panel, model)]

    def _link(self) -> None:
        """Networks trained in the redistancing tab appear in the slice tab."""
        red, sl = self.panels.get("Redistancing"), self.panels.get("Slices")
        if hasattr(red, "on_trained") and hasattr(sl, "set_network") and sl.set_network not in red.on_trained:
            red.on_trained.append(sl.set_network)
            for name, network in red.trained.items():
                sl.set_network(name, network)

    def panel(self, title: str) -> Any:
        """The panel of tab ``title``, built if needed."""
        index = [t for t, _ in TABS].index(title)
        return self._build(index)


def app(backend: str = "auto", eager: bool = False, **options: dict) -> App:
    """All panels in tabs: shape (Fig. 1, 2), your own model (typed in a code editor), curvature (Fig. 3),
    slices (Figs. 4-6), redistancing, fitting (Figs. 7, 8).

    Examples
    --------
    >>> w = app(backend="image", Shape={"resolution": 32, "threaded": False})
    >>> [w.get_title(i) for i in range(len(w.children))]
    ['Shape', 'Model', 'Curvature', 'Slices', 'Redistancing', 'Fitting']
    """
    return App(backend=backend, eager=eager, options=options)
