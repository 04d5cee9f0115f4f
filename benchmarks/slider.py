"""Slider to view: median time from a slider value change to the new mesh in the 3-D view.

The Fig. 1 part, cylinder-radius slider, at 128^3 and 64^3 grid samples.  Each move runs the
whole journey of a slider move: model on the grid -> marching cubes -> vertices
onto f = 0 and grad f -> sensitivity colouring (df/dp, reusing polygonize's grad f) ->
points/faces replaced in the view's one PolyData.  Two ways of evaluating the model, as the
panel does: ``compiled`` (``pyfrep_core.compiled``: torch.compile's fused kernels, dense grid;
what the panel uses once the kernels are compiled, whose one-off time is printed) and
``eager`` (plain torch, sparse grid; what it uses until then).  Reported, as medians over the
moves:

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

import functools
import os
import statistics
import time
from typing import Any

import numpy as np
import torch
from skimage.measure import marching_cubes

from pyfrep_core import Mesh
from pyfrep_core._threads import intra_op_threads
from pyfrep_core.compiled import compiled as compiled_model
from pyfrep_core.meshing.grid import _evaluate_grid, grid_axes
from pyfrep_core.meshing.roots import _normals, _project_vertices
from pyfrep_core.meshing.sparse import SPARSE_GUARD, SPARSE_STEP, _exact_neighbours, _sparse_grid
from pyfrep_core.models import fig1_part
from pyfrep_core.sensitivity import param_derivative
from workbench.shape_panel import shape_panel
from workbench.view import MeshView

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
TARGET_MS = 100.0


def ms(xs: list[float]) -> float:
    return 1000 * statistics.median(xs)


def measure(resolution: int, moves: int, backend: str, compiled: bool) -> dict[str, float]:
    panel = shape_panel(
        fig1_part, resolution=resolution, backend=backend, threaded=False, size=(640, 480), compiled=compiled
    )
    warm = panel.warm_up()  # compile the kernels (0 when eager, or compiled earlier in this process)
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
    assert ("(compiled)" in panel.status.value) == compiled, panel.status.value
    triangles = panel.mesh.n_faces
    panel.view.close()
    return {
        "plotter": ms([t - r for t, r in zip(total, render)]),
        "rendered": ms(total),
        "remesh": ms(remesh),
        "render": ms(render),
        "triangles": triangles,
        "warm_up": warm,
    }


def stages(resolution: int, runs: int, f_model: Any, sparse: bool) -> dict[str, float]:
    """One move split: grid, marching cubes, vertices onto f = 0 (+ grad f), normals, df/dp, plotter, frame."""
    bounds = fig1_part.bounds
    lo = np.asarray(bounds[0])
    axes = grid_axes(bounds, resolution)
    spacing = np.array([a[1] - a[0] for a in axes])
    view = MeshView(backend="offscreen", size=(640, 480))
    view.render = lambda **_: None  # noqa: E731  (the frame is timed separately)
    rows: dict[str, list[float]] = {}
    with intra_op_threads(1):  # as polygonize runs
        for k in range(runs + 1):
            r = 0.5 + 0.01 * k
            f = functools.partial(f_model, r=r)
            t = [time.perf_counter()]
            if sparse:
                values, _, _, mask, evaluated = _sparse_grid(f, axes, torch.float32, "cpu", SPARSE_STEP, SPARSE_GUARD)
            else:
                values, _, _ = _evaluate_grid(f, axes, torch.float32, "cpu", None)
                mask = None
            t.append(time.perf_counter())
            index_verts, faces, _, _ = marching_cubes(values, 0.0, gradient_direction="descent", mask=mask)
            faces = np.ascontiguousarray(faces[:, ::-1], dtype=np.int64)
            t.append(time.perf_counter())
            if sparse:
                _exact_neighbours(f, values, index_verts, evaluated, SPARSE_STEP, axes, torch.float32, "cpu")
            verts, gradient, _ = _project_vertices(f, values, index_verts, lo, spacing, bounds, "cpu")
            t.append(time.perf_counter())
            normals = _normals(gradient, verts, faces)
            t.append(time.perf_counter())
            df_dp = param_derivative(f_model, verts, "r", {"r": r}, chunk=1 << 14)
            t.append(time.perf_counter())
            view.update(Mesh(verts, faces, normals), scalars=-df_dp, title="v", clim=(-1.0, 1.0))
            t.append(time.perf_counter())
            view.plotter.render_window.Render()
            t.append(time.perf_counter())
            if k:  # the first run warms up
                names = ("sparse grid" if sparse else "grid", "marching cubes", "vertices onto f = 0 + grad f")
                names += ("normals", "df/dp", "PolyData into the plotter", "frame (Mesa)")
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
    for compiled in (True, False):
        for resolution in (128, 64):
            for backend in ("offscreen", "image"):
                r = measure(resolution, moves, backend, compiled)
                results[resolution, compiled, backend] = r
                how = "compiled" if compiled else "eager   "
                what = "rendered" if backend == "offscreen" else "+ PNG   "
                warm = f", kernels compiled in {r['warm_up']:.1f} s first" if r["warm_up"] else ""
                print(
                    f"  {resolution:>3}^3 {how}  in plotter {r['plotter']:6.1f} ms  {what} {r['rendered']:6.1f} ms"
                    f"  (remesh {r['remesh']:6.1f} ms, frame {r['render']:5.1f} ms, {r['triangles']} triangles{warm})"
                )
    for label, f_model, sparse in (
        ("compiled, dense", compiled_model(fig1_part), False),
        ("eager, sparse", fig1_part, True),
    ):
        split = stages(128, moves, f_model, sparse)
        print(f"  128^3 move by stage, {label} (median ms): " + ", ".join(f"{k} {v:.1f}" for k, v in split.items()))
    full = results[128, True, "offscreen"]
    eager = results[128, False, "offscreen"]
    preview = results[64, True, "offscreen"]
    verdict = "meets" if full["plotter"] < TARGET_MS else "misses"
    print(
        f"  at 128^3: {full['plotter']:.0f} ms to the new mesh in the plotter with the compiled model ({verdict} the "
        f"{TARGET_MS:.0f} ms target; eager {eager['plotter']:.0f} ms, {eager['plotter'] / full['plotter']:.1f}x "
        f"slower), {full['rendered']:.0f} ms with a software-rendered frame; 64^3: {preview['plotter']:.0f} ms "
        f"(libfive Studio: 250 ms debounce before re-meshing starts); load average now "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )


if __name__ == "__main__":
    main()
