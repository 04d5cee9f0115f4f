"""Slider to view: median time from a slider value change to the new mesh in the 3-D view.

The Fig. 1 part, cylinder-radius slider, at 128^3 and 64^3 grid samples.  Each move runs the
whole journey (ARCHITECTURE.md, journey 1): model on the grid (sparse: exactly only near the
surface) -> marching cubes -> vertices onto f = 0 and grad f -> sensitivity colouring (df/dp,
reusing polygonize's grad f) -> points/faces replaced in the view's one PolyData.  Reported,
as medians over the moves:

- ``in plotter``: slider change -> new geometry and colours in the plotter (what the issue's
  target measures: "the new mesh being in the view, plotter updated"); with the trame
  ``client`` backend the browser renders from here, with WebGL;
- ``rendered``: plus one server-side frame (``render_window.Render()``; in this headless setup
  VTK renders with Mesa's software rasterizer: the trame ``server`` backend's cost);
- ``+ PNG``: plus encoding the frame for the image fallback view.

Then the 128^3 move split into its stages, and the load average (the machine is shared).
Target: < 100 ms at 128^3.

Run: ``.venv/bin/python benchmarks/slider.py`` (PYFREP_QUICK=1: fewer moves).
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np
import torch
from skimage.measure import marching_cubes

from pyfrep_core.mesh import (
    SPARSE_GUARD,
    SPARSE_STEP,
    _evaluate_grid,
    _exact_neighbours,
    _normals,
    _project_vertices,
    _sparse_grid,
    grid_axes,
)
from pyfrep_core.models import fig1_part
from pyfrep_core.sensitivity import param_derivative
from workbench.shape_panel import shape_panel
from workbench.view import MeshView

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
TARGET_MS = 100.0


def ms(xs: list[float]) -> float:
    return 1000 * statistics.median(xs)


def measure(resolution: int, moves: int, backend: str, sparse: bool) -> dict[str, float]:
    panel = shape_panel(
        fig1_part, resolution=resolution, backend=backend, threaded=False, size=(640, 480), sparse=sparse
    )
    slider = panel.sliders["r"]
    values = 0.5 + 0.05 * np.sin(np.arange(1, moves + 2))  # distinct radii around Fig. 2's 0.5
    slider.value = float(values[0])  # warm-up (first render, autograd warm-up)
    total, remesh, render = [], [], []
    for v in values[1:]:
        t0 = time.perf_counter()
        slider.value = float(v)  # the callback remeshes, updates the plotter and renders before returning
        total.append(time.perf_counter() - t0)
        remesh.append(panel.last_remesh_s)
        render.append(panel.view.last_render_s)
    triangles = panel.mesh.n_faces
    panel.view.close()
    return {
        "plotter": ms([t - r for t, r in zip(total, render)]),
        "rendered": ms(total),
        "remesh": ms(remesh),
        "render": ms(render),
        "triangles": triangles,
    }


def stages(resolution: int, runs: int) -> dict[str, float]:
    """One 128^3 move split: grid, marching cubes, projection (+ grad f), normals, df/dp, plotter, frame."""
    bounds = fig1_part.bounds
    lo = np.asarray(bounds[0])
    axes = grid_axes(bounds, resolution)
    spacing = np.array([a[1] - a[0] for a in axes])
    view = MeshView(backend="offscreen", size=(640, 480))
    rows: dict[str, list[float]] = {}
    for k in range(runs + 1):
        r = 0.5 + 0.01 * k
        f = lambda x, r=r: fig1_part(x, r=r)  # noqa: E731
        t = [time.perf_counter()]
        dense, _, _ = _evaluate_grid(f, axes, torch.float32, "cpu", None)
        t.append(time.perf_counter())
        values, _, _, mask, evaluated = _sparse_grid(f, axes, torch.float32, "cpu", SPARSE_STEP, SPARSE_GUARD)
        t.append(time.perf_counter())
        marching_cubes(dense, 0.0, gradient_direction="descent")
        t.append(time.perf_counter())
        index_verts, faces, _, _ = marching_cubes(values, 0.0, gradient_direction="descent", mask=mask)
        faces = np.ascontiguousarray(faces[:, ::-1], dtype=np.int64)
        t.append(time.perf_counter())
        _exact_neighbours(f, values, index_verts, evaluated, SPARSE_STEP, axes, torch.float32, "cpu")
        verts, gradient, _ = _project_vertices(f, values, index_verts, lo, spacing, bounds, "cpu")
        t.append(time.perf_counter())
        normals = _normals(gradient, verts, faces)
        t.append(time.perf_counter())
        df_dp = param_derivative(fig1_part, verts, "r", {"r": r}, chunk=1 << 14)
        t.append(time.perf_counter())
        from pyfrep_core import Mesh

        view.render = lambda reset_camera=False: None  # noqa: E731  (the frame is timed separately)
        view.update(Mesh(verts, faces, normals), scalars=-df_dp, title="v", clim=(-1.0, 1.0))
        t.append(time.perf_counter())
        view.plotter.render_window.Render()
        t.append(time.perf_counter())
        if k:  # the first run warms up
            names = ("dense grid", "sparse grid", "marching cubes (dense)", "marching cubes (sparse mask)")
            names += ("projection + grad f", "normals", "df/dp", "PolyData into the plotter", "frame (Mesa)")
            for name, a, b in zip(names, t[:-1], t[1:]):
                rows.setdefault(name, []).append(b - a)
    view.close()
    return {name: ms(v) for name, v in rows.items()}


def main() -> None:
    moves = 3 if QUICK else 9
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    print(
        f"slider -> view, Fig. 1 part, median of {moves} moves ({os.cpu_count()} CPUs, "
        f"torch {torch.get_num_threads()} threads, load average {load})"
    )
    results = {}
    for resolution in (128, 64):
        for sparse in (True, False):
            for backend in ("offscreen", "image"):
                r = measure(resolution, moves, backend, sparse)
                results[resolution, sparse, backend] = r
                grid = "sparse" if sparse else "dense "
                what = "rendered" if backend == "offscreen" else "+ PNG   "
                print(
                    f"  {resolution:>3}^3 {grid}  in plotter {r['plotter']:6.1f} ms  {what} {r['rendered']:6.1f} ms"
                    f"  (remesh {r['remesh']:6.1f} ms, frame {r['render']:5.1f} ms, {r['triangles']} triangles)"
                )
    split = stages(128, moves)
    print("  128^3 move by stage (median ms): " + ", ".join(f"{k} {v:.1f}" for k, v in split.items()))
    full = results[128, True, "offscreen"]
    dense = results[128, False, "offscreen"]
    preview = results[64, True, "offscreen"]
    verdict = "meets" if full["plotter"] < TARGET_MS else "misses"
    print(
        f"  at 128^3 (sparse): {full['plotter']:.0f} ms to the new mesh in the plotter ({verdict} the "
        f"{TARGET_MS:.0f} ms target; dense grid {dense['plotter']:.0f} ms), {full['rendered']:.0f} ms with a "
        f"software-rendered frame; while dragging the panel shows the 64^3 preview ({preview['rendered']:.0f} ms "
        f"rendered) and remeshes at 128^3 once the slider rests (libfive Studio: 250 ms debounce before "
        f"re-meshing starts); load average now {', '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )


if __name__ == "__main__":
    main()
