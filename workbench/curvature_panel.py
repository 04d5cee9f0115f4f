"""Curvature panel: the surface coloured by mean, Gaussian or principal curvature, with a histogram.

The paper's Fig. 5 (Schwarz D).  Curvatures come from ``pyfrep_core.curvature.curvatures``
(autograd Hessians of f at the mesh vertices, after they are projected onto f = 0); the panel
only meshes, asks for them and draws.  Where a curvature is
undefined (grad f = 0, creases: ``Curvatures.defined``) or its radius is under half the grid
spacing (next to a crease, or a strut thinner than the mesh) the surface is grey and the status
counts the vertices; the colour range is chosen percentiles of the other values, on a diverging
map centred on 0 for a quantity of both signs and a one-sided map for a one-signed one (the
Gaussian curvature of Schwarz D is <= 0 everywhere).
"""

from __future__ import annotations

import html
import time
from typing import Any

import ipywidgets as widgets
import numpy as np

from pyfrep_core import Model, polygonize

from ._threads import LatestWorker, MainThread
from .charts import DPI, figure_png, new_figure
from .colours import ColourRange, colour_range
from .view import MeshView, shows_inside

__all__ = ["CurvaturePanel", "curvature_panel", "QUANTITIES"]

HISTOGRAM_PX = 420  # the histogram's width on the page

# label -> field of pyfrep_core.curvature.Curvatures
QUANTITIES = {"mean H": "H", "Gaussian K": "K", "kmin": "kmin", "kmax": "kmax"}
UNITS = {"H": "1/length", "K": "1/length^2", "kmin": "1/length", "kmax": "1/length"}
EQUATIONS = {
    "H": "H = -div(n)/2, n = grad f/|grad f| (paper eq. 3)",
    "K": "K = grad f . Hessian*(f) . grad f^T / |grad f|^4 (paper eq. 4)",
    "kmin": "kmin = H - sqrt(H^2 - K)",
    "kmax": "kmax = H + sqrt(H^2 - K)",
}


def curvature_table(f: Any, x: np.ndarray) -> dict[str, np.ndarray]:
    """H, K, kmin, kmax (NaN where undefined) and the ``defined`` mask at points ``x`` (N, 3).

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> t = curvature_table(lambda x: sphere(x, r=2.0), np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 0.0]]))
    >>> float(t["H"][0]), float(t["K"][0]), t["defined"].tolist()  # the centre: grad f = 0
    (0.5, 0.25, [True, False])
    """
    from pyfrep_core.curvature import curvatures

    c = curvatures(f, np.asarray(x, dtype=np.float64))
    table = {key: np.asarray(getattr(c, key), dtype=np.float64) for key in QUANTITIES.values()}
    table["defined"] = np.asarray(c.defined, dtype=bool)
    return table


class CurvaturePanel(widgets.VBox):
    """Model, resolution, quantity, percentile clip; the coloured mesh and its histogram.

    Parameters
    ----------
    models : name -> 3-D Model offered in the chooser (Schwarz D first for Fig. 3).
    resolution : marching-cubes samples per axis.
    backend : 3-D view backend.
    threaded : compute on a background thread (default: when a kernel's loop runs).
    """

    def __init__(
        self,
        models: dict[str, Model],
        resolution: int = 64,
        backend: str = "auto",
        threaded: bool | None = None,
        size: tuple[int, int] = (560, 440),
    ):
        if not models:
            raise ValueError("models must name at least one Model")
        self.models = dict(models)
        self.main = MainThread()
        self.threaded = self.main.has_loop if threaded is None else threaded
        self.mesh: Any = None
        self.table: dict[str, np.ndarray] | None = None
        lay = widgets.Layout(width="320px")
        self.model_choice = widgets.Dropdown(options=list(self.models), description="model", layout=lay)
        self.resolution = widgets.Dropdown(
            options=sorted({32, 48, 64, 96, 128, int(resolution)}), value=int(resolution), description="resolution"
        )
        self.quantity = widgets.ToggleButtons(
            options=list(QUANTITIES),
            value="mean H",
            description="colour",
            tooltips=[EQUATIONS[k] for k in QUANTITIES.values()],
        )
        self.quantity.style.button_width = "96px"
        self.clip = widgets.FloatRangeSlider(
            value=(2.0, 98.0),
            min=0.0,
            max=100.0,
            step=0.5,
            description="range (pct)",
            tooltip="the colour range: these percentiles of the defined values; the rest is clipped (end colours)",
            continuous_update=False,
            layout=widgets.Layout(width="380px"),
        )
        # shown at its own size (HISTOGRAM_PX at charts.DPI): its 10 pt fonts stay 10 pt
        self.histogram = widgets.Image(format="png", layout=widgets.Layout(width=f"{HISTOGRAM_PX}px", display="none"))
        self.status = widgets.HTML("computing curvatures...")
        self.colours: ColourRange | None = None
        self.view = MeshView(backend=backend, size=size, section=shows_inside(self.models[next(iter(self.models))]))
        self.worker = LatestWorker(self._compute, self._computed, self.main, settle=0.0)

        self.model_choice.observe(lambda _: self._model_changed(), names="value")
        self.resolution.observe(lambda _: self.request(), names="value")
        # renders belong on the main thread (JupyterLab may call back on a subshell thread)
        self.quantity.observe(lambda _: self.main.call(self.draw), names="value")
        self.clip.observe(lambda _: self.main.call(self.draw), names="value")
        controls = widgets.VBox([self.model_choice, self.resolution, self.quantity, self.clip, self.histogram])
        super().__init__([widgets.HBox([controls, self.view.box]), self.status])
        self.request()

    @property
    def model(self) -> Model:
        return self.models[self.model_choice.value]

    def _model_changed(self) -> None:
        self.view.set_section(on=shows_inside(self.model), render=False)  # a lattice opens, a solid closes
        self.request()

    def request(self) -> None:
        job = {"model": self.model, "resolution": int(self.resolution.value)}
        if self.threaded:
            self.worker.submit(job)
        else:
            self.worker.run_now(job)

    def wait(self, timeout: float = 300.0) -> None:
        self.worker.wait(timeout)

    def _compute(self, job: dict) -> dict:
        t0 = time.perf_counter()
        model = job["model"]
        f = lambda x: model(x)  # noqa: E731  (defaults of the declared parameters)
        # marching cubes, vertices moved onto f = 0 (the paper's way): the curvatures are those of
        # the surface itself.  Dual contouring keeps creases straight, but most of its vertices lie
        # off f = 0 (|f| ~ 1e-2 cell), where the level set is another (H = +-0.05 on Schwarz D)
        mesh = polygonize(f, model.bounds, job["resolution"])
        table = curvature_table(f, mesh.vertices)
        return {"mesh": mesh, "table": table, "seconds": time.perf_counter() - t0}

    def _computed(self, job: dict, result: dict | None, error: Exception | None) -> None:
        if error is not None:
            self.status.value = (
                f"<span style='color:#b00'>{html.escape(type(error).__name__)}: {html.escape(str(error))}</span>"
            )
            return
        first = self.mesh is None
        self.mesh, self.table = result["mesh"], result["table"]
        lo, hi = np.asarray(job["model"].bounds[0]), np.asarray(job["model"].bounds[1])
        self.spacing = float(np.max(hi - lo)) / (job["resolution"] - 1)  # the grid's step: what the mesh resolves
        self.model_name = job["model"].__name__
        self.seconds = result["seconds"]
        self.draw(reset_camera=True if first else job["model"] is not getattr(self, "_shown_model", None))
        self._shown_model = job["model"]

    def draw(self, reset_camera: bool = False) -> None:
        """Colour the mesh by the chosen quantity and redraw the histogram (no recomputation).

        Undefined vertices (grad f = 0, creases: ``Curvatures.defined`` False) are grey and
        counted; the range is the chosen percentiles of the others (:func:`workbench.colours.colour_range`):
        a diverging map centred on 0 for a quantity of both signs, a one-sided one otherwise.
        """
        if self.table is None:
            return
        key = QUANTITIES[self.quantity.value]
        values, defined = self.table[key], self.table["defined"]
        # a radius of curvature under half the grid spacing is finer than this mesh shows: a crease
        # (near one, f's level sets bend on the scale of the distance to it) or a strut thinner than
        # the grid; such values (1e16 at a crease) say nothing about the surface drawn
        bend = np.fmax(np.abs(self.table["kmin"]), np.abs(self.table["kmax"]))
        resolved = defined & (bend * self.spacing <= 2.0)
        self.resolved = resolved
        span = colour_range(values, resolved, percentiles=self.clip.value)
        self.colours = span
        shown = np.where(resolved, values, np.nan)
        unit = UNITS[key]
        self.view.update(
            self.mesh, scalars=shown, title=f"{key} ({unit})", cmap=span.cmap, clim=span.clim, reset_camera=reset_camera
        )
        self.histogram.value = self._histogram(values[resolved], span, key, unit)
        self.histogram.layout.display = ""
        median = float(np.median(values[resolved])) if resolved.any() else float("nan")
        n_undefined, n_fine = int((~defined).sum()), int((defined & ~resolved).sum())
        why = []
        if n_undefined:
            why.append(f"{n_undefined} with no curvature (grad f = 0 or on a crease)")
        if n_fine:
            why.append(
                f"{n_fine} with a radius of curvature under half the grid spacing {self.spacing:.3g} "
                "(creases, or features finer than the mesh: raise the resolution)"
            )
        self.status.value = (
            f"{html.escape(self.model_name)}: {self.mesh.n_vertices} vertices, curvatures in "
            f"{1000 * self.seconds:.0f} ms; {html.escape(EQUATIONS[key])}; {key}: median {median:.4g} {unit}; colour "
            f"{html.escape(span.describe(key, unit))}" + (f": {'; '.join(why)}" if why else "")
        )

    @staticmethod
    def _histogram(values: np.ndarray, span: ColourRange, key: str, unit: str) -> bytes:
        """Histogram of the defined values over the colour range, bars in the map's colours."""
        from matplotlib import colormaps

        fig = new_figure(HISTOGRAM_PX / DPI, 3.0)
        ax = fig.add_subplot()
        counts, edges = np.histogram(np.clip(values, span.lo, span.hi), bins=60, range=span.clim)
        centres = 0.5 * (edges[1:] + edges[:-1])
        cmap = colormaps[span.cmap]
        colours = cmap((centres - span.lo) / (span.hi - span.lo))
        # a thin dark edge: the bars at 0 of a diverging map are white
        ax.bar(centres, counts, width=np.diff(edges), color=colours, edgecolor="0.35", linewidth=0.3)
        if span.lo < 0.0 < span.hi:
            ax.axvline(0.0, color="k", lw=0.8)
        ax.set_title(
            f"{key} at {values.size} vertices\n{100 * span.clipped:.2g}% clipped into the end bars",
            fontsize=10,
        )
        ax.set_xlabel(f"{key} ({unit})", fontsize=10)
        ax.set_ylabel("vertices", fontsize=10)
        ax.tick_params(labelsize=10)
        return figure_png(fig)


def curvature_panel(backend: str = "auto", models: dict[str, Model] | None = None, **kwargs: Any) -> CurvaturePanel:
    """The curvature panel; Schwarz D first (the paper's Fig. 3), then the other 3-D shapes."""
    if models is None:
        from .app import paper_models

        found = paper_models(dim=3)
        order = ["schwarz_d"] + [k for k in found if k != "schwarz_d"]
        models = {k: found[k] for k in order if k in found}
    return CurvaturePanel(models, backend=backend, **kwargs)
