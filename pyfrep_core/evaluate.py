"""Calling a model: the one place that hands a defining function its points and parameters.

The contract every layer relies on: a model ``fn(x, **params)`` is called only with points
``x`` of shape (N, d) (a 2-D tensor: never a grid block, never a single 1-D point) and with
every parameter a 0-d tensor of the points' dtype (a number given is converted), and must
return values of shape (N,).  A user may
write any torch code that does so: ``p[:, i]`` indexing, tuples built from parameters as
centres, ``torch.stack``, ``torch.where``, Python arithmetic on parameters.  What needs more
is done here, around the call:

- points of any shape (..., d) (a grid, a slice, a single point) are flattened to (N, d) and
  the values reshaped back to (...) (:func:`evaluate`);
- large point sets are cut into chunks whose working set stays under the call budget
  (:func:`call_budget`, :func:`budget_points`);
- many parameter sets at once (parameters given as (B,) tensors: the evolution stage of
  :func:`pyfrep_core.fit`, ``model(x, r=torch.tensor([...]))``) run through
  :func:`torch.func.vmap` over the parameters, so the model still sees 0-d parameters; a model
  vmap cannot run (it calls ``.item()``, branches on a value with Python ``if``, writes in
  place) is evaluated set by set instead, with one warning per model naming it and the reason
  (:func:`call_sets`);
- the output is checked: anything but a tensor of shape (N,) raises ValueError naming the
  model, the input shape and the output shape (:func:`call`).

Memory budget.  One call's working set (its points, the temporaries of the model's
operations and, with gradients on, what autograd keeps for the backward pass) is estimated at
``(d + WORK_VALUES) * itemsize`` bytes a point and a parameter set, ``WORK_VALUES`` (128) being
the live intermediate values of a model of about a hundred operations.  Chunks are sized so
that this stays under :func:`call_budget`: an eighth of the memory available now
(:func:`pyfrep_core._array.available_memory`, ``MemAvailable``, the figure
:func:`pyfrep_core.polygonize` checks its grid against before allocating), at most
``MAX_CALL_BYTES`` (1 GiB).  Chunking by points is exact (points are independent), so it
changes no value.

>>> import torch
>>> f = lambda x, r=1.0: r**2 - x[:, 0] ** 2 - x[:, 1] ** 2 - x[:, 2] ** 2  # a paper-style model
>>> evaluate(f, torch.zeros(4, 5, 6, 3)).shape   # a grid block, flattened for f and reshaped back
torch.Size([4, 5, 6])
"""

from __future__ import annotations

import math
import threading
import time
import warnings
import weakref
from collections.abc import Callable, Mapping
from typing import Any

import torch

from . import _array
from ._array import tracing

__all__ = ["evaluate", "call", "call_sets", "call_budget", "budget_points", "vmap_refused", "remember_refusal"]

WORK_VALUES = 128  # live intermediate values per point in one call of a model (about 100 operations)
MAX_CALL_BYTES = 1 << 30  # at most this much working set per call, however much memory is free
MEMORY_FRACTION = 8  # a call uses at most 1/8 of the memory available now
UNKNOWN_BUDGET = 256 << 20  # the budget where the available memory cannot be read
BUDGET_REFRESH = 1.0  # seconds a reading of the available memory is used for

_budget: tuple[float, Any, int] = (-math.inf, None, UNKNOWN_BUDGET)  # (read at, reader, bytes)

_no_vmap: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # fn -> why vmap cannot run it
_no_vmap_lock = threading.Lock()


class ModelOutputError(ValueError):
    """A model returned something other than one value per point (a ValueError)."""


def name_of(fn: Any) -> str:
    """How messages name a model or a defining function: its ``__name__``, else its repr.

    >>> import functools
    >>> def ball(x, r): return r - x[:, 0]
    >>> name_of(functools.partial(ball, r=1.0))
    'ball'
    """
    while hasattr(fn, "func") and callable(fn.func) and not hasattr(fn, "__name__"):
        fn = fn.func  # functools.partial
    return getattr(fn, "__name__", None) or repr(fn)


def call_budget(device: Any = None) -> int:
    """Bytes one call of a model may use for its working set (see the module docstring).

    An eighth of the memory available now, at most ``MAX_CALL_BYTES`` (1 GiB); 256 MiB where
    the available memory cannot be read.  For a CUDA ``device`` that is the device's free memory;
    otherwise the host's, read at most once every ``BUDGET_REFRESH`` seconds (reading it costs
    about 50 us, a small model call less).

    >>> 0 < call_budget() <= MAX_CALL_BYTES
    True
    """
    global _budget
    if device is not None and torch.device(device).type == "cuda":
        have = int(torch.cuda.mem_get_info(torch.device(device))[0])
        return max(1 << 20, min(MAX_CALL_BYTES, have // MEMORY_FRACTION))
    now = time.monotonic()
    read_at, patched, value = _budget
    # re-read when stale, or at once when the reader was replaced (a test fixing the memory)
    if now - read_at > BUDGET_REFRESH or patched is not _array.available_memory:
        have = _array.available_memory()
        value = UNKNOWN_BUDGET if have is None else max(1 << 20, min(MAX_CALL_BYTES, have // MEMORY_FRACTION))
        _budget = (now, _array.available_memory, value)
    return value


def budget_points(dtype: torch.dtype, dim: int, sets: int = 1, budget: int | None = None) -> int:
    """Points per call so that ``sets`` parameter sets at once stay within ``budget`` bytes.

    ``budget`` defaults to :func:`call_budget`.  At least one point.

    >>> budget_points(torch.float64, 3, budget=1 << 20)   # 1 MiB / ((3 + 128) * 8 bytes)
    1000
    >>> budget_points(torch.float64, 3, sets=1000, budget=1 << 20)
    1
    """
    budget = call_budget() if budget is None else budget
    itemsize = dtype.itemsize
    return max(1, budget // ((dim + WORK_VALUES) * itemsize * max(1, sets)))


def _shape_error(label: str, x: torch.Tensor, out: Any, sets: int | None = None) -> ModelOutputError:
    got = tuple(out.shape) if hasattr(out, "shape") else type(out).__name__
    per = f" per parameter set (of {sets})" if sets is not None else ""
    return ModelOutputError(
        f"{label}: a model must map points (N, d) to values (N,){per}; "
        f"called with points of shape {tuple(x.shape)}, it returned shape {got}"
    )


def call(
    fn: Callable, x: torch.Tensor, params: Mapping[str, Any] | None = None, label: str | None = None
) -> torch.Tensor:
    """``fn(x, **params)`` for points (N, d) and scalar parameters, its output checked to be (N,).

    Raises ValueError (naming the model, ``label`` or else ``fn``'s name, the input shape and the
    output shape) for any other output: a model must give one value per point.

    >>> import torch
    >>> call(lambda x: x[:, 0] - 1.0, torch.zeros(2, 3))
    tensor([-1., -1.])
    >>> def flat(x):
    ...     return x.sum()
    >>> try:
    ...     call(flat, torch.zeros(2, 3))
    ... except ValueError as err:
    ...     print(str(err).split("; ")[1])
    called with points of shape (2, 3), it returned shape ()
    """
    out = fn(x, **(params or {}))
    if not isinstance(out, torch.Tensor) or out.shape != x.shape[:1]:
        raise _shape_error(label or name_of(fn), x, out)
    return out


def evaluate(
    fn: Callable,
    x: torch.Tensor,
    params: Mapping[str, Any] | None = None,
    chunk: int | None = None,
    label: str | None = None,
) -> torch.Tensor:
    """``fn`` at points ``x`` of any shape (..., d): flattened to (N, d), in chunks, reshaped to (...).

    Parameters
    ----------
    fn : a defining function ``fn(x, **params)``, (N, d) -> (N,) (a Model too).
    x : tensor (..., d).  A view is passed on where the layout allows (a component-first grid
        block flattens without a copy).
    params : scalar parameters passed on unchanged.
    chunk : points per call; default :func:`budget_points` (the memory budget).  Not chunked
        while tracing (torch.compile, torch.func), where the caller decides.
    label : the model's name in messages (default: ``fn``'s name).

    Returns
    -------
    tensor of shape ``x.shape[:-1]``; ValueError when ``fn`` does not return one value per point.

    Examples
    --------
    >>> import torch
    >>> x = torch.zeros(2, 3, 3)
    >>> evaluate(lambda p: 1.0 - p.norm(dim=1), x, chunk=4)
    tensor([[1., 1., 1.],
            [1., 1., 1.]])
    """
    batch = x.shape[:-1]
    flat = x.reshape(-1, x.shape[-1])
    if tracing(flat):  # one call: the transform's caller chunks (and the budget is not read while compiling)
        return call(fn, flat, params, label).reshape(batch)
    n = flat.shape[0]
    size = chunk if chunk is not None else budget_points(x.dtype, x.shape[-1])
    if n <= size:
        out = call(fn, flat, params, label)
    else:
        out = torch.cat([call(fn, flat[i : i + size], params, label) for i in range(0, n, size)])
    return out.reshape(batch)


def call_sets(
    fn: Callable,
    x: torch.Tensor,
    scalars: Mapping[str, Any],
    batched: Mapping[str, torch.Tensor],
    label: str | None = None,
) -> torch.Tensor:
    """``fn`` at points (N, d) for B parameter sets: values (B, N), the model seeing 0-d parameters.

    Parameters
    ----------
    fn : the defining function ``fn(x, **params)``, (N, d) -> (N,).
    x : points (N, d), shared by every set.
    scalars : parameters common to all sets (floats or 0-d tensors).
    batched : parameters with one value per set, (B,) tensors (all the same B).  Gradients flow
        through them when they require grad.
    label : the model's name in messages (default: ``fn``'s name).

    The sets run through ``torch.func.vmap`` (the points and the scalars are not mapped), in
    chunks of points within the memory budget.  Where vmap cannot run ``fn`` (``.item()``,
    ``if`` on a value, in-place writes ...), the sets are evaluated one after the other, with
    one RuntimeWarning per model naming it and the reason; later calls loop at once.

    The primitives' parameter checks cannot read values under vmap.  A set whose values are not
    finite is run again alone, so a degenerate parameter that makes them so raises the
    primitive's own error (``ellipsoid: a must be positive``); one that leaves them finite (a
    negative radius that is squared) passes, as under any torch.func transform: the declared
    ranges (:meth:`pyfrep_core.model.Model.check`, applied by fit, sampling and the workbench)
    are the guard there.

    Examples
    --------
    >>> import torch
    >>> def ball(x, r, cx):
    ...     return r**2 - (x[:, 0] - cx) ** 2 - x[:, 1] ** 2 - x[:, 2] ** 2
    >>> call_sets(ball, torch.zeros(4, 3), {"cx": 0.0}, {"r": torch.tensor([1.0, 2.0])})
    tensor([[1., 1., 1., 1.],
            [4., 4., 4., 4.]])
    """
    label = label or name_of(fn)
    names = list(batched)
    values = list(batched.values())
    sets = int(values[0].shape[0])
    n = x.shape[0]
    traced = tracing(x, *values)
    size = n if traced else budget_points(x.dtype, x.shape[-1], sets)
    parts = []
    for start in range(0, n, size) if n > size else (0,):
        part = x[start : start + size] if n > size else x

        def one(*vals: torch.Tensor, part: torch.Tensor = part) -> torch.Tensor:
            out = fn(part, **scalars, **dict(zip(names, vals)))
            if not isinstance(out, torch.Tensor) or out.shape != part.shape[:1]:
                raise _shape_error(label, part, out, sets)
            return out

        def loop() -> torch.Tensor:
            return torch.stack([one(*(v[b] for v in values)) for b in range(sets)])

        if vmap_refused(fn):
            parts.append(loop())
            continue
        refused = None
        try:
            # randomness "same": a model's random draws (a spinodoid's seeded wave directions) are
            # one draw shared by every set, as each set's own call would draw them from its seed
            out = torch.func.vmap(one, in_dims=(0,) * len(values), randomness="same")(*values)
        except ModelOutputError:
            raise
        except Exception as error:  # noqa: BLE001  (whatever vmap refuses: the loop decides)
            refused = f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
        if refused is not None:
            parts.append(loop())  # a genuine error of the model raises here, on its own
            remember_refusal(fn, label, refused)
            continue
        if not traced:
            _recheck_nonfinite(one, values, out)
        parts.append(out)
    return parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)


def _recheck_nonfinite(one: Callable, values: list[torch.Tensor], out: torch.Tensor) -> None:
    """Under vmap the primitives' parameter checks are skipped (values cannot be read while
    tracing): where a set gave a non-finite value, run that set alone, so that a degenerate
    parameter raises the primitive's own error (``sphere: r must be positive``) instead of
    passing on silently.  One reduction over the values; nothing is re-run when all are finite."""
    if out.numel() == 0 or all(math.isfinite(v) for v in torch.stack(torch.aminmax(out.detach())).tolist()):
        return
    bad = int(torch.nonzero(~torch.isfinite(out.detach()))[0, 0])
    with torch.no_grad():
        one(*(v[bad].detach() for v in values))


def _weakrefable(fn: Any) -> bool:
    try:
        weakref.ref(fn)
    except TypeError:
        return False
    return True


def vmap_refused(fn: Any) -> bool:
    """Whether ``torch.func.vmap`` is known not to run ``fn`` (a refusal noted by :func:`remember_refusal`)."""
    return _weakrefable(fn) and fn in _no_vmap


def remember_refusal(fn: Any, label: str, reason: str) -> None:
    """Note (once per model, thread-safe) that vmap cannot run ``fn``, and warn once.

    One registry for every batched path (parameter sets here, per-point parameter derivatives
    in :mod:`pyfrep_core.diff`): a model vmap refuses gets one warning, whichever path found it.
    """
    with _no_vmap_lock:
        if _weakrefable(fn):
            if fn in _no_vmap:
                return
            _no_vmap[fn] = reason
    warnings.warn(
        f"{label}: torch.func.vmap cannot run this model ({reason}); parameter sets and per-point "
        "parameter derivatives are evaluated one at a time (slower; write the model without .item(), "
        "Python `if` on parameter values or in-place writes to batch it)",
        RuntimeWarning,
        stacklevel=4,
    )
