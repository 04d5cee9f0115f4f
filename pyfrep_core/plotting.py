"""Static figures for lessons and reports: off-screen renders of meshes, and a projector style.

The kernel returns data; this module only turns a :class:`~pyfrep_core.meshing.Mesh` (or several)
into a PNG, with the choices a lecture needs made once: the camera fills the frame (parallel
projection, fitted to the projected extent of the vertices, not to a bounding sphere), titles and
colour-bar text are large enough for a projector, and a colour bar always says what its colour
means.  pyvista and matplotlib are imported inside the functions, so importing this module costs
nothing and the rest of the kernel never depends on them.

Colour maps: a quantity with a meaningful zero and both signs (curvature, a signed field) takes a
diverging map centred on 0 (:data:`DIVERGING`, limits from :func:`symmetric_limits`); a one-sided
quantity (an error, a distance magnitude) takes a sequential map (:data:`SEQUENTIAL`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "DIVERGING",
    "PROJECTOR_RC",
    "SEQUENTIAL",
    "Picture",
    "render",
    "symmetric_limits",
    "use_projector_style",
]

DIVERGING = "RdBu_r"  # signed quantities: blue < 0 < red, white at 0
SEQUENTIAL = "viridis"  # one-sided quantities: dark = small, light = large

# matplotlib settings for figures shown on a projector: nothing below 11 pt.
PROJECTOR_RC: dict[str, Any] = {
    "font.size": 12,
    "axes.titlesize": 13,
    "axes.labelsize": 12,
    "xtick.labelsize": 11,
    "ytick.labelsize": 11,
    "legend.fontsize": 11,
    "figure.titlesize": 14,
    "lines.linewidth": 1.8,
}

_TITLE_PX = 20  # title font size in pixels (VTK's font_size); 800-1200 px wide figures
_LABEL_PX = 15  # colour-bar tick labels
_BAR_TITLE_PX = 17  # colour-bar caption (what the colour means)
_BAR_Y, _BAR_H = 6, 44  # colour bar: bottom and height in pixels (labels included)


@dataclass(frozen=True)
class Picture:
    """A rendered PNG; Jupyter displays it, :meth:`save` writes it.

    Attributes
    ----------
    data : bytes
        The PNG file's bytes.
    width, height : int
        Size in pixels.

    Examples
    --------
    >>> pic = Picture(b"png bytes", 2, 1)
    >>> pic.width, pic.height, pic._repr_png_() == b"png bytes"
    (2, 1, True)
    """

    data: bytes
    width: int
    height: int

    def _repr_png_(self) -> bytes:
        return self.data

    def save(self, path: str | os.PathLike) -> None:
        """Write the PNG to ``path``."""
        with open(path, "wb") as fh:
            fh.write(self.data)

    def pixels(self) -> np.ndarray:
        """The image as a (height, width, channels) uint8 array (read back from the PNG)."""
        import io

        import matplotlib.image

        img = matplotlib.image.imread(io.BytesIO(self.data), format="png")
        return (np.asarray(img) * 255).round().astype(np.uint8) if img.dtype != np.uint8 else img


def use_projector_style() -> None:
    """Apply :data:`PROJECTOR_RC` to matplotlib's global settings (fonts of 11 pt and more).

    Examples
    --------
    >>> import matplotlib
    >>> use_projector_style()
    >>> matplotlib.rcParams["font.size"] >= 10 and matplotlib.rcParams["xtick.labelsize"] >= 10
    True
    """
    import matplotlib

    matplotlib.rcParams.update(PROJECTOR_RC)


def symmetric_limits(values: Any, percentile: float = 100.0) -> tuple[float, float]:
    """Colour limits ``(-m, m)`` centred on 0 for a diverging map, ``m`` a percentile of ``|values|``.

    Parameters
    ----------
    values : array_like
        The quantity (NaN entries ignored).
    percentile : float
        Percentile of ``|values|`` in (0, 100] taken as ``m`` (100: the largest magnitude; less
        clips a few outliers, and the colour bar then extends past its ends).

    Returns
    -------
    (float, float)

    Examples
    --------
    >>> symmetric_limits([-0.5, 0.2, 2.0, float("nan")])
    (-2.0, 2.0)
    """
    v = np.abs(np.asarray(values, dtype=np.float64))
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ValueError("symmetric_limits: values holds no finite entry")
    if not 0.0 < percentile <= 100.0:
        raise ValueError(f"symmetric_limits: percentile must be in (0, 100], got {percentile}")
    m = float(np.percentile(v, percentile))
    return (-m, m) if m > 0 else (-1.0, 1.0)


def _is_shape(item: Any) -> bool:
    """A Mesh (anything with ``to_pyvista``) or a pyvista data set (a point cloud: ``pv.PolyData(xyz)``)."""
    return hasattr(item, "to_pyvista") or (hasattr(item, "points") and hasattr(item, "point_data"))


def _panels(meshes: Any) -> list[list[Any]]:
    """A Mesh, a list of Meshes (one per panel) or a list of lists (overlays) -> pyvista data, per panel."""
    if _is_shape(meshes):
        meshes = [meshes]
    panels = [[item] if _is_shape(item) else list(item) for item in meshes]
    if not panels or any(not group or not all(_is_shape(m) for m in group) for group in panels):
        raise TypeError("render: meshes must be a Mesh, a list of Meshes or a list of lists of Meshes")
    return [[m.to_pyvista() if hasattr(m, "to_pyvista") else m for m in group] for group in panels]


def _per_panel(value: Any, n: int, name: str) -> list[Any]:
    if value is None or isinstance(value, str) or not isinstance(value, Sequence):
        return [value] * n
    if len(value) != n:
        raise ValueError(f"render: {name} must have one entry per panel ({n}), got {len(value)}")
    return list(value)


def _view_frame(view: Any) -> tuple[np.ndarray, np.ndarray]:
    """(unit direction from the object to the camera, unit up) for ``"iso"``, ``"xy"``... or a pair."""
    named = {
        "iso": ((1.0, 1.0, 1.0), (0.0, 0.0, 1.0)),
        "xy": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
        "xz": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
        "yz": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    }
    if isinstance(view, str):
        if view not in named:
            raise ValueError(f"render: view must be one of {sorted(named)} or (direction, up), got {view!r}")
        view = named[view]
    direction, up = (np.asarray(v, dtype=np.float64) for v in view)
    if direction.shape != (3,) or up.shape != (3,) or np.linalg.norm(direction) == 0:
        raise ValueError(f"render: view must be (direction, up), two 3-vectors, got {view!r}")
    direction = direction / np.linalg.norm(direction)
    up = up - (up @ direction) * direction
    if np.linalg.norm(up) < 1e-9:
        raise ValueError("render: the view's up vector is parallel to its direction")
    return direction, up / np.linalg.norm(up)


def _fit_camera(camera: Any, points: np.ndarray, view: Any, aspect: float, band: tuple[float, float]) -> None:
    """Parallel projection whose frame holds the projected points within the vertical ``band``."""
    direction, up = _view_frame(view)
    right = np.cross(up, direction)  # camera looks along -direction
    u, v, w = points @ right, points @ up, points @ direction
    lo, hi = band
    height = hi - lo
    scale = 1.03 * max((v.max() - v.min()) / (2 * height), (u.max() - u.min()) / (2 * aspect), 1e-12)
    # the content's centre sits at the band's centre, (lo + hi) / 2 of the viewport's height
    v_focal = 0.5 * (v.max() + v.min()) - ((lo + hi) / 2 - 0.5) * 2 * scale
    focal = right * 0.5 * (u.max() + u.min()) + up * v_focal + direction * 0.5 * (w.max() + w.min())
    reach = float(np.ptp(points, axis=0).max()) + 1.0
    camera.focal_point = tuple(focal)
    camera.position = tuple(focal + direction * 4 * reach)
    camera.up = tuple(up)
    camera.parallel_projection = True
    camera.parallel_scale = scale
    camera.clipping_range = (1e-3 * reach, 10 * reach)


def render(
    meshes: Any,
    *,
    titles: Sequence[str] | str | None = None,
    colors: Any = "#8fb3d9",
    scalars: str | None = None,
    bar_title: str | None = None,
    clim: tuple[float, float] | None = None,
    cmap: str | None = None,
    size: tuple[int, int] | None = None,
    view: Any = "iso",
    nan_color: str = "black",
    point_size: float = 4.0,
) -> Picture:
    """Render meshes off-screen, one panel each, cameras fitted to fill the frame; a PNG back.

    Parameters
    ----------
    meshes : Mesh, list of Mesh, or list of lists of Mesh
        One mesh; one mesh per panel (side by side); or per panel a list of meshes drawn together.
        Anything with a ``to_pyvista()`` method works, and pyvista data sets: a point cloud
        ``pyvista.PolyData(xyz)`` (with point data to colour by) is drawn as round points.
    titles : str or list of str, optional
        One title per panel, written above it in 18 px type.
    colors : str or list
        Colour of every mesh, or one per panel (a list per panel for overlays).
    scalars : str, optional
        Name of a point-data array to colour by, instead of ``colors``.
    bar_title : str
        Required with ``scalars``: what the colour means (quantity and unit), shown above a
        horizontal colour bar under each panel.
    clim : (float, float), optional
        Colour limits, shared by the panels; default the data's range over all of them.
    cmap : str, optional
        Colour map; default :data:`DIVERGING` when ``clim`` straddles 0, else :data:`SEQUENTIAL`.
    size : (int, int), optional
        Window size in pixels, default 520 x 440 per panel.
    view : str or (direction, up)
        ``"iso"`` (default), ``"xy"``, ``"xz"``, ``"yz"``, or the direction from the object towards
        the camera and the up vector.
    nan_color : str
        Colour of vertices whose scalar is NaN (undefined), e.g. curvature on a crease.
    point_size : float
        Diameter in pixels of the points of a point cloud.

    Returns
    -------
    Picture
        The PNG (Jupyter displays it; ``.save(path)`` writes it).  No file is left behind.

    Examples
    --------
    >>> from pyfrep_core import polygonize, sphere
    >>> ball = polygonize(lambda x: sphere(x, r=1.0), ((-1.1,) * 3, (1.1,) * 3), 24)
    >>> ball.point_data["height"] = ball.vertices[:, 2]
    >>> pic = render(ball, titles="unit ball", scalars="height", bar_title="height z", size=(400, 380))
    >>> pic.width, pic.height
    (400, 380)
    >>> rgb = pic.pixels()[..., :3].astype(int)
    >>> drawn = (rgb.sum(axis=-1) < 700).any(axis=0)  # columns with something other than white
    >>> bool(drawn.mean() > 0.6)  # the ball and its bar span most of the width
    True
    >>> render(ball, scalars="height")
    Traceback (most recent call last):
    ...
    ValueError: render: bar_title is required with scalars (say what the colour means)

    A point cloud, coloured by a one-sided quantity (a sequential map):

    >>> import numpy as np, pyvista as pv
    >>> cloud = pv.PolyData(np.random.default_rng(0).normal(size=(500, 3)))
    >>> cloud.point_data["radius"] = np.linalg.norm(cloud.points, axis=1)
    >>> render(cloud, scalars="radius", bar_title="distance from 0", size=(300, 300)).height
    300
    """
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")  # before VTK's first window
    import pyvista as pv

    panels = _panels(meshes)
    n = len(panels)
    titles = _per_panel(titles, n, "titles")
    colors = _per_panel(colors, n, "colors")
    if scalars is not None and not bar_title:
        raise ValueError("render: bar_title is required with scalars (say what the colour means)")
    if size is None:
        size = (520 * n, 440)
    width, height = int(size[0]), int(size[1])
    if width <= 0 or height <= 0:
        raise ValueError(f"render: size must be two positive integers, got {size!r}")
    if scalars is not None:
        if clim is None:  # one range for every panel, so that equal colours mean equal values
            values = np.concatenate([np.ravel(m.point_data[scalars]) for group in panels for m in group])
            clim = (float(np.nanmin(values)), float(np.nanmax(values)))
        if cmap is None:
            cmap = DIVERGING if clim[0] < 0 < clim[1] else SEQUENTIAL

    top = (_TITLE_PX + 14) / height if any(titles) else 0.03
    bottom = (_BAR_Y + _BAR_H + _BAR_TITLE_PX + 14) / height if scalars is not None else 0.03
    plotter = pv.Plotter(off_screen=True, shape=(1, n), window_size=(width, height), border=False)
    try:
        plotter.set_background("white")
        for i, group in enumerate(panels):
            plotter.subplot(0, i)
            group_colors = colors[i] if isinstance(colors[i], (list, tuple)) else [colors[i]] * len(group)
            for mesh, color in zip(group, group_colors):
                kwargs: dict[str, Any] = dict(show_scalar_bar=False)
                if mesh.n_cells and not mesh.n_verts:  # a surface
                    kwargs.update(smooth_shading=True, specular=0.2)
                else:  # a point cloud
                    kwargs.update(render_points_as_spheres=True, point_size=point_size)
                if scalars is not None:
                    kwargs.update(scalars=scalars, clim=clim, cmap=cmap, nan_color=nan_color)
                else:
                    kwargs.update(color=color)
                plotter.add_mesh(mesh, **kwargs)
            if scalars is not None:
                # labels under the bar and the caption, a text actor of its own, above it: VTK's own
                # title shares the labels' row and overlaps them on a horizontal bar
                bar = plotter.add_scalar_bar(
                    title=" " * (i + 1),  # pyvista keeps one bar per title: one title per panel
                    vertical=False,
                    position_x=0.2,
                    position_y=_BAR_Y / height,
                    width=0.6,
                    height=_BAR_H / height,
                    label_font_size=_LABEL_PX,
                    unconstrained_font_size=True,
                    n_labels=5,
                    fmt="%.3g",
                    color="black",
                    font_family="arial",
                )
                bar.SetTextPositionToPrecedeScalarBar()
                caption = plotter.add_text(
                    bar_title, position=(width / n / 2, _BAR_Y + _BAR_H + 4), font_size=_BAR_TITLE_PX / 2
                )
                caption.prop.color = "black"
                caption.GetTextProperty().SetJustificationToCentered()
            if titles[i]:
                # a plain text actor: pixel size as given (a corner annotation scales with the window)
                text = plotter.add_text(titles[i], position=(width / n / 2, height - 6), font_size=_TITLE_PX / 2)
                text.prop.color = "black"
                text.GetTextProperty().SetJustificationToCentered()
                text.GetTextProperty().SetVerticalJustificationToTop()
            points = np.vstack([np.asarray(m.points) for m in group])
            if len(points) > 50_000:
                points = points[:: len(points) // 50_000 + 1]
            _fit_camera(plotter.camera, points, view, (width / n) / height, (bottom, 1.0 - top))
        with tempfile.TemporaryDirectory(prefix="pyfrep_render_") as tmp:
            path = os.path.join(tmp, "view.png")
            plotter.screenshot(path)
            with open(path, "rb") as fh:
                data = fh.read()
    finally:
        plotter.close()
    return Picture(data, width, height)
