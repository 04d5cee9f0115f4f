"""Fitting panel: recover a model's parameters from a point cloud or a mesh (paper section 5.4, Figs. 7 and 8).

A fit's journey: points (generated at hidden parameters, optionally moved to a random pose and
with outliers added, or loaded from a mesh or point file) -> ``pyfrep_core.fit`` with the pose,
residual, loss and starts chosen here (on a background thread; Stop sets its ``stop`` flag) ->
progress events -> live loss chart (log scale, one series per stage) and parameter trajectories
against the true values -> the cloud coloured by each point's residual (with its colour bar), the
outliers the robust loss found drawn apart in red, the fitted surface overlaid, and the fitted
values with their standard errors beside the true ones.

What a new model or a new cloud replaces: the charts, the progress bar, the table and the
fitted surface of the previous fit are cleared.  The camera frames the data of a new model or
file; after that it stays where the user turned it (a new cloud of the same model, a fit's
result), unless the new cloud leaves the box it framed or is much smaller (a new random pose).
"""

from __future__ import annotations

import html
import os
import tempfile
import time
from typing import Any

import ipywidgets as widgets
import numpy as np

from pyfrep_core import Mesh, Model, polygonize

from ._threads import BackgroundRun, MainThread
from .charts import LineChart
from .view import MeshView

# a wrapped progress line at text spacing (an HTML widget's line is a control high, 28 px)
PROGRESS_STYLE = "style='display:inline-block;line-height:1.35'"

__all__ = ["FittingPanel", "fitting_panel", "EFFORT", "POSES", "STARTS"]

# fit() settings per effort level: "quick" answers in seconds, "paper" uses the paper's budgets.
EFFORT: dict[str, dict[str, Any]] = {
    "quick": {"cycles": 300, "population_size": 50, "epochs": 5, "batch_size": 1024, "polish_iters": 20, "every": 1},
    "paper": {"cycles": 10_000, "epochs": 100, "polish_iters": 50, "every": 10},
}
ROBUST_POLISH = 100  # a robust loss's polish reweights in rounds: at least this many evaluations
POSES: dict[str, Any] = {"off": False, "rigid": True, "rigid + scale": "scale"}
STARTS: tuple[Any, ...] = ("auto", 1, 2, 4, 8, 16)
MESH_EXTENSIONS = (".stl", ".obj", ".off", ".vtk", ".vtp")
OUTLIER_COLOUR = "#d62728"


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


def random_pose(size: float, seed: int) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """A random rigid motion x -> R x + t: R (3, 3), t (3,) and its pose parameters (tx .. rz).

    The rotation vector has a uniform direction and an angle up to pi; t is up to ``size`` per axis.
    ``pyfrep_core.pose.posed`` with these parameters moves the solid the same way.

    Examples
    --------
    >>> R, t, pose = random_pose(2.0, seed=0)
    >>> bool(np.allclose(R @ R.T, np.eye(3))), sorted(pose)
    (True, ['rx', 'ry', 'rz', 'tx', 'ty', 'tz'])
    """
    import torch

    from pyfrep_core.pose import rotation_matrix

    rng = np.random.default_rng(seed + 1000)
    axis = rng.normal(size=3)
    rotvec = axis / np.linalg.norm(axis) * rng.uniform(0.3, np.pi)
    shift = rng.uniform(-size, size, 3)
    R = rotation_matrix(*torch.tensor(rotvec, dtype=torch.float64)).numpy()
    pose = dict(zip(("tx", "ty", "tz"), map(float, shift))) | dict(zip(("rx", "ry", "rz"), map(float, rotvec)))
    return R, shift, pose


def _box(points: np.ndarray, pad: float = 0.1) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The points' box grown by ``pad`` of its largest extent on each side."""
    lo, hi = points.min(0), points.max(0)
    margin = pad * float(np.max(hi - lo)) or 1.0
    return tuple((lo - margin).tolist()), tuple((hi + margin).tolist())


class FittingPanel(widgets.VBox):
    """Model and data choice, fit options, Run/Stop, live charts, residual-coloured cloud and fitted surface.

    Parameters
    ----------
    models : name -> Model offered in the chooser (3-D models).
    n_points, noise, seed : the generated cloud (noise: standard deviation in length units).
    outliers : fraction of uniform outliers added to a generated cloud.
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
        outliers: float = 0.0,
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
        self.points: np.ndarray | None = None  # what is shown (and fitted, for arrays)
        self.data: Any = None  # what fit() gets: the points, or a loaded Mesh / PointCloud
        self.data_name = ""
        self.truth: dict[str, float] | None = None
        self.true_pose: dict[str, float] | None = None
        self.planted: np.ndarray | None = None  # which generated points are planted outliers
        self.result: Any = None
        self.run: BackgroundRun | None = None
        self.events: list[Any] = []
        self._offsets: dict[str, int] = {}
        self._last_x: dict[str, int] = {}  # the last x charted per stage
        self._next_x = 0
        self._first_loss: float | None = None
        self._generation = 0  # bumped when the data or model changes: a late fit of old data is not drawn
        self._framed: np.ndarray | None = None  # (2, 3) box of the cloud the camera was last fitted to

        lay = widgets.Layout(width="300px")
        self.model_choice = widgets.Dropdown(options=list(self.models), description="model", layout=lay)
        self.source = widgets.ToggleButtons(options=["generated", "file"], value="generated", description="cloud")
        self.source.style.button_width = "90px"
        self.n_points = widgets.BoundedIntText(value=n_points, min=10, max=1_000_000, description="points", layout=lay)
        self.noise = widgets.BoundedFloatText(
            value=noise, min=0.0, max=1e6, step=0.005, description="noise", layout=lay
        )
        self.outliers = widgets.BoundedFloatText(
            value=outliers, min=0.0, max=0.5, step=0.01, description="outliers", layout=lay,
            tooltip="fraction of points added uniformly in the cloud's box",
        )  # fmt: skip
        self.moved = widgets.Checkbox(
            value=False,
            description="random pose",
            indent=False,
            tooltip="move the generated cloud by a random rigid motion",
        )
        self.seed = widgets.IntText(value=seed, description="seed", layout=lay)
        self.upload = widgets.FileUpload(
            accept=".xyz,.ply,.stl,.obj,.off,.vtk", multiple=False, description="mesh / cloud file"
        )
        self.pose = widgets.Dropdown(options=list(POSES), value="off", description="pose", layout=lay)
        self.residual = widgets.Dropdown(
            options=["auto", "algebraic", "geometric"], value="auto", description="residual", layout=lay
        )
        self.loss = widgets.Dropdown(
            options=["l2", "huber", "cauchy", "trimmed"], value="l2", description="loss", layout=lay
        )
        self.starts = widgets.Dropdown(options=list(STARTS), value="auto", description="starts", layout=lay)
        self.effort = widgets.Dropdown(options=list(EFFORT), value=effort, description="effort", layout=lay)
        self.new_cloud = widgets.Button(description="New cloud")
        self.run_button = widgets.Button(description="Run", button_style="success")
        self.stop_button = widgets.Button(description="Stop", button_style="danger", disabled=True)
        self.bar = widgets.IntProgress(value=0, min=0, max=1, description="", layout=widgets.Layout(width="300px"))
        self.progress_text = widgets.HTML("")
        self.table = widgets.HTML("")
        self.status = widgets.HTML("")
        schedule = lambda fn: self.main.call(fn, vtk=False)  # noqa: E731
        self.loss_chart = LineChart("loss per stage", "step", "loss", logy=True, schedule=schedule)
        self.param_chart = LineChart("parameters (dashed: true values)", "step", "value", schedule=schedule)
        self.view = MeshView(backend=backend, size=size)

        # these render: on the main thread (JupyterLab may call back on a subshell thread)
        self.new_cloud.on_click(lambda _: self.main.call(self.make_cloud))
        self.model_choice.observe(lambda _: self.main.call(self._model_changed), names="value")
        self.upload.observe(lambda _: self.main.call(self._uploaded), names="value")
        self.run_button.on_click(lambda _: self.start())
        self.stop_button.on_click(lambda _: self.stop())

        controls = widgets.VBox(
            [
                self.model_choice,
                self.source,
                self.n_points,
                self.noise,
                self.outliers,
                widgets.HBox([self.moved]),
                self.seed,
                widgets.HBox([self.new_cloud, self.upload]),
                widgets.HTML("<b>fit</b>"),
                self.pose,
                self.residual,
                self.loss,
                self.starts,
                self.effort,
                widgets.HBox([self.run_button, self.stop_button]),
                self.bar,
                self.progress_text,
            ],
            layout=widgets.Layout(width="320px"),
        )
        charts = widgets.VBox([self.loss_chart.widget, self.param_chart.widget])
        super().__init__([widgets.HBox([controls, self.view.box, charts]), self.status, self.table])
        self.make_cloud()

    @property
    def model(self) -> Model:
        return self.models[self.model_choice.value]

    # -- the data ---------------------------------------------------------------------------
    def _model_changed(self) -> None:
        """A new model: a new generated cloud of it, or the loaded file kept for the new model."""
        if self.source.value == "file" and self.points is not None:
            self._reset()
            self.truth = None
            self._show_cloud(frame=True)
            self.status.value = f"model {html.escape(self.model.__name__)}; data {html.escape(self.data_name)}"
        else:
            self.make_cloud(frame=True)

    def make_cloud(self, frame: bool = False) -> None:
        """Sample the chosen model at hidden parameter values (plus noise, pose and outliers) and show the cloud.

        ``frame``: fit the camera to the cloud (a new model); otherwise the user's camera is kept
        while the cloud stays within the box it framed.
        """
        from pyfrep_core.sampling import sample_surface

        seed = int(self.seed.value)
        truth = hidden_params(self.model, seed)
        try:
            pts = sample_surface(
                self.model, int(self.n_points.value), params=truth, noise=float(self.noise.value), seed=seed,
                resolution=64,
            )  # fmt: skip
        except Exception as err:
            self._error(err)
            return
        self.true_pose = None
        if self.moved.value:
            lo, hi = np.asarray(self.model.bounds[0]), np.asarray(self.model.bounds[1])
            R, t, self.true_pose = random_pose(float(np.max(hi - lo)), seed)
            pts = pts @ R.T + t
        n_out = int(round(float(self.outliers.value) * len(pts)))
        planted = np.zeros(len(pts) + n_out, bool)
        if n_out:
            lo, hi = _box(pts, 0.05)
            stray = np.random.default_rng(seed + 1).uniform(lo, hi, (n_out, 3))
            pts = np.vstack([pts, stray])
            planted[-n_out:] = True
        self._reset()
        self.points, self.data, self.truth, self.planted = pts, pts, truth, planted
        self.data_name = "generated cloud"
        self.source.value = "generated"
        self._show_cloud(frame=frame)
        moved = ", moved to a random pose" if self.true_pose else ""
        stray = f", {n_out} outliers" if n_out else ""
        self.status.value = f"{len(pts)} points sampled at hidden parameters (noise {self.noise.value:g}{moved}{stray})"

    def load_cloud(self, path: str, name: str | None = None) -> None:
        """Use a mesh file (.stl .obj .off .vtk, or a .ply with faces) or a point file (.xyz, .ply).

        A mesh is fitted on its vertices and points drawn by area (``fit`` does it); a cloud on its
        points.  True values are unknown.  ``name``: what the status calls the file (an upload's own
        name, not the temporary file holding it).
        """
        from pyfrep_core.io import load_mesh, load_points
        from pyfrep_core.sampling import sample_mesh

        name = name or os.path.basename(path)
        ext = os.path.splitext(path)[1].lower()
        try:
            data: Any = None
            if ext in MESH_EXTENSIONS or ext == ".ply":
                try:
                    data = load_mesh(path)
                except ValueError:
                    if ext != ".ply":
                        raise
                if data is not None and len(data.faces) == 0:
                    data = None  # a .ply of points only
            if isinstance(data, Mesh):
                rng = np.random.default_rng(int(self.seed.value))
                points = np.vstack([data.vertices, sample_mesh(data, int(self.n_points.value), rng)])
                what = f"mesh {html.escape(name)}: {data.n_vertices} vertices, {len(data.faces)} triangles"
            else:
                data = load_points(path)
                points = np.asarray(getattr(data, "points", data), dtype=np.float64)
                what = f"{len(points)} points loaded from {html.escape(name)}"
        except Exception as err:
            self._error(err)
            return
        self._reset()
        self.points, self.data, self.data_name = points, data, name
        self.truth, self.true_pose, self.planted = None, None, None
        self.source.value = "file"
        self._show_cloud(frame=True)
        self.status.value = what

    def _uploaded(self) -> None:
        files = self.upload.value
        if not files:
            return
        item = files[0]
        suffix = os.path.splitext(item["name"])[1] or ".xyz"
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "upload" + suffix)
            with open(path, "wb") as fh:
                fh.write(bytes(item["content"]))
            self.load_cloud(path, name=item["name"])

    def _reset(self) -> None:
        """Forget the previous fit: charts, progress bar, table, fitted surface, outliers."""
        self._generation += 1
        if self.run is not None and self.run.running:
            self.run.stop.set()  # its result belongs to the old data: not drawn (see _finished)
            self.run_button.disabled, self.stop_button.disabled = False, True
        self.result = None
        self.events = []
        self._offsets, self._last_x, self._next_x, self._first_loss = {}, {}, 0, None
        self.loss_chart.clear()
        self.param_chart.clear()
        self.loss_chart.refresh(force=True)
        self.param_chart.refresh(force=True)
        self.bar.value, self.bar.max, self.bar.description, self.bar.bar_style = 0, 1, "", ""
        self.progress_text.value = ""
        self.table.value = ""
        self.view.hide_surface()
        self.view.overlay_points(None, name="outliers")

    def _show_cloud(self, frame: bool = False) -> None:
        """The data alone (the stale surface hidden); the camera framing it when asked or needed."""
        camera = self.view.plotter.camera_position
        self.view.hide_surface()
        self.view.overlay_points(None, name="outliers")
        self.view.overlay_points(self.points)
        lo, hi = self.points.min(0), self.points.max(0)
        if frame or self._framed is None or self._outgrown(lo, hi):
            self.view.render(reset_camera=True)
            self._framed = np.array([lo, hi])
        else:
            self.view.plotter.camera_position = camera  # the user's, whatever the view did meanwhile
            self.view.render()

    def _outgrown(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """The cloud (box lo..hi) leaves the framed box by over 5 % of its size, or is under half its size."""
        old_lo, old_hi = self._framed
        size = float(np.linalg.norm(old_hi - old_lo))
        outside = bool(np.any(lo < old_lo - 0.05 * size) or np.any(hi > old_hi + 0.05 * size))
        return outside or float(np.linalg.norm(hi - lo)) < 0.5 * size

    # -- running ------------------------------------------------------------------------------
    def settings(self, **overrides: Any) -> dict[str, Any]:
        """The keyword arguments of ``fit`` for the chosen options (``overrides`` last)."""
        starts = self.starts.value
        cfg = {
            **EFFORT[self.effort.value],
            "pose": POSES[self.pose.value],
            "residual": self.residual.value,
            "loss": self.loss.value,
            "starts": None if starts == "auto" else int(starts),
            "seed": int(self.seed.value),
        }
        if cfg["loss"] != "l2" and "polish_iters" in cfg:
            cfg["polish_iters"] = max(cfg["polish_iters"], ROBUST_POLISH)
        return {**cfg, **overrides}

    def start(self, **overrides: Any) -> BackgroundRun | None:
        """Run the fit on a background thread; returns the run (``.wait()`` blocks until done)."""
        if self.run is not None and self.run.running:
            return self.run
        if self.points is None:
            self.status.value = "<span style='color:#b00'>no points to fit</span>"
            return None
        from pyfrep_core.fitting import fit, fit_error

        model, data, points = self.model, self.data, self.points
        settings = self.settings(**overrides)
        generation = self._generation
        self._clear_fit()
        # a loaded file has no true values: no dashed lines, and the title does not promise them
        self.param_chart.title = "parameters" + (" (dashed: true values)" if self.truth is not None else "")
        if self.truth is not None:
            references = dict(self.truth)
            if settings["pose"] and self.true_pose:
                references.update(self.true_pose)
            for k, v in references.items():
                self.param_chart.set_reference(k, v)
        self.run_button.disabled, self.stop_button.disabled = True, False
        self.status.value = f"fitting {html.escape(model.__name__)} to {html.escape(self.data_name)}..."
        self._t0 = time.perf_counter()

        def target(stop: Any) -> Any:
            result = fit(model, data, callback=self._event, stop=stop, progress=False, **settings)
            fitted = result.model if result.model is not None else model
            shown = result.points if result.points is not None else points
            distance = fit_error(fitted, shown, result.params, residual=result.residual)
            # dual contouring where the fitted model has interval bounds (its sharp edges kept)
            surface = polygonize(
                lambda x: fitted(x, **result.params), _box(shown), self.resolution, method="auto", progress=False
            )
            return result, surface, shown, distance

        self.run = BackgroundRun(target, lambda out, err: self._finished(out, err, generation), self.main).start()
        return self.run

    def stop(self) -> None:
        """Ask the running fit to end (it returns the best parameters so far)."""
        if self.run is not None:
            self.run.stop.set()
            self.status.value = "stopping..."

    def _clear_fit(self) -> None:
        self.events = []
        self._offsets, self._last_x, self._next_x, self._first_loss = {}, {}, 0, None
        self.loss_chart.clear()
        self.param_chart.clear()
        self.bar.value, self.bar.max, self.bar.description, self.bar.bar_style = 0, 1, "", ""
        self.progress_text.value = ""
        self.table.value = ""

    def _event(self, event: Any) -> None:
        """Progress callback (worker thread): chart points, progress text, bar."""
        self.events.append(event)
        if event.stage not in self._offsets:
            self._offsets[event.stage] = self._next_x
        x = self._offsets[event.stage] + event.step
        last = self._last_x.get(event.stage)
        if last is not None and x <= last:  # a stage whose count restarts (the polish's reweighting rounds)
            self._offsets[event.stage] += last + 1 - x
            x = last + 1
        self._last_x[event.stage] = x
        self._next_x = max(self._next_x, x + 1)
        if np.isfinite(event.loss):
            self.loss_chart.add(event.stage, x, max(event.loss, 1e-300))
            if self._first_loss is None:
                self._first_loss = event.loss
        params = event.params() if callable(event.params) else event.params
        for k, v in (params or {}).items():
            self.param_chart.add(k, x, v)
        self.loss_chart.refresh()
        self.param_chart.refresh()
        self.main.call(self._progress_text, event, vtk=False)

    def _progress_text(self, event: Any) -> None:
        if self.run is None or not self.run.running:
            return  # a late event after the end: the bar already says done
        self.bar.max = max(1, event.total)
        self.bar.value = min(event.step + 1, event.total)
        self.bar.description = event.stage
        first = "" if self._first_loss is None else f" (first {self._first_loss:.3e})"
        self.progress_text.value = (
            f"<span class='fit-progress' {PROGRESS_STYLE}>"
            f"{html.escape(event.stage)} {event.step + 1}/{event.total} &middot; "
            f"loss {event.loss:.3e}{first} &middot; {self.loss_chart.n_points} points charted</span>"
        )

    def _finished(self, output: Any, error: BaseException | None, generation: int) -> None:
        """On the main thread: final charts, coloured cloud, outliers, fitted surface, table, summary."""
        self.run_button.disabled, self.stop_button.disabled = False, True
        if generation != self._generation:
            return  # the data or the model changed while it ran: its result is not about what is shown
        self.loss_chart.refresh(force=True)
        self.param_chart.refresh(force=True)
        self.bar.max = max(self.bar.max, 1)
        self.bar.value = self.bar.max  # the run is over, whatever step the last event was
        if error is not None:
            self.bar.description, self.bar.bar_style = "error", "danger"
            self._error(error)
            return
        result, surface, shown, distance = output
        self.result = result
        self.bar.description = "stopped" if result.stopped else "done"
        self.bar.bar_style = "warning" if result.stopped else "success"
        inliers = result.inliers if result.inliers is not None and len(result.inliers) == len(shown) else None
        if inliers is None:
            inliers = np.ones(len(shown), bool)
        unit = f" ({result.units})" if result.units else ""
        # no "|" in a VTK caption: its text renderer takes them for markup
        what = "distance to the fit" if result.residual == "geometric" else "absolute residual f"
        kept = distance[inliers]
        top = float(np.percentile(kept, 99)) if len(kept) else 1.0
        camera = self.view.plotter.camera_position  # the cloud is framed already: the user's camera stays
        if surface.is_empty():
            self.view.hide_surface()
        else:
            self.view.update(surface)  # plain grey: the cloud's colours own the bar
            self.view.set_opacity(0.45)
        self.view.overlay_points(shown[inliers], distance[inliers], f"{what}{unit}", clim=(0.0, top), bar=True)
        n_out = int((~inliers).sum())
        self.view.overlay_points(shown[~inliers] if n_out else None, name="outliers", color=OUTLIER_COLOUR)
        self.view.plotter.camera_position = camera
        self.view.render()
        self.table.value = self._table(result)
        first = "" if self._first_loss is None else f" (first {self._first_loss:.3e})"
        self.progress_text.value = (  # the last word on the run: no stale 'polish 3/20'
            f"<span class='fit-progress' {PROGRESS_STYLE}>{self.bar.description}: {', '.join(result.stages)} &middot; "
            f"loss {result.loss:.3e}{first} &middot; {self.loss_chart.n_points} points charted</span>"
        )
        stopped = " <b>(stopped early)</b>" if result.stopped else ""
        found = ""
        if self.planted is not None and len(self.planted) == len(shown) and self.planted.any():
            hit = int((~inliers & self.planted).sum())
            found = f" ({hit} of the {int(self.planted.sum())} planted)"
        if n_out > 0.5 * len(shown):
            found += (
                " &mdash; most points: the robust noise scale is about 0 (noise-free points?); "
                "use the l2 loss or give a loss scale"
            )
        reason = f"<br>standard errors: {html.escape(result.std_error_reason)}" if result.std_error_reason else ""
        self.status.value = (
            f"<span class='fit-done'>fit done in {time.perf_counter() - self._t0:.1f} s{stopped} "
            f"on {html.escape(self.data_name)}: "
            f"loss {result.loss:.3e}, stages {', '.join(result.stages)}; "
            f"{html.escape(result.residual)} residual, {html.escape(result.loss_function)} loss, "
            f"{len(result.starts) or 1} start(s); RMS {result.rms:.3g}{unit}, max {result.max_distance:.3g}{unit}; "
            f"{n_out} outliers{found} drawn in red</span><br>cloud coloured by the {what}{unit} of the "
            f"inliers (viridis, 0 dark to {top:.2g} yellow, 99th percentile); fitted surface translucent; "
            f"polish: {html.escape(result.termination)}{reason}"
        )

    def _table(self, result: Any) -> str:
        """Fitted values with standard errors, against the true ones where known."""
        truth = dict(self.truth or {})
        if self.true_pose and self.pose.value != "off":
            truth.update(self.true_pose)
        known = bool(truth)
        head = "<tr><th>param</th><th>fitted</th><th>&plusmn; s.e.</th>" + (
            "<th>true</th><th>|error|</th><th>error / s.e.</th>" if known else ""
        ) + "</tr>"  # fmt: skip
        rows = []
        for k, v in result.params.items():
            se = result.std_errors.get(k)
            se = se if se is not None and np.isfinite(se) and se > 0 else None
            se_text = "&mdash;" if se is None else f"{se:.2g}"
            row = f"<tr><td>{html.escape(k)}</td><td>{v:.6g}</td><td>{se_text}</td>"
            if known:
                if k in truth:
                    err = abs(v - truth[k])
                    z = f"{err / se:.2f}" if se else "&mdash;"
                    row += f"<td>{truth[k]:.6g}</td><td>{err:.2e}</td><td>{z}</td>"
                else:
                    row += "<td></td><td></td><td></td>"
            rows.append(row + "</tr>")
        return f"<table class='fit-table'>{head}{''.join(rows)}</table>"

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
    """The fitting panel with the paper's 3-D shapes (Fig. 1 part first; microstructure for Figs. 7, 8)
    and the machined test parts of ``pyfrep_core.models.cad_parts`` (millimetres)."""
    if models is None:
        from pyfrep_core.models.cad_parts import PARTS

        from .app import paper_models

        models = {**paper_models(dim=3), **PARTS}
    return FittingPanel(models, backend=backend, **kwargs)
