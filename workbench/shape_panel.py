"""Shape panel: one slider per declared parameter, the surface re-meshed live in one 3-D view.

The slider's journey: slider -> ``polygonize(model(., **params))`` -> points/faces replaced
in the view's one PolyData -> render.  Meshing runs on a background thread that only ever builds
the newest request (moves made meanwhile are coalesced).  A move is first meshed at
``preview_resolution`` with marching cubes' own vertices (no projection onto f = 0: a quarter of
the time), and the full-resolution mesh is built right after, while the preview is drawn; a
newer move stops it (the next preview comes first), so dragging stays live.  Where the model has
interval bounds, dual contouring (sharp edges kept) then replaces that marching-cubes mesh, and the
exported file is dual contouring's too.
The model is evaluated through :func:`pyfrep_core.compiled.compiled` (torch.compile: one fused
loop per chunk, 5x faster than eager) once its kernels are compiled on a background thread;
until then, and wherever compilation fails, the eager model meshes.
The surface is coloured by the normal velocity of the parameter last moved
(:func:`pyfrep_core.sensitivity.normal_velocity`), on a diverging map centred on 0.
"""

from __future__ import annotations

import ast
import functools
import html
import os
import threading
import time
import warnings
from typing import Any

import ipywidgets as widgets
import numpy as np
import torch

from pyfrep_core import Mesh, Model, polygonize
from pyfrep_core.compiled import CompiledModel, warm_up
from pyfrep_core.compiled import compiled as compile_model
from pyfrep_core.interval import supports
from pyfrep_core.model import check_bounds
from pyfrep_core.sensitivity import normal_velocity, param_derivative, velocity

from ._threads import LatestWorker, MainThread
from .colours import colour_range
from .push_pull import PushPullControls
from .view import MeshView, shows_inside

__all__ = ["ShapePanel", "paper_shape_panel", "param_slider", "shape_panel", "surface_velocity", "symmetric_range"]

RESOLUTIONS = (32, 48, 64, 96, 128, 160, 192, 256)
LABEL_PX = 210  # a slider's label column: "slab threshold near the shell" whole at 13 px
COLOURINGS = ("sensitivity", "plain")


def param_slider(name: str, param: Any, value: float | None = None) -> widgets.FloatSlider:
    """A slider for one declared ``Param``: its range, a step of about range/200 on whose grid the
    default lies (:func:`slider_step`), its label in full (a label column wide enough for the
    paper's longest, and the label, name and range as tooltip).

    Examples
    --------
    >>> from pyfrep_core import Param
    >>> s = param_slider("r", Param(0.5, 0.2, 0.8, label="cylinder radius"))
    >>> s.description, s.min, s.max, round(s.step, 6), s.tooltip
    ('cylinder radius', 0.2, 0.8, 0.002, 'cylinder radius (r), from 0.2 to 0.8')
    """
    step = slider_step(param.lower, param.upper, param.default)
    decimals = max(0, int(np.ceil(-np.log10(step))) + 1) if step < 1 else 0
    return widgets.FloatSlider(
        value=param.default if value is None else value,
        min=param.lower,
        max=param.upper,
        step=step,
        description=param.label or name,
        tooltip=f"{param.label or name} ({name}), from {param.lower:g} to {param.upper:g}",
        readout_format=f".{decimals}f",
        continuous_update=True,
        style={"description_width": f"{LABEL_PX}px"},
        layout=widgets.Layout(width=f"{LABEL_PX + 220}px"),
    )


def slider_step(lower: float, upper: float, default: float) -> float:
    """A step of at most (upper - lower)/200, 1, 2 or 5 times a power of ten when the default lies
    on its grid from ``lower``, else the range/200-ish divisor of (default - lower).

    The browser's slider rounds its value to ``lower + k * step``: a default (or a value set by
    push-pull) off that grid would come back moved by up to half a step.

    Examples
    --------
    >>> slider_step(0.2, 0.8, 0.5), slider_step(0.3, 1.0, 0.9), slider_step(1.0, 10.0, 9.0)
    (0.002, 0.002, 0.02)
    >>> round(slider_step(0.0, 1.0, 1 / 3), 6)  # no decimal grid holds 1/3
    0.004975
    """
    raw = (upper - lower) / 200.0
    offset = default - lower
    power = 10.0 ** np.floor(np.log10(raw))
    for nice in (5 * power, 2 * power, power, power / 2, power / 5, power / 10):
        if nice <= raw * (1 + 1e-9) and abs(offset / nice - round(offset / nice)) < 1e-6:
            return float(nice)
    return offset / max(1, round(offset / raw)) if offset > 0 else raw


def symmetric_range(values: np.ndarray, percentile: float = 99.0) -> tuple[float, float]:
    """(-top, top): the diverging range of :func:`workbench.colours.colour_range` between the
    ``100 - percentile`` and ``percentile`` percentiles (vertices on creases, where the sensitivity
    is a sub-gradient, do not set the scale); all values when those are equal; about 0 if all are 0.

    Examples
    --------
    >>> symmetric_range(np.array([0.0] * 98 + [1.0, -3.0]), percentile=99.0)
    (-3.0, 3.0)
    >>> symmetric_range(np.zeros(5))[1] < 1e-6
    True
    """
    return colour_range(values, percentiles=(100.0 - percentile, percentile), diverging=True).clim


def surface_velocity(model: Model, mesh: Mesh, name: str, params: dict[str, float]) -> np.ndarray:
    """Normal velocity -(df/dp) / |grad f| at the mesh's vertices (V,), reusing the grad f that
    polygonize kept (``mesh.gradient``): one pass (df/dp, by the kernel's one per-point
    parameter derivative, :func:`pyfrep_core.sensitivity.param_derivative`) instead of two.

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part
    >>> m = polygonize(fig1_part, resolution=32)
    >>> v = surface_velocity(fig1_part, m, "r", fig1_part.defaults())
    >>> bool(np.allclose(v, normal_velocity(fig1_part, m.vertices, "r"), atol=1e-12))
    True
    """
    if mesh.gradient is None:
        return normal_velocity(model, mesh.vertices, name, params)
    df_dp = param_derivative(model, mesh.vertices, name, params)
    return velocity(df_dp, np.linalg.norm(mesh.gradient, axis=1))


def _format_bounds(bounds: Any) -> str:
    lo, hi = bounds
    return f"({', '.join(f'{v:g}' for v in lo)}), ({', '.join(f'{v:g}' for v in hi)})"


class ShapePanel(widgets.VBox):
    """Sliders, resolution and bounds controls, a live 3-D view, export and reset.

    Parameters
    ----------
    model : a pyfrep_core ``Model`` of dimension 3 with declared parameters.
    resolution : grid samples per axis of the full-resolution mesh.
    preview_resolution : samples per axis while a slider moves (None: always full).
    bounds : meshing box; default the model's bounds.
    backend : 3-D view backend ("auto", "trame", "image").
    threaded : mesh on a background thread; default: when a kernel's loop runs (notebooks, Voila).
    settle : seconds a slider must rest after a preview is built before the full-resolution mesh
        is started (0: at once; a newer move stops it anyway).
    sparse : mesh with ``polygonize(..., sparse=True)`` (f exactly only near the surface; the
        same mesh as the dense grid on the paper's shapes, see tests/test_mesh.py).  None (the
        default): sparse while the eager model meshes, dense once the compiled one does (its
        grid costs less than the sparse bookkeeping).
    compiled : evaluate through ``pyfrep_core.compiled.compiled(model)`` once its kernels are
        compiled: in the background after the first mesh when ``threaded``, else when
        :meth:`warm_up` is called.  False: always the eager model.

    Attributes
    ----------
    sliders : dict name -> FloatSlider.   view : :class:`MeshView`.   mesh : the Mesh shown.
    status : HTML status line ("remeshed in X ms, N triangles").
    """

    def __init__(
        self,
        model: Model,
        resolution: int = 128,
        preview_resolution: int | None = 64,
        bounds: Any = None,
        backend: str = "auto",
        threaded: bool | None = None,
        settle: float = 0.0,  # a key press: preview, then the full mesh at once
        colouring: str = "sensitivity",
        size: tuple[int, int] = (640, 480),
        export_dir: str | None = None,
        choices: dict[str, Model] | None = None,
        sparse: bool | None = None,
        compiled: bool = True,
    ):
        if not isinstance(model, Model):
            raise TypeError(f"model must be a pyfrep_core Model (declared with @model), got {type(model).__name__}")
        if model.dim != 3:
            raise ValueError(f"the shape panel meshes 3-D models; {model.__name__} has dim={model.dim}")
        bounds = check_bounds(bounds if bounds is not None else model.bounds, 3)
        self.model = model
        self.main = MainThread()
        self.threaded = self.main.has_loop if threaded is None else threaded
        self.preview_resolution = preview_resolution
        self.sparse = sparse
        self.compiled = compiled
        self._fast: dict[int, CompiledModel] = {}  # id(model) -> its compiled form, once warmed up
        self._warming: set[int] = set()
        self._not_compiled: set[int] = set()  # id(model) of models whose compilation failed: eager for good
        self._warm_lock = threading.Lock()
        self.warm_up_s: dict[str, float] = {}  # model name -> seconds its compilation took
        self.warm_up_errors: dict[str, Exception] = {}  # model name -> why it stays eager
        self.export_dir = export_dir
        self.mesh: Mesh | None = None
        self.exported: Mesh | None = None  # the last mesh written by export()
        self.scalars: np.ndarray | None = None
        self.last_moved: str | None = model.names[0] if model.names else None
        self.remesh_count = 0
        self.last_remesh_s = 0.0
        self.last_job: dict[str, Any] | None = None
        self._quiet = False

        self.sliders: dict[str, widgets.FloatSlider] = {}
        self.slider_box = widgets.VBox()
        self.title = widgets.HTML()
        self.choices = {model.__name__: model, **(choices or {})}
        self.choice = widgets.Dropdown(
            options=list(self.choices),
            value=model.__name__,
            description="model",
            layout=widgets.Layout(width="340px", display="flex" if choices else "none"),
        )
        self.resolution = widgets.Dropdown(
            options=sorted({*RESOLUTIONS, int(resolution)}),
            value=int(resolution),
            description="resolution",
            layout=widgets.Layout(width="200px"),
        )
        self.bounds = widgets.Text(
            value=_format_bounds(bounds),
            description="bounds",
            continuous_update=False,
            layout=widgets.Layout(width="340px"),
        )
        self.colouring = widgets.Dropdown(
            options=COLOURINGS, value=colouring, description="colour", layout=widgets.Layout(width="200px")
        )
        self.export_format = widgets.Dropdown(
            options=("stl", "obj", "ply"), value="stl", layout=widgets.Layout(width="70px")
        )
        self.export_button = widgets.Button(description="Export", layout=widgets.Layout(width="100px"))
        self.reset_button = widgets.Button(description="Reset", layout=widgets.Layout(width="100px"))
        self.status = widgets.HTML(value="meshing...")
        self.download = widgets.HTML(value="")
        self.view = MeshView(backend=backend, size=size, section=shows_inside(model))
        self._bounds_value = bounds
        self.worker = LatestWorker(self._build, self._show, self.main, settle=settle)
        self._warm_thread: threading.Thread | None = None
        self.push_pull = PushPullControls(self)  # click the surface, pull it: the sliders are solved for

        self._make_sliders(model)
        self.choice.observe(lambda change: self.set_model(self.choices[change["new"]]), names="value")
        self.export_button.on_click(lambda _: self.export())
        self.resolution.observe(lambda _: self.request(), names="value")
        self.bounds.observe(self._bounds_changed, names="value")
        self.colouring.observe(lambda _: self.request(), names="value")
        self.reset_button.on_click(lambda _: self.reset())

        self.legend = widgets.HTML(
            "<span style='font-size:13px'>colour = normal velocity v = -(&part;f/&part;p)/|&nabla;f| of the "
            "last parameter moved: red moves into the solid, blue outward (units per unit of p)</span>",
            layout=widgets.Layout(width="420px", display="" if colouring == "sensitivity" else "none"),
        )
        controls = widgets.VBox(
            [
                self.choice,
                self.title,
                self.slider_box,
                self.push_pull.widget,
                self.resolution,
                self.bounds,
                self.colouring,
                self.legend,
                widgets.HBox([self.export_format, self.export_button, self.reset_button]),
                self.download,
            ],
            layout=widgets.Layout(width="440px"),
        )
        super().__init__([widgets.HBox([controls, self.view.box]), self.status])
        self.request()

    def _make_sliders(self, model: Model) -> None:
        self.sliders = {name: param_slider(name, p) for name, p in model.params.items()}
        for name, slider in self.sliders.items():
            slider.observe(lambda change, name=name: self._moved(name), names="value")
        self.slider_box.children = tuple(self.sliders.values())
        doc = (model.__doc__ or "").strip().split("\n")[0].replace("``", "")
        title = f"<b>{html.escape(model.__name__)}</b>"
        self.title.value = f"{title} <span style='font-size: 13px'>{html.escape(doc)}</span>"

    def set_model(self, model: Model, bounds: Any = None) -> None:
        """Show another model in the same view (new sliders, its bounds, camera reset)."""
        if not isinstance(model, Model) or model.dim != 3:
            raise ValueError(f"the shape panel needs a 3-D Model, got {model!r}")
        self.model = model
        self.last_moved = model.names[0] if model.names else None
        # before the sliders: once they show, the page shows this model's section state too
        self.view.set_section(on=shows_inside(model), render=False)  # a lattice opens, a solid closes
        self._make_sliders(model)
        self._bounds_value = check_bounds(bounds if bounds is not None else model.bounds, 3)
        self.download.value = ""  # the last export was of the other model
        self._quiet = True
        try:
            self.bounds.value = _format_bounds(self._bounds_value)
        finally:
            self._quiet = False
        self.request(reset_camera=True)

    # -- compiled evaluation ---------------------------------------------------------------
    def evaluator(self, model: Model | None = None) -> Model:
        """What meshes ``model`` (default: the current one) now: its compiled form once warmed up, else itself."""
        model = self.model if model is None else model
        return self._fast.get(id(model), model)

    def warm_up(self, model: Model | None = None) -> float:
        """Compile ``model``'s kernels now (blocking; seconds taken; 0 when done before or disabled)."""
        model = self.model if model is None else model
        if not self.compiled or id(model) in self._fast or id(model) in self._not_compiled:
            return 0.0
        fast = compile_model(model)
        with self._warm_lock:  # one compilation at a time
            if id(model) in self._fast:
                return 0.0
            # the sparse grid (eager default, or asked for) also takes float32 gradients at its coarse nodes
            gradients = (torch.float32, torch.float64) if self.sparse else (torch.float64,)
            seconds = warm_up(fast, {name: p.default for name, p in model.params.items()}, gradients=gradients)
            if fast.failure is None:
                self._fast[id(model)] = fast
            else:  # torch.compile gave up (the wrapper fell back to eager): do not try again
                self._not_compiled.add(id(model))
                self.warm_up_errors[model.__name__] = fast.failure
            self.warm_up_s[model.__name__] = seconds
        return seconds

    def _warm_up_soon(self) -> None:
        """Compile the current model on a background thread (live panels only), once."""
        model = self.model
        done = id(model) in self._fast or id(model) in self._warming or id(model) in self._not_compiled
        if not (self.compiled and self.threaded) or done:
            return
        self._warming.add(id(model))

        def run() -> None:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # a failure leaves the eager model in use; status says so
                    self.warm_up(model)
            except Exception as err:  # noqa: BLE001  (whatever the compiler raised: the eager model stays)
                self._not_compiled.add(id(model))
                self.warm_up_errors[model.__name__] = err
            finally:
                self._warming.discard(id(model))

        self._warm_thread = threading.Thread(target=run, name="pyfrep-warm-up", daemon=True)
        self._warm_thread.start()

    # -- requests ------------------------------------------------------------------------
    @property
    def params(self) -> dict[str, float]:
        """Current slider values."""
        return {name: float(s.value) for name, s in self.sliders.items()}

    def _moved(self, name: str) -> None:
        if self._quiet:
            return
        self.last_moved = name
        self.request()

    def _bounds_changed(self, change: dict) -> None:
        if self._quiet:
            return
        try:
            value = ast.literal_eval(change["new"])
            self._bounds_value = check_bounds(value, 3)
        except (ValueError, SyntaxError, TypeError) as err:
            self.status.value = f"<span style='color:#b00'>bounds not accepted: {html.escape(str(err))}</span>"
            return
        self.request()

    def request(self, full: bool = False, reset_camera: bool = False) -> None:
        """Ask for a new mesh of the current state (coalesced with requests not yet started)."""
        res = int(self.resolution.value)
        job = {
            "model": self.model,
            "params": self.params,
            "resolution": res,
            "bounds": self._bounds_value,
            "moved": self.last_moved,
            "colouring": self.colouring.value,
            "reset_camera": reset_camera,
        }
        if not self.threaded:
            self.main.call(lambda: self._show(job, *self._run_inline(job)))
            return
        # last, where the model has interval bounds: dual contouring (sharp edges kept), after the
        # marching-cubes mesh of the same resolution is shown (that one comes 3-5x sooner)
        sharp = {**job, "followup": True, "sharp": True} if supports(self.model) else None
        preview = self.preview_resolution
        if full or preview is None or preview >= res:
            self.worker.submit(job, followup=sharp)
        else:
            preview_job = {**job, "resolution": int(preview), "preview": True}
            self.worker.submit(preview_job, followup={**job, "followup": True, "then": sharp})

    def _run_inline(self, job: dict) -> tuple[Any, Exception | None]:
        try:
            return self._build(job), None
        except Exception as err:
            return None, err

    def wait(self, timeout: float = 120.0) -> None:
        """Block until the requested meshes are built and shown (scripts and tests)."""
        self.worker.wait(timeout)

    # -- work (background thread) ------------------------------------------------------------
    def _build(self, job: dict) -> dict:
        t0 = time.perf_counter()
        params = job["params"]  # the job's own: the panel may have moved on
        model = self.evaluator(job["model"])
        fused = isinstance(model, CompiledModel)
        sparse = (not fused) if self.sparse is None else self.sparse
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            # a preview keeps marching cubes' vertices (it is replaced a moment later); the followups
            # (marching cubes at full resolution, then dual contouring where the model has interval
            # bounds: its boxes go through the eager model, its points through the same kernels) stop
            # when a newer move arrives (the worker then drops them); moves meshed inline stay on
            # marching cubes
            dc = bool(job.get("sharp"))
            f = functools.partial(model, **params)  # polygonize reads the chunk size
            stop = self.worker.superseded if job.get("followup") else None
            mesh = polygonize(
                f,
                job["bounds"],
                job["resolution"],
                sparse=sparse,
                project=not job.get("preview"),
                stop=stop,
                method="dc" if dc else "mc",
            )
        scalars = None
        if job["colouring"] == "sensitivity" and job["moved"] is not None and not mesh.is_empty():
            scalars = surface_velocity(model, mesh, job["moved"], params)
        note = "; ".join(str(w.message) for w in caught)
        seconds = time.perf_counter() - t0
        return {"mesh": mesh, "scalars": scalars, "seconds": seconds, "note": note, "compiled": fused, "dc": dc}

    # -- display (main thread) -------------------------------------------------------------
    def _show(self, job: dict, result: dict | None, error: Exception | None) -> None:
        if error is not None:
            self.status.value = (
                f"<span style='color:#b00'>{html.escape(type(error).__name__)}: {html.escape(str(error))}</span>"
            )
            return
        mesh, scalars = result["mesh"], result["scalars"]
        self.mesh, self.scalars, self.last_job = mesh, scalars, job
        title = ""
        clim = None
        if scalars is not None:
            clim = symmetric_range(scalars)  # diverging map centred on 0
            title = f"v ({job['moved']})"
        self.view.update(
            mesh, scalars=scalars, title=title, cmap="coolwarm", clim=clim, reset_camera=job["reset_camera"]
        )
        self.legend.layout.display = "" if scalars is not None else "none"  # says what the colours mean
        self.remesh_count += 1
        self.last_remesh_s = result["seconds"]
        values = ", ".join(f"{k} = {v:.4g}" for k, v in job["params"].items())
        extra = f" <span style='color:#a60'>({html.escape(result['note'])})</span>" if result["note"] else ""
        how = "compiled" if result["compiled"] else "eager"
        self._warm_up_soon()  # after the first mesh is built, so that it does not wait for the compiler
        model = job["model"]
        evaluated_eagerly = not result["compiled"]
        if evaluated_eagerly and id(model) in self._warming:
            extra += "; compiling the model's kernels in the background"
        elif evaluated_eagerly and model.__name__ in self.warm_up_errors:
            error = self.warm_up_errors[model.__name__]
            extra += f"; not compiled ({html.escape(type(error).__name__)}): eager"
        method = ", dual contouring" if result.get("dc") else ""
        self.status.value = (
            f"remeshed in {1000 * result['seconds']:.0f} ms ({how}), {mesh.n_faces} triangles "
            f"({job['resolution']}&sup3;{method}; {values}); view {1000 * self.view.last_render_s:.0f} ms{extra}"
        )

    # -- buttons ------------------------------------------------------------------------------
    def reset(self) -> None:
        """Parameters back to their declared defaults (one remesh)."""
        self._quiet = True
        try:
            for name, slider in self.sliders.items():
                slider.value = self.model.params[name].default
        finally:
            self._quiet = False
        self.request()

    def export(self, path: str | None = None) -> str:
        """Write the shown shape as STL/OBJ/PLY and offer it as a browser download; returns the path.

        The file holds ``polygonize(..., method="auto")`` of the shown parameters, bounds and full
        resolution: dual contouring (sharp edges and corners kept) where the model has interval
        bounds, else the marching-cubes mesh; it is kept as ``exported``.  With no ``path`` (and no
        ``export_dir``) the file goes to the kernel's temporary export directory, never the working
        tree, and the link streams it (:mod:`workbench.downloads`).
        """
        if self.mesh is None or self.mesh.is_empty() or self.last_job is None:
            self.status.value = "<span style='color:#b00'>nothing to export yet</span>"
            return ""
        job = self.last_job
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an empty mesh is reported by the shown one
            self.exported = polygonize(
                functools.partial(job["model"], **job["params"]),
                job["bounds"],
                int(self.resolution.value),
                method="auto",
                progress=False,
            )
        from .downloads import downloads

        fmt = self.export_format.value
        name = f"{self.model.__name__}.{fmt}"
        served = path is None and self.export_dir is None
        if path is None:
            path = downloads().new_path(name) if served else os.path.join(self.export_dir, name)
        self.exported.save(path)
        if served:
            self.download.value = downloads().link(path)
        else:
            self.download.value = f"saved to {html.escape(path)}"
        return path


def paper_shape_panel(backend: str = "auto", **kwargs: Any) -> ShapePanel:
    """The shape panel with a chooser of the paper's 3-D shapes (Fig. 1 part first)."""
    from .app import paper_models

    choices = paper_models(dim=3)
    first = next(iter(choices.values()))
    return ShapePanel(first, backend=backend, choices=choices, **kwargs)


def shape_panel(model: Model, **kwargs: Any) -> ShapePanel:
    """The shape panel for any parametric model: ``workbench.shape_panel(my_model)``.

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part
    >>> panel = shape_panel(fig1_part, resolution=32, backend="image", threaded=False)
    >>> panel.sliders["r"].value = 0.35  # Fig. 2, left
    >>> panel.status.value.startswith("remeshed in")
    True
    >>> panel.view.close()
    """
    return ShapePanel(model, **kwargs)
