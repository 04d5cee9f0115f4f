"""Guaranteed bounds of a model over boxes: interval arithmetic without rewriting the model.

:func:`bounds` evaluates a model on a tensor subclass, :class:`Interval`, that carries for every
value a lower and an upper bound (``lo``, ``hi``, tensors of the same shape) and implements
``__torch_function__``: each torch operation the model performs on it (``+``, ``*``, ``sqrt``,
``torch.where``, indexing, ``sum`` ...) is replaced by its interval extension, so the model's own
code, written for points, gives for a batch of boxes (B, d) an enclosure (B,) of every value
it takes in each box.  The defining function is called exactly as the model contract says:
points (N, d) (here N boxes) and 0-d parameters.

Guarantees.

- Soundness: every real value ``f(x)`` for ``x`` in a box, and every value the same torch code
  computes in floating point at such a point, lies in ``[lo, hi]``.  Each operation rounds its
  bounds outward: at least one unit in the last place for the correctly rounded operations
  (``+ - * /``, ``sqrt``: ``torch.nextafter``, or ``eps |v| + tiny`` on large tensors), a
  relative ``(k + 1) eps`` of the result's magnitude for the transcendental functions (torch's
  are accurate to a few ulps), ``n eps sum |x_i|`` for sums of n terms (any summation order) and
  ``24 eps (|f1| + |f2|)`` for a recognised R-function.  A NaN bound (``inf - inf``, ``0 * inf``)
  means unknown and becomes an infinite one.
- No silent guess: an operation without an interval rule (``torch.sort``, ``torch.fft.fft``,
  an in-place write, ``bool()`` of a comparison the bounds cannot decide, i.e. a Python ``if``
  on a value) raises :class:`IntervalUnsupported` naming it; callers fall back to sampling.
- Comparisons give three-valued masks (certainly true, possibly true); ``torch.where`` on an
  undecided mask takes the hull of both branches.

Tightness.  The natural interval extension overestimates when a variable occurs more than
once (``x * x`` over [-1, 1] would give [-1, 1]); cheap exact forms are used where they apply:

- ``x * x`` and ``x ** 2`` (the same tensor twice) are squares, ``[0, 1]`` above;
- the R-functions of paper section 3.1 (:func:`pyfrep_core.intersection`, :func:`pyfrep_core.union`,
  ``f1 + f2 -+ sqrt(f1^2 + f2^2 + c)``) are recognised from the operations that build them (the
  same operand tensors), whatever code wrote them, and bounded by monotonicity: both are
  nondecreasing in each argument (``d/df1 = 1 -+ f1 / sqrt(...) >= 0``), so
  ``[R(lo1, lo2), R(hi1, hi2)]`` is exact;
- ``min``/``max``, ``abs``, ``clamp``, monotone functions and ``sum`` are exact up to rounding.

The width of the bounds shrinks linearly with the box (first-order convergence).  Cost: a few
times a point evaluation of as many points (``benchmarks/interval.py``: about 5x for the Fig. 1
part on 32^3 boxes, one thread); the parts of a possible R-function are computed lazily, so a
recognised one costs two corner evaluations.

>>> import torch
>>> from pyfrep_core import sphere
>>> box_lo, box_hi = torch.zeros(1, 3, dtype=torch.float64), torch.full((1, 3), 0.5, dtype=torch.float64)
>>> lo, hi = bounds(lambda x: sphere(x, r=1.0), box_lo, box_hi)
>>> bool(lo[0] <= 0.25 and hi[0] >= 1.0), round(float(lo[0]), 12), round(float(hi[0]), 12)  # f = 1 - |x|^2
(True, 0.25, 1.0)
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import torch

from ._array import as_tensor, validated_inputs
from .evaluate import budget_points, name_of
from .model import Model

__all__ = ["IntervalUnsupported", "Interval", "bounds", "supports"]

INTERVAL_VALUES = 4  # an interval value costs about lo, hi and their temporaries: 4 point values
TRANSCENDENTAL_ULPS = 4  # torch's exp, log, sin, pow ... are within a few ulps of the exact value


class IntervalUnsupported(TypeError):  # noqa: N818  (the name the callers catch)
    """A torch operation in a model has no interval rule (its name is in the message); sample instead.

    >>> issubclass(IntervalUnsupported, TypeError)
    True
    """


# ---------------------------------------------------------------------------------------------
# the tensor subclass
# ---------------------------------------------------------------------------------------------

_RULES: dict[Any, Callable] = {}
_EMPTY: dict[tuple, torch.Tensor] = {}  # (dtype, device, shape) -> a placeholder: the storage of lazy intervals
_PASS = {  # attributes and queries that do not read values
    "shape", "dtype", "device", "ndim", "dim", "size", "numel", "nelement", "__len__", "is_floating_point",
    "is_complex", "requires_grad", "layout", "is_cuda", "element_size", "is_contiguous", "is_sparse",
    "is_quantized", "is_meta", "is_nested", "names", "itemsize", "nbytes", "stride", "get_device", "is_mps",
    "__hash__", "_is_view", "is_leaf", "grad_fn", "output_nr", "_version", "is_inference", "is_signed",
}  # fmt: skip


class Interval(torch.Tensor):
    """Values known only to lie in ``[lo, hi]`` elementwise; torch operations on it give enclosures.

    Build one with :meth:`Interval.of`; ``.lo`` and ``.hi`` are plain tensors of the interval's
    shape (boolean for comparisons: ``lo`` certainly true, ``hi`` possibly true).  The tensor
    itself has the interval's shape, dtype and device (its storage is ``lo``, or a placeholder
    while the bounds of a possible R-function part are not computed yet); its values are never
    read but through ``lo`` and ``hi``.

    >>> import torch
    >>> x = Interval.of(torch.tensor([-1.0, 2.0]), torch.tensor([1.0, 3.0]))
    >>> y = x * x - 2 * x
    >>> y.lo <= torch.tensor([-1.0, 0.0]), y.hi >= torch.tensor([3.0, 3.0])
    (tensor([True, True]), tensor([True, True]))
    """

    expr: tuple | None

    @staticmethod
    def of(lo: torch.Tensor, hi: torch.Tensor, expr: tuple | None = None) -> Interval:
        """The interval ``[lo, hi]`` (broadcast to one shape); ``expr`` records how it was built.

        >>> import torch
        >>> box = Interval.of(torch.tensor([[0.0, 1.0]]), torch.tensor([[0.5, 2.0]]))
        >>> (box[:, 0] - box[:, 1]).lo <= -2.0
        tensor([True])
        """
        if lo.shape != hi.shape:
            lo, hi = torch.broadcast_tensors(lo, hi)
        out = lo.as_subclass(Interval)
        out._lo, out._hi, out._thunk, out.expr = lo, hi, None, expr
        out._meta = (lo.dtype, lo.device, lo.shape)
        return out

    @staticmethod
    def _lazy(meta: tuple, thunk: Callable[[], Interval], expr: tuple) -> Interval:
        """An interval whose bounds are computed when first read: the parts of an R-function
        (squares, sums, the root), whose own bounds are not needed once it is recognised."""
        base = _EMPTY.get(meta)
        if base is None:
            if len(_EMPTY) > 256:
                _EMPTY.clear()
            dtype, device, shape = meta
            base = _EMPTY.setdefault(meta, torch.empty((), dtype=dtype, device=device).expand(shape))
        out = base.as_subclass(Interval)
        out._lo = out._hi = None
        out._thunk, out.expr, out._meta = thunk, expr, meta
        return out

    @property
    def lo(self) -> torch.Tensor:
        """Lower bounds (a plain tensor of the interval's shape)."""
        if self._thunk is not None:
            self._force()
        return self._lo

    @property
    def hi(self) -> torch.Tensor:
        """Upper bounds (a plain tensor of the interval's shape)."""
        if self._thunk is not None:
            self._force()
        return self._hi

    def _force(self) -> None:
        got = self._thunk()
        self._lo, self._hi, self._thunk = got.lo, got.hi, None

    @classmethod
    def __torch_function__(cls, func: Any, types: Any, args: Sequence = (), kwargs: Any = None) -> Any:
        kwargs = kwargs or {}
        rule = _RULES.get(func)
        if rule is not None:
            return rule(*args, **kwargs)
        name = _name(func)
        if name in _PASS:
            with torch._C.DisableTorchFunctionSubclass():
                return func(*args, **kwargs)
        raise _Blocked(
            f"interval bounds: torch operation {name!r} has no interval rule; the model cannot be bounded "
            "over boxes (evaluate it at points instead)"
        )


def _name(func: Any) -> str:
    name = getattr(func, "__name__", None) or repr(func)
    if name == "__get__":  # a property of Tensor: its name
        name = getattr(getattr(func, "__self__", None), "__name__", name)
    module = getattr(func, "__module__", None)
    if module and module.startswith("torch.") and module not in ("torch._tensor", "torch.functional"):
        name = f"{module}.{name}"
    return name


_NAMESPACES = (torch, torch.Tensor, torch.linalg, torch.special, torch.nn.functional)


def _rule(*names: str) -> Callable[[Callable], Callable]:
    """Register a rule for the torch functions and Tensor methods or properties of these names."""

    def register(fn: Callable) -> Callable:
        for name in names:
            for ns in _NAMESPACES:
                f = ns.__dict__.get(name) if ns is torch.Tensor else getattr(ns, name, None)
                if f is None and ns is torch.Tensor:
                    f = getattr(torch.Tensor, name, None)
                if f is None:
                    continue
                if hasattr(f, "__get__") and type(f).__name__ in ("getset_descriptor", "property"):
                    f = f.__get__
                _RULES[f] = fn
        return fn

    return register


class _Blocked(RuntimeError):  # noqa: N818
    """Raised inside an interval evaluation; :func:`bounds` re-raises it as IntervalUnsupported.

    Not a TypeError: torch turns a TypeError raised by an operator (``a - b``) into
    ``NotImplemented``, and Python then reports "unsupported operand types" without the reason.
    """


def _unsupported(what: str) -> _Blocked:
    return _Blocked(f"interval bounds: {what} cannot be bounded over boxes")


# ---------------------------------------------------------------------------------------------
# helpers: operands, outward rounding
# ---------------------------------------------------------------------------------------------


def _parts(v: Any) -> tuple[Any, Any]:
    """(lo, hi) of an operand: an Interval's bounds, a tensor or a number twice."""
    if isinstance(v, Interval):
        return v.lo, v.hi
    if isinstance(v, torch.Tensor):
        if v.is_complex():
            raise _unsupported("a complex tensor")
        return v, v
    if isinstance(v, bool | numbers.Real):
        return v, v
    raise _unsupported(f"an operand of type {type(v).__name__}")


def _tensor(v: Any, like: torch.Tensor) -> torch.Tensor:
    return v if isinstance(v, torch.Tensor) else torch.as_tensor(v, dtype=like.dtype, device=like.device)


def _like(*values: Any) -> torch.Tensor:
    for v in values:
        if isinstance(v, Interval):
            return v.lo
    for v in values:
        if isinstance(v, torch.Tensor):
            return v
    raise _unsupported("an operation without tensors")


_CONSTANTS: dict[tuple, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}


def _constants(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """-inf, +inf and -eps as 0-d tensors of ``t``'s dtype and device (made once)."""
    key = (t.dtype, t.device)
    got = _CONSTANTS.get(key)
    if got is None:
        eps = torch.finfo(t.dtype).eps
        got = tuple(torch.tensor(v, dtype=t.dtype, device=t.device) for v in (-math.inf, math.inf, -eps))
        _CONSTANTS[key] = got
    return got


def _infs(t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return _constants(t)[:2]


SMALL = 8192  # below this many values a call's overhead, not its arithmetic, dominates


def _out1(lo: torch.Tensor, hi: torch.Tensor, expr: tuple | None = None) -> Interval:
    """Round a correctly rounded result outward by at least one ulp.

    Small tensors: ``torch.nextafter`` (one call a bound).  Large ones: ``v -+ (eps |v| + tiny)``
    (``eps |v| >= ulp(v)`` for a normal v, so it rounds to at most the float below v; three calls,
    but vectorized, where nextafter is not on the CPU).
    """
    if not lo.is_floating_point():
        return Interval.of(lo, hi, expr)
    ninf, pinf, neg_eps = _constants(lo)
    if lo.numel() <= SMALL:
        return Interval.of(torch.nextafter(lo, ninf), torch.nextafter(hi, pinf), expr)
    tiny = torch.finfo(lo.dtype).tiny
    return Interval.of(
        torch.addcmul(lo, lo.abs(), neg_eps).sub_(tiny), torch.addcmul(hi, hi.abs(), neg_eps, value=-1).add_(tiny), expr
    )


def _widen(
    lo: torch.Tensor, hi: torch.Tensor, scale: torch.Tensor | None = None, ulps: float = TRANSCENDENTAL_ULPS
) -> Interval:
    """Widen by ``ulps * eps * scale`` (default scale: the larger magnitude of the bounds) plus one ulp."""
    if not lo.is_floating_point():
        return Interval.of(lo, hi)
    eps = torch.finfo(lo.dtype).eps
    if scale is None:
        scale = torch.maximum(lo.abs(), hi.abs())
    w = (ulps * eps) * scale
    return _out1(lo - w, hi + w)


def _exact(lo: Any, hi: Any) -> Interval:
    """Bounds that are values of the inputs (min, max, selections): no rounding."""
    return Interval.of(lo, hi)


def _nan_safe(lo: torch.Tensor, hi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """NaN bounds (inf - inf, 0 * inf) become infinite ones."""
    ninf, pinf = _infs(lo)
    return torch.where(torch.isnan(lo), ninf, lo), torch.where(torch.isnan(hi), pinf, hi)


def _is_scalar(v: Any) -> bool:
    return isinstance(v, bool | numbers.Real) or (
        isinstance(v, torch.Tensor) and not isinstance(v, Interval) and v.ndim == 0
    )


def _scalar_value(v: Any) -> float | None:
    """A plain scalar's value (reads a 0-d tensor: parameters are plain, not traced, here)."""
    if isinstance(v, bool | numbers.Real):
        return float(v)
    if isinstance(v, torch.Tensor) and not isinstance(v, Interval) and v.ndim == 0:
        return float(v.detach())
    return None


# ---------------------------------------------------------------------------------------------
# arithmetic
# ---------------------------------------------------------------------------------------------


def _add(a: Any, b: Any, alpha: Any = None) -> Interval:
    if alpha is not None and alpha != 1:
        b = _mul(b, alpha)
    if isinstance(a, Interval) and isinstance(b, Interval):
        tight = _r_function(a, b, +1)
        if tight is not None:
            return tight
        expr = ("add", a, b)
        if a.expr and b.expr and a.expr[0] == "sq" and b.expr[0] == "sq":
            expr = ("sumsq", a.expr[1], b.expr[1])
        if a._meta[:2] == b._meta[:2]:  # f1 + f2, f1^2 + f2^2: maybe parts of an R-function
            shape = a._meta[2] if a._meta[2] == b._meta[2] else torch.broadcast_shapes(a._meta[2], b._meta[2])
            return Interval._lazy((*a._meta[:2], shape), lambda: _add_now(a, b), expr)
        return _add_now(a, b, expr)
    if isinstance(a, Interval) and a.expr and a.expr[0] == "sumsq" and _is_scalar(b):
        c = _scalar_value(b)
        if c is not None and c >= 0 and not isinstance(b, torch.Tensor):  # + c >= 0 (safe_sqrt's tiny)
            expr = ("sumsq", a.expr[1], a.expr[2], _sumsq_constant(a) + c)
            return Interval._lazy(a._meta, lambda: _add_now(a, b), expr)
    return _add_now(a, b)


def _add_now(a: Any, b: Any, expr: tuple | None = None) -> Interval:
    (al, ah), (bl, bh) = _parts(a), _parts(b)
    return _out1(al + bl, ah + bh, expr)


def _sub(a: Any, b: Any, alpha: Any = None) -> Interval:
    if alpha is not None and alpha != 1:
        b = _mul(b, alpha)
    if isinstance(a, Interval) and isinstance(b, Interval):
        tight = _r_function(a, b, -1)
        if tight is not None:
            return tight
    (al, ah), (bl, bh) = _parts(a), _parts(b)
    return _out1(al - bh, ah - bl)


def _r_function(a: Interval, b: Interval, sign: int) -> Interval | None:
    """``f1 + f2 +- sqrt(f1^2 + f2^2 + c)`` recognised: exact bounds by monotonicity (module docstring)."""
    s, r = (a, b) if a.expr and a.expr[0] == "add" else (b, a)
    if sign < 0 and s is not a:
        return None  # rho - (f1 + f2) is not an R-function
    if not (s.expr and s.expr[0] == "add" and r.expr and r.expr[0] == "rho"):
        return None
    f1, f2 = s.expr[1], s.expr[2]
    g1, g2, c = r.expr[1], r.expr[2], r.expr[3]
    if not ((f1 is g1 and f2 is g2) or (f1 is g2 and f2 is g1)):
        return None

    def value(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        rho = torch.sqrt(x * x + y * y + c)
        return x + y + rho if sign > 0 else x + y - rho

    lo, hi = value(f1.lo, f2.lo), value(f1.hi, f2.hi)
    # The exact range lies inside the natural one, which it replaces (an unbounded operand gives
    # NaN here: unknown, made infinite at the end).  Rounding: the float evaluation at any point
    # of the box (and at the corners) is within a few roundings of terms of size |f1| + |f2| +
    # rho <= 2 (|f1| + |f2|) + sqrt(c) of the exact value: widened by 24 eps (M1 + M2 + sqrt(c)),
    # M the operands' largest magnitudes over the box
    m1, m2 = torch.maximum(f1.lo.abs(), f1.hi.abs()), torch.maximum(f2.lo.abs(), f2.hi.abs())
    err = (m1 + m2 + math.sqrt(c)) * (24.0 * torch.finfo(lo.dtype).eps)
    return _out1(lo - err, hi + err)


def _rsub(a: Any, b: Any, alpha: Any = None) -> Interval:
    return _sub(b, a if alpha is None else _mul(a, alpha))


def _square(x: Interval) -> Interval:
    return Interval._lazy(x._meta, lambda: _square_now(x), ("sq", x))


def _square_now(x: Interval) -> Interval:
    lo, hi = x.lo, x.hi
    near = torch.clamp(lo, min=0) - torch.clamp(hi, max=0)  # distance from 0 to [lo, hi]
    return _out1(near * near, torch.maximum(lo * lo, hi * hi))


def _mul(a: Any, b: Any) -> Interval:
    if a is b and isinstance(a, Interval):
        return _square(a)
    if not isinstance(a, Interval):
        a, b = b, a
    al, ah = a.lo, a.hi
    if _is_scalar(b) and not isinstance(b, torch.Tensor):
        c = float(b)
        return _out1(al * c, ah * c) if c >= 0 else _out1(ah * c, al * c)
    bl, bh = _parts(b)
    if not isinstance(b, Interval):  # a tensor of points' constants: two products
        p, q = al * bl, ah * bl
        lo, hi = torch.minimum(p, q), torch.maximum(p, q)
    else:
        p1, p2, p3, p4 = al * bl, al * bh, ah * bl, ah * bh
        lo = torch.minimum(torch.minimum(p1, p2), torch.minimum(p3, p4))
        hi = torch.maximum(torch.maximum(p1, p2), torch.maximum(p3, p4))
    return _out1(lo, hi)  # 0 * inf (an unbounded operand) gives NaN: unknown, made infinite at the end


def _div(a: Any, b: Any, rounding_mode: Any = None) -> Interval:
    if rounding_mode is not None:
        raise _unsupported(f"division with rounding_mode={rounding_mode!r}")
    if not isinstance(b, Interval):
        c = _scalar_value(b)
        if c is not None and not isinstance(b, torch.Tensor) and c != 0:
            al, ah = _parts(a)
            return _out1(al / c, ah / c) if c > 0 else _out1(ah / c, al / c)
    (al, ah), (bl, bh) = _parts(a), _parts(b)
    if not isinstance(b, Interval):  # a constant divisor: x / 0 gives inf (or NaN) at points too
        q1, q2 = al / bl, ah / bl
        return _out1(torch.minimum(q1, q2), torch.maximum(q1, q2))
    like = _like(a, b)
    al, ah, bl, bh = (_tensor(v, like) for v in (al, ah, bl, bh))
    q1, q2, q3, q4 = al / bl, al / bh, ah / bl, ah / bh
    lo = torch.minimum(torch.minimum(q1, q2), torch.minimum(q3, q4))
    hi = torch.maximum(torch.maximum(q1, q2), torch.maximum(q3, q4))
    zero = (bl <= 0) & (bh >= 0)  # a divisor that may be 0: unbounded
    ninf, pinf = _infs(lo)
    lo, hi = torch.where(zero, ninf, lo), torch.where(zero, pinf, hi)
    return _out1(lo, hi)


def _rdiv(a: Any, b: Any) -> Interval:
    return _div(b, a)


def _neg(a: Interval) -> Interval:
    return _exact(-a.hi, -a.lo)


def _abs(a: Interval) -> Interval:
    lo, hi = a.lo, a.hi
    return _exact(torch.clamp(lo, min=0) - torch.clamp(hi, max=0), torch.maximum(lo.abs(), hi.abs()))


def _integer(p: Any) -> int | None:
    v = _scalar_value(p)
    if v is not None and math.isfinite(v) and v == int(v) and abs(v) <= 64:
        return int(v)
    return None


def _pow(a: Any, p: Any) -> Interval:
    if not isinstance(a, Interval):  # number ** interval
        return _rpow(p, a)
    if isinstance(p, Interval):
        return _pow_corners(a.lo, a.hi, p.lo, p.hi)
    n = _integer(p)
    lo, hi = a.lo, a.hi
    if n == 2:
        return _square(a)
    if n == 1:
        return a
    if n == 0:
        return _exact(torch.ones_like(lo), torch.ones_like(hi))
    if n is not None and n > 0:
        if n % 2:
            return _widen(lo**n, hi**n, ulps=n + 2)
        near = torch.clamp(lo, min=0) - torch.clamp(hi, max=0)
        far = torch.maximum(lo.abs(), hi.abs())
        return _widen(near**n, far**n, ulps=n + 2)
    if n is not None and n < 0:
        return _div(1.0, _pow(a, -n))
    if _scalar_value(p) is None:  # a tensor of exponents per element
        pl = _tensor(p, lo)
        return _pow_corners(lo, hi, pl, pl)
    e = _scalar_value(p)
    if math.isnan(e):
        raise _unsupported("pow with a NaN exponent")
    # a real exponent: defined for x >= 0 (NaN below, where the model itself gives NaN)
    lo0, hi0 = torch.clamp(lo, min=0), torch.clamp(hi, min=0)
    if e > 0:
        return _widen_nan(lo0**e, hi0**e)
    return _widen_nan(hi0**e, lo0**e)


def _widen_nan(lo: torch.Tensor, hi: torch.Tensor) -> Interval:
    return _widen(lo, hi)  # a NaN bound stays NaN (unknown) and becomes infinite at the end


def _pow_corners(xl: torch.Tensor, xh: torch.Tensor, yl: Any, yh: Any) -> Interval:
    """x^y for x > 0: monotone in each argument, so the extremes are at the corners."""
    c = [xl**yl, xl**yh, xh**yl, xh**yh]
    lo = torch.minimum(torch.minimum(c[0], c[1]), torch.minimum(c[2], c[3]))
    hi = torch.maximum(torch.maximum(c[0], c[1]), torch.maximum(c[2], c[3]))
    bad = xl <= 0
    ninf, pinf = _infs(lo)
    lo, hi = torch.where(bad, ninf, lo), torch.where(bad, pinf, hi)
    return _widen_nan(lo, hi)


def _rpow(a: Interval, base: Any) -> Interval:
    bl, bh = _parts(base)
    like = a.lo
    return _pow_corners(_tensor(bl, like), _tensor(bh, like), a.lo, a.hi)


_rule("add", "__add__", "__radd__")(_add)
_rule("sub", "subtract", "__sub__")(_sub)
_rule("__rsub__", "rsub")(_rsub)
_rule("mul", "multiply", "__mul__", "__rmul__")(_mul)
_rule("div", "divide", "true_divide", "__truediv__", "__div__")(_div)
_rule("__rtruediv__", "__rdiv__")(_rdiv)
_rule("neg", "negative", "__neg__")(_neg)
_rule("abs", "absolute", "__abs__")(_abs)
_rule("pow", "__pow__")(_pow)
_rule("__rpow__")(_rpow)


@_rule("positive", "__pos__")
def _pos(a: Interval) -> Interval:
    return a


@_rule("square")
def _square_rule(a: Interval) -> Interval:
    return _square(a)


@_rule("reciprocal")
def _reciprocal(a: Interval) -> Interval:
    return _div(1.0, a)


@_rule("sqrt")
def _sqrt(a: Interval) -> Interval:
    if a.expr and a.expr[0] == "sumsq":
        return Interval._lazy(a._meta, lambda: _sqrt_now(a), ("rho", a.expr[1], a.expr[2], _sumsq_constant(a)))
    return _sqrt_now(a)


def _sqrt_now(a: Interval) -> Interval:
    # sqrt is defined on x >= 0: below, the model gives NaN itself; bound the defined part
    return _out1(torch.sqrt(torch.clamp(a.lo, min=0)), torch.sqrt(a.hi))


def _sumsq_constant(a: Interval) -> float:
    """The constant c >= 0 of ``f1^2 + f2^2 + c``: the gap between a and the two squares (at most tiny)."""
    return a.expr[3] if len(a.expr) > 3 else 0.0


@_rule("rsqrt")
def _rsqrt(a: Interval) -> Interval:
    return _div(1.0, _sqrt(a))


# ---------------------------------------------------------------------------------------------
# min / max / clamp / where
# ---------------------------------------------------------------------------------------------


def _minmax_pair(a: Any, b: Any, fn: Callable) -> Interval:
    like = _like(a, b)
    (al, ah), (bl, bh) = _parts(a), _parts(b)
    return _exact(fn(_tensor(al, like), _tensor(bl, like)), fn(_tensor(ah, like), _tensor(bh, like)))


@_rule("minimum", "fmin")
def _minimum(a: Any, b: Any) -> Interval:
    return _minmax_pair(a, b, torch.minimum)


@_rule("maximum", "fmax")
def _maximum(a: Any, b: Any) -> Interval:
    return _minmax_pair(a, b, torch.maximum)


class _Reduced(NamedTuple):
    """``x.min(dim)`` / ``x.max(dim)``: values bounded; which index attains them is not known."""

    values: Interval
    indices: None


def _reduce_extreme(a: Any, *args: Any, fn: str, **kwargs: Any) -> Any:
    dim = kwargs.pop("dim", args[0] if args else None)
    keepdim = kwargs.pop("keepdim", args[1] if len(args) > 1 else False)
    if isinstance(dim, Interval | torch.Tensor) and not (
        isinstance(dim, torch.Tensor) and dim.ndim == 0 and not dim.is_floating_point()
    ):
        return (_minimum if fn == "min" else _maximum)(a, dim)  # torch.min(a, b): elementwise
    lo, hi = _parts(a)
    if dim is None:
        red = torch.amin if fn == "min" else torch.amax
        return _exact(red(lo), red(hi))
    red = torch.amin if fn == "min" else torch.amax
    return _Reduced(_exact(red(lo, dim=dim, keepdim=keepdim), red(hi, dim=dim, keepdim=keepdim)), None)


@_rule("min")
def _min(a: Any, *args: Any, **kwargs: Any) -> Any:
    return _reduce_extreme(a, *args, fn="min", **kwargs)


@_rule("max")
def _max(a: Any, *args: Any, **kwargs: Any) -> Any:
    return _reduce_extreme(a, *args, fn="max", **kwargs)


@_rule("amin")
def _amin(a: Interval, dim: Any = (), keepdim: bool = False) -> Interval:
    return _exact(torch.amin(a.lo, dim=dim, keepdim=keepdim), torch.amin(a.hi, dim=dim, keepdim=keepdim))


@_rule("amax")
def _amax(a: Interval, dim: Any = (), keepdim: bool = False) -> Interval:
    return _exact(torch.amax(a.lo, dim=dim, keepdim=keepdim), torch.amax(a.hi, dim=dim, keepdim=keepdim))


@_rule("clamp", "clip")
def _clamp(a: Any, min: Any = None, max: Any = None) -> Interval:  # noqa: A002  (torch's names)
    out = a
    if min is not None:
        out = _maximum(out, min)
    if max is not None:
        out = _minimum(out, max)
    return out if isinstance(out, Interval) else _exact(*_parts(out))


@_rule("clamp_min")
def _clamp_min(a: Any, min: Any) -> Interval:  # noqa: A002
    return _maximum(a, min)


@_rule("clamp_max")
def _clamp_max(a: Any, max: Any) -> Interval:  # noqa: A002
    return _minimum(a, max)


@_rule("relu")
def _relu(a: Interval, inplace: bool = False) -> Interval:
    return _maximum(a, 0.0)


@_rule("where")
def _where(cond: Any, a: Any = None, b: Any = None) -> Interval:
    if a is None or b is None:
        raise _unsupported("torch.where(condition) (indices of a mask)")
    like = _like(a, b, cond)
    (al, ah), (bl, bh) = _parts(a), _parts(b)
    al, ah, bl, bh = (_tensor(v, like) for v in (al, ah, bl, bh))
    if isinstance(cond, Interval):
        sure, maybe = cond.lo, cond.hi
        lo = torch.where(sure, al, torch.where(maybe, torch.minimum(al, bl), bl))
        hi = torch.where(sure, ah, torch.where(maybe, torch.maximum(ah, bh), bh))
        return _exact(lo, hi)
    return _exact(torch.where(cond, al, bl), torch.where(cond, ah, bh))


# ---------------------------------------------------------------------------------------------
# monotone and periodic functions
# ---------------------------------------------------------------------------------------------


def _increasing(fn: Callable, ulps: float = TRANSCENDENTAL_ULPS) -> Callable:
    def rule(a: Interval, *args: Any, **kwargs: Any) -> Interval:
        lo, hi = fn(a.lo, *args, **kwargs), fn(a.hi, *args, **kwargs)
        return _widen_nan(lo, hi) if ulps else _exact(lo, hi)

    return rule


def _decreasing(fn: Callable) -> Callable:
    def rule(a: Interval, *args: Any, **kwargs: Any) -> Interval:
        return _widen_nan(fn(a.hi, *args, **kwargs), fn(a.lo, *args, **kwargs))

    return rule


for _names, _fn in (
    (("exp",), torch.exp),
    (("exp2",), torch.exp2),
    (("expm1",), torch.expm1),
    (("tanh",), torch.tanh),
    (("atan", "arctan"), torch.atan),
    (("asinh", "arcsinh"), torch.asinh),
    (("sinh",), torch.sinh),
    (("sigmoid", "expit"), torch.sigmoid),
    (("erf",), torch.erf),
    (("softplus",), torch.nn.functional.softplus),
):
    _rule(*_names)(_increasing(_fn))
for _names, _fn in ((("floor",), torch.floor), (("ceil",), torch.ceil), (("trunc", "fix"), torch.trunc)):
    _rule(*_names)(_increasing(_fn, ulps=0))
_rule("sign")(_increasing(torch.sign, ulps=0))


@_rule("round")
def _round(a: Interval, decimals: int = 0) -> Interval:
    lo, hi = torch.round(a.lo, decimals=decimals), torch.round(a.hi, decimals=decimals)
    return _exact(lo, hi) if decimals == 0 else _widen(lo, hi)


def _log_like(fn: Callable) -> Callable:
    def rule(a: Interval) -> Interval:
        # defined for x > 0 (x = 0: -inf); NaN below, where the model itself gives NaN
        return _widen_nan(fn(torch.clamp(a.lo, min=0)), fn(a.hi))

    return rule


for _names, _fn in ((("log",), torch.log), (("log2",), torch.log2), (("log10",), torch.log10)):
    _rule(*_names)(_log_like(_fn))


@_rule("log1p")
def _log1p(a: Interval) -> Interval:
    return _widen_nan(torch.log1p(torch.clamp(a.lo, min=-1)), torch.log1p(a.hi))


@_rule("asin", "arcsin")
def _asin(a: Interval) -> Interval:
    return _widen_nan(torch.asin(torch.clamp(a.lo, -1, 1)), torch.asin(torch.clamp(a.hi, -1, 1)))


@_rule("acos", "arccos")
def _acos(a: Interval) -> Interval:
    return _widen_nan(torch.acos(torch.clamp(a.hi, -1, 1)), torch.acos(torch.clamp(a.lo, -1, 1)))


@_rule("cosh")
def _cosh(a: Interval) -> Interval:
    m = _abs(a)
    return _widen_nan(torch.cosh(m.lo), torch.cosh(m.hi))


def _holds_point(lo: torch.Tensor, hi: torch.Tensor, phase: float, period: float) -> torch.Tensor:
    """Whether [lo, hi] may hold ``phase + k period`` for an integer k (erring towards yes)."""
    u, v = (lo - phase) / period, (hi - phase) / period
    tol = 64 * torch.finfo(lo.dtype).eps * (1 + torch.maximum(u.abs(), v.abs()))
    return torch.floor(v + tol) >= torch.ceil(u - tol)


def _periodic(fn: Callable, peak: float) -> Callable:
    """sin or cos: their values at the ends, and +1 (-1) where a peak (a trough, half a period
    after it) may lie inside; the extremes are tested erring towards "inside"."""
    tau = 2 * math.pi

    def rule(a: Interval) -> Interval:
        lo, hi = a.lo, a.hi
        fl, fh = fn(lo), fn(hi)
        low, high = torch.minimum(fl, fh), torch.maximum(fl, fh)
        eps = torch.finfo(lo.dtype).eps
        u, v = lo * (1 / tau) - peak / tau, hi * (1 / tau) - peak / tau  # peaks at the integers
        tol = (u.abs() + v.abs()).mul_(64 * eps).add_(64 * eps)
        u, v = u - tol, v + tol
        up = (torch.floor(v) >= torch.ceil(u)).to(lo.dtype)
        down = (torch.floor(v + 0.5) >= torch.ceil(u + 0.5)).to(lo.dtype)
        # blended arithmetically (torch.where is slow on the CPU); the blend's rounding (2 eps)
        # and sin's and cos's own error (an ulp or two of 1) are covered by the widening
        low = torch.addcmul(low, down, low + 1.0, value=-1).sub_(TRANSCENDENTAL_ULPS * eps)
        high = torch.addcmul(high, up, 1.0 - high).add_(TRANSCENDENTAL_ULPS * eps)
        return _exact(low.clamp_(min=-1.0), high.clamp_(max=1.0))

    return rule


_rule("sin")(_periodic(torch.sin, math.pi / 2))
_rule("cos")(_periodic(torch.cos, 0.0))


@_rule("tan")
def _tan(a: Interval) -> Interval:
    pole = _holds_point(a.lo, a.hi, math.pi / 2, math.pi)
    out = _widen_nan(torch.tan(a.lo), torch.tan(a.hi))
    ninf, pinf = _infs(out.lo)
    return _exact(torch.where(pole, ninf, out.lo), torch.where(pole, pinf, out.hi))


@_rule("atan2", "arctan2")
def _atan2(y: Any, x: Any) -> Interval:
    like = _like(y, x)
    (yl, yh), (xl, xh) = _parts(y), _parts(x)
    yl, yh, xl, xh = (_tensor(v, like) for v in (yl, yh, xl, xh))
    corners = [torch.atan2(yl, xl), torch.atan2(yl, xh), torch.atan2(yh, xl), torch.atan2(yh, xh)]
    lo = torch.minimum(torch.minimum(corners[0], corners[1]), torch.minimum(corners[2], corners[3]))
    hi = torch.maximum(torch.maximum(corners[0], corners[1]), torch.maximum(corners[2], corners[3]))
    # a box that meets the branch cut (x <= 0, y = 0) or the origin: the angle spans (-pi, pi]
    cut = (xl <= 0) & (yl <= 0) & (yh >= 0)
    lo = torch.where(cut, torch.full_like(lo, -math.pi), lo)
    hi = torch.where(cut, torch.full_like(hi, math.pi), hi)
    return _widen_nan(lo, hi)


@_rule("remainder", "__mod__")
def _remainder(a: Interval, p: Any) -> Interval:
    """x mod p (sign of p) for a constant p: increasing within a period, [0, p] across one."""
    if isinstance(p, Interval):
        raise _unsupported("remainder by an interval")
    lo, hi = a.lo, a.hi
    pt = _tensor(p, lo)
    kl, kh = torch.floor(lo / pt), torch.floor(hi / pt)
    rl, rh = torch.remainder(lo, pt), torch.remainder(hi, pt)
    one = (kl == kh) & (rl <= rh)
    zero, full = torch.minimum(torch.zeros_like(pt), pt), torch.maximum(torch.zeros_like(pt), pt)
    low, high = torch.where(one, rl, zero), torch.where(one, rh, full)
    return _widen(low, high, scale=torch.maximum(lo.abs(), hi.abs()) + pt.abs())


# ---------------------------------------------------------------------------------------------
# comparisons and masks
# ---------------------------------------------------------------------------------------------


def _compare(a: Any, b: Any, op: str) -> Interval:
    (al, ah), (bl, bh) = _parts(a), _parts(b)
    like = _like(a, b)
    al, ah, bl, bh = (_tensor(v, like) for v in (al, ah, bl, bh))
    if op in ("gt", "ge"):  # a > b is b < a
        (al, ah), (bl, bh) = (bl, bh), (al, ah)
        op = "lt" if op == "gt" else "le"
    nan = torch.isnan(al) | torch.isnan(ah) | torch.isnan(bl) | torch.isnan(bh)
    if op == "lt":
        sure, maybe = ah < bl, al < bh
    elif op == "le":
        sure, maybe = ah <= bl, al <= bh
    else:
        sure = (al == ah) & (bl == bh) & (al == bl)
        maybe = (al <= bh) & (bl <= ah)
        if op == "ne":
            sure, maybe = ~maybe, ~sure
    return _exact(sure & ~nan, maybe | nan)


for _op, _names in (
    ("lt", ("lt", "less", "__lt__")),
    ("le", ("le", "less_equal", "__le__")),
    ("gt", ("gt", "greater", "__gt__")),
    ("ge", ("ge", "greater_equal", "__ge__")),
    ("eq", ("eq", "__eq__")),
    ("ne", ("ne", "not_equal", "__ne__")),
):
    _rule(*_names)(lambda a, b, _op=_op: _compare(a, b, _op))


def _mask_parts(v: Any) -> tuple[torch.Tensor, torch.Tensor]:
    lo, hi = _parts(v)
    if isinstance(lo, torch.Tensor) and lo.dtype != torch.bool:
        raise _unsupported("a logical operation on non-boolean values")
    return lo, hi


@_rule("logical_and", "bitwise_and", "__and__", "__rand__")
def _and(a: Any, b: Any) -> Interval:
    (al, ah), (bl, bh) = _mask_parts(a), _mask_parts(b)
    return _exact(al & bl, ah & bh)


@_rule("logical_or", "bitwise_or", "__or__", "__ror__")
def _or(a: Any, b: Any) -> Interval:
    (al, ah), (bl, bh) = _mask_parts(a), _mask_parts(b)
    return _exact(al | bl, ah | bh)


@_rule("logical_not", "bitwise_not", "__invert__")
def _not(a: Interval) -> Interval:
    lo, hi = _mask_parts(a)
    return _exact(~hi, ~lo)


@_rule("all")
def _all(a: Interval, *args: Any, **kwargs: Any) -> Interval:
    lo, hi = _mask_parts(a)
    return _exact(lo.all(*args, **kwargs), hi.all(*args, **kwargs))


@_rule("any")
def _any(a: Interval, *args: Any, **kwargs: Any) -> Interval:
    lo, hi = _mask_parts(a)
    return _exact(lo.any(*args, **kwargs), hi.any(*args, **kwargs))


@_rule("__bool__")
def _bool(a: Interval) -> bool:
    if a.numel() != 1:
        raise _unsupported("bool() of a tensor of several values")
    if bool(a.lo) == bool(a.hi):
        return bool(a.lo)
    raise _unsupported("bool() of a comparison the bounds cannot decide (a Python `if` on a value)")


@_rule("item", "__float__", "__int__", "__index__", "tolist", "numpy", "__array__")
def _read(a: Interval, *args: Any, **kwargs: Any) -> Any:
    raise _unsupported("reading values (.item(), float(), .numpy(), .tolist())")


# ---------------------------------------------------------------------------------------------
# reductions
# ---------------------------------------------------------------------------------------------


@_rule("sum")
def _sum(a: Interval, dim: Any = None, keepdim: bool = False, dtype: Any = None) -> Interval:
    if a.lo.dtype == torch.bool:
        raise _unsupported("sum of a comparison")
    kw = {"keepdim": keepdim} if dim is not None else {}
    args = (dim,) if dim is not None else ()
    lo, hi = a.lo.sum(*args, **kw), a.hi.sum(*args, **kw)
    terms = max(1, a.lo.numel() // max(1, lo.numel()))
    scale = torch.maximum(a.lo.abs(), a.hi.abs()).sum(*args, **kw)
    return _widen(lo, hi, scale=scale, ulps=terms + 1)


@_rule("mean")
def _mean(a: Interval, dim: Any = None, keepdim: bool = False, dtype: Any = None) -> Interval:
    s = _sum(a, dim, keepdim)
    return _div(s, float(max(1, a.lo.numel() // max(1, s.lo.numel()))))


def _norm(a: Interval, ord: Any = 2, dim: Any = None, keepdim: bool = False) -> Interval:  # noqa: A002
    if ord is None or ord == 2 or ord == "fro":
        return _sqrt(_sum(_square(a), dim, keepdim))
    if ord == 1:
        return _sum(_abs(a), dim, keepdim)
    if ord in (math.inf, "inf"):
        return _amax(_abs(a), () if dim is None else dim, keepdim)
    if isinstance(ord, numbers.Real) and ord > 0:
        return _pow(_sum(_pow(_abs(a), float(ord)), dim, keepdim), 1.0 / float(ord))
    raise _unsupported(f"a norm of order {ord!r}")


@_rule("norm")
def _norm_rule(
    a: Interval, p: Any = "fro", dim: Any = None, keepdim: bool = False, dtype: Any = None, **kwargs: Any
) -> Interval:
    p = kwargs.pop("ord", p)
    return _norm(a, 2 if p == "fro" else p, dim, keepdim)


@_rule("vector_norm")
def _vector_norm(a: Interval, ord: Any = 2, dim: Any = None, keepdim: bool = False, dtype: Any = None) -> Interval:  # noqa: A002
    return _norm(a, ord, dim, keepdim)


@_rule("hypot")
def _hypot(a: Any, b: Any) -> Interval:
    sa = _square(a) if isinstance(a, Interval) else _exact(*_parts(a * a))
    sb = _square(b) if isinstance(b, Interval) else _exact(*_parts(b * b))
    return _sqrt(_add(sa, sb))


# ---------------------------------------------------------------------------------------------
# shapes, indexing, joining, conversions: the same on both bounds
# ---------------------------------------------------------------------------------------------


def _both(method: str) -> Callable:
    def rule(a: Interval, *args: Any, **kwargs: Any) -> Any:
        if not isinstance(a, Interval):
            raise _unsupported(f"{method} of a tensor with interval arguments")
        args = tuple(v.lo if isinstance(v, Interval) else v for v in args)
        lo, hi = getattr(a.lo, method)(*args, **kwargs), getattr(a.hi, method)(*args, **kwargs)
        if isinstance(lo, tuple | list):
            return type(lo)(_exact(x, y) for x, y in zip(lo, hi, strict=True))
        return _exact(lo, hi)

    return rule


for _method in (
    "reshape", "view", "flatten", "squeeze", "unsqueeze", "expand", "broadcast_to", "permute", "transpose",
    "t", "movedim", "moveaxis", "contiguous", "clone", "detach", "unbind", "split", "chunk", "select", "narrow",
    "index_select", "repeat", "tile", "flip", "roll", "diagonal", "unflatten", "ravel", "swapaxes",
    "requires_grad_", "cpu", "cuda",
):  # fmt: skip
    _rule(_method)(_both(_method))


@_rule("T", "mT")
def _transpose_property(a: Interval) -> Interval:
    return (
        _exact(a.lo.mT, a.hi.mT)
        if a.lo.ndim == 2
        else _exact(a.lo.permute(*range(a.lo.ndim - 1, -1, -1)), a.hi.permute(*range(a.hi.ndim - 1, -1, -1)))
    )


@_rule("__getitem__")
def _getitem(a: Interval, index: Any) -> Interval:
    parts = index if isinstance(index, tuple) else (index,)
    if any(isinstance(i, Interval) for i in parts):
        raise _unsupported("indexing with an undecided mask or index")
    return _exact(a.lo[index], a.hi[index])


@_rule("__setitem__")
def _setitem(a: Interval, *args: Any) -> None:
    raise _unsupported("an in-place write (x[...] = v)")


@_rule("__iter__")
def _iter(a: Interval) -> Any:
    return iter(_exact(x, y) for x, y in zip(a.lo.unbind(0), a.hi.unbind(0), strict=True))


@_rule("expand_as")
def _expand_as(a: Any, other: Any) -> Any:
    shape = other._meta[2] if isinstance(other, Interval) else other.shape
    if not isinstance(a, Interval):  # a constant given the interval's shape
        return a.expand(shape)
    return _exact(a.lo.expand(shape), a.hi.expand(shape))


@_rule("reshape_as", "view_as")
def _reshape_as(a: Any, other: Any) -> Any:
    shape = other._meta[2] if isinstance(other, Interval) else other.shape
    if not isinstance(a, Interval):
        return a.reshape(shape)
    return _exact(a.lo.reshape(shape), a.hi.reshape(shape))


def _convert(lo: torch.Tensor, new_lo: torch.Tensor, new_hi: torch.Tensor) -> Interval:
    """Round outward when a conversion narrows the dtype (float64 -> float32)."""
    if new_lo.dtype != lo.dtype and new_lo.is_floating_point() and lo.is_floating_point():
        if torch.finfo(new_lo.dtype).eps > torch.finfo(lo.dtype).eps:
            return _out1(new_lo, new_hi)
    if new_lo.is_floating_point() != lo.is_floating_point():
        raise _unsupported("converting an interval to a non-float dtype")
    return _exact(new_lo, new_hi)


@_rule("to")
def _to(a: Any, *args: Any, **kwargs: Any) -> Any:
    if any(isinstance(v, Interval) for v in args):  # x.to(other): other's dtype and device
        other = next(v for v in args if isinstance(v, Interval))
        args, kwargs = (), {**kwargs, "dtype": other._meta[0], "device": other._meta[1]}
    if not isinstance(a, Interval):
        return a.to(*args, **kwargs)
    return _convert(a.lo, a.lo.to(*args, **kwargs), a.hi.to(*args, **kwargs))


@_rule("type_as")
def _type_as(a: Any, other: Any) -> Any:
    dtype = other._meta[0] if isinstance(other, Interval) else other.dtype
    if not isinstance(a, Interval):
        return a.to(dtype)
    return _convert(a.lo, a.lo.to(dtype), a.hi.to(dtype))


@_rule("double")
def _double(a: Interval, memory_format: Any = None) -> Interval:
    return _convert(a.lo, a.lo.double(), a.hi.double())


@_rule("float")
def _float(a: Interval, memory_format: Any = None) -> Interval:
    return _convert(a.lo, a.lo.float(), a.hi.float())


def _join(fn: Callable) -> Callable:
    def rule(tensors: Sequence[Any], *args: Any, **kwargs: Any) -> Interval:
        like = _like(*tensors)
        los = [_tensor(_parts(t)[0], like) for t in tensors]
        his = [_tensor(_parts(t)[1], like) for t in tensors]
        return _exact(fn(los, *args, **kwargs), fn(his, *args, **kwargs))

    return rule


_rule("stack")(_join(torch.stack))
_rule("cat", "concat", "concatenate")(_join(torch.cat))
_rule("hstack")(_join(torch.hstack))
_rule("vstack")(_join(torch.vstack))


@_rule("broadcast_tensors")
def _broadcast_tensors(*tensors: Any) -> tuple:
    like = _like(*tensors)
    los = torch.broadcast_tensors(*[_tensor(_parts(t)[0], like) for t in tensors])
    his = torch.broadcast_tensors(*[_tensor(_parts(t)[1], like) for t in tensors])
    return tuple(_exact(x, y) if isinstance(t, Interval) else x for t, x, y in zip(tensors, los, his, strict=True))


@_rule("split")
def _split(a: Interval, size: Any, dim: int = 0) -> tuple:
    return tuple(_exact(x, y) for x, y in zip(torch.split(a.lo, size, dim), torch.split(a.hi, size, dim), strict=True))


@_rule("gather")
def _gather(a: Interval, dim: int, index: torch.Tensor, **kwargs: Any) -> Interval:
    if isinstance(index, Interval):
        raise _unsupported("gather with an undecided index")
    return _exact(torch.gather(a.lo, dim, index, **kwargs), torch.gather(a.hi, dim, index, **kwargs))


@_rule("result_type")
def _result_type(a: Any, b: Any) -> torch.dtype:
    return torch.result_type(a.lo if isinstance(a, Interval) else a, b.lo if isinstance(b, Interval) else b)


_rule("zeros_like")(lambda a, *args, **kw: torch.zeros_like(a.lo, *args, **kw))
_rule("ones_like")(lambda a, *args, **kw: torch.ones_like(a.lo, *args, **kw))
_rule("empty_like")(lambda a, *args, **kw: torch.zeros_like(a.lo, *args, **kw))
_rule("full_like")(lambda a, fill, *args, **kw: torch.full_like(a.lo, fill, *args, **kw))
_rule("new_tensor")(lambda a, *args, **kw: a.lo.new_tensor(*args, **kw))
_rule("new_zeros")(lambda a, *args, **kw: a.lo.new_zeros(*args, **kw))
_rule("new_ones")(lambda a, *args, **kw: a.lo.new_ones(*args, **kw))
_rule("new_full")(lambda a, *args, **kw: a.lo.new_full(*args, **kw))
_rule("new_empty")(lambda a, *args, **kw: a.lo.new_zeros(*args, **kw))


def _linear(a: Any, m: Any, left: bool) -> Interval:
    """``a @ m`` (left) or ``m @ a`` with a constant matrix m: positive and negative parts of m."""
    if isinstance(m, Interval):
        raise _unsupported("a product of two intervals (matmul)")
    lo, hi = a.lo, a.hi
    mp, mn = torch.clamp(m, min=0), torch.clamp(m, max=0)

    def mm(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return x @ y if left else y @ x

    low, high = mm(lo, mp) + mm(hi, mn), mm(hi, mp) + mm(lo, mn)
    n = m.shape[-2] if left else m.shape[-1]
    scale = mm(torch.maximum(lo.abs(), hi.abs()), m.abs())
    return _widen(low, high, scale=scale, ulps=n + 2)


@_rule("matmul", "__matmul__", "mm", "mv", "bmm")
def _matmul(a: Any, b: Any) -> Interval:
    if isinstance(a, Interval):
        return _linear(a, b, left=True)
    return _linear(b, a, left=False)


@_rule("__rmatmul__")
def _rmatmul(a: Interval, b: Any) -> Interval:
    return _linear(a, b, left=False)


def _contracted_length(equation: str, operands: Sequence[torch.Tensor]) -> int:
    """How many products an einsum adds up for one output entry (the summed indices' sizes)."""
    eq = equation.replace(" ", "")
    if "..." in eq:
        raise _unsupported("einsum with '...'")
    lhs, _, rhs = eq.partition("->")
    inputs = lhs.split(",")
    if not rhs and "->" not in eq:
        letters = "".join(inputs)
        rhs = "".join(sorted(c for c in set(letters) if letters.count(c) == 1))
    sizes = {}
    for term, op in zip(inputs, operands, strict=True):
        for c, n in zip(term, op.shape, strict=True):
            sizes[c] = max(sizes.get(c, 1), int(n))
    return max(1, math.prod(n for c, n in sizes.items() if c not in rhs))


@_rule("einsum")
def _einsum(equation: str, *operands: Any) -> Interval:
    """A contraction linear in its one interval operand: midpoint and radius (the others constant)."""
    if len(operands) == 1 and isinstance(operands[0], list | tuple):
        operands = tuple(operands[0])
    which = [i for i, v in enumerate(operands) if isinstance(v, Interval)]
    if len(which) != 1:
        raise _unsupported("einsum of several intervals")
    k = which[0]
    a = operands[k]
    mid = 0.5 * a.lo + 0.5 * a.hi
    rad = torch.maximum(a.hi - mid, mid - a.lo)  # rounded, widened below with the rest
    consts = [v.abs() if isinstance(v, torch.Tensor) else abs(v) for v in operands]
    center = torch.einsum(equation, *[mid if i == k else v for i, v in enumerate(operands)])
    spread = torch.einsum(equation, *[rad if i == k else v for i, v in enumerate(consts)])
    size = torch.einsum(
        equation, *[torch.maximum(a.lo.abs(), a.hi.abs()) if i == k else v for i, v in enumerate(consts)]
    )
    terms = _contracted_length(equation, [a.lo if i == k else v for i, v in enumerate(operands)])
    widen = spread * (1 + 4 * torch.finfo(spread.dtype).eps) + (terms + 4) * torch.finfo(size.dtype).eps * size
    return _out1(center - widen, center + widen)


@_rule("cross")
def _cross(a: Any, b: Any, dim: int | None = None) -> Interval:
    """The cross product from its components (products and differences of intervals); 3-vectors on ``dim``."""
    d = -1 if dim is None else dim

    def comp(v: Any, i: int) -> Any:
        return v.select(d, i)

    x = [(1, 2), (2, 0), (0, 1)]
    parts = [_sub(_mul(comp(a, i), comp(b, j)), _mul(comp(a, j), comp(b, i))) for i, j in x]
    return _join(torch.stack)(parts, d)


@_rule("__repr__", "__str__", "__format__")
def _repr(a: Interval, *args: Any) -> str:
    return f"Interval(lo={a.lo!r}, hi={a.hi!r})"


# ---------------------------------------------------------------------------------------------
# the public entries
# ---------------------------------------------------------------------------------------------


def _boxes(lo: Any, hi: Any) -> tuple[torch.Tensor, torch.Tensor, bool, Any]:
    tl, was_numpy = as_tensor(lo, "lo", fn="bounds")
    th, _ = as_tensor(hi, "hi", fn="bounds")
    if tl.ndim != 2 or th.shape != tl.shape:
        raise ValueError(
            f"bounds: lo and hi must be box corners of one shape (B, d), got {tuple(tl.shape)} and {tuple(th.shape)}"
        )
    if th.dtype != tl.dtype:
        raise TypeError(f"bounds: lo and hi must have one dtype, got {tl.dtype} and {th.dtype}")
    if tl.numel() and not bool(torch.isfinite(tl).all() & torch.isfinite(th).all()):
        raise ValueError("bounds: box corners lo and hi must be finite")
    bad = (tl > th).any(-1)
    if bool(bad.any()):
        i = int(torch.nonzero(bad)[0, 0])
        raise ValueError(f"bounds: box {i} has lo > hi: lo={tl[i].tolist()}, hi={th[i].tolist()}")
    # numpy in, numpy out of the input's dtype (lists and tuples of numbers are float64, as_tensor's rule)
    return tl, th, was_numpy, (np.dtype(str(tl.dtype).removeprefix("torch.")) if was_numpy else tl.dtype)


def _params(f: Callable, like: torch.Tensor, params: dict) -> dict:
    if isinstance(f, Model):
        params = f._resolve(params)
    out = {}
    for name, v in params.items():
        if isinstance(v, np.ndarray):
            v = torch.as_tensor(v)
        if isinstance(v, torch.Tensor):
            if v.ndim != 0:
                raise ValueError(f"bounds: parameter {name} must be a scalar, got shape {tuple(v.shape)}")
            v = v.detach().to(dtype=like.dtype, device=like.device)
        elif isinstance(v, bool) or not isinstance(v, numbers.Real):
            raise TypeError(f"bounds: parameter {name} must be a real number, got {v!r}")
        else:
            v = torch.tensor(float(v), dtype=like.dtype, device=like.device)
        if not bool(torch.isfinite(v)):
            raise ValueError(f"bounds: parameter {name} must be finite, got {float(v)}")
        out[name] = v
    return out


def _evaluate(f: Callable, lo: torch.Tensor, hi: torch.Tensor, params: dict) -> tuple[torch.Tensor, torch.Tensor]:
    box = Interval.of(lo, hi)
    fn = f.fn if isinstance(f, Model) else f
    try:
        with validated_inputs(), torch.no_grad():
            out = fn(box, **params)
    except _Blocked as err:
        raise IntervalUnsupported(f"{name_of(f)}: {err}") from None
    if isinstance(out, Interval):
        olo, ohi = out.lo, out.hi
    elif isinstance(out, torch.Tensor):  # the model ignores its points: a constant
        olo = ohi = out
    else:
        raise ValueError(f"bounds: {name_of(f)} must return a tensor, got {type(out).__name__}")
    if olo.shape != lo.shape[:1]:
        raise ValueError(
            f"bounds: {name_of(f)} must map points (N, d) to values (N,); called with boxes of shape "
            f"{tuple(lo.shape)}, it returned shape {tuple(olo.shape)}"
        )
    if olo.dtype == torch.bool or not olo.is_floating_point():
        raise ValueError(f"bounds: {name_of(f)} returned {olo.dtype} values, not floats")
    olo, ohi = _nan_safe(olo, ohi)
    return olo.to(lo.dtype), ohi.to(lo.dtype)


def bounds(f: Callable, lo: Any, hi: Any, chunk: int | None = None, **params: Any) -> tuple[Any, Any]:
    """Guaranteed lower and upper bounds of ``f`` over each of B axis-aligned boxes.

    Parameters
    ----------
    f : a model (:class:`pyfrep_core.Model`) or any defining function ``f(x, **params)``,
        (N, d) -> (N,), written with torch operations (the catalogue and plain torch code).
    lo, hi : (B, d) torch tensors or numpy arrays, float32 or float64: the boxes' lower and upper
        corners (``lo <= hi``; a degenerate box is a point).
    chunk : boxes per call; default: the memory budget of :func:`pyfrep_core.evaluate.budget_points`
        divided by the cost of an interval value.
    **params : scalar parameters (numbers or 0-d tensors) passed as 0-d tensors of the boxes' dtype;
        a model's defaults fill in the others.

    Returns
    -------
    (flo, fhi) : two (B,) arrays of the kind and dtype of ``lo`` with ``flo <= f(x) <= fhi`` for every
        x in the box, for the exact value and for the value the same code computes in floating point.
        Infinite where the model is unbounded there (a division by an interval holding 0).

    Raises
    ------
    IntervalUnsupported (a TypeError) naming the torch operation when ``f`` uses one without an
    interval rule or branches on a value the bounds cannot decide; ValueError for bad boxes.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import block
    >>> lo = np.array([[0.1, 0.1, 0.1], [2.0, 2.0, 2.0]])
    >>> flo, fhi = bounds(lambda x: block(x, vertex=(0, 0, 0), dx=1, dy=1, dz=1), lo, lo + 0.2)
    >>> bool(flo[0] > 0), bool(fhi[1] < 0)   # the first box is inside the block, the second outside
    (True, True)
    """
    tl, th, was_numpy, dtype = _boxes(lo, hi)
    if isinstance(f, Model) and tl.shape[1] != f.dim:
        shape = tuple(tl.shape)
        raise ValueError(f"bounds: {f.__name__} takes points of {f.dim} coordinates, got boxes of shape {shape}")
    p = _params(f, tl, params)
    n, d = tl.shape
    size = chunk if chunk is not None else max(1, budget_points(tl.dtype, d) // INTERVAL_VALUES)
    if n == 0:
        flo = fhi = tl.new_zeros(0)
    elif n <= size:
        flo, fhi = _evaluate(f, tl, th, p)
    else:
        parts = [_evaluate(f, tl[i : i + size], th[i : i + size], p) for i in range(0, n, size)]
        flo, fhi = torch.cat([a for a, _ in parts]), torch.cat([b for _, b in parts])
    if was_numpy:
        return flo.cpu().numpy().astype(dtype, copy=False), fhi.cpu().numpy().astype(dtype, copy=False)
    return flo, fhi


def supports(f: Callable, d: int = 3, **params: Any) -> bool:
    """Whether :func:`bounds` can bound ``f`` (tried on one small box); False on IntervalUnsupported.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> supports(lambda x: sphere(x, r=1.0)), supports(lambda x: torch.sort(x, dim=1).values[:, 0])
    (True, False)
    """
    if isinstance(f, Model):
        d = f.dim
    box = torch.full((1, d), 0.25, dtype=torch.float64)
    try:
        bounds(f, box, box + 0.125, **params)
    except IntervalUnsupported:
        return False
    return True
