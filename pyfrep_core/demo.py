"""``python -m pyfrep_core.demo``: mesh the paper's Fig. 1 part, write ``fig1.stl`` and ``fig1.png``.

The PNG is rendered off-screen with pyvista (no display needed).  Options: ``--out DIR``
(default: the current directory), ``--resolution N`` (grid samples per axis, default 128)
and ``-r/--radius`` (the cylinders' radius, Fig. 2 shows 0.35, 0.5 and 0.65).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from .meshing import Mesh, polygonize
from .models import fig1_part

__all__ = ["render_png", "main"]


def render_png(mesh: Mesh, path: str | os.PathLike, size: tuple[int, int] = (800, 600)) -> Path:
    """Render ``mesh`` off-screen (pyvista, EGL) to a PNG at ``path``; returns the path.

    Examples
    --------
    >>> import tempfile, os
    >>> from pyfrep_core import polygonize, sphere
    >>> m = polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 16)
    >>> out = render_png(m, os.path.join(tempfile.mkdtemp(), "ball.png"), size=(64, 48))
    >>> out.stat().st_size > 0
    True
    """
    # EGL before pyvista/VTK opens a window: no X server needed, and no warning about one
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    import pyvista as pv

    path = Path(path)
    plotter = pv.Plotter(off_screen=True, window_size=list(size))
    try:
        plotter.set_background("white")
        plotter.add_mesh(mesh.to_pyvista(), color="#8fb3d9", smooth_shading=True, split_sharp_edges=True, specular=0.3)
        plotter.view_isometric()
        plotter.camera.zoom(1.2)
        plotter.screenshot(str(path))
    finally:
        plotter.close()
    return path


def main(argv: list[str] | None = None) -> int:
    """Build the Fig. 1 part, write the STL and the PNG, print where they are with the mesh stats."""
    parser = argparse.ArgumentParser(prog="python -m pyfrep_core.demo", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=".", help="output directory (default: current directory)")
    parser.add_argument("--resolution", type=int, default=128, help="grid samples per axis (default 128)")
    parser.add_argument("-r", "--radius", type=float, default=0.5, help="cylinder radius (default 0.5)")
    args = parser.parse_args(argv)
    fig1_part.check(r=args.radius)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    mesh = polygonize(lambda x: fig1_part(x, r=args.radius), fig1_part.bounds, args.resolution)
    seconds = time.perf_counter() - t0
    stl = out / "fig1.stl"
    mesh.save(stl)
    png = render_png(mesh, out / "fig1.png")

    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    print(f"Fig. 1 part (r = {args.radius}), meshed at {args.resolution}^3 in {seconds:.2f} s:")
    print(f"  {mesh.n_vertices} vertices, {mesh.n_faces} triangles")
    print(f"  volume {mesh.volume():.5f}, area {mesh.area():.5f}")
    print(f"  extent [{lo[0]:.3f}, {hi[0]:.3f}] x [{lo[1]:.3f}, {hi[1]:.3f}] x [{lo[2]:.3f}, {hi[2]:.3f}]")
    print(f"wrote {stl.resolve()}")
    print(f"wrote {png.resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
