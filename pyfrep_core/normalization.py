"""Normalization: approximate distances from a defining function (paper section 5.2).

A function f that vanishes on a boundary is *normalized* to order k when it behaves like the
signed distance there: it vanishes, its normal derivative is 1 and its normal derivatives of
orders 2..k vanish.  With n = grad f / |grad f| (the inward normal, f > 0 inside) and the
normal derivative ``d/dn = n . grad`` (iterated for higher orders, n varying with x):

- Rvachev, paper eq. (omega1): ``omega_1[f] = f / sqrt(f^2 + |grad f|^2)``;
- the recursion ``omega_k = omega_{k-1} - omega_1^k / k! * d^k omega_{k-1} / dn^k``, which keeps
  ``omega_k = 0``, ``d omega_k/dn = 1`` and gives ``d^l omega_k / dn^l = 0`` (l = 2..k) on f = 0;
- Taubin, paper eq. (delta1): ``delta_1[f] = f / |grad f|``.

Every function works in any dimension (points (N, d): the plane for the ellipse of Fig. 4,
space for solids).  The derivatives are nested autograd passes (``create_graph``) through
:mod:`pyfrep_core.diff`: omega_k needs derivatives of f up to order k(k+1)/2, so its cost grows
quickly with k (k = 2, 3 are the useful ones).

Undefined points: where grad f = 0, ``delta_1`` and ``omega_k`` (k >= 2) are NaN (the normal is
undefined); ``omega_1`` is then ``sign(f)``, and NaN only where f = 0 and grad f = 0 together.

Creases (f1 = f2 = 0 in an R-function, where f is not differentiable): the R-functions take the
square root through :func:`~pyfrep_core._array.safe_sqrt`, whose derivatives up to the third
order are finite there, so grad f is the sub-gradient and ``omega_2`` (third derivatives of f) is
finite.  On a crease that lies on the surface f = 0 (an edge of the solid) every normalization is
0 there, as it should be.  On a crease off the surface (a blend's edge, f = a0; an inner edge of a
nested operation) the second normal derivative of omega_1 is unbounded in theory (~1/rho0 with
rho0 = safe_sqrt(0)), so ``omega_k`` (k >= 2) is huge there, of either sign: the recursion itself
is singular along such a crease (its limit is infinite), while ``omega_1`` and ``delta_1`` stay
O(1).  ``omega_3`` needs sixth derivatives and is NaN exactly on a crease.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from ._array import check_memory, named_entry
from .diff import _chunk_size, _flat_points, _leaf, _map_chunks, _out, _vjp
from .evaluate import call, name_of

__all__ = ["omega_1", "omega_k", "delta_1", "normal_derivative", "normalized", "Normalized"]


def _field(f: Callable, xr: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """f, grad f (graph kept) and the unit normal n = grad f / |grad f| (NaN where grad f = 0)."""
    fx = call(f, xr, label=name_of(f))
    g = _vjp(fx, xr, create_graph=True)
    norm = torch.linalg.vector_norm(g, dim=-1, keepdim=True)
    n = g / torch.where(norm > 0, norm, torch.full_like(norm, math.nan))
    return fx, g, n


def _along(v: torch.Tensor, n: torch.Tensor, xr: torch.Tensor) -> torch.Tensor:
    """The normal derivative n . grad v, differentiable again (one backward pass)."""
    return (n * _vjp(v, xr, create_graph=True)).sum(-1)


def _omegas(fx: torch.Tensor, g: torch.Tensor, n: torch.Tensor, xr: torch.Tensor, k: int) -> torch.Tensor:
    """omega_k by the paper's recursion, from f, grad f and n at xr (graph kept)."""
    w1 = fx / torch.sqrt(fx * fx + (g * g).sum(-1))
    w = w1
    for order in range(2, k + 1):
        dk = w
        for _ in range(order):
            dk = _along(dk, n, xr)
        w = w - w1**order / math.factorial(order) * dk
    return w


def _check_order(k: Any, name: str = "k") -> int:
    if isinstance(k, bool) or not isinstance(k, int) or k < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {k!r}")
    return k


# Memory of omega_k, measured (peak RSS, float64, CPU, f = a sphere, at 1 and 100 points): k = 3 takes
# 14 MiB + ~40 KiB a point, k = 4 1.1 GiB + 6 MiB a point (14 s at one point).  omega_k nests
# L = k (k + 1) / 2 normal derivatives (omega_1 one, then 2, 3, ..., k more), and each nested backward
# pass differentiates the whole graph built so far, so the graph grows geometrically with L: by about
# x3 a level here (x20 from k = 2 to k = 3, three levels; x83 from k = 3 to k = 4, four levels).  So
# k = 5 (15 levels) needs 3^5 = 243 times k = 4: about 270 GiB for a sphere at one point.  The estimate
# below scales the k = 4 figures by 3^(L - 10); a larger f (more operations) needs more than that.
OMEGA4_BYTES = 1.1 * 2**30
OMEGA4_BYTES_PER_POINT = 6 * 2**20
OMEGA_GROWTH_PER_LEVEL = 3.0


def _check_omega_memory(k: int, x: Any, create_graph: bool, chunk: int | None) -> None:
    """MemoryBudgetError when omega_k's nested derivatives cannot fit (see ``OMEGA4_BYTES``)."""
    try:
        shape = tuple(x.shape) if isinstance(x, torch.Tensor | np.ndarray) else np.shape(x)
    except ValueError:  # ragged: _flat_points says what is wrong
        return
    n = math.prod(shape[:-1]) if len(shape) > 1 else 1
    device = x.device if isinstance(x, torch.Tensor) else torch.device("cpu")
    size = _chunk_size(x if isinstance(x, torch.Tensor) else torch.empty(0), chunk)
    # points differentiated at once: all of them with a graph kept, else chunks (in parallel on the CPU)
    live = n if create_graph or n <= size else size * (torch.get_num_threads() if device.type == "cpu" else 1)
    scale = OMEGA_GROWTH_PER_LEVEL ** (k * (k + 1) // 2 - 10)
    check_memory(
        (OMEGA4_BYTES + OMEGA4_BYTES_PER_POINT * live) * scale,
        "omega_k",
        f"k={k} ({k * (k + 1) // 2} nested derivatives) at {live} point{'s' * (live != 1)} at once",
        "use k <= 3 (k = 4 only for a few points, with chunk=)",
    )


def _apply(kernel: Callable, x: Any, create_graph: bool, chunk: int | None) -> Any:
    """Run ``kernel(xr) -> (N,)`` (xr differentiable) on validated points, chunked unless a graph is kept."""
    t, was_numpy, batch = _flat_points(x)

    def one(c: torch.Tensor) -> tuple[torch.Tensor]:
        with torch.enable_grad():
            value = kernel(_leaf(c, create_graph))
        return (value if create_graph else value.detach(),)

    (value,) = one(t) if create_graph else _map_chunks(one, t, chunk)
    return _out(value, was_numpy, batch)


@named_entry
def omega_1(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Rvachev's normalization ``f / sqrt(f^2 + |grad f|^2)`` (paper eq. omega1), shape (N,).

    Parameters
    ----------
    f : callable (N, d) -> (N,), f > 0 inside.
    x : (N, d) points (numpy or torch, float32/float64, any device, any d).
    create_graph : keep the graph (use in a loss); no chunking then.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import circle
    >>> omega_1(lambda p: circle(p, r=1.0), np.array([[1.0, 0.0], [0.0, 0.0]]))
    array([0., 1.])
    """

    def kernel(xr: torch.Tensor) -> torch.Tensor:
        fx, g, _ = _field(f, xr)
        return fx / torch.sqrt(fx * fx + (g * g).sum(-1))

    return _apply(kernel, x, create_graph, chunk)


@named_entry
def omega_k(f: Callable, x: Any, k: int = 2, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Rvachev's normalization to order k by the paper's recursion, shape (N,).

    ``omega_k = omega_{k-1} - omega_1^k / k! * d^k omega_{k-1} / dn^k`` with n = grad f/|grad f|;
    k = 1 is :func:`omega_1`.  NaN where grad f = 0 (k >= 2).  The nested derivatives grow
    about threefold with each of the k(k+1)/2 levels: a call whose estimate exceeds the available
    memory raises :class:`~pyfrep_core._array.MemoryBudgetError` up front (k = 5 always does: about
    270 GiB at a single point; k = 4 takes 1.1 GiB + 6 MiB a point).

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import circle
    >>> # a circle's omega_2 is exact at second order: r - |x| = 0.1 at |x| = 0.9
    >>> bool(abs(omega_k(lambda p: circle(p, r=1.0), np.array([[0.9, 0.0]]), 2)[0] - 0.1) < 2e-3)
    True
    """
    k = _check_order(k)
    _check_omega_memory(k, x, create_graph, chunk)
    return _apply(lambda xr: _omegas(*_field(f, xr), xr, k), x, create_graph, chunk)


@named_entry
def delta_1(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Taubin's normalization ``f / |grad f|`` (paper eq. delta1), shape (N,); NaN where grad f = 0.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import sphere
    >>> delta_1(lambda p: sphere(p, r=1.0), np.array([[0.5, 0.0, 0.0]]))
    array([0.75])
    """

    def kernel(xr: torch.Tensor) -> torch.Tensor:
        fx, g, n = _field(f, xr)
        norm = torch.linalg.vector_norm(g, dim=-1)
        return torch.where(norm > 0, fx / torch.where(norm > 0, norm, torch.ones_like(norm)), math.nan)

    return _apply(kernel, x, create_graph, chunk)


@named_entry
def normal_derivative(
    f: Callable,
    x: Any,
    order: int = 1,
    of: Callable | None = None,
    create_graph: bool = False,
    chunk: int | None = None,
) -> Any:
    """The iterated normal derivative ``d^order u / dn^order`` with n = grad f / |grad f|, shape (N,).

    ``u`` is ``of`` (a callable on points, differentiable: e.g. ``normalized(f, "omega2")``)
    or f itself.  This is the operator of the normalization's boundary conditions.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import circle
    >>> ball = lambda p: circle(p, r=1.0)
    >>> normal_derivative(ball, np.array([[1.0, 0.0]]), 1, of=normalized(ball, "omega1"))
    array([1.])
    """
    order = _check_order(order, "order")
    u = f if of is None else of

    def kernel(xr: torch.Tensor) -> torch.Tensor:
        _, _, n = _field(f, xr)
        value = call(u, xr, label=name_of(u))
        for _ in range(order):
            value = _along(value, n, xr)
        return value

    return _apply(kernel, x, create_graph, chunk)


_KINDS = re.compile(r"^(omega|delta)_?(\d+)$")


class Normalized:
    """A normalized defining function, callable on points (..., d) like f (see :func:`normalized`).

    Attributes: ``f``, ``kind`` ("omega" or "delta"), ``order``; ``bounds`` and ``dim`` copied
    from f when it is a Model, so ``polygonize(normalized(model))`` and slices work.
    Torch points that require grad keep the graph (the result can be differentiated again).
    """

    def __init__(self, f: Callable, kind: str = "omega1", chunk: int | None = None):
        if not callable(f):
            raise TypeError(f"f must be callable, got {type(f).__name__}")
        match = _KINDS.match(str(kind).lower())
        if match is None:
            raise ValueError(f"kind must be 'omega<k>' (k >= 1) or 'delta1', got {kind!r}")
        self.kind, self.order = match.group(1), int(match.group(2))
        if self.order < 1 or (self.kind == "delta" and self.order != 1):
            raise ValueError(f"kind must be 'omega<k>' (k >= 1) or 'delta1', got {kind!r}")
        self.f = f
        self.chunk = chunk
        self.bounds = getattr(f, "bounds", None)
        self.dim = getattr(f, "dim", None)
        self.__name__ = f"{kind}[{getattr(f, '__name__', 'f')}]"

    def __repr__(self) -> str:
        return f"<normalized {self.kind}_{self.order} of {getattr(self.f, '__name__', self.f)!r}>"

    def __call__(self, x: Any) -> Any:
        keep = isinstance(x, torch.Tensor) and x.requires_grad and torch.is_grad_enabled()
        if self.kind == "delta":
            return delta_1(self.f, x, create_graph=keep, chunk=self.chunk)
        return omega_k(self.f, x, self.order, create_graph=keep, chunk=self.chunk)


def normalized(f: Callable, kind: str = "omega1", chunk: int | None = None) -> Normalized:
    """f normalized by ``kind`` ("omega1", "omega2", "omega3", ... or "delta1"), as a callable.

    The result maps points (..., d) to (...) like a defining function, so it can be meshed
    (:func:`pyfrep_core.polygonize`), sliced or differentiated again.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import sphere
    >>> d = normalized(lambda p: sphere(p, r=2.0), "delta1")
    >>> d(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]))
    array([1.5, 0. ])
    """
    return Normalized(f, kind, chunk)
