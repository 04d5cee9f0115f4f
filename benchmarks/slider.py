"""Slider to view: median time from a slider value change to the new mesh in the 3-D view.

The Fig. 1 part, cylinder-radius slider, at 128^3 and 64^3 grid samples.  Each move runs the
whole journey (ARCHITECTURE.md, journey 1): model on the grid -> marching cubes -> Newton
projection and normals -> sensitivity colouring -> points/faces replaced in the view's one
PolyData -> ``plotter.render()`` off-screen.  Reported: the median over the moves, split into
remesh (core) and render, and with the PNG the image fallback sends.  Target: < 100 ms at 128^3.

Run: ``.venv/bin/python benchmarks/slider.py`` (PYFREP_QUICK=1: fewer moves).
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

from pyfrep_core.models import fig1_part
from workbench.shape_panel import shape_panel

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
TARGET_MS = 100.0


def measure(resolution: int, moves: int, backend: str, colouring: str = "sensitivity") -> dict[str, float]:
    panel = shape_panel(
        fig1_part, resolution=resolution, backend=backend, threaded=False, colouring=colouring, size=(640, 480)
    )
    slider = panel.sliders["r"]
    values = 0.5 + 0.05 * np.sin(np.arange(1, moves + 2))  # distinct radii around Fig. 2's 0.5
    slider.value = float(values[0])  # warm-up (first render, autograd warm-up)
    total, remesh, render = [], [], []
    for v in values[1:]:
        t0 = time.perf_counter()
        slider.value = float(v)  # the callback remeshes and renders before returning
        total.append(time.perf_counter() - t0)
        remesh.append(panel.last_remesh_s)
        render.append(panel.view.last_render_s)
    triangles = panel.mesh.n_faces
    panel.view.close()
    ms = lambda xs: 1000 * statistics.median(xs)  # noqa: E731
    return {"total": ms(total), "remesh": ms(remesh), "render": ms(render), "triangles": triangles}


def main() -> None:
    moves = 3 if QUICK else 9
    print(f"slider -> view, Fig. 1 part, median of {moves} moves ({os.cpu_count()} CPUs)")
    rows = []
    for resolution in (128, 64):
        for backend, what in (("offscreen", "plotter.render()"), ("image", "+ PNG for the image view")):
            r = measure(resolution, moves, backend)
            rows.append((resolution, what, r))
            print(
                f"  {resolution:>3}^3  {what:<26} {r['total']:7.1f} ms  (remesh {r['remesh']:6.1f} ms, "
                f"view {r['render']:6.1f} ms, {r['triangles']} triangles)"
            )
    full = rows[0][2]["total"]
    preview = rows[2][2]["total"]
    print(
        f"  at 128^3: {full:.0f} ms per move ({'meets' if full < TARGET_MS else 'misses'} the "
        f"{TARGET_MS:.0f} ms target); "
        f"while dragging the panel shows the 64^3 preview ({preview:.0f} ms) and remeshes at 128^3 once the "
        f"slider rests (libfive Studio: 250 ms debounce before re-meshing starts)"
    )


if __name__ == "__main__":
    main()
