"""Fitting panel: recover a model's parameters from a point cloud (paper section 5.4, Figs. 7 and 8).

A fit's journey: points -> ``pyfrep_core.fitting.fit`` (on a background thread, Stop
sets its ``stop`` flag) -> progress events -> live loss chart (log scale, one series per stage)
and parameter trajectories against the true values -> the cloud coloured by the per-point
residual |f(x_i; p)| and the fitted surface (``polygonize``) overlaid in the 3-D view.
"""

from __future__ import annotations

import html
import os
import tempfile
import time
from typing import Any

import ipywidgets as widgets
import numpy as np

from pyfrep_core import Model, polygonize

from ._threads import BackgroundRun, MainThread
from .charts import LineChart
from .view import MeshView

__all__ = ["FittingPanel", "fitting_panel", "EFFORT"]

# fit() settings per effort level: "quick" answers in seconds, "paper" uses the paper's budgets.
EFFORT: dict[str, dict[str, Any]] = {
    "quick": {"cycles": 300, "population_size": 50, "epochs": 5, "batch_size": 1024, "polish_iters": 20, "every": 1},
    "paper": {"cycles": 10_000, "epochs": 100, "polish_iters": 50, "every": 10},
}


def hidden_params(model: Model, seed: int) -> dict[str, float]:
    """Parameter values drawn uniformly in the middle 60% of each declared range (the 'unknown' truth).

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part
    >>> r = hidden_params(fig1_part, seed=0)["r"]
    >>> 0.2 + 0.2 * 0.6 <= r <= 0.8 - 0.2 * 0.6
    True
    """
    rng = np.random.default_rng(seed)
    return {k: float(p.lower + (0.2 + 0.6 * rng.random()) * (p.upper - p.lower)) for k, p in model.params.items()}


class FittingPanel(widgets.VBox):
    """Model and cloud choice, Run/Stop, live charts, residual-coloured cloud and fitted surface.

    Parameters
    ----------
    models : name -> Model offered in the chooser (3-D models).
    n_points, noise, seed : the generated cloud.
    effort : "quick" or "paper" (see ``EFFORT``).
    backend : 3-D view backend.
    resolution : grid samples per axis for the fitted surface.
    """

    def __init__(
        self,
        models: dict[str, Model],
        n_points: int = 2000,
        noise: float = 0.0,
        seed: int = 1,
        effort: str = "quick",
        backend: str = "auto",
        resolution: int = 64,
        size: tuple[int, int] = (560, 420),
    ):
        if not models:
            raise ValueError("models must name at least one Model")
        self.models = dict(models)
        self.main = MainThread()
        self.resolution = resolution
        self.points: np.ndarray | None = None
        self.truth: dict[str, float] | None = None
        self.result: Any = None
        self.run: BackgroundRun | None = None
        self.events: list[Any] = []
        self._offsets: dict[str, int] = {}
        self._next_x = 0
        self._first_loss: float | None = None

        lay = widgets.Layout(width="300px")
        self.model_choice = widgets.Dropdown(options=list(self.models), description="model", layout=lay)
        self.source = widgets.ToggleButtons(options=["generated", "file"], value="generated", description="cloud")
        self.source.style.button_width = "90px"
        self.n_points = widgets.BoundedIntText(value=n_points, min=10, max=1_000_000, description="points", layout=lay)
        self.noise = widgets.BoundedFloatText(
            value=noise, min=0.0, max=1.0, step=0.005, description="noise", layout=lay
        )
        self.seed = widgets.IntText(value=seed, description="seed", layout=lay)
        self.upload = widgets.FileUpload(accept=".xyz,.ply", multiple=False, description="XYZ/PLY")
        self.effort = widgets.Dropdown(options=list(EFFORT), value=effort, description="effort", layout=lay)
        self.new_cloud = widgets.Button(description="New cloud")
        self.run_button = widgets.Button(description="Run", button_style="success")
        self.stop_button = widgets.Button(description="Stop", button_style="danger", disabled=True)
        self.bar = widgets.IntProgress(value=0, min=0, max=1, description="", layout=widgets.Layout(width="300px"))
        self.progress_text = widgets.HTML("")
        self.status = widgets.HTML("")
        schedule = lambda fn: self.main.call(fn, vtk=False)  # noqa: E731
        self.loss_chart = LineChart("loss E(p) = mean f(x_i; p)^2", "step", "E", logy=True, schedule=schedule)
        self.param_chart = LineChart("parameters (dashed: true values)", "step", "value", schedule=schedule)
        self.view = MeshView(backend=backend, size=size)

        # these render: on the main thread (JupyterLab may call back on a subshell thread)
        self.new_cloud.on_click(lambda _: self.main.call(self.make_cloud))
        self.model_choice.observe(lambda _: self.main.call(self.make_cloud), names="value")
        self.upload.observe(lambda _: self.main.call(self._uploaded), names="value")
        self.run_button.on_click(lambda _: self.start())
        self.stop_button.on_click(lambda _: self.stop())

        controls = widgets.VBox(
            [
                self.model_choice,
                self.source,
                self.n_points,
                self.noise,
                self.seed,
                widgets.HBox([self.new_cloud, self.upload]),
                self.effort,
                widgets.HBox([self.run_button, self.stop_button]),
                self.bar,
                self.progress_text,
            ],
            layout=widgets.Layout(width="320px"),
        )
        charts = widgets.VBox([self.loss_chart.widget, self.param_chart.widget])
        super().__init__([widgets.HBox([controls, self.view.widget, charts]), self.status])
        self.make_cloud()

    @property
    def model(self) -> Model:
        return self.models[self.model_choice.value]

    # -- the cloud --------------------------------------------------------------------------
    def make_cloud(self) -> None:
        """Sample the chosen model at hidden parameter values (plus noise) and show the cloud."""
        from pyfrep_core.sampling import sample_surface

        self.truth = hidden_params(self.model, int(self.seed.value))
        try:
            self.points = sample_surface(
                self.model,
                int(self.n_points.value),
                params=self.truth,
                noise=float(self.noise.value),
                seed=int(self.seed.value),
                resolution=64,
            )
        except Exception as err:
            self._error(err)
            return
        self.source.value = "generated"
        self._show_cloud()
        self.status.value = f"{len(self.points)} points sampled at hidden parameters (noise {self.noise.value:g})"

    def load_cloud(self, path: str) -> None:
        """Use the points of an XYZ or PLY file (``pyfrep_core.io.load_points``); true values unknown."""
        from pyfrep_core.io import load_points

        try:
            cloud = load_points(path)
            self.points = np.asarray(getattr(cloud, "points", cloud), dtype=np.float64)
        except Exception as err:
            self._error(err)
            return
        self.truth = None
        self.source.value = "file"
        self._show_cloud()
        self.status.value = f"{len(self.points)} points loaded from {html.escape(os.path.basename(path))}"

    def _uploaded(self) -> None:
        files = self.upload.value
        if not files:
            return
        item = files[0]
        suffix = os.path.splitext(item["name"])[1] or ".xyz"
        with tempfile.NamedTemporaryFile(suffix=suffix, delete=False) as fh:
            fh.write(bytes(item["content"]))
        try:
            self.load_cloud(fh.name)
        finally:
            os.unlink(fh.name)

    def _show_cloud(self) -> None:
        self.view.set_opacity(0.0)
        self.view.overlay_points(self.points)
        self.view.render(reset_camera=True)

    # -- running ------------------------------------------------------------------------------
    def start(self, **overrides: Any) -> BackgroundRun | None:
        """Run the fit on a background thread; returns the run (``.wait()`` blocks until done)."""
        if self.run is not None and self.run.running:
            return self.run
        if self.points is None:
            self.status.value = "<span style='color:#b00'>no points to fit</span>"
            return None
        from pyfrep_core.fitting import fit

        model, points = self.model, self.points
        settings = {**EFFORT[self.effort.value], "seed": int(self.seed.value), **overrides}
        self._reset_charts()
        self.run_button.disabled, self.stop_button.disabled = True, False
        self.status.value = f"fitting {model.__name__} to {len(points)} points..."
        self._t0 = time.perf_counter()

        def target(stop: Any) -> Any:
            result = fit(model, points, callback=self._event, stop=stop, progress=False, **settings)
            surface = polygonize(lambda x: model(x, **result.params), model.bounds, self.resolution)
            return result, surface

        self.run = BackgroundRun(target, self._finished, self.main).start()
        return self.run

    def stop(self) -> None:
        """Ask the running fit to end (it returns the best parameters so far)."""
        if self.run is not None:
            self.run.stop.set()
            self.status.value = "stopping..."

    def _reset_charts(self) -> None:
        self.events = []
        self._offsets, self._next_x, self._first_loss = {}, 0, None
        self.loss_chart.clear()
        self.param_chart.clear()
        if self.truth is not None:
            for k, v in self.truth.items():
                self.param_chart.set_reference(k, v)

    def _event(self, event: Any) -> None:
        """Progress callback (worker thread): chart points, progress text, bar."""
        self.events.append(event)
        if event.stage not in self._offsets:
            self._offsets[event.stage] = self._next_x
        x = self._offsets[event.stage] + event.step
        self._next_x = max(self._next_x, x + 1)
        if np.isfinite(event.loss):
            self.loss_chart.add(event.stage, x, max(event.loss, 1e-300))
            if self._first_loss is None:
                self._first_loss = event.loss
        for k, v in (event.params or {}).items():
            self.param_chart.add(k, x, v)
        self.loss_chart.refresh()
        self.param_chart.refresh()
        self.main.call(self._progress_text, event, vtk=False)

    def _progress_text(self, event: Any) -> None:
        self.bar.max = max(1, event.total)
        self.bar.value = min(event.step + 1, event.total)
        self.bar.description = event.stage
        first = "" if self._first_loss is None else f" (first {self._first_loss:.3e})"
        self.progress_text.value = (
            f"<span class='fit-progress'>{html.escape(event.stage)} {event.step + 1}/{event.total} &middot; "
            f"loss {event.loss:.3e}{first} &middot; {self.loss_chart.n_points} points charted</span>"
        )

    def _finished(self, output: Any, error: BaseException | None) -> None:
        """On the main thread: final charts, coloured cloud, fitted surface, summary."""
        self.run_button.disabled, self.stop_button.disabled = False, True
        self.loss_chart.refresh(force=True)
        self.param_chart.refresh(force=True)
        if error is not None:
            self._error(error)
            return
        result, surface = output
        self.result = result
        self.view.overlay_points(self.points, scalars=result.residuals, title="|f| residual")
        if not surface.is_empty():
            self.view.update(surface)
            self.view.set_opacity(0.45)
        self.view.render()
        rows = "".join(
            f"<tr><td>{html.escape(k)}</td><td>{v:.6g}</td>"
            + (f"<td>{self.truth[k]:.6g}</td><td>{abs(v - self.truth[k]):.2e}</td>" if self.truth else "")
            + "</tr>"
            for k, v in result.params.items()
        )
        head = "<tr><th>param</th><th>fitted</th>" + ("<th>true</th><th>|error|</th>" if self.truth else "") + "</tr>"
        stopped = " <b>(stopped early)</b>" if result.stopped else ""
        res = result.residuals
        self.status.value = (
            f"<span class='fit-done'>fit done in {time.perf_counter() - self._t0:.1f} s{stopped}: "
            f"loss {result.loss:.3e}, stages {', '.join(result.stages)}; residual max "
            f"{float(np.max(res)):.2e}</span><br><small>cloud coloured by the residual |f(x_i; p)| "
            f"(viridis, {float(np.min(res)):.2e} dark to {float(np.max(res)):.2e} yellow); "
            f"fitted surface translucent</small><table>{head}{rows}</table>"
        )

    def _error(self, err: BaseException) -> None:
        self.status.value = (
            f"<span style='color:#b00'>{html.escape(type(err).__name__)}: {html.escape(str(err))}</span>"
        )

    def wait(self, timeout: float = 300.0) -> Any:
        """Block until the running fit ends (scripts and tests); returns the FitResult."""
        if self.run is not None:
            self.run.wait(timeout)
        return self.result


def fitting_panel(backend: str = "auto", models: dict[str, Model] | None = None, **kwargs: Any) -> FittingPanel:
    """The fitting panel with the paper's 3-D shapes (Fig. 1 part first; microstructure for Figs. 7, 8)."""
    if models is None:
        from .app import paper_models

        models = paper_models(dim=3)
    return FittingPanel(models, backend=backend, **kwargs)
