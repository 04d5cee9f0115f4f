"""Meshing the Fig. 1 part over [-1.1, 1.1]^3 at 128^3 and 256^3: seconds, volume error, and sdfcad.

``polygonize`` = float32 grid evaluation (dense, or ``sparse=True``: exactly only in blocks
near the surface, the same mesh) + scikit-image marching cubes + every vertex moved onto
f = 0 in float64 + normals from grad f.  ``compiled``: the same, with the model evaluated
through ``pyfrep_core.compiled`` (torch.compile's fused kernels; their one-off compilation
time is printed apart).  Evaluation runs in chunks of 2^15 points on a pool
of single-threaded workers (torch's own 2-thread operations stall when a core is busy).
The peer is ``sdfcad`` (a PyPI fork of
fogleman/sdf) on the same shape written with its own operations, with the same voxel size,
in the same run: ``generate`` (threaded, sparse: it skips blocks that the distance bound
proves empty) returning a triangle soup.  Issue targets: at or below fogleman/sdf (about
1.5 s at 256^3 and 0.30 s at 128^3 on this kind of machine).

Times are the median of a few runs after a warm-up; on a machine shared with other jobs they
are noisy (torch's threads wait for each other when a core is taken), so polygonize is also
timed with one torch thread; the load average is printed with the figures.

Dual contouring (``polygonize(method="dc")``, issue 13): the Fig. 1 part at 128^3- and
256^3-equivalent voxel size (and 512^3, 1024^3 unless PYFREP_QUICK), a closed gyroid block and
the paper's microstructure, each against marching cubes at the same voxel size: seconds,
triangles, volume error (closed forms: the Fig. 1 part; the gyroid solid over [-1, 1]^3 is half
the cube, 4, since f(-x) = -f(x)), pairs of self-intersecting faces (pymeshlab's candidates
confirmed by VTK's collision filter), and peak memory
(the child process's VmHWM less its resident size before meshing).  The peer named by the
issue, libfive, is not on PyPI as a library (its Python package needs the C++ build): "peer not
available" is printed instead of its figures.

Run: ``.venv/bin/python benchmarks/mesh.py [runs]`` (PYFREP_QUICK=1: 3 runs);
``benchmarks/mesh.py dc [runs]``: the dual-contouring table only.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import numpy as np
import torch
from skimage.measure import marching_cubes

from pyfrep_core import polygonize
from pyfrep_core._threads import intra_op_threads
from pyfrep_core.compiled import compiled, warm_up
from pyfrep_core.meshing.grid import _evaluate_grid, grid_axes
from pyfrep_core.meshing.roots import _project_vertices
from pyfrep_core.meshing.sparse import SPARSE_GUARD, SPARSE_STEP, _exact_neighbours, _sparse_grid
from pyfrep_core.models import fig1_part

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
BOUNDS = ((-1.1,) * 3, (1.1,) * 3)
EXACT_VOLUME = 0.9887887  # see tests/test_mesh.py
RESOLUTIONS = (128, 256)


def median_seconds(fn, runs: int) -> tuple[float, object]:
    out = fn()  # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def sdfcad_shape():
    try:
        from sdf import X, Y, box, cylinder, sphere
    except ImportError:
        return None
    # the Fig. 1 program: sphere & cube, minus three infinite cylinders (z, x, y)
    return sphere(1) & box(1.5) - cylinder(0.5) - cylinder(0.5).orient(X) - cylinder(0.5).orient(Y)


def sdfcad_mesh(shape, resolution: int) -> np.ndarray:
    step = 2.2 / (resolution - 1)  # the same voxel size; sdf samples np.arange(lo, hi, step)
    bounds = ((-1.1,) * 3, (1.1 + step / 2,) * 3)
    return np.asarray(shape.generate(bounds=bounds, step=step, verbose=False)).reshape(-1, 3, 3)


def soup_volume(triangles: np.ndarray) -> float:
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def stages(resolution: int) -> dict[str, float]:
    """One run split into grid evaluation (dense and sparse), marching cubes and projection + grad f.

    On one intra-op thread, as polygonize runs them on the CPU.
    """
    with intra_op_threads(1):
        return _stages(resolution)


def _stages(resolution: int) -> dict[str, float]:
    axes = grid_axes(BOUNDS, resolution)
    t0 = time.perf_counter()
    _evaluate_grid(fig1_part, axes, torch.float32, "cpu", None)
    t1 = time.perf_counter()
    values, _, _, mask, evaluated = _sparse_grid(fig1_part, axes, torch.float32, "cpu", SPARSE_STEP, SPARSE_GUARD)
    t2 = time.perf_counter()
    index_verts, _, _, _ = marching_cubes(values, level=0.0, gradient_direction="descent", mask=mask)
    t3 = time.perf_counter()
    spacing = np.array([a[1] - a[0] for a in axes])
    _exact_neighbours(fig1_part, values, index_verts, evaluated, SPARSE_STEP, axes, torch.float32, "cpu")
    _project_vertices(fig1_part, values, index_verts, np.asarray(BOUNDS[0]), spacing, BOUNDS, "cpu")
    t4 = time.perf_counter()
    return {"dense grid": t1 - t0, "sparse grid": t2 - t1, "marching cubes": t3 - t2, "projection": t4 - t3}


def main() -> None:
    runs = int(sys.argv[1]) if len(sys.argv) > 1 else (3 if QUICK else 5)
    shape = sdfcad_shape()
    print(
        f"meshing the Fig. 1 part over [-1.1, 1.1]^3, median of {runs} runs after a warm-up "
        f"({os.cpu_count()} CPUs, torch {torch.__version__} with {torch.get_num_threads()} threads, "
        f"load average {', '.join(f'{x:.2f}' for x in os.getloadavg())})"
    )
    fast_model = compiled(fig1_part)
    warm = warm_up(fast_model)
    for n in RESOLUTIONS:
        seconds, mesh = median_seconds(lambda n=n: polygonize(fig1_part, BOUNDS, n), runs)
        fast, sparse = median_seconds(lambda n=n: polygonize(fig1_part, BOUNDS, n, sparse=True), runs)
        same = np.array_equal(mesh.faces, sparse.faces) and np.abs(mesh.vertices - sparse.vertices).max() <= 1e-12
        err = mesh.volume() - EXACT_VOLUME
        split = ", ".join(f"{k} {v:.3f} s" for k, v in stages(n).items())
        print(f"  {n}^3  polygonize {seconds:6.3f} s  volume error {err:+.1e}  {mesh.n_faces} triangles  ({split})")
        print(
            f"         sparse=True {fast:6.3f} s  ({seconds / fast:.2f}x; {'the same' if same else 'a DIFFERENT'} mesh)"
        )
        fused, fused_mesh = median_seconds(lambda n=n: polygonize(fast_model, BOUNDS, n), runs)
        gap = (
            np.abs(fused_mesh.vertices - mesh.vertices).max()
            if np.array_equal(fused_mesh.faces, mesh.faces)
            else float("inf")
        )
        agree = f"same faces, vertices within {gap:.0e}" if np.isfinite(gap) else "OTHER faces"
        print(
            f"         compiled   {fused:6.3f} s  ({seconds / fused:.2f}x; compiled(fig1_part), kernels compiled "
            f"in {warm:.1f} s once; {agree})"
        )
        if shape is None:
            print("         sdfcad not installed: no peer figure")
            continue
        peer, soup = median_seconds(lambda n=n: sdfcad_mesh(shape, n), runs)
        peer_err = soup_volume(soup) - EXACT_VOLUME
        print(
            f"         sdfcad     {peer:6.3f} s  volume error {peer_err:+.1e}  {len(soup)} triangles  "
            f"-> sdfcad / polygonize = {peer / seconds:.2f}x (dense), {peer / fast:.2f}x (sparse), "
            f"{peer / fused:.2f}x (compiled)"
        )
    print(f"  load average after the runs: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


# ----------------------------------------------------------------------------- dual contouring


def gyroid_block(x: torch.Tensor) -> torch.Tensor:
    """The gyroid solid (paper's lattice, period 1) cut to [-1, 1]^3: exact volume 4."""
    from pyfrep_core import block, gyroid, intersection

    return intersection(gyroid(x), block(x, vertex=(-1.0, -1.0, -1.0), dx=2.0, dy=2.0, dz=2.0))


CASES = {
    "fig1": (lambda: fig1_part, BOUNDS, EXACT_VOLUME),
    "gyroid": (lambda: gyroid_block, BOUNDS, 4.0),
    "microstructure": (lambda: __import__("pyfrep_core.models", fromlist=["x"]).microstructure, None, None),
}


def _resident_kib(key: str) -> int:
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(key):
                return int(line.split()[1])
    return 0


def _child(case: str, method: str, n: int, runs: int) -> None:
    """Mesh once to warm up, then ``runs`` times; print seconds, triangles, volume, flagged faces, MiB."""
    import json

    from pyfrep_core.meshing.dual_contouring import dual_contour  # noqa: F401  (imported before measuring)

    make, bounds, _ = CASES[case]
    f = make()
    polygonize(f, bounds, min(n, 64), method=method, progress=False)
    before = _resident_kib("VmRSS")
    seconds, mesh = median_seconds(lambda: polygonize(f, bounds, n, method=method, progress=False), runs)
    peak = _resident_kib("VmHWM") - before
    # pairs of faces (no common vertex) that intersect: pymeshlab's candidates confirmed by VTK's collision
    # filter (tests/test_octree_dc.py; pymeshlab alone also flags coplanar neighbours that only touch)
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
    from test_octree_dc import self_intersecting_pairs

    flagged = len(self_intersecting_pairs(mesh))
    print(json.dumps([seconds, mesh.n_faces, mesh.volume(), flagged, peak / 1024]))


def measure(case: str, method: str, n: int, runs: int) -> tuple[float, int, float, int, float]:
    import json
    import subprocess

    out = subprocess.run(
        [sys.executable, __file__, "child", case, method, str(n), str(runs)], capture_output=True, text=True
    )
    if out.returncode:
        raise RuntimeError(out.stderr[-2000:])
    return tuple(json.loads(out.stdout.strip().splitlines()[-1]))


def dual_contouring_table(runs: int) -> None:
    print(
        "dual contouring (octree, certified pruning) against marching cubes at the same voxel size "
        f"(median of {runs} runs, each case in its own process; load average "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())})"
    )
    print("  libfive: peer not available")
    rows = [("fig1", 128), ("fig1", 256), ("gyroid", 128), ("microstructure", 128)]
    if not QUICK:
        rows += [("fig1", 512), ("fig1", 1024)]
    for case, n in rows:
        exact = CASES[case][2]
        line = []
        figures = {}
        for method in ("mc", "dc"):
            if method == "mc" and n > 512:
                line.append("mc: skipped (dense grid)")
                continue
            reps = runs if n <= 256 else 1
            seconds, faces, volume, flagged, mib = measure(case, method, n, reps)
            figures[method] = seconds
            err = f"volume error {volume - exact:+.1e}" if exact is not None else f"volume {volume:.4f}"
            line.append(
                f"{method} {seconds:7.3f} s {faces:9d} triangles {err} self-intersecting pairs {flagged} {mib:6.0f} MiB"
            )
        ratio = f"  mc / dc = {figures['mc'] / figures['dc']:.2f}x" if len(figures) == 2 else ""
        print(f"  {case:>14} {n:4d}^3  " + "\n                         ".join(line) + ratio)
    print(f"  load average after the runs: {', '.join(f'{x:.2f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "child":
        _child(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]))
    elif len(sys.argv) > 1 and sys.argv[1] == "dc":
        dual_contouring_table(int(sys.argv[2]) if len(sys.argv) > 2 else (3 if QUICK else 5))
    else:
        main()
        dual_contouring_table(int(sys.argv[1]) if len(sys.argv) > 1 else (3 if QUICK else 5))
