"""Push-pull on the surface: pick a point in the 3-D view, drag it or type how far to move it.

The mouse goes to the view's own VTK interactor (the trame view is rendered on the server and
forwards every press, move and release to it), where a cell picker finds the surface point
under the pixel.  With "drag the surface" off, a press-and-drag turns the camera and a click
picks.  With it on, a press on the surface picks the point there and the drag that follows
pulls it: the mouse's travel projected on the normal's direction on the screen, divided by
how many pixels one length unit along the normal spans there, is the displacement, so the
point follows the mouse (see :meth:`PushPullControls.screen_normal` for a normal seen nearly
end-on); a press beside the shape still turns the camera.

The "pull" slider is the distance along the outward normal at the point (a drag sets it; a
value can be typed in its box); each value is solved for by :func:`pyfrep_core.push_pull.push_pull`
from the parameters at the time of the pick (so dragging back and forth is consistent) and
the shape panel's sliders are set to the result: one remesh, coloured by the parameter that
changed most.
"""

from __future__ import annotations

import html
from typing import Any

import ipywidgets as widgets
import numpy as np
import pyvista as pv
from vtkmodules.vtkRenderingCore import vtkCellPicker

from pyfrep_core.diff import value_and_grad
from pyfrep_core.push_pull import push_pull

from ._threads import LatestWorker

__all__ = ["PushPullControls"]


class PushPullControls:
    """Push-pull controls attached to a :class:`~workbench.shape_panel.ShapePanel`.

    Attributes
    ----------
    widget : the controls (an instruction, the drag toggle, the pull slider) to place in a layout.
    pull : the FloatSlider of the displacement (length units, > 0 outward).
    drag : the ToggleButton "drag the surface" (on: a press on the surface picks, dragging pulls).
    point : (3,) the picked point, or None.   normal : (3,) the outward unit normal there.
    base : the parameters at the pick.   result : the last :class:`~pyfrep_core.push_pull.PushPull`.
    """

    CLICK_PX = 3  # a press and release this close is a click (a pick), not a drag

    def __init__(self, panel: Any):
        self.panel = panel
        self.point: np.ndarray | None = None
        self.normal: np.ndarray | None = None
        self._press_xy: tuple[int, int] | None = None
        self._dragging = False
        self._pixels: tuple[np.ndarray, float] | None = None  # screen direction of the normal, px per unit
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
        self.drag = widgets.ToggleButton(
            value=False,
            description="drag the surface",
            tooltip=(
                "on: press on the surface and drag to pull it along its normal (press beside the shape to turn "
                "the view); off: dragging turns the view, a click picks a point"
            ),
            layout=widgets.Layout(width="150px"),
        )
        self.status = widgets.HTML(layout=widgets.Layout(width="340px"))
        self._instruct()
        self.widget = widgets.VBox([self.status, widgets.HBox([self.drag]), self.pull])
        # the status says which mode the kernel is in (a drag started before it knows would turn the view)
        self.drag.observe(lambda _: self._instruct() if self.point is None else None, names="value")
        # Reset or another model: the picked point and the last pull no longer describe the view
        panel.reset_button.on_click(lambda _: self.forget())
        panel.choice.observe(lambda _: self.forget(), names="value")
        self.worker = LatestWorker(self._solve, self._solved, panel.main, settle=0.0)
        self.pull.observe(self._pulled, names="value")
        self.picker = vtkCellPicker()
        self.picker.SetTolerance(0.0005)
        try:
            self._listen(panel.view.plotter.iren)
            self.picking = True
        except Exception as err:  # noqa: BLE001  (no interactor: pick() still works from code)
            self.picking = False
            self._say(f"clicking not available ({html.escape(str(err))}): pick() from code")

    def _instruct(self) -> None:
        """The status line's instruction for the mode the toggle is in (no point picked)."""
        if self.drag.value:
            self._say(
                "<i>drag the surface</i> is on: press on the surface and drag it along its normal (the "
                "parameters that move it there are solved for, within their ranges); press beside the "
                "shape to turn the view"
            )
        else:
            self._say(
                "click the surface to pick a point, then drag the pull slider or type it; or turn on "
                "<i>drag the surface</i> and drag the point itself (the parameters that move it there "
                "are solved for, within their ranges)"
            )

    def _say(self, text: str) -> None:
        """The status line (its own line height: the widget's is one control high)."""
        self.status.value = f"<div style='line-height:1.35;font-size:13px'><b>push-pull</b>: {text}</div>"

    def forget(self) -> None:
        """No point picked: the pull at 0 and disabled, the marker hidden, the instruction shown."""
        self.point = self.normal = self.base = self._applied = self.result = None
        self._dragging, self._pixels = False, None
        self._quiet = True
        try:
            self.pull.value = 0.0
            self.pull.disabled = True
        finally:
            self._quiet = False
        self._instruct()
        if self.marker_actor is not None:
            self.marker_actor.visibility = False
            self.panel.view.render()

    # -- the mouse ------------------------------------------------------------------------------
    def _listen(self, iren: Any) -> None:
        """Observe the left button and the mouse on the view's interactor style.

        The style (pyvista's trackball camera) turns the camera from its own press observer; the
        press observer here runs after it (priority -1) and, when a drag of the surface begins,
        ends that rotation.  Observing MouseMoveEvent replaces the style's own handling of it
        (VTK calls a style's observers instead of its method), so the move observer hands it back
        to the style whenever no surface is dragged.
        """
        style = iren.style
        if style is None:
            raise RuntimeError("the view has no interactor style")
        self._iren, self._style = iren.interactor, style
        style.AddObserver("LeftButtonPressEvent", self._on_press, -1.0)
        style.AddObserver("MouseMoveEvent", self._on_move)
        style.AddObserver("LeftButtonReleaseEvent", self._on_release, 1.0)

    def _on_press(self, *_: Any) -> None:
        x, y = self._iren.GetEventPosition()
        self._press_xy, self._dragging = (x, y), False
        if not self.drag.value:
            return
        point = self._surface_at(x, y)
        if point is None:
            return  # beside the shape: the camera turns
        self._style.EndRotate()  # started by the style's own press observer
        self.pick(point)
        self._dragging = self.normal is not None
        self.panel.view.hold_camera = self._dragging  # the camera stays put under the mouse

    def _on_move(self, *_: Any) -> None:
        if not self._dragging:
            self._style.OnMouseMove()  # the camera's own handling
            return
        x, y = self._iren.GetEventPosition()
        self.drag_to(x, y)

    def _on_release(self, *_: Any) -> None:
        if self._dragging:
            self._dragging = False
            self.panel.view.hold_camera = False
            return
        if self._press_xy is None or self.drag.value:
            return
        x, y = self._iren.GetEventPosition()
        if max(abs(x - self._press_xy[0]), abs(y - self._press_xy[1])) <= self.CLICK_PX:
            point = self._surface_at(x, y)
            if point is not None:
                self.pick(point)

    def _surface_at(self, x: int, y: int) -> np.ndarray | None:
        """The surface point under pixel (x, y) (display coordinates, origin bottom left), or None."""
        actor = self.panel.view.actor
        if actor is None or not actor.GetVisibility():
            return None
        self.picker.InitializePickList()
        self.picker.AddPickList(actor)
        self.picker.PickFromListOn()
        if not self.picker.Pick(x, y, 0, self.panel.view.plotter.renderer):
            return None
        return np.array(self.picker.GetPickPosition(), dtype=np.float64)

    def _display(self, point: np.ndarray) -> np.ndarray:
        ren = self.panel.view.plotter.renderer
        ren.SetWorldPoint(*point, 1.0)
        ren.WorldToDisplay()
        return np.array(ren.GetDisplayPoint()[:2], dtype=np.float64)

    def screen_normal(self) -> tuple[np.ndarray, float]:
        """The drag's direction on the screen (unit, display coordinates) and pixels per length unit along it.

        The normal's own projection, its pixels per unit at least half those of a direction across
        the view at the point's depth (a normal seen nearly end-on would turn a few pixels into a
        long pull: 30 px were 0.37 units on the Fig. 1 part's far hole wall); where it spans under
        a tenth of those (end-on), the screen's vertical, up meaning towards the viewer.
        """
        camera = self.panel.view.plotter.camera
        h = 1e-3 * max(camera.distance, 1e-12)
        at = self._display(self.point)
        along = (self._display(self.point + h * self.normal) - at) / h
        across = np.linalg.norm(self._display(self.point + h * np.asarray(camera.up)) - at) / h
        if np.linalg.norm(along) >= 0.1 * across:
            return along / np.linalg.norm(along), float(max(np.linalg.norm(along), 0.5 * across))
        towards = np.dot(self.normal, np.asarray(camera.position) - self.point) > 0
        return np.array([0.0, 1.0 if towards else -1.0]), float(0.5 * across)

    def drag_to(self, x: int, y: int) -> None:
        """The point dragged to pixel (x, y): the pull is the travel along the normal on the screen."""
        if self.point is None or self._press_xy is None:
            return
        if self._pixels is None:
            self._pixels = self.screen_normal()
        direction, per_unit = self._pixels
        travel = np.array([x - self._press_xy[0], y - self._press_xy[1]], dtype=np.float64)
        d = float(np.dot(travel, direction)) / per_unit
        step = self.pull.step
        d = min(max(round(d / step) * step, self.pull.min), self.pull.max)
        self.pull.value = d

    def click(self, x: int, y: int) -> None:
        """A left click at pixel (x, y) of the view (VTK's display coordinates, origin bottom left)."""
        iren = self.panel.view.plotter.iren.interactor
        iren.SetEventInformation(int(x), int(y))
        iren.InvokeEvent("LeftButtonPressEvent")
        iren.InvokeEvent("LeftButtonReleaseEvent")

    def drag_mouse(self, start: tuple[int, int], end: tuple[int, int], moves: int = 4) -> None:
        """Press at pixel ``start``, move to ``end`` in ``moves`` steps, release (as the browser sends it)."""
        iren = self.panel.view.plotter.iren.interactor
        iren.SetEventInformation(int(start[0]), int(start[1]))
        iren.InvokeEvent("LeftButtonPressEvent")
        for k in range(1, moves + 1):
            t = k / moves
            x = round(start[0] + t * (end[0] - start[0]))
            y = round(start[1] + t * (end[1] - start[1]))
            iren.SetEventInformation(x, y)
            iren.InvokeEvent("MouseMoveEvent")
        iren.InvokeEvent("LeftButtonReleaseEvent")

    def pick(self, point: Any) -> None:
        """Pick ``point`` (3,) on the surface: the pull starts from the current parameters, at 0."""
        point = np.asarray(point, dtype=np.float64).reshape(3)
        self.point, self.model = point, self.panel.model
        self.base = dict(self.panel.params)
        self._applied = dict(self.base)
        self.normal, self._pixels = self._outward(point), None
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

    def _outward(self, point: np.ndarray) -> np.ndarray | None:
        """-grad f / |grad f| at ``point`` (f >= 0 inside), or None where grad f vanishes."""
        _, g = value_and_grad(lambda q: self.model(q, **self.base), point[None])
        g = np.asarray(g[0], dtype=np.float64)
        norm = float(np.linalg.norm(g))
        return -g / norm if np.isfinite(norm) and norm > 0 else None

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
        if self.marker_actor is not None:
            self.marker_actor.visibility = True
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
