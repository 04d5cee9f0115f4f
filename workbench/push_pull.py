"""Push-pull on the surface: click a point in the 3-D view, drag or type how far to move it.

The click goes to the view's own VTK interactor (the trame view is rendered on the server and
forwards mouse events to it), where a cell picker finds the surface point under the pixel; a
press-and-drag still turns the camera, only a click picks.  The "pull" slider is the distance
along the outward normal at that point; each value is solved for by
:func:`pyfrep_core.push_pull.push_pull` from the parameters at the time of the pick (so
dragging back and forth is consistent) and the shape panel's sliders are set to the result:
one remesh, coloured by the parameter that changed most.
"""

from __future__ import annotations

import html
from typing import Any

import ipywidgets as widgets
import numpy as np
import pyvista as pv

from pyfrep_core.push_pull import push_pull

from ._threads import LatestWorker

__all__ = ["PushPullControls"]


class PushPullControls:
    """Push-pull controls attached to a :class:`~workbench.shape_panel.ShapePanel`.

    Attributes
    ----------
    widget : the controls (an instruction, the pull slider, a status line) to place in a layout.
    pull : the FloatSlider of the displacement (length units, > 0 outward).
    point : (3,) the picked point, or None.   base : the parameters at the pick.
    result : the last :class:`~pyfrep_core.push_pull.PushPull`.
    """

    def __init__(self, panel: Any):
        self.panel = panel
        self.point: np.ndarray | None = None
        self.base: dict[str, float] | None = None
        self.model: Any = None
        self.result: Any = None
        self._applied: dict[str, float] | None = None
        self._quiet = False
        self.marker = pv.PolyData()
        self.marker_actor: Any = None
        self.pull = widgets.FloatSlider(
            value=0.0,
            min=-0.25,
            max=0.25,
            step=0.0025,
            description="pull",
            disabled=True,
            continuous_update=True,
            readout_format=".4f",
            tooltip="distance along the outward normal at the picked point (type a value in the box)",
            style={"description_width": "110px"},
            layout=widgets.Layout(width="340px"),
        )
        self.status = widgets.HTML(layout=widgets.Layout(width="340px"))
        self._say(
            "click the surface to pick a point, then drag or type the pull "
            "(the parameters that move it there are solved for, within their ranges)"
        )
        self.widget = widgets.VBox([self.status, self.pull])
        self.worker = LatestWorker(self._solve, self._solved, panel.main, settle=0.0)
        self.pull.observe(self._pulled, names="value")
        plotter = panel.view.plotter
        try:  # a click (not a drag) on the surface picks; the view's camera keeps its drag
            plotter.enable_surface_point_picking(
                callback=self._clicked, show_message=False, show_point=False, left_clicking=True, picker="cell"
            )
            self.picking = True
        except Exception as err:  # noqa: BLE001  (no interactor: pick() still works from code)
            self.picking = False
            self._say(f"clicking not available ({html.escape(str(err))}): pick() from code")

    def _say(self, text: str) -> None:
        """The status line (its own line height: the widget's is one control high)."""
        self.status.value = f"<div style='line-height:1.35;font-size:12px'><b>push-pull</b>: {text}</div>"

    # -- picking --------------------------------------------------------------------------------
    def _clicked(self, point: Any) -> None:
        if point is None:
            return
        self.pick(np.asarray(point, dtype=np.float64))

    def click(self, x: int, y: int) -> None:
        """A left click at pixel (x, y) of the view (VTK's display coordinates, origin bottom left)."""
        iren = self.panel.view.plotter.iren.interactor
        iren.SetEventInformation(int(x), int(y))
        iren.InvokeEvent("LeftButtonPressEvent")
        iren.InvokeEvent("LeftButtonReleaseEvent")

    def pick(self, point: Any) -> None:
        """Pick ``point`` (3,) on the surface: the pull starts from the current parameters, at 0."""
        point = np.asarray(point, dtype=np.float64).reshape(3)
        self.point, self.model = point, self.panel.model
        self.base = dict(self.panel.params)
        self._applied = dict(self.base)
        from .shape_panel import slider_step  # (the shape panel imports this module)

        lo, hi = self.panel._bounds_value
        size = float(np.max(np.subtract(hi, lo)))
        # +-size/4 on a grid of 1, 2 or 5 x 10^k through 0: a typed 0.05 stays 0.05 in the browser
        step = slider_step(-size / 4, size / 4, 0.0) / 2
        half = step * round(size / 4 / step)
        self._quiet = True
        try:
            self.pull.disabled = False
            self.pull.max, self.pull.min = max(self.pull.max, half), -half
            self.pull.max = half
            self.pull.step = step
            self.pull.value = 0.0
        finally:
            self._quiet = False
        self._draw(point, point)
        where = ", ".join(f"{v:.3f}" for v in point)
        self._say(f"picked ({where}); drag or type the pull")

    # -- solving --------------------------------------------------------------------------------
    def _pulled(self, change: dict) -> None:
        if self._quiet or self.point is None:
            return
        if self.panel.model is not self.model:
            self._say("another model is shown: pick a point again")
            return
        if self.panel.params != self._applied:  # sliders moved by hand since: start from them
            self.base = dict(self.panel.params)
        job = {"model": self.model, "point": self.point, "d": float(change["new"]), "params": dict(self.base)}
        if self.panel.threaded:
            self.worker.submit(job)
        else:
            self.worker.run_now(job)

    def _solve(self, job: dict) -> Any:
        return push_pull(job["model"], job["point"], job["d"], job["params"])

    def _solved(self, job: dict, result: Any, error: Exception | None) -> None:
        if error is not None:
            self._say(f"<span style='color:#b00'>{html.escape(str(error))}</span>")
            return
        if job["model"] is not self.panel.model:
            return
        self.result = result
        panel = self.panel
        moved = max(result.change, key=lambda k: abs(result.change[k]))
        panel._quiet = True  # one remesh for all the sliders
        try:
            for name, value in result.params.items():
                panel.sliders[name].value = value
        finally:
            panel._quiet = False
        self._applied = dict(panel.params)
        if abs(result.change[moved]) > 0:
            panel.last_moved = moved
        panel.request()
        self._draw(result.point, result.target)
        changes = ", ".join(f"{k} {v:+.4g}" for k, v in result.change.items() if v != 0) or "no change"
        if result.converged:
            how = "the surface passes through the target"
        else:
            held = f" ({', '.join(result.at_bound)} at a bound)" if result.at_bound else ""
            how = f"<span style='color:#a60'>{result.distance:.3g} short of the target{held}</span>"
        self._say(f"{job['d']:+.4g}: {html.escape(changes)}; {how}")

    def wait(self, timeout: float = 60.0) -> None:
        """Block until the last pull is solved and applied (scripts and tests)."""
        self.worker.wait(timeout)

    # -- drawing --------------------------------------------------------------------------------
    def _draw(self, point: np.ndarray, target: np.ndarray) -> None:
        """The picked point and the segment to its target, over the surface."""
        pts = np.array([point, target], dtype=np.float64)
        line = pv.PolyData(pts, lines=np.array([2, 0, 1]))
        self.marker.shallow_copy(line)
        plotter = self.panel.view.plotter
        if self.marker_actor is None:
            self.marker_actor = plotter.add_mesh(
                self.marker,
                color="#e0a000",
                point_size=12,
                line_width=4,
                render_points_as_spheres=True,
                render_lines_as_tubes=True,
                pickable=False,
                reset_camera=False,
                name="push-pull",
            )
        self.panel.view.render()
