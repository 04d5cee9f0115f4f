"""Transformations and deformations acting on points (paper section 3; HyperFun names).

A transformation here maps the points ``x`` (..., 3) where a solid is queried to the
points where the *untransformed* solid is evaluated: ``f(T(x))`` is the transformed
solid, so ``T`` is the inverse of the motion applied to the solid.  Each docstring says
which way the solid moves.  For example

>>> import math, torch
>>> from pyfrep_core import sphere, translate, rotate3DZ
>>> x = torch.tensor([[2.0, 0.0, 0.0]])
>>> sphere(translate(x, (2.0, 0.0, 0.0)), r=1.0)  # the ball moved to (2, 0, 0)
tensor([1.])

Every numeric argument may be a float or a tensor with ``requires_grad`` (d f / d angle
works); a (B, 1) tensor gives (B, N, 3) points, hence (B, N) field values.  Only torch
operations on ``x`` are used (no ``.item()``, no Python ``if`` on values).
"""

from __future__ import annotations

from typing import Any

import torch

from ._array import check_param, check_points, frep, param_array, safe_sqrt, shown, vec

Vector = tuple[float, float, float] | torch.Tensor
Number = float | torch.Tensor

__all__ = [
    "translate",
    "shift3D",
    "scale",
    "scale3D",
    "stretch3D",
    "rotate3DX",
    "rotate3DY",
    "rotate3DZ",
    "rotate",
    "orient",
    "twistX",
    "twistY",
    "twistZ",
    "twist",
    "taperX",
    "taperY",
    "taperZ",
    "bend",
]


def _num(v: Any, like: torch.Tensor) -> torch.Tensor:
    """A scalar (or (B, 1) batch) argument as a tensor on ``like``'s device and dtype; keeps the graph."""
    if isinstance(v, torch.Tensor):
        return v.to(device=like.device, dtype=like.dtype)
    return torch.as_tensor(v, dtype=like.dtype, device=like.device)


def _stack(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """Three coordinate arrays (broadcastable) -> points (..., 3)."""
    return torch.stack(torch.broadcast_tensors(a, b, c), dim=-1)


def _components(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    check_points(x, empty=True)  # no points give no values
    return x[..., 0], x[..., 1], x[..., 2]


def _distinct(fn: str, names: tuple[str, str], t1: Number, t2: Number) -> None:
    """ValueError naming ``fn``'s two arguments when they are equal (a linear ramp over no length)."""
    for name, value in zip(names, (t1, t2)):
        check_param(value, name, fn)
    a, b = param_array(t1, names[0], fn), param_array(t2, names[1], fn)
    if a is not None and b is not None and (a == b).any():
        raise ValueError(f"{fn}: {names[0]} and {names[1]} must differ, got {shown(t1)!r} and {shown(t2)!r}")


def _same_sign(fn: str, s1: Number, s2: Number) -> None:
    """ValueError unless the taper scales s1, s2 are nonzero with one sign (s(t) never crosses 0)."""
    check_param(s1, "s1", fn, nonzero=True)
    check_param(s2, "s2", fn, nonzero=True)
    a, b = param_array(s1, "s1", fn), param_array(s2, "s2", fn)
    if a is not None and b is not None and not (a * b > 0).all():
        raise ValueError(f"{fn}: s1 and s2 must be nonzero with the same sign, got {shown(s1)!r} and {shown(s2)!r}")


def _rotate_pair(u: torch.Tensor, v: torch.Tensor, theta: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Rotate the (u, v) coordinates by -theta: the solid turns by +theta from u towards v."""
    c, s = torch.cos(theta), torch.sin(theta)
    return u * c + v * s, -u * s + v * c


@frep
def translate(x: torch.Tensor, offset: Vector) -> torch.Tensor:
    """Translation: returns ``x - offset``; the solid moves by ``+offset``.

    Parameters
    ----------
    x : (..., 3) points.
    offset : (3,) displacement of the solid (or (B, 3) for B displacements).

    Returns
    -------
    (..., 3) points at which to evaluate the untransformed solid.

    Examples
    --------
    >>> import torch
    >>> translate(torch.tensor([[1.0, 2.0, 3.0]]), (1.0, 1.0, 1.0))
    tensor([[0., 1., 2.]])
    """
    check_points(x, empty=True)  # no points give no values
    check_param(offset, "offset", "translate")
    return x - vec(offset, x, name="offset")


@frep
def shift3D(x: torch.Tensor, dx: Number = 0.0, dy: Number = 0.0, dz: Number = 0.0) -> torch.Tensor:
    """Translation by components (HyperFun ``hfShift3D``): the solid moves by ``(dx, dy, dz)``.

    Parameters
    ----------
    x : (..., 3) points.
    dx, dy, dz : displacement of the solid along x, y, z.

    Returns
    -------
    (..., 3) points ``x - (dx, dy, dz)``.

    Examples
    --------
    >>> import torch
    >>> shift3D(torch.tensor([[1.0, 2.0, 3.0]]), dx=1.0, dz=-1.0)
    tensor([[0., 2., 4.]])
    """
    px, py, pz = _components(x)
    for name, value in (("dx", dx), ("dy", dy), ("dz", dz)):
        check_param(value, name, "shift3D")
    return _stack(px - dx, py - dy, pz - dz)


def _per_axis(factor: Any) -> bool:
    """True for three factors (sx, sy, sz): a length-3 sequence, or a tensor whose last axis has 3 entries."""
    if isinstance(factor, torch.Tensor):  # numpy arrays arrive as tensors (frep converts them)
        return factor.ndim >= 1 and factor.shape[-1] == 3
    return isinstance(factor, list | tuple) and len(factor) == 3


@frep
def scale(x: torch.Tensor, factor: Number | Vector) -> torch.Tensor:
    """Scaling about the origin: returns ``x / factor``; the solid grows by ``factor``.

    ``factor`` is one number (uniform scaling) or three, ``(sx, sy, sz)``, one per axis (as the
    reference code's ``scale(p, (sx, sy, sz))``; the same as :func:`scale3D`).

    Parameters
    ----------
    x : (..., 3) points.
    factor : scale factor, or (3,) factors along x, y, z; non-zero (a negative factor also
        mirrors the solid).  A (B, 1) tensor gives B uniform scalings, a (B, 3) tensor B
        per-axis ones: (B, N, 3) points.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import torch
    >>> scale(torch.tensor([[2.0, 4.0, 6.0]]), 2.0)
    tensor([[1., 2., 3.]])
    >>> scale(torch.tensor([[2.0, 4.0, 6.0]]), (2.0, 4.0, 3.0))
    tensor([[1., 1., 2.]])
    """
    check_points(x, empty=True)  # no points give no values
    if not _per_axis(factor):
        check_param(factor, "factor", "scale", nonzero=True)
        return x / _num(factor, x)[..., None]
    check_param(factor, "factor", "scale")
    values = param_array(factor, "factor", "scale")
    if values is not None and not (values != 0).all():
        raise ValueError(f"scale: factor must have no zero component, got {shown(factor)!r}")
    return x / vec(factor, x, name="factor")


@frep
def scale3D(x: torch.Tensor, sx: Number = 1.0, sy: Number = 1.0, sz: Number = 1.0) -> torch.Tensor:
    """Scaling about the origin (HyperFun ``hfScale3D``): the solid is stretched by sx, sy, sz.

    Parameters
    ----------
    x : (..., 3) points.
    sx, sy, sz : scale factors of the solid along x, y, z (non-zero).

    Returns
    -------
    (..., 3) points ``(x/sx, y/sy, z/sz)``.

    Examples
    --------
    >>> import torch
    >>> scale3D(torch.tensor([[2.0, 2.0, 2.0]]), sx=2.0, sy=4.0, sz=0.5)
    tensor([[1.0000, 0.5000, 4.0000]])
    """
    px, py, pz = _components(x)
    for name, value in (("sx", sx), ("sy", sy), ("sz", sz)):
        check_param(value, name, "scale3D", nonzero=True)
    return _stack(px / sx, py / sy, pz / sz)


@frep
def stretch3D(
    x: torch.Tensor, x0: Vector = (0.0, 0.0, 0.0), sx: Number = 1.0, sy: Number = 1.0, sz: Number = 1.0
) -> torch.Tensor:
    """Scaling about the point ``x0`` (HyperFun ``hfStretch3D``): the solid is stretched by sx, sy, sz.

    Parameters
    ----------
    x : (..., 3) points.
    x0 : (3,) fixed point of the stretch.
    sx, sy, sz : stretch factors of the solid along x, y, z (non-zero).

    Returns
    -------
    (..., 3) points ``x0 + (x - x0) / s``.

    Examples
    --------
    >>> import torch
    >>> stretch3D(torch.tensor([[3.0, 1.0, 1.0]]), x0=(1.0, 1.0, 1.0), sx=2.0)
    tensor([[2., 1., 1.]])
    """
    px, py, pz = _components(x)
    check_param(x0, "x0", "stretch3D")
    for name, value in (("sx", sx), ("sy", sy), ("sz", sz)):
        check_param(value, name, "stretch3D", nonzero=True)
    c = vec(x0, x, name="x0")
    return _stack(
        c[..., 0] + (px - c[..., 0]) / sx, c[..., 1] + (py - c[..., 1]) / sy, c[..., 2] + (pz - c[..., 2]) / sz
    )


@frep
def rotate3DX(x: torch.Tensor, theta: Number) -> torch.Tensor:
    """Rotation about the x axis (HyperFun ``hfRotate3DX``): the solid turns by ``+theta``.

    Positive angles turn the solid counter-clockwise seen from +x (right-hand rule:
    +y towards +z); the points are rotated by ``-theta``.

    Parameters
    ----------
    x : (..., 3) points.
    theta : angle in radians.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> rotate3DX(torch.tensor([[1.0, 0.0, 1.0]], dtype=torch.float64), math.pi / 2).round(decimals=12)
    tensor([[1., 1., 0.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(theta, "theta", "rotate3DX")
    y2, z2 = _rotate_pair(py, pz, _num(theta, x))
    return _stack(px, y2, z2)


@frep
def rotate3DY(x: torch.Tensor, theta: Number) -> torch.Tensor:
    """Rotation about the y axis (HyperFun ``hfRotate3DY``): the solid turns by ``+theta``.

    Right-hand rule about +y: +z turns towards +x.

    Parameters
    ----------
    x : (..., 3) points.
    theta : angle in radians.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> rotate3DY(torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64), math.pi / 2).round(decimals=12)
    tensor([[0., 0., 1.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(theta, "theta", "rotate3DY")
    z2, x2 = _rotate_pair(pz, px, _num(theta, x))
    return _stack(x2, py, z2)


@frep
def rotate3DZ(x: torch.Tensor, theta: Number) -> torch.Tensor:
    """Rotation about the z axis (HyperFun ``hfRotate3DZ``): the solid turns by ``+theta``.

    Right-hand rule about +z: +x turns towards +y.  A solid at (1, 0, 0) is found at
    (0, 1, 0) after ``theta = pi/2``, so the point (0, 1, 0) maps to (1, 0, 0).

    Parameters
    ----------
    x : (..., 3) points.
    theta : angle in radians.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> rotate3DZ(torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64), math.pi / 2).round(decimals=12)
    tensor([[1., 0., 0.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(theta, "theta", "rotate3DZ")
    x2, y2 = _rotate_pair(px, py, _num(theta, x))
    return _stack(x2, y2, pz)


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / safe_sqrt((v * v).sum(-1, keepdim=True))


@frep
def rotate(x: torch.Tensor, angle: Number, axis: Vector = (0.0, 0.0, 1.0)) -> torch.Tensor:
    """Rotation by ``angle`` about any axis through the origin (Rodrigues' formula).

    The solid turns by ``+angle`` about ``axis`` (right-hand rule); the points are
    rotated by ``-angle``: ``x cos a - (n x x) sin a + n (n . x)(1 - cos a)`` with
    ``n = axis / |axis|``.  ``rotate(x, t, (0, 0, 1))`` equals ``rotate3DZ(x, t)``.

    Parameters
    ----------
    x : (..., 3) points.
    angle : angle in radians.
    axis : (3,) non-zero direction of the axis (need not be unit length).

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    >>> rotate(p, 2 * math.pi / 3, axis=(1.0, 1.0, 1.0)).round(decimals=12)  # permutes the axes
    tensor([[0., 1., 0.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(angle, "angle", "rotate")
    check_param(axis, "axis", "rotate", nonzero=True)
    n = _unit(vec(axis, x, name="axis"))
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    a = _num(angle, x)
    c, s = torch.cos(a), torch.sin(a)
    along = (nx * px + ny * py + nz * pz) * (1.0 - c)
    return _stack(
        px * c - (ny * pz - nz * py) * s + nx * along,
        py * c - (nz * px - nx * pz) * s + ny * along,
        pz * c - (nx * py - ny * px) * s + nz * along,
    )


@frep
def orient(x: torch.Tensor, direction: Vector) -> torch.Tensor:
    """Turn the solid so that its +z axis points along ``direction`` (shortest rotation).

    Useful to lay a primitive built along z (``cylZ``, ``coneZ``, ``torusZ``) along any
    direction.  For ``direction`` = -z the solid is turned by pi about the x axis.

    Parameters
    ----------
    x : (..., 3) points.
    direction : (3,) non-zero new direction of the solid's z axis.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import torch
    >>> orient(torch.tensor([[2.0, 0.0, 0.0]], dtype=torch.float64), (1.0, 0.0, 0.0))
    tensor([[0., 0., 2.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(direction, "direction", "orient", nonzero=True)
    d = _unit(vec(direction, x, name="direction"))
    # R maps e_z to d; R^T x = c x - v x x + v (v . x) / (1 + c), v = e_z x d, c = e_z . d
    vx, vy, c = -d[..., 1], d[..., 0], d[..., 2]
    # 1 / (1 + c) = (1 - c) / |v|^2: accurate even when d is close to -z; only d = -z exactly is special
    v2 = vx * vx + vy * vy
    flipped = (v2 == 0) & (c < 0)
    k = (1.0 - c) / torch.where(v2 > 0, v2, torch.full_like(v2, 2.0))
    vdotp = (vx * px + vy * py) * k
    general = _stack(c * px - vy * pz + vx * vdotp, c * py + vx * pz + vy * vdotp, c * pz - (vx * py - vy * px))
    return torch.where(flipped[..., None], _stack(px, -py, -pz), general)


def _twist_angle(t: torch.Tensor, t1: Number, t2: Number, theta1: Number, theta2: Number) -> torch.Tensor:
    """Angle linear in the coordinate: theta1 at t1, theta2 at t2 (extrapolated beyond)."""
    s = (t - t1) / (t2 - t1)
    return (1.0 - s) * theta1 + s * theta2


@frep
def twistX(x: torch.Tensor, x1: Number, x2: Number, theta1: Number, theta2: Number) -> torch.Tensor:
    """Twist about the x axis (HyperFun ``hfTwistX``).

    The cross-section at abscissa x is turned by ``theta(x)``, linear in x with
    ``theta(x1) = theta1`` and ``theta(x2) = theta2`` (extrapolated outside [x1, x2]), in
    the direction of :func:`rotate3DX`.  A point p of the untwisted solid ends up at
    ``rotate3DX``'s inverse: ``(p_x, R(theta(p_x)) (p_y, p_z))``.

    Parameters
    ----------
    x : (..., 3) points.
    x1, x2 : abscissas where the angle is theta1 and theta2 (x1 != x2).
    theta1, theta2 : angles in radians.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[1.0, 0.0, 1.0]], dtype=torch.float64)
    >>> twistX(p, 0.0, 1.0, 0.0, math.pi / 2).round(decimals=12)  # at x = 1 the solid turned by pi/2
    tensor([[1., 1., 0.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    _distinct("twistX", ("x1", "x2"), x1, x2)
    check_param(theta1, "theta1", "twistX")
    check_param(theta2, "theta2", "twistX")
    y2, z2 = _rotate_pair(py, pz, _twist_angle(px, x1, x2, theta1, theta2))
    return _stack(px, y2, z2)


@frep
def twistY(x: torch.Tensor, y1: Number, y2: Number, theta1: Number, theta2: Number) -> torch.Tensor:
    """Twist about the y axis (HyperFun ``hfTwistY``): the section at y turns by ``theta(y)``.

    ``theta`` is linear in y with ``theta(y1) = theta1``, ``theta(y2) = theta2``; the
    direction is that of :func:`rotate3DY`.

    Parameters
    ----------
    x : (..., 3) points.
    y1, y2 : ordinates where the angle is theta1 and theta2 (y1 != y2).
    theta1, theta2 : angles in radians.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[0.0, 2.0, 1.0]], dtype=torch.float64)
    >>> twistY(p, 0.0, 1.0, 0.0, math.pi / 4).round(decimals=12)  # theta(2) = pi/2
    tensor([[-1.,  2.,  0.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    _distinct("twistY", ("y1", "y2"), y1, y2)
    check_param(theta1, "theta1", "twistY")
    check_param(theta2, "theta2", "twistY")
    z2, x2 = _rotate_pair(pz, px, _twist_angle(py, y1, y2, theta1, theta2))
    return _stack(x2, py, z2)


@frep
def twistZ(x: torch.Tensor, z1: Number, z2: Number, theta1: Number, theta2: Number) -> torch.Tensor:
    """Twist about the z axis (HyperFun ``hfTwistZ``): the section at z turns by ``theta(z)``.

    ``theta`` is linear in z with ``theta(z1) = theta1``, ``theta(z2) = theta2``; the
    direction is that of :func:`rotate3DZ`.  The same values as the reference code's
    ``twistZ`` (which read y instead of z until its fix of 2 October 2025).

    Parameters
    ----------
    x : (..., 3) points.
    z1, z2 : heights where the angle is theta1 and theta2 (z1 != z2).
    theta1, theta2 : angles in radians.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[0.0, 1.0, 1.0]], dtype=torch.float64)
    >>> twistZ(p, 0.0, 1.0, 0.0, math.pi / 2).round(decimals=12)
    tensor([[1., 0., 1.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    _distinct("twistZ", ("z1", "z2"), z1, z2)
    check_param(theta1, "theta1", "twistZ")
    check_param(theta2, "theta2", "twistZ")
    x2, y2 = _rotate_pair(px, py, _twist_angle(pz, z1, z2, theta1, theta2))
    return _stack(x2, y2, pz)


@frep
def twist(x: torch.Tensor, k: Number) -> torch.Tensor:
    """Twist about the z axis by ``k`` radians per unit of height (the reference code's ``twist``).

    Returns ``(x cos kz - y sin kz, x sin kz + y cos kz, z)``: the points turn by ``+k z``
    about z, so the solid's section at height z turns by ``-k z`` (against :func:`rotate3DZ`'s
    direction).  The same values as the reference code: ``twist(x, k)`` equals
    ``twistZ(x, 0, 1, 0, -k)``.

    Parameters
    ----------
    x : (..., 3) points.
    k : twist rate in radians per length unit (a float, a 0-d tensor, or (B, 1) for B rates).

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[1.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    >>> twist(p, math.pi / 2).round(decimals=12)  # at z = 1 the point turns by a quarter turn
    tensor([[0., 1., 1.],
            [1., 0., 0.]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(k, "k", "twist")
    x2, y2 = _rotate_pair(px, py, -_num(k, x) * pz)
    return _stack(x2, y2, pz)


def _taper_scale(t: torch.Tensor, t1: Number, t2: Number, s1: Number, s2: Number) -> torch.Tensor:
    """Scale s1 before t1, s2 after t2, linear in between (clamped, so continuous)."""
    u = torch.clamp((t - t1) / (t2 - t1), 0.0, 1.0)
    return (1.0 - u) * s1 + u * s2


@frep
def taperX(x: torch.Tensor, x1: Number, x2: Number, s1: Number, s2: Number) -> torch.Tensor:
    """Taper along x (HyperFun ``hfTaperX``): the solid's y, z are scaled by ``s(x)``.

    ``s = s1`` for x <= x1, ``s2`` for x >= x2, linear in between.  A point p of the
    untapered solid ends up at ``(p_x, s(p_x) p_y, s(p_x) p_z)``.

    Parameters
    ----------
    x : (..., 3) points.
    x1, x2 : abscissas bounding the linear part (x1 != x2; with x1 > x2 the roles swap).
    s1, s2 : scale factors (non-zero, of one sign, so that s never crosses 0) at x1 and x2.

    Returns
    -------
    (..., 3) points ``(x, y / s(x), z / s(x))``.

    Examples
    --------
    >>> import torch
    >>> taperX(torch.tensor([[0.5, 1.0, 1.0], [2.0, 1.0, 1.0]]), 0.0, 1.0, 1.0, 0.5)
    tensor([[0.5000, 1.3333, 1.3333],
            [2.0000, 2.0000, 2.0000]])
    """
    px, py, pz = _components(x)
    _distinct("taperX", ("x1", "x2"), x1, x2)
    _same_sign("taperX", s1, s2)
    s = _taper_scale(px, x1, x2, s1, s2)
    return _stack(px, py / s, pz / s)


@frep
def taperY(x: torch.Tensor, y1: Number, y2: Number, s1: Number, s2: Number) -> torch.Tensor:
    """Taper along y (HyperFun ``hfTaperY``): the solid's x, z are scaled by ``s(y)``.

    ``s = s1`` for y <= y1, ``s2`` for y >= y2, linear in between.

    Parameters
    ----------
    x : (..., 3) points.
    y1, y2 : ordinates bounding the linear part (y1 != y2; with y1 > y2 the roles swap).
    s1, s2 : scale factors (non-zero, of one sign, so that s never crosses 0) at y1 and y2.

    Returns
    -------
    (..., 3) points ``(x / s(y), y, z / s(y))``.

    Examples
    --------
    >>> import torch
    >>> taperY(torch.tensor([[1.0, 1.0, 1.0]]), 0.0, 1.0, 1.0, 0.5)
    tensor([[2., 1., 2.]])
    """
    px, py, pz = _components(x)
    _distinct("taperY", ("y1", "y2"), y1, y2)
    _same_sign("taperY", s1, s2)
    s = _taper_scale(py, y1, y2, s1, s2)
    return _stack(px / s, py, pz / s)


@frep
def taperZ(x: torch.Tensor, z1: Number, z2: Number, s1: Number, s2: Number) -> torch.Tensor:
    """Taper along z (HyperFun ``hfTaperZ``): the solid's x, y are scaled by ``s(z)``.

    ``s = s1`` for z <= z1, ``s2`` for z >= z2, linear in between.

    Parameters
    ----------
    x : (..., 3) points.
    z1, z2 : heights bounding the linear part (z1 != z2; with z1 > z2 the roles swap).
    s1, s2 : scale factors (non-zero, of one sign, so that s never crosses 0) at z1 and z2.

    Returns
    -------
    (..., 3) points ``(x / s(z), y / s(z), z)``.

    Examples
    --------
    >>> import torch
    >>> taperZ(torch.tensor([[1.0, 1.0, -1.0]]), 0.0, 1.0, 2.0, 1.0)
    tensor([[ 0.5000,  0.5000, -1.0000]])
    """
    px, py, pz = _components(x)
    _distinct("taperZ", ("z1", "z2"), z1, z2)
    _same_sign("taperZ", s1, s2)
    s = _taper_scale(pz, z1, z2, s1, s2)
    return _stack(px / s, py / s, pz)


def _atan_ratio(z: torch.Tensor) -> torch.Tensor:
    """atan(z) / z, smooth through z = 0 (Taylor series there; double where keeps grads finite)."""
    small = z.abs() < 1e-4
    zs = torch.where(small, torch.ones_like(z), z)
    z2 = z * z
    return torch.where(small, 1.0 - z2 / 3.0 + z2 * z2 / 5.0, torch.atan(zs) / zs)


@frep
def bend(x: torch.Tensor, k: Number) -> torch.Tensor:
    """Circular bend of the x axis towards +y with curvature ``k`` (radius 1/k).

    The solid's x axis becomes the circle of radius ``1/k`` through the origin, tangent
    to x there, centered at (0, 1/k, 0); lengths along the x axis are kept and z is
    unchanged (Barr's bend).  A point p of the unbent solid ends up at
    ``(rho sin(k p_x), 1/k - rho cos(k p_x), p_z)`` with ``rho = 1/k - p_y``.  The
    inverse computed here is ``(atan2(k x, 1 - k y) / k, (2 y - k (x^2 + y^2)) / (1 + q), z)``
    with ``q = sqrt((k x)^2 + (1 - k y)^2)``, written without division by k, so
    ``k = 0`` is the identity and d/dk is exact there.  It is valid for bends up to
    ``|k p_x| < pi`` and points on the near side of the center (``k p_y < 1``).

    Parameters
    ----------
    x : (..., 3) points.
    k : curvature (1/length); negative bends towards -y.

    Returns
    -------
    (..., 3) points.

    Examples
    --------
    >>> import math, torch
    >>> p = torch.tensor([[1.0, 1.0, 0.5]], dtype=torch.float64)  # on the circle of radius 1
    >>> bend(p, 1.0).round(decimals=12)  # arc length pi/2 along the bent axis
    tensor([[1.5708, 0.0000, 0.5000]], dtype=torch.float64)
    """
    px, py, pz = _components(x)
    check_param(k, "k", "bend")
    k = _num(k, x)
    b = 1.0 - k * py
    a = k * px
    near = b > 0.5  # there k p_x / b is a tangent: atan form, smooth in k through 0
    k_far = torch.where(near, torch.ones_like(b), k)
    b_near = torch.where(near, b, torch.ones_like(b))
    u = torch.where(near, px / b_near * _atan_ratio(a / b_near), torch.atan2(a, b) / k_far)
    v = (2.0 * py - k * (px * px + py * py)) / (1.0 + safe_sqrt(a * a + b * b))
    return _stack(u, v, pz)
