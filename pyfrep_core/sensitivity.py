"""Shape sensitivity: how fast the surface f = 0 moves when one parameter changes (paper section 4).

For a surface point x(p) with f(x(p), p) = 0, differentiating gives
grad f . dx/dp + df/dp = 0, so the speed of the surface along the unit vector
grad f / |grad f| is

    v = -(df/dp) / |grad f|.

With f >= 0 inside, grad f points into the solid: v > 0 where the surface moves into the
solid (material is removed), v < 0 where the solid grows.  A drilled cylinder of radius r
(f = y^2 + z^2 - r^2 near its wall) has v = -(-2r) / (2r) = 1 on its wall: the hole widens
at unit speed.

df/dp and grad f come from the kernel's one implementation of per-point parameter derivatives
(per-sample reverse mode, :func:`pyfrep_core.diff.param_grad`), from one forward and one reverse
pass; it is chunked, thread-safe and works for any model that maps (N, d) to (N,).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ._array import as_tensor, check_finite, check_option, check_points, named_entry
from .diff import _param_jacobian
from .model import Model

__all__ = ["normal_velocity", "param_derivative", "velocity"]


@named_entry
def param_derivative(
    model: Model, x: Any, name: str, params: dict[str, Any] | None = None, chunk: int | None = None
) -> Any:
    """df/dp at each point: the derivative of ``model(x, **params)`` w.r.t. parameter ``name``.

    Parameters
    ----------
    model : a :class:`~pyfrep_core.model.Model`.
    x : (N, dim) points, numpy or torch.
    name : the parameter to differentiate by (a declared name).
    params : values of the parameters (defaults filled in).
    chunk : points per reverse pass (a positive integer); default: as :func:`pyfrep_core.diff.param_grad`.

    Returns
    -------
    (N,) array or tensor (same kind and dtype as ``x``).

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import model, Param, sphere
    >>> @model(r=Param(1.0, 0.5, 2.0))
    ... def ball(x, r):
    ...     return sphere(x, r=r)  # r^2 - |x|^2
    >>> param_derivative(ball, np.array([[0.3, 0.0, 0.0]]), "r", {"r": 1.5})
    array([3.])
    """
    t, was_numpy = _model_points(model, x)
    values = _params(model, name, params)
    if chunk is not None:
        chunk = check_option(chunk, "chunk", "param_derivative", "int", positive=True)
    out = _param_jacobian(model.fn, t, values, [name], chunk=chunk, label=model.__name__)[:, 0]
    return out.cpu().numpy() if was_numpy else out


@named_entry
def normal_velocity(
    model: Model, x: Any, name: str, params: dict[str, Any] | None = None, chunk: int | None = None
) -> Any:
    """Speed ``v = -(df/dp) / |grad f|`` of the surface through ``x`` when parameter ``name`` grows.

    Positive where the surface moves into the solid (along grad f), negative where it
    moves outward; 0 where the parameter does not act.  Exact on f = 0 (use surface points,
    e.g. mesh vertices); points where grad f vanishes get 0.

    Parameters
    ----------
    model : a :class:`~pyfrep_core.model.Model`.
    x : (N, dim) points, numpy or torch, float32 or float64.
    name : parameter name.
    params : parameter values (defaults filled in).
    chunk : points per pass (a positive integer); default: as :func:`pyfrep_core.diff.param_grad`.

    Returns
    -------
    (N,) array or tensor like ``x``: length units per unit of the parameter.

    Examples
    --------
    The sphere f = r^2 - |x|^2 grows outward at unit speed when r grows:

    >>> import numpy as np
    >>> from pyfrep_core import model, Param, sphere
    >>> @model(r=Param(1.0, 0.5, 2.0))
    ... def ball(x, r):
    ...     return sphere(x, r=r)
    >>> normal_velocity(ball, np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]), "r")
    array([-1., -1.])
    """
    t, was_numpy = _model_points(model, x)
    values = _params(model, name, params)
    if chunk is not None:
        chunk = check_option(chunk, "chunk", "normal_velocity", "int", positive=True)
    # df/dp and grad f from one forward and one reverse pass
    df_dp, g = _param_jacobian(model.fn, t, values, [name], chunk=chunk, label=model.__name__, spatial=True)
    out = velocity(df_dp[:, 0], g.norm(dim=-1))
    return out.cpu().numpy() if was_numpy else out


def velocity(df_dp: torch.Tensor, grad_norm: torch.Tensor) -> torch.Tensor:
    """``-(df/dp) / |grad f|`` where ``|grad f| > 0``, 0 elsewhere (torch or numpy, like the inputs).

    >>> import numpy as np
    >>> velocity(np.array([2.0, 1.0]), np.array([4.0, 0.0]))
    array([-0.5,  0. ])
    """
    if isinstance(df_dp, torch.Tensor):
        return torch.where(grad_norm > 0, -df_dp / grad_norm.clamp_min(torch.finfo(df_dp.dtype).tiny), 0.0)
    return np.where(grad_norm > 0, -df_dp / np.where(grad_norm > 0, grad_norm, 1.0), 0.0)


def _model_points(model: Model, x: Any) -> tuple[torch.Tensor, bool]:
    if not isinstance(model, Model):
        raise TypeError(f"model must be a pyfrep_core Model (declared with @model), got {type(model).__name__}")
    t, was_numpy = as_tensor(x, "x")
    check_points(t, dim=model.dim, name="x")
    if t.ndim != 2:
        raise ValueError(f"x must have shape (N, {model.dim}), got {tuple(t.shape)}")
    check_finite(t, "x")
    return t.detach(), was_numpy


def _params(model: Model, name: str, params: dict[str, Any] | None) -> dict[str, Any]:
    if name not in model.params:
        raise ValueError(f"{model.__name__} has no parameter {name!r}; declared: {', '.join(model.names) or 'none'}")
    values = model.check(**(params or {}))
    return {k: float(v) if not isinstance(v, torch.Tensor) else v for k, v in values.items()}
