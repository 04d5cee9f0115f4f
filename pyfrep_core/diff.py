"""Spatial and parameter derivatives of defining functions by reverse-mode autodiff (paper section 4).

This module is the only place that calls autograd for spatial derivatives.  Functions take
a callable ``f`` (points (N, d) -> values (N,)) and points ``x``; numpy in gives numpy out,
torch in gives torch out.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import torch

from ._array import as_tensor, check_finite, check_points

CHUNK = 1 << 18  # points per autograd pass when no graph is kept: bounds memory


def _value_and_grad(f: Callable, x: torch.Tensor, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """f(x) and grad f(x) for x (N, d); one backward pass.  Keeps the graph if asked."""
    with torch.enable_grad():
        xr = x if (create_graph and x.requires_grad) else x.detach().requires_grad_(True)
        y = f(xr)
        if y.shape != xr.shape[:-1]:
            raise ValueError(
                f"f must map points {tuple(xr.shape)} to values {tuple(xr.shape[:-1])}, got {tuple(y.shape)}"
            )
        (g,) = torch.autograd.grad(y.sum(), xr, create_graph=create_graph)
    if not create_graph:
        y, g = y.detach(), g.detach()
    return y, g


def value_and_grad(f: Callable, x: Any, create_graph: bool = False, chunk: int = CHUNK) -> tuple[Any, Any]:
    """f(x) and its spatial gradient, evaluated in chunks of ``chunk`` points.

    Parameters
    ----------
    f : callable, (N, d) -> (N,)
    x : (N, d) points, numpy or torch, float32 or float64, any device.
    create_graph : keep the graph (for use inside a loss); then no chunking is done.

    Returns
    -------
    values (N,), gradients (N, d): same kind (numpy/torch) as ``x``.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import sphere
    >>> v, g = value_and_grad(lambda p: sphere(p, r=1.0), np.array([[0.5, 0.0, 0.0]]))
    >>> v, g
    (array([0.75]), array([[-1., -0., -0.]]))
    """
    t, was_numpy = as_tensor(x, "x")
    check_points(t, dim=(1, 2, 3, 4), name="x")
    if create_graph or t.shape[0] <= chunk:
        y, g = _value_and_grad(f, t, create_graph)
    else:
        parts = [_value_and_grad(f, t[i : i + chunk]) for i in range(0, t.shape[0], chunk)]
        y = torch.cat([p[0] for p in parts])
        g = torch.cat([p[1] for p in parts])
    if was_numpy:
        return y.cpu().numpy(), g.cpu().numpy()
    return y, g


def grad(f: Callable, x: Any, create_graph: bool = False, chunk: int = CHUNK) -> Any:
    """Spatial gradient grad f(x), shape (N, d) (paper Fig. 5).

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> grad(lambda p: sphere(p, r=1.0), torch.tensor([[0.0, 1.0, 0.0]]))
    tensor([[-0., -2., -0.]])
    """
    return value_and_grad(f, x, create_graph=create_graph, chunk=chunk)[1]


class Projection(NamedTuple):
    """Result of :func:`project_to_surface` (kind of arrays follows the input)."""

    points: Any  # (N, d) projected points; points that did not converge keep their input position
    converged: Any  # (N,) bool
    gradient: Any  # (N, d) grad f at the returned points
    value: Any  # (N,) f at the returned points


def project_to_surface(
    f: Callable,
    points: Any,
    tol: float | None = None,
    max_iter: int = 20,
    max_step: float | None = None,
    max_distance: float | None = None,
    chunk: int = CHUNK,
    warn: bool = True,
) -> Projection:
    """Move points onto f = 0 by Newton steps ``x <- x - f grad f / |grad f|^2``.

    A point has converged when its first-order distance ``|f| / |grad f|`` is below
    ``tol``.  Points whose gradient vanishes, that do not converge in ``max_iter`` steps
    or that would move farther than ``max_distance`` keep their input position and are
    reported in ``converged`` (and by a warning unless ``warn=False``), never kept silently.

    Parameters
    ----------
    f : callable (N, d) -> (N,)
    points : (N, d) array or tensor.
    tol : distance tolerance in length units; default ``100 * eps * max(1, max|x|)``.
    max_iter : Newton steps at most.
    max_step : longest single step (length units); None for unlimited.
    max_distance : longest total displacement accepted; None for unlimited.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> p = project_to_surface(lambda x: sphere(x, r=1.0), torch.tensor([[0.9, 0.0, 0.0]], dtype=torch.float64))
    >>> p.points, bool(p.converged[0])
    (tensor([[1., 0., 0.]], dtype=torch.float64), True)
    """
    x0, was_numpy = as_tensor(points, "points")
    check_points(x0, dim=(1, 2, 3, 4), name="points")
    if x0.ndim != 2:
        raise ValueError(f"points must have shape (N, d), got {tuple(x0.shape)}")
    check_finite(x0, "points")
    x0 = x0.detach()
    eps = torch.finfo(x0.dtype).eps
    if tol is None:
        tol = 100.0 * eps * max(1.0, float(x0.abs().max()))
    if tol <= 0:
        raise ValueError(f"tol must be positive, got {tol}")
    x = x0.clone()
    n = x.shape[0]
    value = torch.empty(n, dtype=x.dtype, device=x.device)
    gradient = torch.empty_like(x)
    converged = torch.zeros(n, dtype=torch.bool, device=x.device)
    active = torch.arange(n, device=x.device)
    for step in range(max_iter + 1):
        if active.numel() == 0:
            break
        y, g = value_and_grad(f, x[active], chunk=chunk)
        value[active], gradient[active] = y, g
        g2 = (g * g).sum(-1)
        dist = y.abs() / torch.sqrt(g2)
        done = dist < tol
        converged[active[done]] = True
        keep = ~done & (g2 > 0) & torch.isfinite(dist)
        if step == max_iter:
            break
        active, y, g, g2 = active[keep], y[keep], g[keep], g2[keep]
        move = (y / g2).unsqueeze(-1) * g
        if max_step is not None:
            length = move.norm(dim=-1, keepdim=True)
            move = move * torch.clamp(max_step / length.clamp_min(torch.finfo(x.dtype).tiny), max=1.0)
        x[active] -= move
    if max_distance is not None:
        converged &= (x - x0).norm(dim=-1) <= max_distance
    failed = ~converged
    n_failed = int(failed.sum())
    if n_failed:
        x[failed] = x0[failed]
        y, g = value_and_grad(f, x[failed], chunk=chunk)
        value[failed], gradient[failed] = y, g
        if warn:
            warnings.warn(
                f"project_to_surface: {n_failed} of {n} points did not converge "
                f"(tol={tol:.3g}, max_iter={max_iter}); they keep their input position",
                RuntimeWarning,
                stacklevel=2,
            )
    out = Projection(x, converged, gradient, value)
    if was_numpy:
        return Projection(*(t.cpu().numpy() for t in out))
    return out
