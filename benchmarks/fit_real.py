"""Fitting measured parts: wall time and final distances for each part of pyfrep_core.models.cad_parts.

For each part: 5,000 points on its true surface, Gaussian noise of 0.1 % of its size, a random
rigid pose, and (second row) 5 % of stray points in the cloud's bounding box
(:func:`pyfrep_core.models.cad_parts.scan`).  ``fit(part, points, pose=True, loss="cauchy",
units="mm")`` from its automatic starts: the geometric residual, the pose candidates' local
evolution side by side, the reweighted polish.  Printed: wall and process CPU time, the RMS and
largest geometric distance of the inliers (mm) and the RMS over the noise, the worst dimension in
standard errors, the outliers' precision and recall.

Target (issue 12): every part fitted in under 3 s on this 2-core machine (one core free), RMS
within 1.5x the noise.  There is no outside program to compare with; the peer row is the paper's
loss with the same pose machinery (algebraic residual, l2), timed in the same run, to show what the
robust geometric fit buys.  One-time costs (torch.func's first transforms, the samples) are paid by
a warm-up fit before the clocks start; ``fit`` runs on one intra-op thread, so on a shared machine
the CPU time printed beside the wall time is close to what the wall time would be on a quiet one.

Run: ``.venv/bin/python benchmarks/fit_real.py [part ...]`` (PYFREP_QUICK=1: 2,000 points).
"""

from __future__ import annotations

import os
import sys
import time
import warnings

import numpy as np

from pyfrep_core import fit
from pyfrep_core.fitting import IdentifiabilityWarning
from pyfrep_core.models.cad_parts import PARTS, scan

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
N = 2000 if QUICK else 5000
TARGET_SECONDS, TARGET_RMS = 3.0, 1.5


def run(name: str, data: dict, **options) -> tuple:
    wall, cpu = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)  # the axisymmetric parts' free turn
        res = fit(PARTS[name], data["points"], pose=True, units="mm", seed=0, progress=False, **options)
    return res, time.perf_counter() - wall, time.process_time() - cpu


def row(label: str, res, wall: float, cpu: float, data: dict) -> str:
    sigma = data["sigma"]
    worst = max(
        (abs(res.params[k] - v) / res.std_errors[k] for k, v in data["truth"].items() if k in res.std_errors),
        default=float("nan"),
    )
    found, true = ~res.inliers, data["outlier"]
    hits = int((found & true).sum())
    pr = f"{hits / max(found.sum(), 1):.3f}/{hits / true.sum():.3f}" if true.any() else "  -  "
    return (
        f"  {label:28s} {wall:6.2f} s wall {cpu:6.2f} s cpu   rms {res.rms:.4f} mm ({res.rms / sigma:4.2f} x noise)"
        f"  max {res.max_distance:.4f}   worst dim {worst:7.1f} SE   outliers P/R {pr}"
    )


def main() -> None:
    names = sys.argv[1:] or sorted(PARTS)
    warm = scan("l_bracket", n=500, seed=1)
    run("l_bracket", warm, loss="cauchy", cycles=100)  # warm-up: torch.func's first calls, scipy
    print(f"fit_real: {N} points a part, noise 0.1 % of the size; load average {os.getloadavg()}")
    for name in names:
        clean = scan(name, n=N, outliers=0.0, seed=7)
        dirty = scan(name, n=N, outliers=0.05, seed=7)
        print(f"{name} (noise {clean['sigma']:.4f} mm)")
        timings = []
        for label, data in (("clean, cauchy", clean), ("5 % outliers, cauchy", dirty)):
            res, wall, cpu = run(name, data, loss="cauchy")
            timings.append((wall, cpu, res.rms / data["sigma"]))
            print(row(label, res, wall, cpu, data))
        peer, pwall, pcpu = run(name, dirty, residual="algebraic", loss="l2")
        print(row("peer: 5 % outliers, alg. l2", peer, pwall, pcpu, dirty))
        wall, cpu, ratio = timings[-1]
        print(
            f"  ours / peer: time {wall / pwall:.2f}x wall, {cpu / pcpu:.2f}x cpu; rms {res.rms / peer.rms:.3f}x;  "
            f"target {TARGET_SECONDS} s: {'met' if cpu < TARGET_SECONDS else 'NOT met'} (cpu), "
            f"rms < {TARGET_RMS} x noise: {'met' if ratio < TARGET_RMS else 'NOT met'}"
        )
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    main()
