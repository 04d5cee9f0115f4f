"""Array plumbing shared by the kernel: numpy in -> numpy out, torch in -> torch out.

Primitives are written once, on torch tensors.  The :func:`frep` decorator lets a
numpy user call them too: numpy arrays are converted (float64 stays float64) and
the result is converted back when no torch tensor came in.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

Array = torch.Tensor | np.ndarray
Scalar = float | torch.Tensor


def _to_torch(value: Any, device: torch.device | None = None) -> Any:
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "iub":
            value = value.astype(np.float64)
        return torch.from_numpy(np.ascontiguousarray(value)).to(device or "cpu")
    return value


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


def frep(fn: Callable) -> Callable:
    """Make a torch function accept numpy arrays and return numpy for numpy input.

    Torch tensors pass through untouched (no copy, graph kept).  Numpy arrays are converted;
    the result goes back to numpy only when no tensor came in (a numpy point set with a
    tensor parameter that requires grad gives a tensor, so the gradient is not lost).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        device = None
        has_numpy = False
        for a in (*args, *kwargs.values()):
            if isinstance(a, torch.Tensor):
                device = device or a.device
            elif isinstance(a, np.ndarray):
                has_numpy = True
        if not has_numpy:
            return fn(*args, **kwargs)
        for name, a in (*enumerate(args), *kwargs.items()):
            if isinstance(a, np.ndarray) and a.dtype.kind == "f" and not np.isfinite(a).all():
                label = f"argument {name}" if isinstance(name, int) else name
                raise ValueError(
                    f"{fn.__name__}: {label} contains NaN or inf (first at {np.argwhere(~np.isfinite(a))[0]})"
                )
        # numpy beside a tensor (numpy points, a tensor parameter): compute in torch, return torch
        out = fn(*[_to_torch(a, device) for a in args], **{k: _to_torch(v, device) for k, v in kwargs.items()})
        return out if device is not None else _back(out)

    return wrapper


def as_tensor(x: Any, name: str = "x", dtype: torch.dtype | None = None) -> tuple[torch.Tensor, bool]:
    """Convert ``x`` to a floating torch tensor; also say whether it came in as numpy.

    Integer input becomes float64 (numpy) or the default dtype (torch).
    """
    if isinstance(x, torch.Tensor):
        t = x
        if not t.is_floating_point():
            t = t.to(dtype or torch.get_default_dtype())
        elif dtype is not None:
            t = t.to(dtype)
        return t, False
    if isinstance(x, np.ndarray | list | tuple):
        try:
            arr = np.asarray(x, dtype=np.float64 if dtype is None else None)
        except (TypeError, ValueError) as err:
            raise TypeError(f"{name} must be a numeric array, got {type(x).__name__}: {err}") from None
        t = torch.from_numpy(np.ascontiguousarray(arr))
        if dtype is not None:
            t = t.to(dtype)
        return t, True
    raise TypeError(f"{name} must be a torch tensor or a numpy array, got {type(x).__name__}")


def check_points(x: torch.Tensor, dim: int | Sequence[int] = 3, name: str = "x") -> None:
    """Raise ValueError unless ``x`` has shape (..., dim) with at least one point."""
    dims = (dim,) if isinstance(dim, int) else tuple(dim)
    if x.ndim < 1 or x.shape[-1] not in dims:
        want = " or ".join(f"(N, {d})" for d in dims)
        raise ValueError(f"{name} must have shape {want}, got {tuple(x.shape)}")
    if x.numel() == 0:
        raise ValueError(f"{name} is empty (shape {tuple(x.shape)})")


def check_finite(x: torch.Tensor, name: str = "x") -> None:
    """Raise ValueError naming the first non-finite entry of ``x`` (one device sync)."""
    bad = ~torch.isfinite(x)
    if bool(bad.any()):
        idx = tuple(int(i) for i in torch.nonzero(bad)[0])
        raise ValueError(f"{name} contains a non-finite value ({x[idx].item()}) at index {idx}")


def vec(v: Any, like: torch.Tensor, n: int = 3, name: str = "center") -> torch.Tensor:
    """A length-``n`` vector (tuple, list, array or tensor) as a tensor on ``like``'s device/dtype.

    Tensors with ``requires_grad`` keep their graph, so a center can be a shape parameter.
    A batched vector of shape (B, n) is allowed; it broadcasts against points as (B, 1, n)
    when the points are (N, n).
    """
    # like is the point set: a wrong point shape gets a clear error here, before broadcasting
    if like.ndim == 0 or not n <= like.shape[-1] <= 3:
        raise ValueError(f"points x must have shape (N, {n}), got {tuple(like.shape)}")
    if isinstance(v, torch.Tensor):
        t = v.to(device=like.device, dtype=like.dtype)
    elif isinstance(v, list | tuple) and any(isinstance(c, torch.Tensor) for c in v):
        # batched components ((B, 1) from a Model) beside plain numbers: broadcast, then stack
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
    if torch.compiler.is_compiling():
        return True
    return any(
        isinstance(v, torch.Tensor) and torch._C._functorch.is_functorch_wrapped_tensor(v) for v in values
    )


def param_array(value: Any, name: str, fn: str) -> np.ndarray | None:
    """A geometric parameter's values as a float64 numpy array, or None while :func:`tracing`.

    ``value`` is a number, a sequence of numbers (possibly 0-d tensors) or a tensor (a
    parameter, possibly requiring grad: read without its graph, one device sync).  Checks
    that relate two parameters (``x1 != x2``) read them through this.

    >>> param_array((1, 2.5), "e", "superQuadric")
    array([1. , 2.5])
    """
    if isinstance(value, torch.Tensor):
        if tracing(value):
            return None
        return value.detach().cpu().double().numpy()
    if isinstance(value, list | tuple) and tracing(*value):
        return None
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


class MemoryBudgetError(ValueError, MemoryError):
    """A call that would need more memory than the machine has (a ValueError for bad input, and a MemoryError)."""


def check_memory(need: float, fn: str, what: str, advice: str) -> None:
    """Raise :class:`MemoryBudgetError` before allocating when ``need`` bytes exceed the available memory.

    The budget is :func:`pyfrep_core.mesh.available_memory` (``MemAvailable``), the one
    :func:`pyfrep_core.polygonize` checks its grids against; unknown memory passes.

    >>> check_memory(1024, "spinodoid", "numwaves=10", "use fewer waves")
    >>> try:
    ...     check_memory(1e30, "spinodoid", "numwaves=1e28", "use fewer waves")
    ... except MemoryBudgetError as err:
    ...     print(str(err).split(",")[0])
    spinodoid: numwaves=1e28 needs about 9.31e+20 GiB
    """
    from .mesh import available_memory  # the kernel's one memory budget (mesh imports this module's users)

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
