"""Curvature panel: the surface coloured by mean, Gaussian or principal curvature, with a histogram.

The paper's Fig. 3 (Schwarz D).  Curvatures come from ``pyfrep_core.curvature.curvatures``
(autograd Hessians of f at the mesh vertices, after they are projected onto f = 0); the panel
only meshes, asks for them and draws.  The colour range is clipped at chosen percentiles so a
few extreme values (near sharp edges) do not wash out the map.
"""

from __future__ import annotations

import html
import time
from typing import Any

import ipywidgets as widgets
import numpy as np

from pyfrep_core import Model, polygonize

from ._threads import LatestWorker, MainThread
from .charts import figure_png, new_figure
from .view import MeshView

__all__ = ["CurvaturePanel", "curvature_panel", "QUANTITIES"]

# label -> key in the curvature table
QUANTITIES = {"mean H": "H", "Gaussian K": "K", "kmin": "kmin", "kmax": "kmax"}


def curvature_table(f: Any, x: np.ndarray) -> dict[str, np.ndarray]:
    """H, K, kmin, kmax at points ``x`` (N, 3), from ``pyfrep_core.curvature``.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> t = curvature_table(lambda x: sphere(x, r=2.0), np.array([[0.0, 0.0, 2.0]]))
    >>> float(t["H"][0]), float(t["K"][0])
    (0.5, 0.25)
    """
    from pyfrep_core import curvature

    out = curvature.curvatures(f, x)
    if hasattr(out, "_asdict"):
        out = out._asdict()
    elif not isinstance(out, dict):
        out = {k: getattr(out, k) for k in ("H", "K", "kmin", "kmax") if hasattr(out, k)}
    aliases = {"mean": "H", "gaussian": "K", "k_min": "kmin", "k_max": "kmax", "k1": "kmin", "k2": "kmax"}
    table = {aliases.get(k, k): np.asarray(v, dtype=np.float64) for k, v in out.items()}
    missing = [k for k in QUANTITIES.values() if k not in table]
    if missing:
        raise KeyError(f"pyfrep_core.curvature.curvatures gave no {missing}; got {sorted(table)}")
    return table


def clip_range(values: np.ndarray, percentiles: tuple[float, float]) -> tuple[float, float]:
    """The colour range: the given percentiles of the finite values.

    Examples
    --------
    >>> clip_range(np.array([0.0, 1.0, 2.0, 3.0, 4.0, np.nan]), (25, 75))
    (1.0, 3.0)
    """
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return (-1.0, 1.0)
    lo, hi = np.percentile(finite, percentiles)
    return (float(lo), float(hi)) if hi > lo else (float(lo) - 1e-12, float(hi) + 1e-12)


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
        self.quantity = widgets.ToggleButtons(options=list(QUANTITIES), value="mean H", description="colour")
        self.quantity.style.button_width = "96px"
        self.clip = widgets.FloatRangeSlider(
            value=(2.0, 98.0), min=0.0, max=100.0, step=0.5, description="percentiles", continuous_update=False
        )
        self.histogram = widgets.Image(format="png", layout=widgets.Layout(width="420px"))
        self.status = widgets.HTML("computing curvatures...")
        self.view = MeshView(backend=backend, size=size)
        self.worker = LatestWorker(self._compute, self._computed, self.main, settle=0.0)

        self.model_choice.observe(lambda _: self.request(), names="value")
        self.resolution.observe(lambda _: self.request(), names="value")
        # renders belong on the main thread (JupyterLab may call back on a subshell thread)
        self.quantity.observe(lambda _: self.main.call(self.draw), names="value")
        self.clip.observe(lambda _: self.main.call(self.draw), names="value")
        controls = widgets.VBox([self.model_choice, self.resolution, self.quantity, self.clip, self.histogram])
        super().__init__([widgets.HBox([controls, self.view.widget]), self.status])
        self.request()

    @property
    def model(self) -> Model:
        return self.models[self.model_choice.value]

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
        self.model_name = job["model"].__name__
        self.seconds = result["seconds"]
        self.draw(reset_camera=True if first else job["model"] is not getattr(self, "_shown_model", None))
        self._shown_model = job["model"]

    def draw(self, reset_camera: bool = False) -> None:
        """Colour the mesh by the chosen quantity and redraw the histogram (no recomputation)."""
        if self.table is None:
            return
        key = QUANTITIES[self.quantity.value]
        values = self.table[key]
        clim = clip_range(values, self.clip.value)
        if key in ("H", "K") and clim[0] < 0 < clim[1]:
            top = max(-clim[0], clim[1])
            clim = (-top, top)  # signed quantities: diverging map centred on 0
        self.view.update(
            self.mesh, scalars=np.clip(values, *clim), title=key, cmap="coolwarm", clim=clim, reset_camera=reset_camera
        )
        self.histogram.value = self._histogram(values, clim, key)
        finite = values[np.isfinite(values)]
        self.status.value = (
            f"{html.escape(self.model_name)}: {self.mesh.n_vertices} vertices, curvatures in "
            f"{1000 * self.seconds:.0f} ms; {key}: median {np.median(finite):.4g}, "
            f"range [{finite.min():.4g}, {finite.max():.4g}], colour clipped to [{clim[0]:.4g}, {clim[1]:.4g}]"
        )

    @staticmethod
    def _histogram(values: np.ndarray, clim: tuple[float, float], key: str) -> bytes:
        fig = new_figure(4.6, 2.8)
        ax = fig.add_subplot()
        finite = values[np.isfinite(values)]
        ax.hist(finite, bins=60, range=clim, color="#4c72b0")
        ax.axvline(0.0, color="k", lw=0.8)
        outside = int(np.sum((finite < clim[0]) | (finite > clim[1])))
        ax.set_title(f"{key} at the {finite.size} mesh vertices ({outside} outside the range)", fontsize=9)
        ax.set_xlabel(key, fontsize=8)
        ax.set_ylabel("vertices", fontsize=8)
        ax.tick_params(labelsize=7)
        return figure_png(fig)


def curvature_panel(backend: str = "auto", models: dict[str, Model] | None = None, **kwargs: Any) -> CurvaturePanel:
    """The curvature panel; Schwarz D first (the paper's Fig. 3), then the other 3-D shapes."""
    if models is None:
        from .app import paper_models

        found = paper_models(dim=3)
        order = ["schwarz_d"] + [k for k in found if k != "schwarz_d"]
        models = {k: found[k] for k in order if k in found}
    return CurvaturePanel(models, backend=backend, **kwargs)
