"""A first-order bound on the rounding error of evaluating a model in float32.

Evaluating f in floating point rounds the result of every operation: each intermediate v_i gets a
relative error of at most u (the unit roundoff, or a few ulp for transcendental functions), and that
error reaches the output multiplied by the adjoint df/dv_i.  To first order

    |f_computed - f| <= c * eps * sum_i |v_i * df/dv_i|

(Linnainmaa's automatic rounding-error analysis).  The sum is the problem's own condition: it is
large exactly where the program cancels large terms (R-functions of big intermediates, sines of big
arguments), and it does not depend on the machine or on how a compiler orders or fuses the
operations, so a tolerance built from it holds for eager, vectorised and scalar compiled code alike.

The sum is computed in float64: every per-point intermediate of a float64 evaluation keeps its
gradient (``retain_grad``), one backward pass gives all adjoints, and the parameters count as
intermediates too (a float32 evaluation rounds them once).
"""

from __future__ import annotations

import torch
from torch.overrides import TorchFunctionMode

# eps per operation: a correctly rounded operation errs by eps/2 and a float literal mixed into it by
# another eps/2; the vectorised libm of Inductor and ATen (SLEEF) promises sin/cos/exp/log/sqrt to 1 ulp.
ULPS_PER_OPERATION = 2.0


class _KeepIntermediates(TorchFunctionMode):
    def __init__(self, n: int):
        super().__init__()
        self.n = n
        self.kept: list[torch.Tensor] = []

    def __torch_function__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for t in out if isinstance(out, tuple | list) else (out,):
            if isinstance(t, torch.Tensor) and t.requires_grad and t.ndim >= 1 and t.shape[0] == self.n:
                t.retain_grad()
                self.kept.append(t)
        return out


def condition_sum(fn, x: torch.Tensor, **params: float) -> torch.Tensor:
    """sum_i |v_i * df/dv_i| at every point of ``x`` (N, d): float64, shape (N,).

    ``fn(x, **params)`` is evaluated in float64 at the float32 points given (exactly representable).
    """
    x64 = x.detach().to(torch.float64).requires_grad_(True)
    p64 = {k: torch.tensor(float(v), dtype=torch.float64, requires_grad=True) for k, v in params.items()}
    mode = _KeepIntermediates(x64.shape[0])
    with mode:
        out = fn(x64, **p64)
    out.sum().backward()
    total = torch.zeros(x64.shape[0], dtype=torch.float64)
    for v in mode.kept:
        if v.grad is not None:
            total += (v.detach() * v.grad).abs().reshape(v.shape[0], -1).sum(dim=1)
    for p in p64.values():
        # a parameter enters every point; its adjoint summed over the points is not per point, so
        # bound each point by the parameter's magnitude times the largest per-point sensitivity
        if p.grad is not None:
            total += p.detach().abs() * _per_point_sensitivity(fn, x64.detach(), p64, p)
    return total


def _per_point_sensitivity(fn, x64, p64, p):
    name = next(k for k, v in p64.items() if v is p)
    fixed = {k: v.detach() for k, v in p64.items() if k != name}

    def one(value):
        return fn(x64, **fixed, **{name: value})

    return torch.func.jacfwd(one)(p.detach()).abs()


def float32_error_bound(fn, x: torch.Tensor, **params: float) -> torch.Tensor:
    """The first-order bound on |f32 - f| at every point of ``x``: (N,) float64."""
    eps = torch.finfo(torch.float32).eps
    return ULPS_PER_OPERATION * eps * condition_sum(fn, x, **params)
