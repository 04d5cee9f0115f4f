"""f and grad f of the Fig. 1 part: eager autograd, autograd through the compiled kernel, the fused kernel.

``value_and_grad(compiled(model), x)`` takes first derivatives through one fused kernel: the
forward and backward passes traced together (``torch.func.grad_and_value``) and compiled into
one loop, with no autograd graph at run time (:meth:`pyfrep_core.compiled.CompiledModel.value_and_grad`).
Before it, the compiled model was differentiated by autograd through its values' kernel and that
kernel's compiled backward: that path is measured too (``autograd + kernel``: the model called
under ``first_order()`` and ``torch.autograd.grad``), with plain eager autograd
(``value_and_grad(model, x)``).  float64, one intra-op thread (as the mesher's workers run);
the point counts are a root finder's last small calls, a 128^3 slab's edges, and a chunk.

Prints the median time per call of each, the ratios, and whether the fused results equal
autograd's bit for bit.  Run: ``.venv/bin/python benchmarks/gradient.py`` (PYFREP_QUICK=1: fewer calls).
"""

from __future__ import annotations

import os
import statistics
import time

import torch

from pyfrep_core import value_and_grad
from pyfrep_core._threads import intra_op_threads
from pyfrep_core.compiled import compiled, first_order, warm_up
from pyfrep_core.models import fig1_part

QUICK = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
SIZES = (300, 26_000, 1 << 18)


def median_ms(fn, calls: int) -> float:
    fn()
    times = []
    for _ in range(calls):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def through_autograd(fast, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """f and grad f by autograd's backward through the compiled values' kernel (the path before fusion)."""
    xr = x.detach().requires_grad_(True)
    with torch.enable_grad(), first_order():
        value = fast(xr)
        (gradient,) = torch.autograd.grad(value.sum(), xr)
    return value.detach(), gradient


def main() -> None:
    fast = compiled(fig1_part)
    with intra_op_threads(1):
        print(f"compiling (once per process, cached on disk): {warm_up(fast, dtypes=(torch.float64,)):.1f} s")
        through_autograd(fast, torch.rand(64, 3, dtype=torch.float64))  # the autograd variant too
        print(f"{'points':>8} {'eager':>10} {'autograd + kernel':>18} {'fused':>10}  fused / eager, fused / autograd")
        for n in SIZES:
            x = torch.rand(n, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(n)) * 2.2 - 1.1
            calls = max(5, (20 if QUICK else 200) * 300 // n)
            eager = median_ms(lambda x=x: value_and_grad(fig1_part, x), calls)
            before = median_ms(lambda x=x: through_autograd(fast, x), calls)
            fused = median_ms(lambda x=x: value_and_grad(fast, x), calls)
            same = all(torch.equal(a, b) for a, b in zip(value_and_grad(fast, x), through_autograd(fast, x)))
            print(
                f"{n:>8} {eager:>8.3f}ms {before:>16.3f}ms {fused:>8.3f}ms  {fused / eager:.2f}x, {fused / before:.2f}x"
                f"  (bit for bit: {same})"
            )
    print(f"load average: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
