"""Interval bounds over the cells of an n^3 grid on [-1.1, 1.1]^3 against point evaluation of as many points.

For the Fig. 1 part, the microstructure of Fig. 8 (over its own box) and a gyroid: seconds for
:func:`pyfrep_core.interval.bounds` on the n^3 cells (float64 and float32) and for evaluating the
model at n^3 points (the cells' lower corners), least CPU time of several runs in one process; their
ratio; how many cells are proved empty (bounds of one sign: no surface inside), and, for
comparison, how many cells hold a sign change at their 8 corners (those must never be proved
empty).  One torch thread, CPU time of this process (both sides alike; steadier than wall time
on a shared machine); ``os.getloadavg()`` is printed: timings on a loaded machine are relative.

Run: ``.venv/bin/python benchmarks/interval.py`` (PYFREP_QUICK=1: 32^3 only).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import torch

from pyfrep_core import gyroid
from pyfrep_core.interval import bounds
from pyfrep_core.models import fig1_part, microstructure

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")


def best(fn: Callable, repeats: int = 9) -> float:
    """Least CPU seconds of this process over the repeats (steadier than wall time on a shared machine)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


def cells(n: int, lo: float, hi: float, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.linspace(lo, hi, n + 1, dtype=torch.float64)
    c = torch.stack(torch.meshgrid(g[:-1], g[:-1], g[:-1], indexing="ij"), -1).reshape(-1, 3)
    return c.to(dtype), (c + (hi - lo) / n).to(dtype)


def main() -> None:
    torch.set_num_threads(1)
    print(f"load {os.getloadavg()}, torch threads {torch.get_num_threads()}; times: CPU seconds")
    cases = [
        ("fig1_part", fig1_part, -1.1, 1.1),
        ("microstructure", microstructure, -10.5, 10.5),
        ("gyroid", lambda x: gyroid(x, alpha=1.0, beta=1.0, gamma=1.0, c=0.0), -1.1, 1.1),
    ]
    head = ("model", "n", "dtype", "bounds", "points", "ratio", "empty", "crossing")
    print("{:16s} {:>4s} {:8s} {:>9s} {:>9s} {:>6s} {:>14s} {:>9s}".format(*head))
    for n in (32,) if QUICK else (32, 64):
        for name, f, lo, hi in cases:
            for dtype in (torch.float64, torch.float32):
                clo, chi = cells(n, lo, hi, dtype)
                t_bounds = best(lambda f=f, clo=clo, chi=chi: bounds(f, clo, chi))
                t_points = best(lambda f=f, clo=clo: f(clo))
                flo, fhi = bounds(f, clo, chi)
                empty = int(((flo > 0) | (fhi < 0)).sum())
                g = torch.linspace(lo, hi, n + 1, dtype=dtype)
                v = f(torch.stack(torch.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)).reshape(
                    n + 1, n + 1, n + 1
                )
                corners = torch.stack(
                    [v[i : i + n, j : j + n, k : k + n] for i in (0, 1) for j in (0, 1) for k in (0, 1)], -1
                ).reshape(-1, 8)
                crossing = (corners.amax(-1) > 0) & (corners.amin(-1) < 0)
                assert not bool((crossing & ((flo > 0) | (fhi < 0))).any())
                print(
                    f"{name:16s} {n:4d} {str(dtype)[6:]:8s} {t_bounds:9.4f} {t_points:9.4f} {t_bounds / t_points:6.1f} "
                    f"{empty:7d} {100 * empty / n**3:5.1f}% {int(crossing.sum()):9d}"
                )
    print(f"load {os.getloadavg()}")


if __name__ == "__main__":
    main()
