"""A compiled model's values kernel called many times: through dynamo on every call, or the graph called directly.

``CompiledModel.values_kernel`` (what the meshers' root finding calls) sends its calls after the
first probed one straight to the graph dynamo chose (``pyfrep_core._graph_calls``); with
``pyfrep_core.compiled.DIRECT_CALLS = False`` every call goes through dynamo's frame hook and
guards, as before.  Both are timed here on the Fig. 1 part in float64, component-first points,
one intra-op thread per caller (as the mesher's workers run): one thread calling, and two
threads calling side by side (time per pair of calls; each release of the GIL can hand it to
the other thread).  Point counts: a root finder's last small calls, a 128^3 slab's edges.

Prints the median microseconds per call (per pair with two threads), the ratio direct / dynamo,
and whether the two give the same values bit for bit.  Run:
``.venv/bin/python benchmarks/kernel_calls.py`` (PYFREP_QUICK=1: fewer calls).
"""

from __future__ import annotations

import os
import statistics
import threading
import time

import torch

import pyfrep_core.compiled as compiled_module
from pyfrep_core._threads import intra_op_threads
from pyfrep_core.compiled import compiled, warm_up
from pyfrep_core.models import fig1_part

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
SIZES = (16, 26_000)


def points(n: int) -> torch.Tensor:
    x = torch.rand(n, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(n)) * 2.2 - 1.1
    return torch.empty_strided((n, 3), (1, n), dtype=torch.float64).copy_(x)


def kernel_for(fast, direct: bool):
    """A values kernel whose later calls go direct (or through dynamo), past its first two calls."""
    compiled_module.DIRECT_CALLS = direct
    try:
        kernel = fast.values_kernel()
        for n in (64, 64):
            kernel(points(n))  # the model's call, then the probed one (decides direct or not)
    finally:
        compiled_module.DIRECT_CALLS = True
    return kernel


def per_call_us(kernel, x: torch.Tensor, calls: int, threads: int) -> float:
    """Median over 5 repeats of the wall time of ``calls`` calls per thread, per call (per round of
    one call in each thread)."""

    def run() -> None:
        with intra_op_threads(1):
            for _ in range(calls):
                kernel(x)

    times = []
    for _ in range(5):
        workers = [threading.Thread(target=run) for _ in range(threads)]
        start = time.perf_counter()
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        times.append((time.perf_counter() - start) / calls)
    return 1e6 * statistics.median(times)


def main() -> None:
    fast = compiled(fig1_part)
    with intra_op_threads(1):
        print(f"compiling (once per process, cached on disk): {warm_up(fast, dtypes=(torch.float64,)):.1f} s")
    through, direct = kernel_for(fast, False), kernel_for(fast, True)
    print(f"{'points':>8} {'threads':>8} {'dynamo':>10} {'direct':>10}  direct / dynamo")
    for n in SIZES:
        x = points(n)
        same = torch.equal(through(x), direct(x))
        calls = max(20, (200 if QUICK else 2000) * 16 // max(n // 100, 16))
        for threads in (1, 2):
            slow = per_call_us(through, x, calls, threads)
            fast_us = per_call_us(direct, x, calls, threads)
            print(f"{n:>8} {threads:>8} {slow:>8.1f}us {fast_us:>8.1f}us  {fast_us / slow:.2f}x  (bit for bit: {same})")
    print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
