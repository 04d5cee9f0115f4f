"""Array plumbing shared by the kernel: numpy in -> numpy out, torch in -> torch out.

Primitives are written once, on torch tensors.  The :func:`frep` decorator lets a
numpy user call them too: numpy arrays are converted and the result is converted back
when no torch tensor came in.

Input validation: one path for every public entry that takes points or field values
(:func:`frep` for the catalogue, :class:`~pyfrep_core.model.Model` calls, the analyses
through :func:`as_tensor`, :func:`check_points` and :func:`check_finite`):

- dtype: float32 or float64 tensors and numpy arrays (lists become float64).  Complex,
  integer, boolean and half-precision arrays raise TypeError (:func:`check_dtype`): converting
  them would drop an imaginary part or round silently.  Results come back in the points' dtype.
- shape: points are (..., d), d = 3 (or 2 for planar models).
- finite: points, values and parameters must be finite, torch as well as numpy (ValueError
  naming the function, the argument and the value).
- empty: pointwise evaluation (primitives, operations, transforms, model calls) of no points
  gives no values (shape (0,)); entries that need points to work on (derivatives, fitting,
  sampling, distances) raise ValueError.

The value checks (one isfinite pass) run once per public call: an entry that has checked its
inputs marks the call (:func:`validated_inputs`) and what it calls skips them, so a model made
of 30 primitives reads its points once and polygonize's millions of grid points are not read
again per primitive.  They are skipped too while :func:`tracing` (torch.compile, torch.func),
where values cannot be read: the kernel checks before it enters such a transform.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import inspect
import math
import numbers
import os
import re
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
import torch
from torch.fx.experimental.proxy_tensor import get_proxy_mode

Array = torch.Tensor | np.ndarray
Scalar = float | torch.Tensor

FLOAT_DTYPES = (torch.float32, torch.float64)

# set by an entry that has checked its inputs: the entries it calls skip their value checks
_VALIDATED: contextvars.ContextVar[bool] = contextvars.ContextVar("pyfrep_inputs_validated", default=False)


@contextlib.contextmanager
def validated_inputs() -> Iterator[None]:
    """Mark the calls made inside as working on inputs an outer entry has already checked.

    Nested entries (:func:`frep` functions, model calls, :func:`check_finite`) skip their value
    checks inside, so a model of 30 primitives reads its points once, not 30 times.  The mark is
    per thread and per task (a :class:`contextvars.ContextVar`).

    >>> import torch
    >>> with validated_inputs():
    ...     check_finite(torch.tensor([float("nan")]), "x", "sphere")  # an outer entry checked
    >>> skip_checks()
    False
    """
    token = _VALIDATED.set(True)
    try:
        yield
    finally:
        _VALIDATED.reset(token)


def skip_checks(*values: Any) -> bool:
    """True where value checks are skipped: inside :func:`validated_inputs` or while :func:`tracing`.

    >>> skip_checks()
    False
    >>> with validated_inputs():
    ...     skip_checks()
    True
    """
    return torch.compiler.is_compiling() or _VALIDATED.get() or tracing(*values)


def _label(fn: str | None, name: str) -> str:
    return f"{fn}: {name}" if fn else name


def _to_torch(value: Any, device: torch.device | None = None) -> Any:
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "iub":
            value = value.astype(np.float64)
        return _from_numpy(value).to(device or "cpu")
    return value


def _from_numpy(arr: np.ndarray) -> torch.Tensor:
    """A tensor on ``arr``'s memory when torch can share it (contiguous, writable, native byte order)."""
    if not arr.dtype.isnative:
        arr = arr.astype(arr.dtype.newbyteorder("="))
    if not arr.flags.writeable:
        arr = arr.copy()
    return torch.from_numpy(np.ascontiguousarray(arr))


def _back(value: Any) -> Any:
    if isinstance(value, torch.Tensor):
        return value.detach().cpu().numpy()
    if isinstance(value, tuple):
        return tuple(_back(v) for v in value)
    if isinstance(value, list):
        return [_back(v) for v in value]
    if isinstance(value, dict):
        return {k: _back(v) for k, v in value.items()}
    return value


def named_error(err: ValueError, fn: str) -> ValueError:
    """``err`` with its message prefixed by ``fn: `` (unless it already names ``fn``); same type and traceback.

    An entry uses it on errors raised by what it calls (a point shape found wrong inside a
    primitive, a degenerate parameter of a primitive inside a model), so every message says
    which public call failed.

    >>> str(named_error(ValueError("points x must have shape (N, 3), got (4, 2)"), "sphere"))
    'sphere: points x must have shape (N, 3), got (4, 2)'
    """
    short = fn.rsplit(".", 1)[-1]  # sdf.shell's own messages say "shell: ..."
    if len(err.args) == 1 and isinstance(err.args[0], str) and not err.args[0].startswith((f"{fn}:", f"{short}:")):
        err.args = (f"{fn}: {err.args[0]}",)
    return err


_ENTRY: contextvars.ContextVar[str | None] = contextvars.ContextVar("pyfrep_entry", default=None)


def named_entry(fn: Callable) -> Callable:
    """Decorator for a public analysis entry (grad, curvatures, ...): its errors name it.

    A ValueError or TypeError raised inside (a bad point found by the shared checks, a
    degenerate parameter of a primitive inside f) gets the entry's name as prefix
    (:func:`named_error`); only the outermost entry adds its name (``grad`` calls
    ``value_and_grad``: the message says ``grad: ...``).

    >>> @named_entry
    ... def grad_like(x):
    ...     check_finite(as_tensor(x)[0])
    >>> grad_like([[0.0, float("nan"), 0.0]])
    Traceback (most recent call last):
    ...
    ValueError: grad_like: x contains a non-finite value (nan) at index (0, 1)
    """
    label = fn.__name__

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if _ENTRY.get() is not None:
            return fn(*args, **kwargs)
        token = _ENTRY.set(label)
        try:
            return fn(*args, **kwargs)
        except (ValueError, TypeError) as err:
            raise named_error(err, label)  # noqa: B904  (the same exception, its message prefixed)
        finally:
            _ENTRY.reset(token)

    return wrapper


# the arguments of a catalogue function that hold points or field values (checked for dtype):
# the first one (x, f, d, f1, d1) and the further operands of an operation (f2, f3, d2)
_OPERAND = re.compile(r"[fd][2-9]")


def _check_argument(value: Any, name: str, fn: str) -> None:
    """Refuse a complex or non-finite argument of ``fn`` (tensor, array, number or sequence of numbers)."""
    if isinstance(value, torch.Tensor | np.ndarray):
        if value.dtype.kind == "c" if isinstance(value, np.ndarray) else value.is_complex():
            check_dtype(value, name, fn)
        if value.dtype.kind == "f" if isinstance(value, np.ndarray) else value.is_floating_point():
            check_finite(value, name, fn)
    elif isinstance(value, bool | str):
        return
    elif isinstance(value, numbers.Real):
        if not math.isfinite(value):
            raise ValueError(f"{fn}: {name} must be finite, got {value!r}")
    elif isinstance(value, numbers.Complex):
        raise TypeError(f"{fn}: {name} must be a real number, got {value!r}")
    elif isinstance(value, list | tuple):
        for item in value:
            if isinstance(item, numbers.Number | torch.Tensor | np.ndarray) and not isinstance(item, bool):
                try:
                    _check_argument(item, name, fn)
                except ValueError:
                    raise ValueError(f"{fn}: {name} must be finite, got {shown(value)!r}") from None


def frep(fn: Callable) -> Callable:
    """Make a torch function of points (or of field values) a checked public entry.

    - Torch tensors pass through untouched (no copy, graph kept); numpy arrays are converted,
      and the result goes back to numpy only when no tensor came in (a numpy point set with a
      tensor parameter that requires grad gives a tensor, so the gradient is not lost).
    - The points (first argument; for an operation its operands f1, f2, f3 / d1, d2) must be
      float32 or float64 arrays: complex, integer, boolean and half-precision input raise
      TypeError (:func:`check_dtype`).  The result has their dtype (float32 in, float32 out,
      numpy or torch).
    - Every array argument and every numeric parameter must be finite, torch as well as numpy
      (:func:`check_finite`: ValueError naming the function, the argument and the value).
      Complex parameters raise TypeError.
    - No points (shape (0, 3)) give no values (shape (0,)): evaluating ``f(x[mask])`` with an
      all-False mask is ordinary, as for numpy and torch functions.
    - Value errors raised inside are prefixed with the function's name (:func:`named_error`).

    The checks run once per public call: inside a checked call (a primitive of a model, the
    primitives a transform calls) and while :func:`tracing`, the wrapper only converts numpy.

    >>> import numpy as np
    >>> @frep
    ... def half(x):
    ...     return 0.5 * x[..., 0]
    >>> half(np.ones((2, 3), np.float32)).dtype
    dtype('float32')
    >>> half(np.array([[np.inf, 0.0, 0.0]]))
    Traceback (most recent call last):
    ...
    ValueError: half: x contains a non-finite value (inf) at index (0, 0)
    """
    names = list(inspect.signature(fn).parameters)
    operands = [names[0], *(n for n in names[1:] if _OPERAND.fullmatch(n))]
    points = names[0] == "x"
    label = f"sdf.{fn.__name__}" if fn.__module__.endswith(".sdf") else fn.__name__

    def convert_and_call(args: tuple, kwargs: dict) -> Any:
        device = None
        has_numpy = False
        for a in (*args, *kwargs.values()):
            if isinstance(a, torch.Tensor):
                device = device or a.device
            elif isinstance(a, np.ndarray):
                has_numpy = True
        if not has_numpy:
            return fn(*args, **kwargs)
        # numpy beside a tensor (numpy points, a tensor parameter): compute in torch, return torch
        out = fn(*[_to_torch(a, device) for a in args], **{k: _to_torch(v, device) for k, v in kwargs.items()})
        return out if device is not None else _back(out)

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if tracing():
            return convert_and_call(args, kwargs)
        if _VALIDATED.get():
            # inside a checked call: its points were read; numbers (parameters) cost nothing to check
            for name, value in (*zip(names, args, strict=False), *kwargs.items()):
                if not isinstance(value, torch.Tensor | np.ndarray):
                    _check_argument(value, name, label)
            return convert_and_call(args, kwargs)
        given = {**dict(zip(names, args, strict=False)), **kwargs}
        dtype = None
        for name in operands:
            if name not in given:
                continue  # a missing argument: the call itself raises TypeError
            value = given[name]
            if isinstance(value, torch.Tensor | np.ndarray):
                check_dtype(value, name, label)
                vdt = value.dtype if isinstance(value, torch.Tensor) else torch.from_numpy(value[:0]).dtype
                dtype = vdt if dtype is None else torch.promote_types(dtype, vdt)
            elif points or name == names[0] or not isinstance(value, numbers.Real) or isinstance(value, bool):
                what = "points" if points else "values"
                raise TypeError(
                    f"{label}: {name} must be a torch tensor or a numpy array of {what}, got {type(value).__name__}"
                )
        for name, value in given.items():
            _check_argument(value, name, label)
        if tracing(*given.values()):
            return convert_and_call(args, kwargs)
        with validated_inputs():
            try:
                out = convert_and_call(args, kwargs)
            except ValueError as err:
                raise named_error(err, label)  # noqa: B904  (the same exception, its message prefixed)
        return _in_dtype(out, dtype)

    return wrapper


def _in_dtype(out: Any, dtype: torch.dtype | None) -> Any:
    """``out`` (a tensor or a numpy array) in ``dtype`` when it is floating and not yet in it."""
    if dtype is None:
        return out
    if isinstance(out, torch.Tensor) and out.is_floating_point() and out.dtype != dtype:
        return out.to(dtype)
    if isinstance(out, np.ndarray) and out.dtype.kind == "f":
        want = torch.empty(0, dtype=dtype).numpy().dtype
        return out if out.dtype == want else out.astype(want)
    return out


def check_dtype(x: torch.Tensor | np.ndarray, name: str = "x", fn: str | None = None) -> None:
    """Raise TypeError unless ``x`` holds float32 or float64 numbers.

    Complex input would lose its imaginary part, integer input would round (a centre 0.5 in
    integer arithmetic is 0), so neither is converted silently.

    >>> import numpy as np
    >>> check_dtype(np.zeros(3, np.float32), "x", "sphere")
    >>> check_dtype(np.zeros(3, np.int64), "x", "sphere")
    Traceback (most recent call last):
    ...
    TypeError: sphere: x must be float32 or float64, got int64; convert it first (x.astype(np.float64))
    """
    if isinstance(x, torch.Tensor):
        if x.dtype in FLOAT_DTYPES:
            return
        dtype, is_complex, convert = str(x.dtype).removeprefix("torch."), x.is_complex(), f"{name}.double()"
    else:
        if x.dtype in (np.float32, np.float64):
            return
        dtype, is_complex, convert = str(x.dtype), x.dtype.kind == "c", f"{name}.astype(np.float64)"
    if is_complex:
        raise TypeError(
            f"{_label(fn, name)} must be real (float32 or float64), got {dtype}; "
            f"pass {name}.real if the imaginary part is to be dropped"
        )
    raise TypeError(f"{_label(fn, name)} must be float32 or float64, got {dtype}; convert it first ({convert})")


def as_tensor(
    x: Any, name: str = "x", dtype: torch.dtype | None = None, fn: str | None = None
) -> tuple[torch.Tensor, bool]:
    """Points (or values) as a float32/float64 torch tensor; also say whether they came in as numpy.

    Tensors and numpy arrays keep their dtype (float32 stays float32) unless ``dtype`` is given;
    a numpy array's memory is shared when it can be.  Lists and tuples of numbers become float64
    (Python numbers carry no precision of their own).  Complex, integer, boolean and
    half-precision arrays raise TypeError (:func:`check_dtype`); ``fn`` names the caller in messages.

    >>> import numpy as np
    >>> t, was_numpy = as_tensor(np.zeros((2, 3), np.float32))
    >>> t.dtype, was_numpy
    (torch.float32, True)
    >>> as_tensor([[0, 0, 1]])[0].dtype
    torch.float64
    """
    if isinstance(x, torch.Tensor):
        check_dtype(x, name, fn)
        return (x if dtype is None else x.to(dtype)), False
    if isinstance(x, list | tuple):
        try:
            arr = np.asarray(x)
        except (TypeError, ValueError) as err:
            raise TypeError(f"{_label(fn, name)} must be a numeric array, got {type(x).__name__}: {err}") from None
        if arr.dtype.kind in "biuf":
            arr = arr.astype(np.float64)
        elif arr.dtype.kind != "c":
            raise TypeError(f"{_label(fn, name)} must be a numeric array, got {type(x).__name__} of {arr.dtype}")
    elif isinstance(x, np.ndarray):
        arr = x
    else:
        raise TypeError(f"{_label(fn, name)} must be a torch tensor or a numpy array, got {type(x).__name__}")
    check_dtype(arr, name, fn)
    t = _from_numpy(arr)
    return (t if dtype is None else t.to(dtype)), True


def check_points(
    x: torch.Tensor, dim: int | Sequence[int] = 3, name: str = "x", fn: str | None = None, empty: bool = False
) -> None:
    """Raise ValueError unless ``x`` has shape (..., dim) and, unless ``empty``, at least one point.

    Pointwise evaluation allows no points (``empty=True``: no values back); entries that need
    a point to work on (derivatives, fitting, sampling) do not.

    >>> import torch
    >>> check_points(torch.zeros(0, 3), 3, "x", "grad")
    Traceback (most recent call last):
    ...
    ValueError: grad: x is empty (shape (0, 3)); give at least one point
    """
    dims = (dim,) if isinstance(dim, int) else tuple(dim)
    if x.ndim < 1 or x.shape[-1] not in dims:
        want = " or ".join(f"(N, {d})" for d in dims)
        raise ValueError(f"{_label(fn, name)} must have shape {want}, got {tuple(x.shape)}")
    if x.numel() == 0 and not empty:
        raise ValueError(f"{_label(fn, name)} is empty (shape {tuple(x.shape)}); give at least one point")


def check_finite(x: torch.Tensor | np.ndarray, name: str = "x", fn: str | None = None) -> None:
    """Raise ValueError naming the first non-finite entry of ``x`` (one pass, one device sync).

    Skipped inside an entry that has already checked its inputs (:func:`validated_inputs`) and
    while :func:`tracing`.

    >>> import torch
    >>> check_finite(torch.tensor([[0.0, float("nan")]]), "x", "sphere")
    Traceback (most recent call last):
    ...
    ValueError: sphere: x contains a non-finite value (nan) at index (0, 1)
    """
    if isinstance(x, np.ndarray):
        if skip_checks() or bool(np.isfinite(x).all()):
            return
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(x))[0])
        raise ValueError(f"{_label(fn, name)} contains a non-finite value ({x[idx]}) at index {idx}")
    if skip_checks(x) or x.numel() == 0 or not x.is_floating_point():
        return
    # min and max propagate NaN, and are finite exactly when every entry is: one reduction, no
    # temporaries (torch.isfinite(x).all() is ~8x slower on the CPU: 30 ms for 1e6 points)
    values = x.detach()
    if values.ndim == 2 and not values.is_contiguous() and values.t().is_contiguous():
        values = values.t()  # the same entries in memory order: a transposed reduction is ~10x slower
    if all(math.isfinite(v) for v in torch.stack(torch.aminmax(values)).tolist()):
        return
    bad = ~torch.isfinite(x.detach())
    idx = tuple(int(i) for i in torch.nonzero(bad)[0])
    raise ValueError(f"{_label(fn, name)} contains a non-finite value ({x[idx].item()}) at index {idx}")


def vec(v: Any, like: torch.Tensor, n: int = 3, name: str = "center") -> torch.Tensor:
    """A length-``n`` vector (tuple, list, array or tensor) as a tensor on ``like``'s device/dtype.

    Tensors with ``requires_grad`` keep their graph, so a center can be a shape parameter.
    A batched vector of shape (B, n) is allowed for direct calls; it broadcasts against points
    as (B, 1, n) when the points are (N, n).  The kernel never passes one: a Model's parameter
    sets run through ``torch.func.vmap`` (:mod:`pyfrep_core.evaluate`), so its function sees 0-d
    parameters.
    """
    # like is the point set: a wrong point shape gets a clear error here, before broadcasting
    if like.ndim == 0 or not n <= like.shape[-1] <= 3:
        raise ValueError(f"points x must have shape (N, {n}), got {tuple(like.shape)}")
    if isinstance(v, torch.Tensor):
        t = v.to(device=like.device, dtype=like.dtype)
    elif isinstance(v, list | tuple) and any(isinstance(c, torch.Tensor) for c in v):
        # batched (B, 1) components beside plain numbers (a direct call; a Model's sets go through vmap)
        comps = [torch.as_tensor(c, dtype=like.dtype, device=like.device) for c in v]
        t = torch.stack(torch.broadcast_tensors(*comps), dim=-1)
    else:
        t = torch.as_tensor(np.asarray(v, dtype=np.float64), dtype=like.dtype, device=like.device)
    if t.ndim == 0 or t.shape[-1] != n:
        raise ValueError(f"{name} must have {n} components, got shape {tuple(t.shape)}")
    if t.ndim == 2 and like.ndim >= 2:
        t = t.reshape(t.shape[0], *([1] * (like.ndim - 1)), n)
    return t


def safe_sqrt(s: torch.Tensor) -> torch.Tensor:
    """sqrt with finite derivatives at 0, up to the third order in the arguments of ``s``.

    Adds ``sqrt(tiny)`` (``tiny`` the dtype's smallest normal number) under the root, so at
    s = 0 the value is ``rho0 = tiny^(1/4)``: about 3e-10 in float32, 1e-77 in float64 (far below
    a unit of rounding of any O(1) value).  For ``rho = safe_sqrt(f1^2 + f2^2)`` the k-th
    derivatives at f1 = f2 = 0 are of order ``rho0^(1 - k)``; with this ``rho0`` autograd's
    intermediate products up to the third order (``rho0^-3``: 3e28 in float32, 5e230 in float64)
    stay finite, so the exact zeros they are multiplied by give 0, not ``0 * inf = NaN``
    (``tiny`` itself under the root overflows already at the third order).  Hence:

    - R-functions at f1 = f2 = 0 give the sub-gradient grad f1 + grad f2 instead of NaN;
    - their second derivatives there are finite but huge (~1/rho0: 3e9 in float32, 8e76 in
      float64), the mark of a crease (:mod:`pyfrep_core.curvature` reports no curvature there);
    - third derivatives are finite, so ``omega_2`` (:mod:`pyfrep_core.normalization`) is
      finite on creases (0 where the crease lies on f = 0).

    Examples
    --------
    >>> import torch
    >>> x = torch.zeros(1, 2, dtype=torch.float64, requires_grad=True)
    >>> (g,) = torch.autograd.grad(safe_sqrt((x * x).sum(-1)).sum(), x)
    >>> g
    tensor([[0., 0.]], dtype=torch.float64)
    >>> bool(safe_sqrt(torch.zeros(1, dtype=torch.float64)) < 1e-76)
    True
    """
    return torch.sqrt(s + torch.finfo(s.dtype).tiny ** 0.5)


def tracing(*values: Any) -> bool:
    """True where values cannot be inspected: under torch.compile or inside a torch.func transform.

    Checks that read a tensor's values (``bool(t > 0)``) are skipped there: they would break the
    graph (compile) or raise on a batched tensor (vmap).  The kernel validates its inputs before it
    enters such a transform, so nothing unchecked reaches a model that way.
    """
    if torch.compiler.is_compiling() or torch._C._are_functorch_transforms_active():
        return True
    if get_proxy_mode() is not None:  # make_fx tracing (a compiled derivative kernel): values are symbolic
        return True
    return any(isinstance(v, torch.Tensor) and torch._C._functorch.is_functorch_wrapped_tensor(v) for v in values)


def param_array(value: Any, name: str, fn: str) -> np.ndarray | None:
    """A geometric parameter's values as a float64 numpy array, or None while :func:`tracing`.

    ``value`` is a number, a sequence of numbers (possibly 0-d tensors) or a tensor (a
    parameter, possibly requiring grad: read without its graph, one device sync).  Checks
    that relate two parameters (``x1 != x2``) read them through this.

    >>> param_array((1, 2.5), "e", "superQuadric")
    array([1. , 2.5])
    """
    if torch.compiler.is_compiling():
        return None  # numbers too: numpy on them would be traced into the graph (a graph break)
    if isinstance(value, torch.Tensor):
        if tracing(value):
            return None
        return value.detach().cpu().double().numpy()
    if isinstance(value, list | tuple) and tracing(*value):
        return None
    if isinstance(value, list | tuple) and any(isinstance(v, torch.Tensor) for v in value):
        try:  # batched (B, 1) components beside numbers (a direct call), broadcast as vec() does
            comps = [torch.as_tensor(v).detach().cpu().double() for v in value]
            return torch.stack(torch.broadcast_tensors(*comps), dim=-1).numpy()
        except (TypeError, ValueError, RuntimeError):
            raise TypeError(f"{fn}: {name} must be numbers or tensors that broadcast, got {value!r}") from None
    try:
        return np.asarray(
            [v.detach().cpu().double() if isinstance(v, torch.Tensor) else v for v in value]
            if isinstance(value, list | tuple)
            else value,
            dtype=np.float64,
        )
    except (TypeError, ValueError):
        raise TypeError(f"{fn}: {name} must be a number, got {value!r}") from None


def shown(value: Any) -> Any:
    """A parameter as plain numbers for an error message (a tensor becomes a list)."""
    return value.detach().cpu().tolist() if isinstance(value, torch.Tensor) else value


def check_param(
    value: Any,
    name: str,
    fn: str,
    *,
    positive: bool = False,
    nonzero: bool = False,
    nonnegative: bool = False,
) -> None:
    """Raise ValueError naming ``fn``'s argument ``name`` when a geometric parameter is degenerate.

    ``value`` is a number, a sequence of numbers or a tensor (a parameter, possibly requiring grad);
    it must be finite, and positive / nonzero / nonnegative (every entry) when asked.  ``nonzero``
    is for a number or a direction: no row along the last axis may be all zero (a (3,) axis must
    not be the zero vector; a (B, 1) batch of scale factors must have no zero).  Tensors are
    inspected only outside :func:`tracing` (one device sync).

    >>> check_param(0.5, "r", "sphere", positive=True)
    >>> check_param(0.0, "r", "sphere", positive=True)
    Traceback (most recent call last):
    ...
    ValueError: sphere: r must be positive, got 0.0
    >>> check_param((0.0, 0.0, 0.0), "axis", "rotate", nonzero=True)
    Traceback (most recent call last):
    ...
    ValueError: rotate: axis must not be zero, got (0.0, 0.0, 0.0)
    """
    arr = param_array(value, name, fn)
    if arr is None:
        return
    if not np.isfinite(arr).all():
        raise ValueError(f"{fn}: {name} must be finite, got {shown(value)!r}")
    if positive and not (arr > 0).all():
        raise ValueError(f"{fn}: {name} must be positive, got {shown(value)!r}")
    if nonnegative and not (arr >= 0).all():
        raise ValueError(f"{fn}: {name} must be nonnegative, got {shown(value)!r}")
    if nonzero and not (arr != 0).reshape(-1, arr.shape[-1] if arr.ndim else 1).any(-1).all():
        raise ValueError(f"{fn}: {name} must not be zero, got {shown(value)!r}")


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (``MemAvailable``), or None if unknown.

    The kernel's one memory figure: grids (:func:`pyfrep_core.polygonize`), :func:`check_memory`
    and the chunks of a model's calls (:mod:`pyfrep_core.evaluate`) are sized against it.

    >>> available_memory() is None or available_memory() > 0
    True
    """
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


class MemoryBudgetError(ValueError, MemoryError):
    """A call that would need more memory than the machine has (a ValueError for bad input, and a MemoryError)."""


def check_memory(need: float, fn: str, what: str, advice: str) -> None:
    """Raise :class:`MemoryBudgetError` before allocating when ``need`` bytes exceed the available memory.

    The budget is :func:`available_memory` (``MemAvailable``), the one
    :func:`pyfrep_core.polygonize` checks its grids against; unknown memory passes.

    >>> check_memory(1024, "spinodoid", "numwaves=10", "use fewer waves")
    >>> try:
    ...     check_memory(1e30, "spinodoid", "numwaves=1e28", "use fewer waves")
    ... except MemoryBudgetError as err:
    ...     print(str(err).split(",")[0])
    spinodoid: numwaves=1e28 needs about 9.31e+20 GiB
    """
    have = available_memory()
    if have is not None and need > have:
        raise MemoryBudgetError(
            f"{fn}: {what} needs about {need / 2**30:.3g} GiB, but only {have / 2**30:.3g} GiB "
            f"of memory is available; {advice}"
        )


def check_option(
    value: Any,
    name: str,
    fn: str,
    kind: str = "float",
    *,
    positive: bool = False,
    minimum: float | None = None,
    maximum: float | None = None,
    none: bool = False,
    choices: Sequence[Any] | None = None,
) -> Any:
    """Validate a setting ``name`` of ``fn`` (a step count, a rate, a flag) and return it as a plain value.

    ``kind`` is ``"int"`` (an integer; an integral float such as ``1e4`` is accepted and returned as
    int), ``"float"`` (a finite real number, returned as float), ``"bool"`` (True or False) or
    ``"choice"`` (one of ``choices``).  Numbers must also be positive, and within
    [``minimum``, ``maximum``], when asked; ``none=True`` lets None through.  A value of the wrong
    type raises TypeError, a bad value ValueError; both messages name ``fn``, ``name`` and the value.
    Unlike :func:`check_param` (geometric parameters, possibly tensors under a transform), options are
    plain Python values read once, before any work.

    >>> check_option(1e3, "steps", "redistance", "int", positive=True)
    1000
    >>> check_option(float("inf"), "lr", "fit", positive=True)
    Traceback (most recent call last):
    ...
    ValueError: fit: lr must be a finite number, got inf
    >>> check_option(2.5, "fourier_features", "redistance", "int", minimum=0)
    Traceback (most recent call last):
    ...
    ValueError: redistance: fourier_features must be an integer, got 2.5
    """
    if value is None and none:
        return None
    if kind == "choice":
        if choices is None or not any(value is c or (type(value) is type(c) and value == c) for c in choices):
            raise ValueError(f"{fn}: {name} must be one of {', '.join(map(repr, choices or ()))}, got {value!r}")
        return value
    if kind == "bool":
        if not isinstance(value, bool | np.bool_):
            raise TypeError(f"{fn}: {name} must be True or False, got {value!r}")
        return bool(value)
    if kind not in ("int", "float"):
        raise ValueError(f"check_option: kind must be 'int', 'float', 'bool' or 'choice', got {kind!r}")
    if isinstance(value, torch.Tensor) and value.numel() == 1 and not value.requires_grad:
        value = value.item()
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.integer | np.floating):
        what = "an integer" if kind == "int" else "a number"
        raise TypeError(f"{fn}: {name} must be {what}{' or None' if none else ''}, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{fn}: {name} must be a finite number, got {value!r}")
    if kind == "int":
        if int(value) != value:
            raise ValueError(f"{fn}: {name} must be an integer, got {value!r}")
        out: int | float = int(value)
    else:
        out = float(value)
    if positive and not out > 0:
        raise ValueError(f"{fn}: {name} must be positive, got {value!r}")
    if minimum is not None and out < minimum:
        raise ValueError(f"{fn}: {name} must be >= {minimum}, got {value!r}")
    if maximum is not None and out > maximum:
        raise ValueError(f"{fn}: {name} must be <= {maximum}, got {value!r}")
    return out
