"""Redistancing panel: train a network to the signed distance of a model, watch the loss live.

Training is ``pyfrep_core.redistancing.redistance(f, bounds, mode=, callback=, stop=, progress=)``
on a background thread (Stop sets its ``stop`` flag), in the mode chosen in the panel (the
default, with distance labels, or the paper's, from f alone: :data:`MODES`); its events feed a
log-scale loss chart and a progress bar.  When it ends, slices of f and of the trained distance are drawn side by side
with the error against the true distance (3-D models), and the network is offered to the
slice panel (``on_trained`` callbacks).
"""

from __future__ import annotations

import html
import os
import time
from collections.abc import Callable
from typing import Any

import ipywidgets as widgets
import numpy as np

from pyfrep_core import Model
from pyfrep_core.sampling import plane_points

from ._threads import BackgroundRun, MainThread
from .charts import LineChart
from .slice_panel import AXES, draw_slices, field_functions

# a wrapped progress line at text spacing (an HTML widget's line is a control high, 28 px)
PROGRESS_STYLE = "style='display:inline-block;line-height:1.35'"

__all__ = ["MODES", "RedistancePanel", "redistance_panel", "trained_network"]

# redistance's modes as the panel offers them: menu label, and what the mode trains on
MODES: dict[str, tuple[str, str]] = {
    "supervised": (
        "with distance labels",
        "the eikonal loss (eq. 9) as a light regularizer plus distances to the surface computed beforehand "
        "(labels): accurate in seconds, but not the paper's training",
    ),
    "paper": (
        "paper: eikonal, no labels",
        "the paper's training (section 5.3): the eikonal loss (eq. 9) over the box and near the surface, d = 0 "
        "and &nabla;d = &minus;&nabla;f/|&nabla;f| on points of f = 0, every target from f alone; slower to "
        "converge",
    ),
}


def trained_network(result: Any) -> Callable:
    """The callable distance network in what ``redistance`` returned (the network itself or a result holding it)."""
    if callable(result):  # pyfrep_core.redistancing.RedistancedSDF: the signed distance itself
        return result
    for name in ("sdf", "distance", "network"):
        candidate = getattr(result, name, None)
        if callable(candidate) and not isinstance(candidate, Model):
            return candidate
    raise TypeError(f"redistance returned {type(result).__name__}, which holds no callable network")


class RedistancePanel(widgets.VBox):
    """Model, bounds, Train/Stop, progress bar, live loss chart; slices and error after training.

    Parameters
    ----------
    models : name -> Model.
    settings : extra keyword arguments for ``redistance`` (e.g. fewer steps in quick mode).
    slice_resolution : samples per side of the result slices.
    """

    def __init__(
        self,
        models: dict[str, Model],
        settings: dict[str, Any] | None = None,
        slice_resolution: int = 100,
        distance_resolution: int = 64,
        backend: str = "auto",  # noqa: ARG002  (no 3-D view here; accepted like every panel)
    ):
        if not models:
            raise ValueError("models must name at least one Model")
        self.models = dict(models)
        self.settings = dict(settings or {})
        self.slice_resolution = slice_resolution
        self.distance_resolution = distance_resolution
        self.main = MainThread()
        self.run: BackgroundRun | None = None
        self.network: Callable | None = None
        self.trained: dict[str, Callable] = {}  # model name -> network
        self.events: list[Any] = []
        self.on_trained: list[Callable[[str, Callable], None]] = []
        self._offsets: dict[str, int] = {}
        self._next_x = 0
        self._first_loss: float | None = None
        lay = widgets.Layout(width="320px")
        self.model_choice = widgets.Dropdown(options=list(self.models), description="model", layout=lay)
        self.bounds = widgets.HTML()
        self.mode = widgets.Dropdown(
            options=[(label, name) for name, (label, _) in MODES.items()],
            value="supervised",
            description="training",
            tooltip="what the network is trained on (redistance's mode)",
            layout=lay,
        )
        self.mode_help = widgets.HTML(layout=widgets.Layout(width="320px"))
        self.train_button = widgets.Button(description="Train", button_style="success")
        self.stop_button = widgets.Button(description="Stop", button_style="danger", disabled=True)
        self.bar = widgets.IntProgress(value=0, min=0, max=1, layout=widgets.Layout(width="300px"))
        self.progress_text = widgets.HTML("")
        self.status = widgets.HTML("")
        # redrawn at most once a second, never queued twice: a kernel busy drawing charts answers
        # neither the Stop button nor the 3-D views' connections
        self.loss_chart = LineChart(
            "training loss",
            "step",
            "loss",
            logy=True,
            min_interval=1.0,
            schedule=lambda fn: self.main.call(fn, vtk=False),
        )
        self._shown_event: Any = None  # the progress line's newest event, shown by the one queued call
        self._progress_queued = False
        self._progress_at = 0.0
        # hidden until the first slices (an empty Image shows a broken-image icon)
        self.slices = widgets.Image(format="png", layout=widgets.Layout(align_self="flex-start", display="none"))
        self.model_choice.observe(lambda _: self._show_bounds(), names="value")
        self.mode.observe(lambda _: self._show_mode(), names="value")
        self._show_mode()
        self.train_button.on_click(lambda _: self.start())
        self.stop_button.on_click(lambda _: self.stop())
        self._show_bounds()
        controls = widgets.VBox(
            [
                self.model_choice,
                self.bounds,
                self.mode,
                self.mode_help,
                widgets.HBox([self.train_button, self.stop_button]),
                self.bar,
                self.progress_text,
            ],
            layout=widgets.Layout(width="340px"),
        )
        super().__init__([widgets.HBox([controls, self.loss_chart.widget]), self.status, self.slices])

    @property
    def model(self) -> Model:
        return self.models[self.model_choice.value]

    def _show_bounds(self) -> None:
        lo, hi = self.model.bounds
        self.bounds.value = f"<span style='font-size:13px'>bounds {tuple(lo)} to {tuple(hi)}</span>"

    def _show_mode(self) -> None:
        text = MODES[self.mode.value][1]
        self.mode_help.value = f"<div style='font-size:13px;line-height:1.3;color:#333'>{text}</div>"

    # -- training -----------------------------------------------------------------------------
    def start(self, **overrides: Any) -> BackgroundRun | None:
        """Train on a background thread; returns the run (``.wait()`` blocks until it ends)."""
        if self.run is not None and self.run.running:
            return self.run
        try:
            from pyfrep_core.redistancing import redistance
        except ImportError as err:
            self._error(err, "redistancing not available yet")
            return None
        model = self.model
        settings = {"mode": self.mode.value, **self.settings, **overrides}
        self.events, self._offsets, self._next_x, self._first_loss = [], {}, 0, None
        self.loss_chart.clear()
        self.train_button.disabled, self.stop_button.disabled = True, False
        how = MODES[settings["mode"]][0] if settings["mode"] in MODES else settings["mode"]
        self._how = how
        self.status.value = f"training a distance network for {html.escape(model.__name__)} ({how})..."
        self._t0 = time.perf_counter()

        def target(stop: Any) -> Any:
            f = lambda x: model(x)  # noqa: E731
            result = redistance(f, model.bounds, callback=self._event, stop=stop, progress=False, **settings)
            network = trained_network(result)
            return result, network, self._slices(model, network)

        self.run = BackgroundRun(target, self._finished, self.main).start()
        return self.run

    def stop(self) -> None:
        """Ask the training to stop (nothing when none runs: a late click changes nothing)."""
        if self.run is not None and self.run.running:
            self.run.stop.set()
            self.status.value = "stopping..."  # until _finished says where it stopped

    def wait(self, timeout: float = 600.0) -> Any:
        if self.run is not None:
            self.run.wait(timeout)
        return self.network

    def _event(self, event: Any) -> None:
        self.events.append(event)
        if event.stage not in self._offsets:
            self._offsets[event.stage] = self._next_x
        x = self._offsets[event.stage] + event.step
        self._next_x = max(self._next_x, x + 1)
        if np.isfinite(event.loss) and event.loss > 0:
            self.loss_chart.add(event.stage, x, event.loss)
            if self._first_loss is None:
                self._first_loss = event.loss
        self.loss_chart.refresh()
        # the progress line: the newest event, at most 5 times a second, one call queued at a time
        self._shown_event = event
        now = time.monotonic()
        if not self._progress_queued and now - self._progress_at >= 0.2:
            self._progress_queued, self._progress_at = True, now
            self.main.call(self._flush_progress, vtk=False)

    def _flush_progress(self) -> None:
        self._progress_queued = False
        if self._shown_event is not None:
            self._progress_text(self._shown_event)

    def _progress_text(self, event: Any) -> None:
        self.bar.max = max(1, event.total)
        self.bar.value = min(event.step + 1, event.total)
        first = "" if self._first_loss is None else f" (first {self._first_loss:.3e})"
        self.progress_text.value = (
            f"<span class='train-progress' {PROGRESS_STYLE}>"
            f"{html.escape(event.stage)} {event.step + 1}/{event.total} &middot; "
            f"loss {event.loss:.3e}{first}</span>"
        )

    def _slices(self, model: Model, network: Callable) -> tuple[bytes, dict[str, tuple[float, float]]]:
        """f and the network on the middle plane, with the error against the true distance (worker thread)."""
        pts, uv = plane_points(
            model.bounds, 2, 0.5 * (model.bounds[0][-1] + model.bounds[1][-1]), self.slice_resolution, model.dim
        )
        flat = pts.reshape(-1, model.dim)
        funcs = field_functions(model, network)
        fields = {name: funcs[name](flat).reshape(pts.shape[:2]) for name in ("f", "redistanced")}
        truth = None
        if model.dim == 3:
            from pyfrep_core.distance import true_distance

            d = true_distance(lambda x: model(x), model.bounds, resolution=self.distance_resolution)
            truth = np.asarray(d(flat)).reshape(pts.shape[:2])
            fields["true distance"] = truth
        errors = {}
        if truth is not None:
            for k in ("f", "redistanced"):
                e = np.abs(fields[k] - truth)
                errors[k] = (float(e.mean()), float(e.max()))
        labels = ("x", "y")
        return draw_slices(uv, fields, truth, labels), errors

    def _finished(self, output: Any, error: BaseException | None) -> None:
        self.train_button.disabled, self.stop_button.disabled = False, True
        self.loss_chart.refresh(force=True)
        if error is not None:
            self._error(error)
            return
        _, network, (png, errors) = output
        self.network = network
        self.slices.value = png
        self.slices.layout.display = ""
        if self.events:
            self._progress_text(self.events[-1])  # the bar ends where training ended
        name = self.model_choice.value
        self.trained[name] = network
        for callback in self.on_trained:
            callback(name, network)
        # where training ended, not whether Stop was pressed: a click that arrives after the last
        # step (the kernel was busy) stopped nothing
        last = self.events[-1] if self.events else None
        early = last is None or last.step + 1 < last.total
        stopped = f" (stopped early at step {last.step + 1 if last else 0})" if early else ""
        err = "".join(f"; |{k} - d| mean {m:.3g}, max {x:.3g}" for k, (m, x) in errors.items())
        self.status.value = (
            f"<span class='train-done'>trained in {time.perf_counter() - self._t0:.1f} s, {self._how}{stopped}{err} "
            f"(slice {AXES[2]} = middle)</span>"
        )

    def _error(self, err: BaseException, what: str = "") -> None:
        text = (f"{what}: " if what else "") + f"{type(err).__name__}: {err}"
        self.status.value = f"<span style='color:#b00'>{html.escape(text)}</span>"


def redistance_panel(backend: str = "auto", models: dict[str, Model] | None = None, **kwargs: Any) -> RedistancePanel:
    """The redistancing panel with the paper's shapes; short training in quick mode (PYFREP_QUICK)."""
    if models is None:
        from .app import paper_models

        models = paper_models(dim=3)  # redistance() trains on 3-D boxes
    if os.environ.get("PYFREP_QUICK", "") not in ("", "0"):
        kwargs.setdefault("slice_resolution", 64)
        kwargs.setdefault("distance_resolution", 40)
        kwargs.setdefault("settings", {"steps": 200, "surface_resolution": 40, "pool_size": 1 << 13})
    return RedistancePanel(models, backend=backend, **kwargs)
