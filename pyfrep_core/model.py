"""Named, bounded shape parameters: ``@model`` and ``Param`` (paper section 4, parametric modeling).

A model declares its parameters once; the declaration drives the workbench sliders,
the fitting bounds and sampling.  Calling a model evaluates its defining function.

The calling contract: the kernel calls the defining function ``fn(x, **params)`` only with
points ``x`` of shape (N, d) (a 2-D tensor: never a grid block, never a single 1-D point) and
with every parameter a 0-d tensor of the points' dtype (a number given is converted),
and expects values of shape (N,).  Any torch code
that does so works: ``p[:, i]`` indexing as in the paper's code, tuples built from parameters
(``sphere(x, center=(cx, 0.0, 0.0), r=r)``), ``torch.stack``, ``torch.where``, Python arithmetic
on parameters.  Points of another shape (..., d) are flattened for it and the values reshaped
back; parameters given as (B,) tensors (B parameter sets) are mapped with ``torch.func.vmap``,
so ``fn`` still sees 0-d parameters, and give (B, ...) values; a wrong output shape is a
ValueError naming the model (see :mod:`pyfrep_core.evaluate`, which does all of it).

>>> import torch
>>> from pyfrep_core import model, Param, sphere
>>> @model(bounds=((-1, -1, -1), (1, 1, 1)), r=Param(0.5, 0.1, 0.9, label="radius"))
... def ball(x, r):
...     return sphere(x, r=r)
>>> x = torch.zeros(2, 3)
>>> ball(x).shape, ball(x, r=torch.tensor([0.2, 0.3, 0.4])).shape
(torch.Size([2]), torch.Size([3, 2]))
"""

from __future__ import annotations

import functools
import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from ._array import (
    as_tensor,
    check_finite,
    check_param,
    check_points,
    named_error,
    skip_checks,
    tracing,
    validated_inputs,
)
from .evaluate import call_sets, evaluate

Bounds = tuple[tuple[float, ...], tuple[float, ...]]


@dataclass(frozen=True)
class Param:
    """One scalar shape parameter: default value, closed range [lower, upper] and a label.

    default, lower and upper are real numbers of any type (``int``, ``float``, numpy scalars,
    0-d numpy arrays and tensors); other types than ``int`` and ``float`` are stored as ``float``.
    ``bool`` is refused (TypeError), as are NaN and inf (ValueError).

    >>> import numpy as np
    >>> Param(np.float32(0.5), 0, 1).default
    0.5
    >>> Param(True, 0, 1)
    Traceback (most recent call last):
    ...
    TypeError: Param default must be a real number, got True
    """

    default: float
    lower: float
    upper: float
    label: str = ""

    def __post_init__(self) -> None:
        for name in ("default", "lower", "upper"):
            value = getattr(self, name)
            number = value
            if isinstance(value, np.ndarray | torch.Tensor) and value.ndim == 0:
                number = value.item()
            if isinstance(number, bool | np.bool_) or not isinstance(number, numbers.Real):
                raise TypeError(f"Param {name} must be a real number, got {value!r}")
            if type(number) not in (int, float):
                number = float(number)
            if not math.isfinite(number):
                raise ValueError(f"Param {name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, number)
        if self.lower >= self.upper:
            raise ValueError(f"Param lower ({self.lower}) must be below upper ({self.upper})")
        if not self.lower <= self.default <= self.upper:
            raise ValueError(f"Param default {self.default} is outside [{self.lower}, {self.upper}]")


def check_bounds(bounds: Any, dim: int | None = None, name: str = "bounds") -> Bounds:
    """Validate ``((xmin, ymin, zmin), (xmax, ymax, zmax))``; return it as float tuples."""
    try:
        lo, hi = bounds
        lo = tuple(float(v) for v in lo)
        hi = tuple(float(v) for v in hi)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be ((xmin, ...), (xmax, ...)), got {bounds!r}") from None
    if len(lo) != len(hi) or (dim is not None and len(lo) != dim):
        want = dim if dim is not None else len(lo)
        raise ValueError(f"{name} must give {want} lower and {want} upper values, got {bounds!r}")
    for i, (a, b) in enumerate(zip(lo, hi, strict=True)):
        if not (math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"{name} must be finite, got {bounds!r}")
        if not a < b:
            raise ValueError(f"{name} are inverted or empty on axis {i}: lower {a} >= upper {b}")
    return lo, hi


class Model:
    """A defining function ``fn(x, **params)`` with declared parameters and default bounds.

    Attributes
    ----------
    params : dict name -> Param, in declaration order.
    bounds : ((xmin, ...), (xmax, ...)) or None: the box used by meshing, sampling and
        the workbench when none is given.
    dim : number of spatial coordinates (3, or 2 for planar models).
    """

    def __init__(self, fn: Callable, params: Mapping[str, Param], bounds: Any = None, dim: int = 3):
        for name, p in params.items():
            if not isinstance(p, Param):
                raise TypeError(f"parameter {name!r} must be declared with Param(...), got {p!r}")
        self.fn = fn
        self.params: dict[str, Param] = dict(params)
        self.dim = dim
        self.bounds: Bounds | None = None if bounds is None else check_bounds(bounds, dim)
        functools.update_wrapper(self, fn)

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={p.default}" for k, p in self.params.items())
        return f"<model {self.__name__}({ps})>"

    @property
    def names(self) -> list[str]:
        """Parameter names in declaration order."""
        return list(self.params)

    def defaults(self) -> dict[str, float]:
        """Default value of every parameter."""
        return {k: p.default for k, p in self.params.items()}

    def _resolve(self, overrides: Mapping[str, Any]) -> dict[str, Any]:
        unknown = [k for k in overrides if k not in self.params]
        if unknown:
            raise TypeError(
                f"{self.__name__} has no parameter {unknown[0]!r}; declared: {', '.join(self.params) or 'none'}"
            )
        values = self.defaults()
        values.update(overrides)
        return values

    def check(self, **values: Any) -> dict[str, float]:
        """Validate parameter values against the declared ranges.

        Returns the full parameter dict (defaults filled in).  Raises TypeError for an
        undeclared name and ValueError naming the value and range for one out of range
        or not finite.  Tensors are checked element-wise.
        """
        full = self._resolve(values)
        for name, value in full.items():
            p = self.params[name]
            arr = np.asarray(value.detach().cpu() if isinstance(value, torch.Tensor) else value, dtype=float)
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"parameter {name}={value!r} is not finite")
            if np.any(arr < p.lower) or np.any(arr > p.upper):
                raise ValueError(f"parameter {name}={value!r} is outside its range [{p.lower}, {p.upper}]")
        return full

    def __call__(self, x: Any, **overrides: Any) -> Any:
        """Evaluate f at points ``x`` (..., dim); tensors of shape (B,) as parameters give (B, ...).

        The defining function gets the points as (N, dim) and 0-d parameters (the contract in the
        module docstring): (B,) parameters run through ``torch.func.vmap`` (gradients flow to them),
        or set by set, with one RuntimeWarning per model, where vmap cannot run it; large point
        sets run in chunks within the memory budget of :mod:`pyfrep_core.evaluate`.  A result of
        any shape other than (N,) raises ValueError naming the model and both shapes.

        The points are checked here, once (the primitives inside do not check them again):
        float32 or float64 tensors or numpy arrays, or lists (float64), of shape (..., dim), finite;
        complex, integer and boolean arrays raise TypeError, NaN and inf ValueError naming the
        model and the first bad point.  Parameter values (numbers, 0-d tensors, (B,) tensors or
        arrays) must be finite: ValueError naming the parameter.  The result has the points' dtype
        (numpy float32 in, numpy float32 out).  No points, shape (0, dim), give no values, shape (0,).
        Under torch.compile and torch.func transforms, and inside a checked call, nothing is read.

        Examples
        --------
        >>> import numpy as np
        >>> from pyfrep_core import model, Param, sphere
        >>> @model(r=Param(0.5, 0.1, 0.9))
        ... def ball(x, r):
        ...     return sphere(x, r=r)
        >>> ball(np.zeros((2, 3), np.float32)).dtype, ball(np.zeros((0, 3))).shape
        (dtype('float32'), (0,))
        >>> ball(np.zeros((1, 3)), r=float("nan"))
        Traceback (most recent call last):
        ...
        ValueError: ball: r must be finite, got nan
        """
        label = self.__name__
        t, was_numpy = as_tensor(x, "x", fn=label)
        check_points(t, self.dim, "x", fn=label, empty=True)
        values = self._resolve(overrides)
        traced = tracing(t, *values.values())
        check = not traced and not skip_checks()  # points: once, by the outermost checked call
        if check:
            check_finite(t, "x", label)
        if not traced:  # parameters: always (an outer call checked its points, not these values)
            for name, v in values.items():
                check_param(v, name, label)
        scalars, batched = {}, {}
        for name, v in values.items():
            if isinstance(v, np.ndarray):
                v = torch.as_tensor(v, dtype=t.dtype, device=t.device)
            if isinstance(v, torch.Tensor) and v.ndim >= 1:
                if v.ndim != 1:
                    raise ValueError(f"parameter {name} must be a scalar or a (B,) batch, got shape {tuple(v.shape)}")
                sizes = {b.shape[0] for b in batched.values()}
                if sizes and v.shape[0] not in sizes:
                    raise ValueError(f"parameter {name} has a batch of {v.shape[0]}, others have {sizes.pop()}")
                batched[name] = v.to(dtype=t.dtype, device=t.device)
            elif isinstance(v, torch.Tensor):
                scalars[name] = v
            else:  # a number becomes a 0-d tensor, so torch code on parameters (torch.stack) works too
                scalars[name] = torch.tensor(float(v), dtype=t.dtype, device=t.device)
        points = t.reshape(-1, t.shape[-1])  # the model sees (N, d) only: grids and single points flattened
        shape = (next(iter(batched.values())).shape[0],) if batched else ()
        shape += tuple(t.shape[:-1])
        if check:
            with validated_inputs():
                try:
                    out = self._call(points, scalars, batched)
                except ValueError as err:
                    raise named_error(err, label)  # noqa: B904  (the same exception, its message prefixed)
            if isinstance(out, torch.Tensor) and out.is_floating_point() and out.dtype != t.dtype:
                out = out.to(t.dtype)
        else:
            out = self._call(points, scalars, batched)
        out = out.reshape(shape)
        return out.detach().cpu().numpy() if was_numpy else out

    def _call(self, x: torch.Tensor, scalars: dict[str, Any], batched: dict[str, torch.Tensor]) -> torch.Tensor:
        """The defining function at points (N, d): one parameter set, or B sets (values (B, N))."""
        if batched:
            return call_sets(self.fn, x, scalars, batched, self.__name__)
        return evaluate(self.fn, x, scalars, label=self.__name__)


def model(bounds: Any = None, dim: int = 3, **params: Param) -> Callable[[Callable], Model]:
    """Declare a parametric model: ``@model(bounds=..., name=Param(default, lower, upper, label))``.

    Parameters
    ----------
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)), optional
        Default box for meshing, sampling and the workbench.
    dim : int
        Spatial dimension of the points (3, or 2 for planar models such as the ellipse of Fig. 4).
    **params : Param
        The shape parameters, in the order the sliders and fit vectors use.

    Examples
    --------
    >>> from pyfrep_core import model, Param, sphere
    >>> @model(r=Param(0.5, 0.2, 0.8, label="radius"))
    ... def ball(x, r):
    ...     return sphere(x, r=r)
    >>> ball.params["r"].upper
    0.8
    """
    from ._array import check_option

    dim = check_option(dim, "dim", "model", "int", positive=True)

    def wrap(fn: Callable) -> Model:
        return Model(fn, params, bounds=bounds, dim=dim)

    return wrap
