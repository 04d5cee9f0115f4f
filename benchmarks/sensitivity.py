"""Per-point parameter derivatives df/dp: seconds and peak memory, before and after issue 11.

After: the kernel's one implementation (per-sample reverse mode, ``vmap(grad(f_one_point))``
over chunks of points, :func:`pyfrep_core.diff.param_grad`), behind ``param_derivative``, the
shape panel's colouring (``surface_velocity``: -(df/dp) / |grad f| with the grad f polygonize
kept) and the fitting polish's Jacobian.  Before: one copy of each parameter per point and one
reverse pass (the method the kernel used until issue 11, kept here only as ``per_point_copies``);
it relies on the model broadcasting its parameters element-wise, which the paper's models do.

Cases: the Fig. 1 part (``pyfrep_core.models.fig1_part``) meshed at 128^3 and 256^3 (df/dr at
the vertices, and the colouring), the fitting Jacobian of the microstructure for 40,000 surface
points x 4 parameters, and (after only) the colouring of the two-parameter box with a hole at
128^3, where the per-point copies allocated N x N (9 GB at 11,776 vertices).  Target: no slower
than the per-point copies on the paper's models.

Seconds are the median of ``repeats`` runs after a warm-up call, before and after interleaved,
on ``torch.get_num_threads()`` threads, as wall time and as process CPU time (all threads: the
work done, steadier than the wall time on a shared machine); peak memory is the growth of the
resident set during one run (VmHWM reset through /proc/self/clear_refs; "n/a" where that is not
available).  The script re-executes itself with
glibc's mmap threshold fixed at 128 KiB, so that large tensors are returned to the system when
freed and every run's peak is seen (not hidden by memory an earlier run left in the heap).

Run: ``.venv/bin/python benchmarks/sensitivity.py [repeats]`` (PYFREP_QUICK=1: one repeat, 128^3 only).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np
import torch

from pyfrep_core import Param, block, cylZ, difference, model, polygonize, sample_surface
from pyfrep_core.fitting import _jacobian, _Problem
from pyfrep_core.models import fig1_part, microstructure
from pyfrep_core.sensitivity import param_derivative
from workbench.shape_panel import surface_velocity

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
FIT_PARAMS = dict(scale1=9.0, scale2=3.0, freq1=0.75, freq2=0.85)  # the paper's experiment (benchmarks/fitting.py)


@model(bounds=((-1.0,) * 3, (1.0,) * 3), size=Param(1.0, 0.6, 1.4), hole=Param(0.2, 0.05, 0.28))
def box_with_hole(x, size, hole):
    h = size / 2
    return difference(block(x, vertex=(-h, -h, -h), dx=size, dy=size, dz=size), cylZ(x, r=hole))


def per_point_copies(m, x: torch.Tensor, names: list[str], values: dict, chunk: int = 1 << 14) -> torch.Tensor:
    """Before: df/dp (N, P) by one reverse pass per chunk with one copy of each parameter per point."""
    parts = []
    for i in range(0, x.shape[0], chunk):
        xc = x[i : i + chunk]
        copies = [torch.full((xc.shape[0],), float(values[k]), dtype=xc.dtype, requires_grad=True) for k in names]
        with torch.enable_grad():
            y = m.fn(xc, **{**values, **dict(zip(names, copies))})
            grads = torch.autograd.grad(y.sum(), copies)
        parts.append(torch.stack(grads, dim=1))
    return torch.cat(parts)


def _rss() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _peak() -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _peak_growth(fn: Callable[[], object]) -> float | None:
    """Peak growth of the resident set (MB) during one ``fn()``, or None where it cannot be read."""
    base = _rss()
    exact = _reset_peak()
    fn()
    peak = _peak()
    return (peak - base) / 1e6 if exact and peak is not None else None


def compare(label: str, after: Callable[[], object], before: Callable[[], object] | None, repeats: int) -> None:
    """Print median wall and CPU seconds and the peak memory of ``after`` (and ``before``, runs interleaved)."""
    fns = {"after": after} if before is None else {"after": after, "before": before}
    results = {k: np.asarray(fn()) for k, fn in fns.items()}  # warm-up, and the values compared
    wall: dict[str, list[float]] = {k: [] for k in fns}
    cpu: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(repeats):  # interleaved: a change of the machine's load hits both alike
        for k, fn in fns.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    peak = {k: _peak_growth(fn) for k, fn in fns.items()}

    def cell(k: str) -> str:
        mb = "n/a" if peak[k] is None else f"{peak[k]:.0f} MB"
        return f"{k} {statistics.median(wall[k]) * 1e3:6.1f} ms (CPU {statistics.median(cpu[k]) * 1e3:6.1f}), +{mb}"

    line = f"  {label:<22} {cell('after')}"
    if before is not None:
        ratio = statistics.median(wall["before"]) / statistics.median(wall["after"])
        ratio_cpu = statistics.median(cpu["before"]) / statistics.median(cpu["after"])
        diff = float(np.abs(results["after"] - results["before"]).max())
        line += f" | {cell('before')} | before/after {ratio:.2f}x (CPU {ratio_cpu:.2f}x), max |diff| {diff:.0e}"
    print(line)


def fig1_case(res: int, repeats: int) -> None:
    """df/dr and the colouring at the vertices of the Fig. 1 part meshed at ``res``^3."""
    values = fig1_part.defaults()
    mesh = polygonize(fig1_part, resolution=res)
    verts = torch.as_tensor(mesh.vertices)
    length = np.linalg.norm(mesh.gradient, axis=1)
    print(f"Fig. 1 part at {res}^3: {mesh.n_vertices} vertices, float64")
    compare(
        "df/dr",
        lambda: param_derivative(fig1_part, mesh.vertices, "r", values),
        # param_derivative's chunk was 2^18 points, the panel's (surface_velocity) 2^14
        lambda: per_point_copies(fig1_part, verts, ["r"], values, 1 << 18)[:, 0].numpy(),
        repeats,
    )

    def colour_before() -> np.ndarray:
        df = per_point_copies(fig1_part, verts, ["r"], values, 1 << 14)[:, 0].numpy()
        return np.where(length > 0, -df / np.where(length > 0, length, 1.0), 0.0)

    compare("colouring", lambda: surface_velocity(fig1_part, mesh, "r", values), colour_before, repeats)


def main() -> None:
    if "MALLOC_MMAP_THRESHOLD_" not in os.environ:  # see the module docstring
        env = dict(os.environ, MALLOC_MMAP_THRESHOLD_=str(128 << 10))
        os.execve(sys.executable, [sys.executable, *sys.argv], env)
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else (1 if QUICK else 5)
    resolutions = (128,) if QUICK else (128, 256)
    print(f"df/dp per point, torch {torch.__version__}, {torch.get_num_threads()} threads, median of {repeats}")
    print(f"  machine load: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min)")
    for res in resolutions:
        fig1_case(res, repeats)

    points = sample_surface(microstructure, 40_000, params=FIT_PARAMS, seed=0, resolution=128)
    x = torch.as_tensor(points, dtype=torch.float64)
    prob = _Problem(microstructure, {}, {k: (p.lower, p.upper) for k, p in microstructure.params.items()})
    q = torch.tensor(list(FIT_PARAMS.values()), dtype=torch.float64)
    print(f"fitting Jacobian of the microstructure: {x.shape[0]} points x {q.shape[0]} parameters, float64")
    compare(
        "N x P Jacobian",
        lambda: _jacobian(prob, x, q).numpy(),
        lambda: per_point_copies(microstructure, x, prob.free, FIT_PARAMS, 1 << 16).numpy(),
        repeats,
    )

    mesh = polygonize(box_with_hole, resolution=128)
    values = box_with_hole.defaults()
    print(f"box with a hole at 128^3: {mesh.n_vertices} vertices (before: N x N, 9 GB at 11,776 vertices)")
    for name in box_with_hole.names:
        compare(f"colouring by {name}", lambda n=name: surface_velocity(box_with_hole, mesh, n, values), None, repeats)


if __name__ == "__main__":
    main()
