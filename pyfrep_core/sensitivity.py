"""Shape sensitivity: how fast the surface f = 0 moves when one parameter changes (paper section 4).

For a surface point x(p) with f(x(p), p) = 0, differentiating gives
grad f . dx/dp + df/dp = 0, so the speed of the surface along the unit vector
grad f / |grad f| is

    v = -(df/dp) / |grad f|.

With f >= 0 inside, grad f points into the solid: v > 0 where the surface moves into the
solid (material is removed), v < 0 where the solid grows.  A drilled cylinder of radius r
(f = y^2 + z^2 - r^2 near its wall) has v = -(-2r) / (2r) = 1 on its wall: the hole widens
at unit speed.

df/dp is taken per point in one reverse pass with one copy of the parameter per point (see
``_df_dp``), grad f in another (:func:`pyfrep_core.diff.value_and_grad`).
"""

from __future__ import annotations

import threading
from typing import Any

import torch
import torch.autograd.forward_ad as fwad

from ._array import as_tensor, check_finite, check_option, check_points, named_entry
from .compiled import first_order
from .diff import CHUNK, value_and_grad
from .model import Model

__all__ = ["normal_velocity", "param_derivative"]


@named_entry
def param_derivative(model: Model, x: Any, name: str, params: dict[str, Any] | None = None, chunk: int = CHUNK) -> Any:
    """df/dp at each point: the derivative of ``model(x, **params)`` w.r.t. parameter ``name``.

    Parameters
    ----------
    model : a :class:`~pyfrep_core.model.Model`.
    x : (N, dim) points, numpy or torch.
    name : the parameter to differentiate by (a declared name).
    params : values of the parameters (defaults filled in).
    chunk : points per reverse pass (a positive integer): bounds the memory of the graph.

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
    t, was_numpy = _points(model, x)
    values = _params(model, name, params)
    chunk = check_option(chunk, "chunk", "param_derivative", "int", positive=True)
    parts = []
    for i in range(0, t.shape[0], chunk):
        parts.append(_df_dp(model, t[i : i + chunk], name, values))
    out = torch.cat(parts) if parts else t.new_zeros(0)
    return out.cpu().numpy() if was_numpy else out


@named_entry
def normal_velocity(model: Model, x: Any, name: str, params: dict[str, Any] | None = None, chunk: int = CHUNK) -> Any:
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
    chunk : points per pass (a positive integer).

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
    t, was_numpy = _points(model, x)
    values = _params(model, name, params)
    chunk = check_option(chunk, "chunk", "normal_velocity", "int", positive=True)
    out = t.new_zeros(t.shape[0])
    for i in range(0, t.shape[0], chunk):
        xi = t[i : i + chunk]
        df_dp = _df_dp(model, xi, name, values)
        _, g = value_and_grad(lambda p: model(p, **values), xi)
        norm = g.norm(dim=-1)
        out[i : i + chunk] = torch.where(norm > 0, -df_dp / norm.clamp_min(torch.finfo(t.dtype).tiny), 0.0)
    return out.cpu().numpy() if was_numpy else out


def _points(model: Model, x: Any) -> tuple[torch.Tensor, bool]:
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


def _df_dp(model: Model, x: torch.Tensor, name: str, values: dict[str, Any]) -> torch.Tensor:
    """Per-point df/dp.

    Reverse mode with one copy of the parameter per point: f_i depends on p_i only, so the
    gradient of sum_i f(x_i; p_i) w.r.t. (p_1..p_N) is df/dp at every point, in one backward
    pass.  This needs the model's elementwise broadcasting (the contract: a parameter tensor
    broadcasts against the points); a model that does not broadcast falls back to forward mode.
    Reverse mode is preferred because forward-mode levels are process-global in torch: two
    threads in forward mode at once (a slider's remesh beside a fit's polish) would collide.
    """
    n = x.shape[0]
    p = torch.full((n,), float(values[name]), dtype=x.dtype, device=x.device, requires_grad=True)
    try:
        with torch.enable_grad(), first_order():  # one backward pass: a compiled model's kernel may take it
            f = model.fn(x, **{**values, name: p})
        if isinstance(f, torch.Tensor) and f.shape == (n,) and f.requires_grad:
            (g,) = torch.autograd.grad(f.sum(), p, allow_unused=True)
            return torch.zeros_like(p).detach() if g is None else g.detach()
        if isinstance(f, torch.Tensor) and f.shape == (n,):
            return torch.zeros(n, dtype=x.dtype, device=x.device)  # f does not depend on p
    except (RuntimeError, ValueError, TypeError):
        pass
    return _df_dp_forward(model, x, name, values)


_FORWARD_AD = threading.Lock()


def _df_dp_forward(model: Model, x: torch.Tensor, name: str, values: dict[str, Any]) -> torch.Tensor:
    """Per-point df/dp by forward-mode AD: one pass, tangent 1 on the parameter."""
    p = torch.as_tensor(values[name], dtype=x.dtype, device=x.device)
    with _FORWARD_AD, torch.no_grad(), fwad.dual_level():
        dual = fwad.make_dual(p, torch.ones_like(p))
        f = model(x, **{**values, name: dual})
        tangent = fwad.unpack_dual(f).tangent
    if tangent is None:  # f does not depend on this parameter
        return torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
    return tangent.reshape(x.shape[0])
