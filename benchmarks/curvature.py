"""Mean + Gaussian curvature at the vertices of the Fig. 1 part meshed at 256^3, float32 and float64.

Times (best of several runs, wall clock and CPU; the mesh is not timed), in one process:

- ours, separate calls: :func:`mean_curvature` then :func:`gaussian_curvature` (each one
  evaluation of f and 3 backward passes: the gradient and two Hessian-vector products along a
  tangent frame, in chunks spread over ``torch.get_num_threads()`` threads);
- ours, one :func:`curvatures` call (H, K, principal curvatures and directions together);
- the same two, fused: ``compiled(fig1_part, second_order=True)``, whose passes are traced
  once into a graph without autograd and compiled by Inductor (the compilation, paid once per
  dtype and cached on disk by Inductor, is timed and printed separately);
- variants, for the record: the full Hessian (1 + 3 passes) + the paper's formulas
  (:func:`curvatures_from_hessian`); per-point functional derivatives ``vmap(jacrev(grad))``
  (reverse over reverse) and ``vmap(torch.func.hessian)`` (forward over reverse: forward-mode
  AD is process-global in torch, so run on one thread), + the paper's formulas;
- the paper's code (fayolle/PyFRep, ``FRep.curvature.meanCurvature`` then
  ``GaussianCurvature`` on the Fig. 1 program written with its own primitives) when
  ``PYFREP_SRC`` names a checkout of it; otherwise a re-implementation of its algorithm
  (H = -1/2 div(n) by a loop of backward passes with ``create_graph``, then K from a
  separately built Hessian).

Targets (issue 11): 4x the paper's code with the separate calls, 8x with ``curvatures``.
Accuracy column: H against the paper's formulas on our full Hessian in float64, 99.9th
percentile of |dH| / (1 + |H|) over the vertices where the curvature is defined (a few dozen
land exactly on R-function creases: NaN in ours, huge values in the paper's code).

Run: ``PYFREP_SRC=/path/to/PyFRep .venv/bin/python benchmarks/curvature.py``
(PYFREP_QUICK=1: 128^3 and fewer repeats).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable

import numpy as np
import torch
from torch.func import grad as func_grad
from torch.func import hessian as func_hessian
from torch.func import jacrev, vmap

from pyfrep_core import polygonize
from pyfrep_core.compiled import compiled, warm_up
from pyfrep_core.curvature import curvatures, curvatures_from_hessian, gaussian_curvature, mean_curvature
from pyfrep_core.diff import _map_chunks, value_grad_hessian
from pyfrep_core.models import fig1_part

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")


def f(x: torch.Tensor) -> torch.Tensor:
    return fig1_part(x)


def separate(x: torch.Tensor):
    return mean_curvature(f, x), gaussian_curvature(f, x)


def ours(x: torch.Tensor):
    return curvatures(f, x)


FUSED = compiled(fig1_part, second_order=True)


def fused_separate(x: torch.Tensor):
    return mean_curvature(FUSED, x), gaussian_curvature(FUSED, x)


def fused(x: torch.Tensor):
    return curvatures(FUSED, x)


def full_hessian(x: torch.Tensor):
    _, g, h = value_grad_hessian(f, x)
    return curvatures_from_hessian(g, h, x)


def _single(p: torch.Tensor) -> torch.Tensor:
    return f(p.unsqueeze(0)).squeeze(0)  # the model sees (1, 3) points


def reverse_over_reverse(x: torch.Tensor):
    def grad_twice(p):
        g = func_grad(_single)(p)
        return g, g

    g, h = _map_chunks(lambda c: vmap(jacrev(grad_twice, has_aux=True))(c)[::-1], x, None)
    return curvatures_from_hessian(g, h)


def forward_over_reverse(x: torch.Tensor):
    def one(c):
        return vmap(func_grad(_single))(c), vmap(func_hessian(_single))(c)

    g, h = _map_chunks(one, x, None, parallel=False)  # forward-mode AD levels are process-global
    return curvatures_from_hessian(g, h)


def papers_algorithm(x: torch.Tensor):
    """H = -1/2 div(grad f/|grad f|) by a loop of backward passes, then K from a Hessian (paper Figs. 5-6)."""
    vt = x.detach().clone().requires_grad_(True)
    ft = f(vt)
    g = torch.autograd.grad(ft, [vt], grad_outputs=torch.ones_like(ft), create_graph=True)[0]
    n = g / torch.linalg.norm(g, 2, dim=1, keepdim=True)
    div = 0.0
    for i in range(3):
        div += torch.autograd.grad(n[..., i], vt, grad_outputs=torch.ones_like(n[..., i]), create_graph=True)[0][..., i]
    mean = (-0.5 * div).detach()
    vt = x.detach().clone().requires_grad_(True)
    ft = f(vt)
    g = torch.autograd.grad(ft, [vt], grad_outputs=torch.ones_like(ft), create_graph=True)[0]
    rows = [
        torch.autograd.grad(g[..., i], vt, grad_outputs=torch.ones_like(g[..., i]), create_graph=True)[0]
        for i in range(3)
    ]
    gauss = curvatures_from_hessian(g.detach(), torch.stack(rows, 1).detach()).K
    return mean, gauss


def papers_code() -> Callable | None:
    """meanCurvature + GaussianCurvature of the paper's code on its Fig. 1 program, or None without PYFREP_SRC."""
    src = os.environ.get("PYFREP_SRC", "")
    if not src:
        return None
    if not os.path.isfile(os.path.join(src, "FRep", "curvature.py")):
        raise SystemExit(f"PYFREP_SRC={src!r} is not a checkout of fayolle/PyFRep (no FRep/curvature.py)")
    sys.path.insert(0, src)
    from FRep.curvature import GaussianCurvature, meanCurvature
    from FRep.ops import difference, intersection
    from FRep.primitives import block, cylX, cylY, cylZ, sphere

    def fig1(p):  # the paper's Fig. 1 program, as written there
        sp1 = sphere(p, center=(0, 0, 0), r=1)
        b1 = block(p, vertex=(-0.75, -0.75, -0.75), dx=1.5, dy=1.5, dz=1.5)
        t1 = intersection(sp1, b1)
        c1 = cylX(p, center=(0, 0, 0), r=0.5)
        c2 = cylY(p, center=(0, 0, 0), r=0.5)
        c3 = cylZ(p, center=(0, 0, 0), r=0.5)
        return difference(difference(difference(t1, c1), c2), c3)

    def run(x: torch.Tensor):
        v = x.numpy().astype(np.float64)  # its entry takes numpy points and a dtype
        return torch.from_numpy(meanCurvature(fig1, v, dtype=x.dtype)), torch.from_numpy(
            GaussianCurvature(fig1, v, dtype=x.dtype)
        )

    return run


def best_of(fn, x, repeats: int) -> tuple[float, float, object]:
    fn(x[:20000])  # warm-up
    walls, cpus, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn(x)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus), out


def main() -> None:
    resolution = 128 if QUICK else 256
    repeats = 3 if QUICK else 7
    t0 = time.perf_counter()
    mesh = polygonize(fig1_part, resolution=resolution)
    x64 = torch.as_tensor(mesh.vertices, dtype=torch.float64)
    print(
        f"Fig. 1 part at {resolution}^3: {mesh.n_vertices} vertices (mesh {time.perf_counter() - t0:.1f} s, "
        f"not timed); torch {torch.__version__}, {torch.get_num_threads()} threads, {os.cpu_count()} CPUs; "
        f"load average {' '.join(f'{v:.2f}' for v in os.getloadavg())}"
    )
    ref = full_hessian(x64).H
    defined = torch.isfinite(ref)  # vertices on a crease have no curvature (NaN): left out of the comparison
    paper = papers_code()
    reference = (
        ("paper's code (PyFRep, PYFREP_SRC)", paper)
        if paper
        else ("paper's algorithm, re-implemented", papers_algorithm)
    )
    if paper is None:
        print("  PYFREP_SRC not set: the paper's algorithm re-implemented here stands in for its code")
    sphere_part = (np.abs(np.linalg.norm(mesh.vertices, axis=1) - 1) < 1e-9) & (np.abs(mesh.vertices).max(1) < 0.74)
    for dtype in (torch.float32, torch.float64):
        x = x64.to(dtype)
        print(f"{str(dtype).removeprefix('torch.')}:")
        rows = {}
        seconds = warm_up(FUSED, dtypes=(), gradients=(), second_order=(dtype,))
        print(f"  compiling the fused second-order kernel: {seconds:.1f} s (once per dtype, cached on disk)")
        for name, fn, reps in (
            ("ours: mean_curvature + gaussian_curvature", separate, repeats),
            ("ours: curvatures (H, K, kmin, kmax, dirs)", ours, repeats),
            ("fused: mean_curvature + gaussian_curvature", fused_separate, repeats),
            ("fused: curvatures (H, K, kmin, kmax, dirs)", fused, repeats),
            ("hessian (1+3 passes) + paper formulas", full_hessian, max(2, repeats // 2)),
            ("vmap(jacrev(grad)) + paper formulas", reverse_over_reverse, 2),
            ("vmap(hessian), one thread + formulas", forward_over_reverse, 2),
            (reference[0], reference[1], max(2, repeats // 2)),
        ):
            wall, cpu, out = best_of(fn, x, reps)
            H = out[0] if isinstance(out, tuple) and not hasattr(out, "H") else out.H
            both = defined & torch.isfinite(H)
            dev = (torch.abs(H.double() - ref) / (1 + torch.abs(ref)))[both]
            dev = float(torch.kthvalue(dev, max(1, int(0.999 * dev.numel())))[0])
            rows[name] = (wall, cpu)
            print(
                f"  {name:<42} {wall:7.3f} s wall {cpu:7.3f} s CPU   "
                f"H vs formulas: 99.9 % within {dev:.0e}, {int((defined & ~both).sum())} more NaN"
            )
        c = curvatures(f, x)
        err_h = float(np.abs(c.H.double().numpy()[sphere_part] - 1).max())
        err_k = float(np.abs(c.K.double().numpy()[sphere_part] - 1).max())
        n_sphere = int(sphere_part.sum())
        print(f"  on the {n_sphere} vertices of the sphere patches: |H - 1| {err_h:.1e}, |K - 1| {err_k:.1e}")
        ref_wall, ref_cpu = rows[reference[0]]
        for name, target in (
            ("ours: mean_curvature + gaussian_curvature", 4),
            ("ours: curvatures (H, K, kmin, kmax, dirs)", 8),
            ("fused: mean_curvature + gaussian_curvature", 4),
            ("fused: curvatures (H, K, kmin, kmax, dirs)", 8),
        ):
            wall, cpu = rows[name]
            print(
                f"  {name}: {ref_wall / wall:.1f}x the {reference[0]} in wall time, "
                f"{ref_cpu / cpu:.1f}x in CPU time (target {target}x)"
            )


if __name__ == "__main__":
    main()
