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

__all__ = ["MeshView", "resolve_backend"]

BACKENDS = ("trame", "image", "offscreen")  # offscreen: render only, no picture pushed (benchmarks)


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

    Parameters
    ----------
    backend : "auto", "trame" or "image" (see module docstring).
    size : window size in pixels (width, height).
    color : surface colour when no scalars are shown.

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

    def __init__(self, backend: str = "auto", size: tuple[int, int] = (640, 480), color: str = "#c8c8d2"):
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
        self.bar: Any = None  # the scalar bar actor
        self.renders = 0
        self.last_render_s = 0.0
        self.widget = self._make_widget()

    def _make_widget(self) -> widgets.Widget:
        if self.backend == "trame":
            try:
                import trame_pyvista  # noqa: F401

                with contextlib.redirect_stdout(io.StringIO()):  # trame_vtklocal prints its wasm path
                    view = self.plotter.show(jupyter_backend="trame", return_viewer=True)
                if view is None:
                    raise RuntimeError("pyvista returned no trame viewer")
                view.layout = widgets.Layout(width=f"{self.size[0]}px", height=f"{self.size[1] + 10}px")
                return view
            except Exception as err:  # no trame server possible here: fall back, say why
                self.backend = "image"
                self.fallback_reason = f"{type(err).__name__}: {err}"
        return widgets.Image(format="png", layout=widgets.Layout(width=f"{self.size[0]}px"))

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
        """Replace the surface with ``mesh`` (a pyfrep_core Mesh or a PolyData), coloured by ``scalars`` (V,)."""
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
            self._colour(scalars, title, cmap, clim)
        self.render(reset_camera=first or reset_camera)

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
        # one scalar bar, updated in place (pyvista's add/remove_scalar_bar each render the scene)
        if self.bar is None:
            self.bar = self.plotter.add_scalar_bar(
                title=title or " ", mapper=mapper, n_labels=5, fmt="%.2g", vertical=True, position_x=0.84, width=0.07
            )
        self.bar.SetTitle(title or " ")
        self.bar.SetLookupTable(mapper.lookup_table)
        self.bar.SetVisibility(True)

    def overlay_points(self, points: np.ndarray | None, scalars: np.ndarray | None = None, title: str = "") -> None:
        """Show a point cloud (replaced in place), coloured by ``scalars``; None removes it."""
        if points is None:
            if self.overlay_actor is not None:
                self.overlay_actor.visibility = False
            return
        cloud = pv.PolyData(np.asarray(points, dtype=np.float64))
        if scalars is not None:
            cloud.point_data["values"] = np.asarray(scalars, dtype=np.float64)
        if self.overlay_poly is None:
            self.overlay_poly = pv.PolyData()
        self.overlay_poly.shallow_copy(cloud)
        if self.overlay_actor is None:
            self.overlay_actor = self.plotter.add_mesh(
                self.overlay_poly,
                scalars="values" if scalars is not None else None,
                cmap="viridis",
                point_size=5,
                render_points_as_spheres=True,
                color="#1f77b4",
                name="cloud",
                show_scalar_bar=False,
            )
        self.overlay_actor.visibility = True
        mapper = self.overlay_actor.mapper
        mapper.scalar_visibility = scalars is not None
        if scalars is not None:
            mapper.SetScalarModeToUsePointFieldData()
            mapper.SelectColorArray("values")
            lo, hi = float(np.min(scalars)), float(np.max(scalars))
            mapper.scalar_range = (lo, hi if hi > lo else lo + 1e-12)
            mapper.lookup_table.cmap = "viridis"
            mapper.lookup_table.scalar_range = mapper.scalar_range
        if self.actor is None:
            self.render(reset_camera=True)

    def set_opacity(self, opacity: float) -> None:
        if self.actor is not None:
            self.actor.prop.opacity = opacity

    # -- drawing ------------------------------------------------------------------------
    def render(self, reset_camera: bool = False) -> None:
        """Render on the calling (main) thread and push the frame to the widget."""
        t0 = time.perf_counter()
        if reset_camera:
            self.plotter.view_isometric()
            self.plotter.reset_camera()
        if self.backend == "trame":
            self.plotter.render()  # the trame viewer listens to this render
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
