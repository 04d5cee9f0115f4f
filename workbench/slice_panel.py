"""Slice panel: a plane through a model; f and its distance approximations side by side (Figs. 4-6).

For the chosen plane (axis and offset) the panel evaluates, through pyfrep_core, f, the
normalized functions omega_1, omega_2 and delta_1 (``pyfrep_core.normalization``), a
redistanced network when one was trained (``set_network``) and the true signed distance
(``pyfrep_core.distance.true_distance``, 3-D models); it draws filled contours with the zero
level bold and, under each, its absolute error against the true distance.  2-D models (the
ellipse of Fig. 4) are shown in their own plane.
"""

from __future__ import annotations

import html
import os
import time
from collections.abc import Callable
from typing import Any

import ipywidgets as widgets
import numpy as np
import torch

from pyfrep_core import Model
from pyfrep_core.sampling import plane_points

from ._threads import LatestWorker, MainThread
from .charts import figure_png, new_figure
from .colours import UNDEFINED_COLOUR, colour_range

__all__ = ["SlicePanel", "slice_panel", "FIELDS", "draw_slices", "slice_figure"]

FIELDS = ("f", "omega_1", "omega_2", "delta_1", "redistanced", "true distance")
AXES = ("x", "y", "z")


def field_functions(model: Model, network: Callable | None = None) -> dict[str, Callable]:
    """name -> function (N, dim) numpy -> (N,) numpy, for the fields pyfrep_core offers now."""
    f = lambda x: model(x)  # noqa: E731
    funcs: dict[str, Callable] = {"f": lambda x: np.asarray(model(x))}
    try:
        from pyfrep_core import normalization as nz
    except ImportError:
        nz = None
    if nz is not None:
        funcs["omega_1"] = lambda x: _numpy(nz.omega_1(f, x))
        funcs["omega_2"] = lambda x: _numpy(nz.omega_k(f, x, 2))
        funcs["delta_1"] = lambda x: _numpy(nz.delta_1(f, x))
    if network is not None:

        def net(x: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                t = torch.as_tensor(x, dtype=_net_dtype(network))
                return _numpy(network(t)).reshape(len(x))

        funcs["redistanced"] = net
    return funcs


def _net_dtype(network: Any) -> torch.dtype:
    try:
        return next(network.parameters()).dtype
    except (AttributeError, StopIteration):
        return torch.float64


def _numpy(v: Any) -> np.ndarray:
    if isinstance(v, torch.Tensor):
        return v.detach().cpu().double().numpy()
    return np.asarray(v, dtype=np.float64)


FONT = 10  # points: readable on a projector (matplotlib's 6-7 pt ticks are not)
UNITS = {"f": "units of f", "redistanced": "length", "true distance": "length"}  # else length (distance estimates)


def draw_slices(
    axes_uv: list[np.ndarray],
    fields: dict[str, np.ndarray],
    truth: np.ndarray | None,
    labels: tuple[str, str],
    columns: int = 3,
) -> bytes:
    """:func:`slice_figure` as PNG bytes.

    Examples
    --------
    >>> u = v = np.linspace(-1.0, 1.0, 20)
    >>> f = 0.5 - np.hypot(*np.meshgrid(u, v))
    >>> draw_slices([u, v], {"f": f}, None, ("x", "y"))[:4]
    b'\\x89PNG'
    """
    return figure_png(slice_figure(axes_uv, fields, truth, labels, columns))


def slice_figure(
    axes_uv: list[np.ndarray],
    fields: dict[str, np.ndarray],
    truth: np.ndarray | None,
    labels: tuple[str, str],
    columns: int = 3,
) -> Any:
    """Filled contours of each field (zero level bold) and, below each, |field - truth|; a Figure.

    Colour ranges come from :func:`workbench.colours.colour_range` (robust percentiles, a
    diverging map centred on 0 for signed fields, one-sided for the errors); each title states
    the fraction of samples its range clips and any undefined (NaN, grey) samples.  Fonts >= 10 pt.

    Examples
    --------
    >>> u = v = np.linspace(-1.0, 1.0, 20)
    >>> f = 0.5 - np.hypot(*np.meshgrid(u, v))
    >>> fig = slice_figure([u, v], {"f": f}, None, ("x", "y"))
    >>> fig.axes[0].get_title().splitlines()[0]
    'f'
    """
    names = list(fields)
    cols = max(1, min(columns, len(names)))
    blocks = -(-len(names) // cols)  # rows of fields; each with a row of errors under it
    per = 2 if truth is not None else 1
    u, v = axes_uv
    # each plot as tall as the plane's aspect asks (the ellipse's box is 2.5 times wider than tall),
    # plus its title and tick labels
    aspect = float(np.ptp(v) / np.ptp(u)) if np.ptp(u) > 0 else 1.0
    # inches per column: the plot, and about 1.9 for its tick labels and colour bar; the row's
    # height: the plot's at the plane's aspect, and about 1 for the two-line title and the x ticks
    width = 4.0
    height = (width - 1.9) * min(max(aspect, 0.3), 1.5) + 1.0
    # at charts.DPI FONT points are FONT points on the page (the 80 dpi used before made 10 pt 8.3)
    fig = new_figure(width * cols, height * blocks * per + 0.2)  # charts.DPI

    def panel(row: int, col: int) -> Any:
        ax = fig.add_subplot(blocks * per, cols, row * cols + col + 1)
        ax.set_facecolor(UNDEFINED_COLOUR)  # NaN samples (undefined) show grey, not white
        ax.set_aspect("equal")
        ax.tick_params(labelsize=FONT)
        return ax

    def contour(ax: Any, z: np.ndarray, span: Any, unit: str) -> None:
        levels = np.linspace(span.lo, span.hi, 22)
        cs = ax.contourf(u, v, np.clip(z, span.lo, span.hi), levels=levels, cmap=span.cmap)
        bar = fig.colorbar(cs, ax=ax, shrink=0.9, ticks=np.linspace(span.lo, span.hi, 5), format="%.3g")
        bar.ax.tick_params(labelsize=FONT)
        bar.set_label(unit, fontsize=FONT)

    def caption(span: Any) -> str:
        text = f"{100 * span.clipped:.2g}% clipped"
        return text + (f", {span.undefined} undefined" if span.undefined else "")

    for j, name in enumerate(names):
        block, col = divmod(j, cols)
        z = fields[name]
        ax = panel(block * per, col)
        span = colour_range(z, percentiles=(1.0, 99.0), diverging=True)  # signed fields: white is 0
        contour(ax, z, span, UNITS.get(name, "length"))
        if np.isfinite(z).any():
            ax.contour(u, v, z, levels=np.linspace(span.lo, span.hi, 11), colors="k", linewidths=0.3, alpha=0.4)
            ax.contour(u, v, z, levels=[0.0], colors="k", linewidths=2.2)
        ax.set_title(f"{name}\n{caption(span)}", fontsize=FONT)
        ax.set_xlabel(labels[0], fontsize=FONT)
        ax.set_ylabel(labels[1], fontsize=FONT)
        if truth is not None and name != "true distance":
            ax = panel(block * per + 1, col)
            err = np.abs(z - truth)
            span = colour_range(err, percentiles=(0.0, 99.0), diverging=False)  # >= 0: one-sided
            contour(ax, err, span, "length")
            ax.contour(u, v, truth, levels=[0.0], colors="w", linewidths=1.2)
            ax.set_title(
                f"|{name} - d|\nmean {np.nanmean(err):.2g}, max {np.nanmax(err):.2g}; {caption(span)}",
                fontsize=FONT,
            )
    return fig


class SlicePanel(widgets.VBox):
    """Model, plane (axis, offset), resolution and fields; contour plots and their errors.

    Parameters
    ----------
    models : name -> Model (2-D or 3-D).
    resolution : samples per side of the plane.
    distance_resolution : marching-cubes resolution of the true-distance samples (3-D).
    threaded : compute on a background thread (default: when a kernel's loop runs).
    """

    def __init__(
        self,
        models: dict[str, Model],
        resolution: int = 120,
        distance_resolution: int = 64,
        threaded: bool | None = None,
        backend: str = "auto",  # noqa: ARG002  (no 3-D view here; accepted like every panel)
    ):
        if not models:
            raise ValueError("models must name at least one Model")
        self.models = dict(models)
        self.distance_resolution = distance_resolution
        self.main = MainThread()
        self.threaded = self.main.has_loop if threaded is None else threaded
        self.networks: dict[str, Callable] = {}
        self._distances: dict[str, Any] = {}
        self.values: dict[str, np.ndarray] = {}
        self.truth: np.ndarray | None = None
        self.errors: dict[str, tuple[float, float]] = {}

        # one Layout per widget: a shared one is one object, and hiding the offset for a 2-D model
        # would hide every control sharing it
        def lay() -> widgets.Layout:
            return widgets.Layout(width="300px")

        self.model_choice = widgets.Dropdown(options=list(self.models), description="model", layout=lay())
        self.axis = widgets.ToggleButtons(
            options=AXES, value="z", description="normal", tooltip="the axis normal to the slice plane"
        )
        self.axis.style.button_width = "40px"
        self.offset = widgets.FloatSlider(
            description="offset",
            tooltip="where the plane cuts its normal axis (model units)",
            continuous_update=False,
            layout=lay(),
            step=0.01,
        )
        self.resolution = widgets.IntSlider(
            value=resolution,
            min=32,
            max=400,
            step=8,
            description="samples",
            tooltip="samples per side of the plane",
            continuous_update=False,
            layout=lay(),
        )
        self.fields = widgets.SelectMultiple(
            options=FIELDS, value=FIELDS, description="fields", rows=len(FIELDS), layout=lay()
        )
        # natural size; hidden until the first plot (an empty Image shows a broken-image icon)
        self.image = widgets.Image(format="png", layout=widgets.Layout(align_self="flex-start", display="none"))
        self.status = widgets.HTML("slicing...")
        self.worker = LatestWorker(self._compute, self._computed, self.main, settle=0.0)
        self._sync_offset()
        self.model_choice.observe(self._model_changed, names="value")
        for w in (self.axis, self.offset, self.resolution, self.fields):
            w.observe(lambda _: self.request(), names="value")
        controls = widgets.HBox([self.model_choice, self.axis, self.offset, self.resolution])
        super().__init__([controls, widgets.HBox([self.fields, self.status]), self.image])
        self.request()

    @property
    def model(self) -> Model:
        return self.models[self.model_choice.value]

    def set_network(self, model_name: str, network: Callable) -> None:
        """Use a trained distance network (from the redistancing panel) for ``model_name``."""
        self.networks[model_name] = network
        if model_name == self.model_choice.value:
            self.request()

    def _sync_offset(self) -> None:
        m = self.model
        self.axis.layout.display = "none" if m.dim == 2 else "flex"
        self.offset.layout.display = "none" if m.dim == 2 else "flex"
        if m.dim == 3:
            i = AXES.index(self.axis.value)
            lo, hi = m.bounds[0][i], m.bounds[1][i]
            self.offset.min, self.offset.max = min(lo, self.offset.min), max(hi, self.offset.max)
            self.offset.min, self.offset.max = lo, hi
            self.offset.step = (hi - lo) / 200
            self.offset.value = 0.5 * (lo + hi)

    def _model_changed(self, _: Any) -> None:
        self._sync_offset()
        self.request()

    def request(self) -> None:
        job = {
            "model": self.model,
            "axis": AXES.index(self.axis.value),
            "offset": float(self.offset.value),
            "n": int(self.resolution.value),
            "fields": tuple(self.fields.value),
            "network": self.networks.get(self.model_choice.value),
        }
        if self.threaded:
            self.worker.submit(job)
        else:
            self.worker.run_now(job)

    def wait(self, timeout: float = 300.0) -> None:
        self.worker.wait(timeout)

    def true_distance_of(self, model: Model) -> Any:
        """The model's true signed distance: a closed form ``pyfrep_core.models.<name>_distance`` when the
        core has one (the ellipse of Fig. 4), else ``pyfrep_core.distance.true_distance`` (3-D; cached)."""
        from pyfrep_core import models

        exact = getattr(models, f"{model.__name__}_distance", None)
        if callable(exact):
            return lambda x: exact(x, **model.defaults())
        if model.dim != 3:
            return None
        key = model.__name__
        if key not in self._distances:
            from pyfrep_core.distance import true_distance

            self._distances[key] = true_distance(lambda x: model(x), model.bounds, resolution=self.distance_resolution)
        return self._distances[key]

    def _compute(self, job: dict) -> dict:
        t0 = time.perf_counter()
        model = job["model"]
        pts, uv = plane_points(model.bounds, job["axis"], job["offset"], job["n"], model.dim)
        flat = pts.reshape(-1, model.dim)
        funcs = field_functions(model, job["network"])
        values, missing = {}, []
        truth = None
        for name in job["fields"]:
            if name == "true distance":
                try:
                    d = self.true_distance_of(model)
                except ImportError as err:
                    missing.append(f"true distance ({err})")
                    continue
                if d is None:
                    missing.append("true distance (3-D models only)")
                    continue
                truth = np.asarray(d(flat), dtype=np.float64).reshape(pts.shape[:2])
                values[name] = truth
            elif name in funcs:
                values[name] = funcs[name](flat).reshape(pts.shape[:2])
            else:
                missing.append(name if name != "redistanced" else "redistanced (train one in the Redistancing tab)")
        return {"values": values, "truth": truth, "uv": uv, "missing": missing, "seconds": time.perf_counter() - t0}

    def _computed(self, job: dict, result: dict | None, error: Exception | None) -> None:
        if error is not None:
            self.status.value = (
                f"<span style='color:#b00'>{html.escape(type(error).__name__)}: {html.escape(str(error))}</span>"
            )
            return
        self.values, self.truth = result["values"], result["truth"]
        shown = dict(self.values)
        model = job["model"]
        others = [AXES[i] for i in range(3) if i != job["axis"]] if model.dim == 3 else ["x", "y"]
        self.errors = {}
        if self.truth is not None:
            for k, v in self.values.items():
                if k != "true distance":
                    err = np.abs(v - self.truth)
                    self.errors[k] = (float(np.nanmean(err)), float(np.nanmax(err)))
        if shown:
            self.image.value = draw_slices(result["uv"], shown, self.truth, (others[0], others[1]))
            self.image.layout.display = ""
        plane = f"{AXES[job['axis']]} = {job['offset']:.3g}" if model.dim == 3 else "its plane"
        table = "".join(f"<tr><td>{k}</td><td>{m:.3g}</td><td>{x:.3g}</td></tr>" for k, (m, x) in self.errors.items())
        missing = "".join(f"<li>{html.escape(m)}: not available yet</li>" for m in result["missing"])
        self.status.value = (
            f"<b>{html.escape(model.__name__)}</b> sliced at {plane}, {job['n']}&sup2; samples in "
            f"{1000 * result['seconds']:.0f} ms"
            + (f"<table><tr><th>field</th><th>mean |err|</th><th>max |err|</th></tr>{table}</table>" if table else "")
            + (f"<ul>{missing}</ul>" if missing else "")
        )


def slice_panel(backend: str = "auto", models: dict[str, Model] | None = None, **kwargs: Any) -> SlicePanel:
    """The slice panel with the paper's shapes (the ellipse of Fig. 4 first when available)."""
    if models is None:
        from .app import paper_models

        found = paper_models()
        order = [k for k in ("ellipse", "fig1_part") if k in found] + [
            k for k in found if k not in ("ellipse", "fig1_part")
        ]
        models = {k: found[k] for k in order}
    if os.environ.get("PYFREP_QUICK", "") not in ("", "0"):
        kwargs.setdefault("resolution", 80)
        kwargs.setdefault("distance_resolution", 48)
    return SlicePanel(models, backend=backend, **kwargs)
