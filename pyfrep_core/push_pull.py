"""Push-pull: move the surface through a point by a given distance, solving for the parameters.

A point x0 on f = 0 is pulled by ``d`` along the outward normal n = -grad f / |grad f| (with
f >= 0 inside, grad f points into the solid), to the target y = x0 + d n.  The surface passes
through y when f(y, p + dp) = 0.  Linearised with the normal velocities
V_j = -(df/dp_j) / |grad f| (paper section 4: how fast the surface moves into the solid when
p_j grows) and the signed distance s = f(y) / |grad f(y)| of y inside the surface, this reads

    sum_j V_j dp_j = s,

one equation in P unknowns.  Each Gauss-Newton step solves it for the smallest total change
from the starting parameters in units of each parameter's range (the declared [lower, upper]:
1 % of one range costs as much as 1 % of another), within the bounds
(:func:`scipy.optimize.lsq_linear`), then evaluates V and s again at the target with the new
parameters, until y is on the surface.  A parameter at its bound
stops there: the result says how far from y the surface stayed.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch
from scipy.optimize import lsq_linear

from ._array import as_tensor, check_finite, check_option, check_points, named_entry
from .diff import _param_jacobian, project_to_surface, value_and_grad
from .model import Model
from .sensitivity import velocity

__all__ = ["PushPull", "push_pull"]


class PushPull(NamedTuple):
    """What :func:`push_pull` found.

    Attributes
    ----------
    params : every parameter's new value (name -> float), within its declared range.
    change : new minus old value of each free parameter.
    point : (d,) float64: the point pulled, on f = 0 at the old parameters.
    target : (d,) float64: ``point + displacement * n``, n the outward unit normal at ``point``.
    distance : how far (length units) the surface at the new parameters is from the target, along
        grad f (0 up to ``tol`` when ``converged``; |f| / |grad f| where that walk does not converge).
    steps : Gauss-Newton steps taken.
    converged : the surface passes through the target within ``tol``.
    at_bound : the free parameters that ended at a bound of their range.
    """

    params: dict[str, float]
    change: dict[str, float]
    point: np.ndarray
    target: np.ndarray
    distance: float
    steps: int
    converged: bool
    at_bound: tuple[str, ...]


@named_entry
def push_pull(
    model: Model,
    point: Any,
    displacement: float,
    params: dict[str, Any] | None = None,
    free: Sequence[str] | None = None,
    tol: float = 1e-9,
    max_steps: int = 20,
) -> PushPull:
    """Parameters that move the surface through ``point`` by ``displacement`` along its outward normal.

    Parameters
    ----------
    model : a :class:`~pyfrep_core.model.Model`.
    point : (d,) or (1, d) point on the surface f = 0 (e.g. a mesh vertex), numpy or torch;
        computed in float64.  It is first moved onto f = 0 by Newton steps along grad f
        (:func:`~pyfrep_core.diff.project_to_surface`).
    displacement : distance along the outward normal (length units): > 0 pulls the surface
        out of the solid (it grows there), < 0 pushes it in.
    params : current parameter values (defaults filled in; checked against the ranges).
    free : the parameters allowed to change (default: all declared).
    tol : distance (length units) from the target at which the surface counts as through it.
    max_steps : Gauss-Newton steps at most.

    Returns
    -------
    PushPull
        new ``params``, their ``change``, ``distance`` left, ``converged``, ``at_bound``.

    Raises
    ------
    ValueError : no free parameter moves the surface at ``point`` (every V_j = 0 there), grad f
        vanishes at ``point`` (no normal), an unknown name in ``free``, a non-finite input.

    Examples
    --------
    Pulling the sphere f = r^2 - |x|^2 out by 0.1 at (1, 0, 0) grows r from 1 to 1.1:

    >>> from pyfrep_core import model, Param, sphere
    >>> @model(r=Param(1.0, 0.5, 2.0))
    ... def ball(x, r):
    ...     return sphere(x, r=r)
    >>> result = push_pull(ball, [1.0, 0.0, 0.0], 0.1)
    >>> round(result.params["r"], 9), result.converged
    (1.1, True)
    """
    if not isinstance(model, Model):
        raise TypeError(f"model must be a pyfrep_core Model (declared with @model), got {type(model).__name__}")
    x, _ = as_tensor(point, "point", dtype=torch.float64)
    check_points(x, model.dim, "point")
    if x.numel() != model.dim:
        raise ValueError(f"point must be one point, shape ({model.dim},) or (1, {model.dim}), got {tuple(x.shape)}")
    x = x.reshape(1, model.dim)
    check_finite(x, "point")
    displacement = check_option(displacement, "displacement", "push_pull")
    tol = check_option(tol, "tol", "push_pull", positive=True)
    max_steps = check_option(max_steps, "max_steps", "push_pull", "int", positive=True)
    values = {k: float(v) for k, v in model.check(**(params or {})).items()}
    names = list(model.names) if free is None else list(free)
    unknown = [n for n in names if n not in model.params]
    if unknown or not names:
        raise ValueError(
            f"free must name declared parameters of {model.__name__} ({', '.join(model.names) or 'none'}), "
            f"got {list(free) if free is not None else []!r}"
        )
    lower = np.array([model.params[n].lower for n in names])
    upper = np.array([model.params[n].upper for n in names])
    span = upper - lower

    def field(p: dict[str, float], y: torch.Tensor) -> tuple[float, torch.Tensor]:
        f, g = value_and_grad(lambda q: model(q, **p), y)
        return float(f[0]), g[0]

    # onto f = 0 first: the pull is measured from the surface, not from a point beside it
    _, g0 = field(values, x)
    if float(g0 @ g0) == 0.0:
        raise ValueError(f"grad f vanishes at point {x[0].tolist()}: the surface has no normal there")
    on = project_to_surface(lambda q: model(q, **values), x, tol=0.1 * tol, warn=False)
    if bool(on.converged[0]):
        x = on.points
    _, g0 = field(values, x)
    normal = -g0 / g0.norm()  # outward: f grows inward
    target = x + displacement * normal

    p0 = np.array([values[n] for n in names])
    u = np.zeros(len(names))  # the total change, in units of each range
    lo, hi = (lower - p0) / span, (upper - p0) / span
    steps, distance, moved = 0, np.inf, np.inf
    while True:
        p = np.clip(p0 + u * span, lower, upper)
        current = {**values, **dict(zip(names, p.tolist()))}
        f, g = field(current, target)
        size = float(g.norm())
        if size == 0.0:
            raise ValueError(f"grad f vanishes at the target {target[0].tolist()}: no normal to move along")
        s = f / size  # signed distance of the target inside the surface (to first order)
        distance = abs(s)
        if (distance <= tol and moved <= tol) or steps >= max_steps:  # on target, and the split settled
            break
        df_dp = _param_jacobian(model.fn, target, current, names, label=model.__name__)[0]
        v = velocity(df_dp, torch.tensor(size, dtype=torch.float64)).numpy()  # V_j: inward speed per unit p_j
        a = (v * span)[None, :]
        if not np.any(a):
            raise ValueError(
                f"no free parameter of {model.__name__} ({', '.join(names)}) moves the surface at "
                f"{x[0].tolist()}: every normal velocity is 0 there"
            )
        # the smallest total change meeting a (u_new - u) = s: its fixed point is the smallest change
        # that puts the surface through the target (a tiny Levenberg damping makes the solution unique)
        damping = 1e-10 * float(np.sum(a * a))
        rows = np.vstack([a, np.sqrt(damping) * np.eye(len(names))])
        rhs = np.concatenate([[s + float(a[0] @ u)], np.zeros(len(names))])
        # bvls: an active bound is met exactly (the trust-region method stops just inside it)
        u_new = lsq_linear(rows, rhs, bounds=(lo, hi), method="bvls").x
        steps += 1
        if np.array_equal(u_new, u):  # held at a bound: nothing left to move
            break
        moved = float(np.max(np.abs(u_new - u) * span))
        u = u_new
    new = {**values, **dict(zip(names, p.tolist()))}
    if distance > tol:  # not through the target: the distance along grad f to the surface, not to first order
        foot = project_to_surface(lambda q: model(q, **new), target, tol=0.1 * tol, warn=False)
        if bool(foot.converged[0]):
            distance = float((foot.points - target).norm())
    at_bound = tuple(n for n, v, lo, hi in zip(names, p, lower, upper) if v <= lo or v >= hi)
    return PushPull(
        params=new,
        change={n: new[n] - values[n] for n in names},
        point=x[0].numpy(),
        target=target[0].numpy(),
        distance=float(distance),
        steps=steps,
        converged=bool(distance <= tol),
        at_bound=at_bound,
    )
