"""The 3-D view: one pyvista Plotter and one PolyData, updated in place.

``MeshView.widget`` is what a panel places in its layout:

- backend ``"trame"``: the trame viewer (server-side rendering: no WebGL needed in the browser),
  refreshed by ``plotter.render()``;
- backend ``"image"``: an ``ipywidgets.Image`` holding the PNG of an off-screen render; works
  with no trame and no WebGL (nbval, plain servers, tests).

``"auto"`` takes ``$PYFREP_VIEW`` when set, else trame inside a running kernel when it imports,
else the image.  Renders must happen on the main thread (VTK renders black frames from other threads).
"""

from __future__ import annotations

import contextlib
import io
import os
import tempfile
import time
from typing import Any

import ipywidgets as widgets
import numpy as np

# EGL needs no X server; set before VTK creates its first window (saves ~1.5 s at the first render).
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
# Offline: trame_vtklocal (loaded by pyvista's trame server, unused here) downloads a VTK wasm
# bundle from gitlab.kitware.com unless pointed at a local directory; an empty one will do.
_NO_WASM = os.path.join(tempfile.gettempdir(), "pyfrep-no-vtk-wasm")
os.makedirs(_NO_WASM, exist_ok=True)
os.environ.setdefault("VTK_WASM_DIR_OVERRIDE", _NO_WASM)

import pyvista as pv  # noqa: E402
from vtkmodules.vtkCommonDataModel import vtkPlane  # noqa: E402

from .colours import UNDEFINED_COLOUR  # noqa: E402
from .trame_delivery import prompt_image_delivery, remote_geometry_on_demand  # noqa: E402

__all__ = ["LATTICES", "MeshView", "resolve_backend", "shows_inside"]

LATTICES = ("microstructure",)  # the paper's shapes whose interesting part is inside a skin


def shows_inside(model: object) -> bool:
    """Whether a view of ``model`` opens with its section on: a lattice (one of :data:`LATTICES`,
    or any model given ``model.lattice = True``), whose struts a closed skin would hide.

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part, microstructure
    >>> shows_inside(microstructure), shows_inside(fig1_part)
    (True, False)
    """
    return bool(getattr(model, "lattice", False)) or getattr(model, "__name__", "") in LATTICES


BACKENDS = ("trame", "image", "offscreen")  # offscreen: render only, no picture pushed (benchmarks)


def _white_png(size: tuple[int, int]) -> bytes:
    """A white PNG of ``size`` (width, height): what an image view shows before its first frame."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", tuple(size), "white").save(buf, format="png")
    return buf.getvalue()


def _in_kernel() -> bool:
    try:
        from IPython import get_ipython
    except ImportError:
        return False
    shell = get_ipython()
    return shell is not None and getattr(shell, "kernel", None) is not None


def resolve_backend(backend: str = "auto") -> str:
    """``"trame"``, ``"image"`` or ``"offscreen"``; ``"auto"`` reads ``$PYFREP_VIEW``, then probes
    for a kernel and trame.

    Examples
    --------
    >>> resolve_backend("image")
    'image'
    >>> resolve_backend("auto") if "PYFREP_VIEW" not in os.environ else "image"  # no kernel in a doctest
    'image'
    """
    if backend == "auto":
        backend = os.environ.get("PYFREP_VIEW", "auto").strip().lower() or "auto"
    if backend == "auto":
        if not _in_kernel():
            return "image"
        try:
            import trame_pyvista  # noqa: F401  (pyvista's trame backends live there since 0.49)
        except ImportError:
            return "image"
        return "trame"
    if backend not in BACKENDS:
        raise ValueError(f"backend must be 'auto', 'trame', 'image' or 'offscreen', got {backend!r}")
    return backend


class MeshView:
    """A 3-D view of one surface whose geometry and colouring are replaced in place.

    ``box`` is what a panel shows: the view and, under it, its section control (a clip plane:
    on/off, the axis it cuts, where), which opens a lattice's closed skin to show its struts.
    The camera re-frames itself when the surface outgrows (or shrinks well inside) what it frames.

    Parameters
    ----------
    backend : "auto", "trame" or "image" (see module docstring).
    size : window size in pixels (width, height).
    color : surface colour when no scalars are shown.
    section : the clip plane on at first (lattices: their inside is what there is to see).

    Examples
    --------
    >>> from pyfrep_core import polygonize, sphere
    >>> view = MeshView(backend="image", size=(160, 120))
    >>> mesh = polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 16)
    >>> view.update(mesh, scalars=mesh.vertices[:, 2], title="z")
    >>> poly = view.poly
    >>> view.update(mesh, scalars=-mesh.vertices[:, 2])  # same PolyData, new colours
    >>> view.poly is poly, bytes(view.widget.value[:4])
    (True, b'\x89PNG')
    >>> view.close()
    """

    def __init__(
        self, backend: str = "auto", size: tuple[int, int] = (640, 480), color: str = "#c8c8d2", section: bool = False
    ):
        self.backend = resolve_backend(backend)
        self.size = size
        self.color = color
        # notebook=True: pyvista's own probe says "no kernel" inside widget callbacks (a tab opened later)
        self.plotter = pv.Plotter(off_screen=True, notebook=self.backend == "trame", window_size=list(size))
        self.plotter.set_background("white")
        # no 4x multisampling: Mesa's software renderer pays per sample (~0.2 -> ~0.12 s per 100k-triangle frame)
        self.plotter.render_window.SetMultiSamples(0)
        self.poly = pv.PolyData()
        self.actor: Any = None
        self.overlay_poly: pv.PolyData | None = None
        self.overlay_actor: Any = None
        self.overlays: dict[str, tuple[pv.PolyData, Any]] = {}  # further named clouds (a fit's outliers)
        self.bar: Any = None  # the scalar bar actor
        self.renders = 0
        self.last_render_s = 0.0
        self.framed: tuple[float, ...] | None = None  # the bounds the camera was last fitted to
        self._quiet = False
        self.hold_camera = False  # set while the user drags the surface: no refit under the mouse
        self.plane = vtkPlane()  # the section's clip plane, shared by the surface and the cloud
        self.widget = self._make_widget()
        self._make_section(section)
        self.box = widgets.VBox([self.widget, self.section_controls])

    def _make_widget(self) -> widgets.Widget:
        if self.backend == "trame":
            try:
                import trame_pyvista  # noqa: F401

                prompt_image_delivery()  # frames reach the browser when encoded, not 0.5 s later
                remote_geometry_on_demand()  # pictures only: the scene goes to the browser when it renders
                # a first white frame: the viewer's first image is otherwise whatever the fresh
                # framebuffer holds (a black and white smear)
                self.plotter.render_window.Render()
                with contextlib.redirect_stdout(io.StringIO()):  # trame_vtklocal prints its wasm path
                    view = self.plotter.show(
                        jupyter_backend="trame",
                        return_viewer=True,
                        # the toolbar folded into one button: unfolded it covers the top of the scene
                        jupyter_kwargs={"collapse_menu": True},
                    )
                if view is None:
                    raise RuntimeError("pyvista returned no trame viewer")
                if "://localhost:" in view.value and "reconnect=auto" in view.value:
                    # the websocket's address: without it trame's client first POSTs to a session
                    # manager at /paraview/ (405 in the console) and then falls back to this one
                    view.value = view.value.replace("reconnect=auto", "reconnect=auto&amp;sessionURL=ws://USE_HOST/ws")
                view.layout = widgets.Layout(width=f"{self.size[0]}px", height=f"{self.size[1] + 10}px")
                return view
            except Exception as err:  # no trame server possible here: fall back, say why
                self.backend = "image"
                self.fallback_reason = f"{type(err).__name__}: {err}"
        # a white frame until the first render (an empty Image shows a broken-image icon)
        layout = widgets.Layout(width=f"{self.size[0]}px")
        return widgets.Image(value=_white_png(self.size), format="png", layout=layout)

    # -- section (clip plane) ---------------------------------------------------------------
    def _make_section(self, on: bool) -> None:
        self.section = widgets.Checkbox(
            value=on,
            description="section",
            tooltip="cut the surface with a plane to see inside (a lattice's struts behind its skin)",
            indent=False,
            layout=widgets.Layout(width="90px"),
        )
        self.section_axis = widgets.ToggleButtons(
            options=("x", "y", "z"),
            value="z",
            tooltips=("plane normal to x", "plane normal to y", "plane normal to z"),
            style={"button_width": "32px"},
        )
        self.section_at = widgets.FloatSlider(
            value=0.5,
            min=0.0,
            max=1.0,
            step=0.01,
            description="keep below",
            tooltip="where the plane cuts its axis, as a fraction of the shape's extent; the part below it is kept",
            readout_format=".0%",
            continuous_update=True,
            style={"description_width": "80px"},
            layout=widgets.Layout(width="300px"),
        )
        self.section_controls = widgets.HBox([self.section, self.section_axis, self.section_at])
        for w in (self.section, self.section_axis, self.section_at):
            w.observe(lambda _: self._section_changed(), names="value")

    def _section_changed(self) -> None:
        if self._quiet:
            return
        self._apply_section()
        self.render()

    def set_section(
        self, on: bool | None = None, axis: str | None = None, at: float | None = None, render: bool = True
    ) -> None:
        """Turn the clip plane on/off, set the axis it cuts ("x", "y", "z") and where (0..1 of the extent).

        ``render=False``: only remember it, for the next :meth:`update` (a new model on its way).
        """
        self._quiet = True  # one render for the three changes
        try:
            if axis is not None:
                self.section_axis.value = axis
            if at is not None:
                self.section_at.value = at
            if on is not None:
                self.section.value = on
        finally:
            self._quiet = False
        if render:
            self._section_changed()

    def _apply_section(self) -> None:
        """Clip the surface (and the cloud) at the plane: in the mapper, nothing re-meshed."""
        actors = [a for a in (self.actor, self.overlay_actor, *(a for _, a in self.overlays.values())) if a is not None]
        for actor in actors:
            actor.mapper.RemoveAllClippingPlanes()
        if not self.section.value or self.poly.n_points == 0:
            return
        k = "xyz".index(self.section_axis.value)
        lo, hi = self.poly.bounds[2 * k], self.poly.bounds[2 * k + 1]
        origin = [0.0, 0.0, 0.0]
        origin[k] = lo + self.section_at.value * (hi - lo)
        normal = [0.0, 0.0, 0.0]
        normal[k] = -1.0  # VTK keeps (x - origin) . normal >= 0: the part below the plane
        self.plane.SetOrigin(origin)
        self.plane.SetNormal(normal)
        for actor in actors:
            actor.mapper.AddClippingPlane(self.plane)

    def visible_fraction(self) -> float:
        """Fraction of the surface's vertices on the kept side of the section (1 with no section)."""
        if not self.section.value or self.poly.n_points == 0:
            return 1.0
        k = "xyz".index(self.section_axis.value)
        return float(np.mean(np.asarray(self.poly.points)[:, k] <= self.plane.GetOrigin()[k]))

    # -- geometry -----------------------------------------------------------------------
    def update(
        self,
        mesh: Any,
        scalars: np.ndarray | None = None,
        title: str = "",
        cmap: str = "coolwarm",
        clim: tuple[float, float] | None = None,
        reset_camera: bool = False,
    ) -> None:
        """Replace the surface with ``mesh`` (a pyfrep_core Mesh or a PolyData), coloured by ``scalars`` (V,).

        NaN scalars (undefined values) are drawn in the neutral :data:`workbench.colours.UNDEFINED_COLOUR`.
        ``title`` labels the colour bar (name and unit).  The camera is re-fitted when asked, on the
        first surface, and when the surface leaves (or shrinks well inside) the box it was fitted to.
        """
        new = mesh if isinstance(mesh, pv.PolyData) else mesh.to_pyvista()
        new = new.copy(deep=False)
        if "Normals" in new.point_data:  # grad f normals from the core: VTK shades with them, none recomputed
            new.point_data.active_normals_name = "Normals"
        if scalars is not None:
            new.point_data["values"] = np.asarray(scalars, dtype=np.float64)
            new.set_active_scalars("values")
        self.poly.shallow_copy(new)  # same PolyData object: the actor keeps its dataset
        first = self.actor is None
        if first and self.poly.n_points:
            self.actor = self.plotter.add_mesh(
                self.poly,
                scalars="values" if scalars is not None else None,
                color=self.color,
                cmap=cmap,
                smooth_shading=False,  # smooth anyway: the point normals above (pyvista's would re-run a filter)
                show_scalar_bar=False,
                name="surface",
            )
            self.plotter.add_axes()
        if self.actor is not None:
            self.actor.visibility = True  # shown again after hide_surface()
            self._colour(scalars, title, cmap, clim)
            self._apply_section()
        if first or reset_camera:
            self.render(reset_camera=True)
        elif self._outgrown() and not self.hold_camera:
            self.render(refit=True)
        else:
            self.render()

    def _outgrown(self) -> bool:
        """The surface left the box the camera frames, or is under half its size (a size change)."""
        if self.framed is None or self.poly.n_points == 0:
            return self.poly.n_points > 0
        new, old = np.asarray(self.poly.bounds), np.asarray(self.framed)
        size_new = np.linalg.norm(new[1::2] - new[::2])
        size_old = np.linalg.norm(old[1::2] - old[::2])
        slack = 0.02 * size_old
        outside = bool(np.any(new[::2] < old[::2] - slack) or np.any(new[1::2] > old[1::2] + slack))
        return outside or size_new < 0.5 * size_old

    def _colour(self, scalars: np.ndarray | None, title: str, cmap: str, clim: tuple[float, float] | None) -> None:
        mapper = self.actor.mapper
        if scalars is None or len(scalars) == 0:
            mapper.scalar_visibility = False
            self.actor.prop.color = self.color
            if self.bar is not None:
                self.bar.SetVisibility(False)
            return
        mapper.scalar_visibility = True
        mapper.SetScalarModeToUsePointFieldData()  # colour by the "values" array of the new geometry
        mapper.SelectColorArray("values")
        if clim is None:
            clim = (float(np.min(scalars)), float(np.max(scalars)))
        if clim[0] >= clim[1]:
            clim = (clim[0] - 1e-12, clim[1] + 1e-12)
        mapper.scalar_range = clim
        mapper.lookup_table.cmap = cmap
        mapper.lookup_table.scalar_range = clim
        mapper.lookup_table.nan_color = UNDEFINED_COLOUR
        # interpolating texture coordinates towards a NaN vertex sweeps the whole map across the
        # triangle (a striped sawtooth along creases); colours interpolate to grey instead
        mapper.SetInterpolateScalarsBeforeMapping(not bool(np.isnan(scalars).any()))
        self._show_bar(mapper, title)

    def overlay_points(
        self,
        points: np.ndarray | None,
        scalars: np.ndarray | None = None,
        title: str = "",
        *,
        name: str = "cloud",
        color: str = "#1f77b4",
        clim: tuple[float, float] | None = None,
        bar: bool = False,
    ) -> None:
        """Show a point cloud (replaced in place), coloured by ``scalars``; None removes it.

        Several clouds can be shown at once under different ``name`` s (a fit's inliers and its
        outliers in a colour of their own); "cloud" is ``overlay_poly``/``overlay_actor``.
        ``bar``: the colour bar (captioned ``title``) tells the cloud's colours instead of the surface's.
        """
        poly, actor = (
            (self.overlay_poly, self.overlay_actor) if name == "cloud" else self.overlays.get(name, (None, None))
        )
        if points is None:
            if actor is not None:
                actor.visibility = False
            return
        cloud = pv.PolyData(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if scalars is not None:
            cloud.point_data["values"] = np.asarray(scalars, dtype=np.float64)
        if poly is None:
            poly = pv.PolyData()
        poly.shallow_copy(cloud)
        if actor is None:
            actor = self.plotter.add_mesh(
                poly,
                scalars="values" if scalars is not None else None,
                cmap="viridis",
                point_size=5,
                render_points_as_spheres=True,
                color=color,
                name=name,
                show_scalar_bar=False,
            )
        if name == "cloud":
            self.overlay_poly, self.overlay_actor = poly, actor
        else:
            self.overlays[name] = (poly, actor)
        actor.visibility = True
        actor.prop.color = color
        mapper = actor.mapper
        mapper.scalar_visibility = scalars is not None
        if scalars is not None:
            mapper.SetScalarModeToUsePointFieldData()
            mapper.SelectColorArray("values")
            lo, hi = clim if clim is not None else (float(np.nanmin(scalars)), float(np.nanmax(scalars)))
            mapper.scalar_range = (lo, hi if hi > lo else lo + 1e-12)
            mapper.lookup_table.cmap = "viridis"
            mapper.lookup_table.scalar_range = mapper.scalar_range
            if bar:
                self._show_bar(mapper, title)
        self._apply_section()
        if self.actor is None:
            self.render(reset_camera=True)

    def _show_bar(self, mapper: Any, title: str) -> None:
        """The one colour bar, telling ``mapper``'s colours (the surface's, or a cloud's)."""
        # one scalar bar, updated in place (pyvista's add/remove_scalar_bar each render the scene)
        if self.bar is None:
            self.bar = self.plotter.add_scalar_bar(
                title=title or " ", mapper=mapper, n_labels=5, fmt="%.2g", vertical=True, position_x=0.8,
                width=0.08, title_font_size=16, label_font_size=14,
            )  # fmt: skip
        self.bar.SetTitle(title or " ")
        self.bar.SetLookupTable(mapper.lookup_table)
        self.bar.SetVisibility(True)

    def hide_surface(self) -> None:
        """Hide the surface (a stale one, until the next ``update``): the camera then frames the clouds."""
        if self.actor is not None:
            self.actor.visibility = False
        if self.bar is not None:
            self.bar.SetVisibility(False)

    def set_opacity(self, opacity: float) -> None:
        if self.actor is not None:
            self.actor.prop.opacity = opacity

    # -- drawing ------------------------------------------------------------------------
    def render(self, reset_camera: bool = False, refit: bool = False) -> None:
        """Render on the calling (main) thread and push the frame to the widget.

        ``reset_camera``: the isometric view of the whole surface; ``refit``: the same direction,
        distance and centre fitted to the surface's size.
        """
        t0 = time.perf_counter()
        if reset_camera:
            self.plotter.view_isometric()
        if reset_camera or refit:
            self.plotter.reset_camera()
            if self.poly.n_points:
                self.framed = tuple(self.poly.bounds)
        if self.backend == "trame":
            # the trame viewer renders the window itself when it sends the frame: say that it
            # changed and tell the viewer (plotter.render() would render once more before that)
            self.plotter.render_window.Modified()
            for callback in self.plotter._on_render_callbacks:
                callback(self.plotter)
        else:
            # pyvista's render() does nothing before a first show(), and screenshot() re-reads the
            # last frame without rendering: render the window itself
            self.plotter.render_window.Render()
            if self.backend == "image":
                self.widget.value = self.png()
        self.renders += 1
        self.last_render_s = time.perf_counter() - t0

    def png(self) -> bytes:
        """The current frame as PNG bytes."""
        from PIL import Image

        frame = self.plotter.screenshot(return_img=True)
        buf = io.BytesIO()
        Image.fromarray(frame).save(buf, format="png", compress_level=1)
        return buf.getvalue()

    def close(self) -> None:
        self.plotter.close()
