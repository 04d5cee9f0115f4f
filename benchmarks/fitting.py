"""Fitting the paper's microstructure (section 5.4): wall time per stage and accuracy.

The paper's protocol on 40,000 surface points sampled at the experiment's parameters
(scale1, scale2, freq1, freq2) = (9, 3, 0.75, 0.85): regularized evolution (10,000 cycles,
population 100, tournaments of 10), then 100 SGD (Adam) epochs, then our least-squares polish.
The paper's code takes 17 s + 12 s = 29 s for the first two stages here and ends with a
parameter 2 % off.  Target: at least 20x less wall time (< 1.45 s) with every parameter
within 0.1 %.  SGD alone from a random start (Fig. 7) is run too.

One-time costs (imports, torch's first-call initialization) are paid by a small warm-up fit
before the clock starts; sampling the cloud is not timed.  ``fit`` runs on one intra-op thread,
so on a shared machine the process CPU time, printed beside the wall time, is close to what the
wall time would be on a quiet one.

Run: ``.venv/bin/python benchmarks/fitting.py [repeats]`` (PYFREP_QUICK=1: one repeat).
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import scipy.optimize  # noqa: F401  (imported before timing: the polish uses it)
import torch

from pyfrep_core import fit, sample_surface
from pyfrep_core.models import microstructure

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
PAPER = dict(scale1=9.0, scale2=3.0, freq1=0.75, freq2=0.85)  # the experiment's parameters
PAPER_SECONDS = 17.0 + 12.0  # the paper's code here: regularized evolution + 100 SGD epochs
PROTOCOL = dict(cycles=10_000, population_size=100, sample_size=10, epochs=100)
STAGES = ("evolution", "sgd", "polish", "total")


def relative_errors(params: dict[str, float]) -> dict[str, float]:
    return {k: abs(params[k] / v - 1.0) for k, v in PAPER.items()}


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else (1 if QUICK else 3)
    points = sample_surface(microstructure, 40_000, params=PAPER, seed=0, resolution=128)
    fit(microstructure, points[:1000], cycles=200, epochs=1, progress=False, seed=0)  # warm-up
    print(f"fitting the microstructure to {len(points)} points, torch {torch.__version__}, 1 intra-op thread")
    runs, cpu = [], []
    for seed in range(repeats):
        c0 = time.process_time()
        runs.append(fit(microstructure, points, seed=seed, progress=False, **PROTOCOL))
        cpu.append(time.process_time() - c0)
    median = {s: statistics.median(r.timings[s] for r in runs) for s in STAGES}
    print("full protocol (evolution -> SGD -> polish), median of", repeats, "runs:")
    for s in STAGES:
        print(f"  {s:<10} {median[s]:7.3f} s")
    print(f"  CPU time  {statistics.median(cpu):7.3f} s (median; ~ the wall time on a quiet machine)")
    worst = max(max(relative_errors(r.params).values()) for r in runs)
    for r in runs:
        errs = ", ".join(f"{k} {v:.1e}" for k, v in relative_errors(r.params).items())
        print(f"  run: {r.timings['total']:.3f} s, relative errors {errs}")
    print(f"  worst relative error {worst:.1e} (target < 1e-3; the paper's code: 2e-2)")
    print(
        f"  the paper's code: {PAPER_SECONDS:.0f} s -> ratio {PAPER_SECONDS / median['total']:.1f}x "
        f"(target >= 20x, i.e. <= {PAPER_SECONDS / 20:.2f} s); by CPU time "
        f"{PAPER_SECONDS / statistics.median(cpu):.1f}x"
    )
    sgd = fit(microstructure, points, stages=("sgd",), seed=0, progress=False, epochs=PROTOCOL["epochs"])
    errs = ", ".join(f"{k} {v:.1e}" for k, v in relative_errors(sgd.params).items())
    print(f"SGD alone from a random start: {sgd.timings['total']:.3f} s, E = {sgd.loss:.2e}, relative errors {errs}")
    print(f"  (full protocol E = {runs[0].loss:.2e})")


if __name__ == "__main__":
    main()
