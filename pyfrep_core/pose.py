"""A model in an unknown rigid pose: translation and rotation (optionally a uniform scale) as parameters.

A part measured by a scanner lies wherever the scanner put it.  :func:`posed` wraps a model so that
its pose is a set of ordinary declared parameters, fitted like any shape parameter:

    x_model = R(r)^T (x - t) / s,      f_posed(x) = f(x_model)

with ``t = (tx, ty, tz)``, ``r = (rx, ry, rz)`` a rotation vector (axis times angle, Rodrigues'
formula) and ``s`` the optional uniform scale.  In the plane (a model of ``dim = 2``) the pose is
``tx, ty, angle``.  The solid moves by ``x -> s R x + t``.  Everything is torch arithmetic on 0-d
parameters, so parameter sets (``torch.func.vmap``) and per-point df/dp work on the posed model as
on any other.

:func:`initial_pose` proposes starting poses from a point cloud: the centroid, the principal axes
(PCA) matched to the model's own, and the extent ratio for the scale; a principal axis has no sign,
and axes of (nearly) equal spread may be swapped, so every proper rotation (det = +1) those
ambiguities allow is a candidate, equal rotations counted once.

>>> import numpy as np, torch
>>> from pyfrep_core import model, Param, sphere
>>> @model(bounds=((-1,) * 3, (1,) * 3), r=Param(0.5, 0.1, 0.9))
... def ball(x, r):
...     return sphere(x, r=r)
>>> moved = posed(ball)
>>> moved.names
['r', 'tx', 'ty', 'tz', 'rx', 'ry', 'rz']
>>> float(moved(torch.tensor([[2.0, 0.0, 0.0]]), tx=2.0)[0])   # the ball's centre moved to (2, 0, 0)
0.25
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from ._array import as_tensor, check_finite, check_option
from .model import Model, Param, check_bounds

__all__ = ["posed", "is_posed", "initial_pose", "rotation_matrix", "rotation_vector", "POSE_NAMES"]

POSE_NAMES = {3: ("tx", "ty", "tz", "rx", "ry", "rz"), 2: ("tx", "ty", "angle")}
ROTATION_BOUND = math.pi + 0.5  # rotation-vector components: |r| <= pi covers every rotation, with a margin
SMALL_ANGLE2 = 1e-8  # below this squared angle Rodrigues' coefficients use their Taylor series


def rotation_matrix(rx: Any, ry: Any, rz: Any) -> torch.Tensor:
    """The rotation matrix (3, 3) of the rotation vector ``(rx, ry, rz)`` (Rodrigues' formula).

    ``R = I + A K + B K^2`` with K the cross-product matrix of r, ``A = sin(theta)/theta`` and
    ``B = (1 - cos(theta))/theta^2``, theta = |r|; near theta = 0 the coefficients are their Taylor
    series, so the value and its derivatives are finite at r = 0 (no 0/0 in the gradient).

    Examples
    --------
    >>> import math, torch
    >>> rotation_matrix(torch.tensor(0.0), torch.tensor(0.0), torch.tensor(math.pi / 2)).round(decimals=6)
    tensor([[ 0., -1.,  0.],
            [ 1.,  0.,  0.],
            [ 0.,  0.,  1.]])
    """
    r = torch.stack(torch.broadcast_tensors(*(torch.as_tensor(v) for v in (rx, ry, rz))))
    t2 = (r * r).sum()
    small = t2 < SMALL_ANGLE2
    safe = torch.where(small, torch.ones_like(t2), t2)
    theta = torch.sqrt(safe)
    a = torch.where(small, 1.0 - t2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - t2 / 24.0, (1.0 - torch.cos(theta)) / safe)
    zero = torch.zeros_like(r[0])
    k = torch.stack(
        [
            torch.stack([zero, -r[2], r[1]]),
            torch.stack([r[2], zero, -r[0]]),
            torch.stack([-r[1], r[0], zero]),
        ]
    )
    eye = torch.eye(3, dtype=r.dtype, device=r.device)
    return eye + a * k + b * (k @ k)


def rotation_vector(matrix: Any) -> np.ndarray:
    """The rotation vector (3,) of a rotation matrix (3, 3), angle in [0, pi] (float64 numpy).

    Examples
    --------
    >>> import numpy as np
    >>> np.round(rotation_vector(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])), 6)
    array([0.      , 0.      , 1.570796])
    """
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(matrix, dtype=np.float64)).as_rotvec()


def is_posed(m: Any) -> bool:
    """Whether ``m`` is a model made by :func:`posed` (its pose parameters are declared).

    >>> from pyfrep_core import model, Param, sphere
    >>> ball = model(bounds=((-1,) * 3, (1,) * 3), r=Param(0.5, 0.1, 0.9))(lambda x, r: sphere(x, r=r))
    >>> is_posed(ball), is_posed(posed(ball))
    (False, True)
    """
    return isinstance(m, Model) and getattr(m, "pose_base", None) is not None


def _translation_box(m: Model, translation: Any) -> tuple[np.ndarray, np.ndarray]:
    d = m.dim
    if translation is not None:
        lo, hi = check_bounds(translation, d, "posed: translation")
        return np.asarray(lo), np.asarray(hi)
    if m.bounds is None:
        raise ValueError(
            f"posed: {m.__name__} has no default bounds, so the translation range cannot be derived; "
            "give translation=((xmin, ...), (xmax, ...))"
        )
    lo, hi = (np.asarray(b, dtype=float) for b in m.bounds)
    size = hi - lo
    return lo - size, hi + size  # the model's box moved by up to its own size in every direction


def posed(
    m: Model,
    scale: bool = False,
    translation: Any = None,
    scale_range: tuple[float, float] = (0.5, 2.0),
) -> Model:
    """``m`` in a rigid pose (and optional uniform scale) given by declared parameters.

    The new model's defining function maps the points to the model's frame,
    ``x_model = R(r)^T (x - t) / s``, and evaluates ``m`` there: the solid is moved by
    ``x -> s R(r) x + t`` (R by Rodrigues' formula, :func:`rotation_matrix`).  Its parameters are
    ``m``'s, then ``tx, ty, tz, rx, ry, rz`` (``tx, ty, angle`` for a planar model), then ``s``
    when ``scale`` is True; the pose parameters default to the identity.

    Parameters
    ----------
    m : a Model (``@model``) whose parameter names do not include the pose names.
    scale : add the uniform scale ``s`` (length ratio, in ``scale_range``).
    translation : ((xmin, ...), (xmax, ...)) range of t; default: ``m.bounds`` widened by the
        box's size on every side (:func:`pyfrep_core.fit` with ``pose=True`` sets it from the data).
    scale_range : (lower, upper) range of ``s``, 0 < lower < 1 < upper.

    Returns
    -------
    Model, with attributes ``pose_base`` (``m``), ``pose_names`` and ``pose_scale``.  Its default
    bounds cover ``m``'s box turned anyhow and moved anywhere in the translation range.

    Raises
    ------
    TypeError when ``m`` is not a Model; ValueError when a pose name is already one of its
    parameters, or for a bad range.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import model, Param, block
    >>> @model(bounds=((-1,) * 3, (1,) * 3), a=Param(0.5, 0.1, 0.9))
    ... def cube(x, a):
    ...     return block(x, vertex=(-a / 2, -a / 2, -a / 2), dx=a, dy=a, dz=a)
    >>> p = posed(cube, scale=True)
    >>> x = torch.tensor([[0.0, 0.0, 0.45]], dtype=torch.float64)
    >>> bool(p(x, a=0.5, s=2.0)[0] > 0), bool(p(x, a=0.5)[0] > 0)   # twice as large: the point is inside
    (True, False)
    """
    if not isinstance(m, Model):
        raise TypeError(f"posed: m must be a Model declared with @model, got {m!r}")
    if is_posed(m):
        raise ValueError(f"posed: {m.__name__} is already posed (its parameters include {', '.join(m.pose_names)})")
    if m.dim not in POSE_NAMES:
        raise ValueError(f"posed: models of dimension 2 or 3 can be posed, {m.__name__} has dim={m.dim}")
    scale = check_option(scale, "scale", "posed", "bool")
    names = POSE_NAMES[m.dim] + (("s",) if scale else ())
    clash = [k for k in names if k in m.params]
    if clash:
        raise ValueError(
            f"posed: {m.__name__} already declares {', '.join(map(repr, clash))}, a pose parameter name; rename it"
        )
    try:
        s_lo, s_hi = (float(v) for v in scale_range)
    except (TypeError, ValueError):
        raise ValueError(f"posed: scale_range must be (lower, upper), got {scale_range!r}") from None
    if not (0 < s_lo < 1 < s_hi and math.isfinite(s_hi)):
        raise ValueError(f"posed: scale_range must satisfy 0 < lower < 1 < upper, got {scale_range!r}")
    lo, hi = _translation_box(m, translation)
    params: dict[str, Param] = dict(m.params)
    centre = 0.5 * (lo + hi)
    axes = "xyz"[: m.dim]
    for i, a in enumerate(axes):
        t0 = 0.0 if lo[i] <= 0.0 <= hi[i] else float(centre[i])
        params[f"t{a}"] = Param(t0, float(lo[i]), float(hi[i]), label=f"translation {a}")
    if m.dim == 3:
        for a in axes:
            params[f"r{a}"] = Param(0.0, -ROTATION_BOUND, ROTATION_BOUND, label=f"rotation vector {a} (rad)")
    else:
        params["angle"] = Param(0.0, -ROTATION_BOUND, ROTATION_BOUND, label="rotation angle (rad)")
    if scale:
        params["s"] = Param(1.0, s_lo, s_hi, label="uniform scale")
    base_fn, shape_names, dim = m.fn, list(m.params), m.dim

    def fn(x: torch.Tensor, **p: Any) -> torch.Tensor:
        shape = {k: p[k] for k in shape_names}
        if dim == 3:
            t = torch.stack([p["tx"], p["ty"], p["tz"]]).to(x.dtype)
            rot = rotation_matrix(p["rx"], p["ry"], p["rz"]).to(x.dtype)
        else:
            t = torch.stack([p["tx"], p["ty"]]).to(x.dtype)
            c, s_ = torch.cos(p["angle"]), torch.sin(p["angle"])
            rot = torch.stack([torch.stack([c, -s_]), torch.stack([s_, c])]).to(x.dtype)
        local = (x - t) @ rot  # row i: R^T (x_i - t)
        if "s" in p:
            local = local / p["s"]
        return base_fn(local, **shape)

    fn.__name__ = f"posed_{m.__name__}"
    fn.__doc__ = f"{m.__name__} moved by x -> {'s ' if scale else ''}R x + t (pyfrep_core.pose.posed)."
    # default bounds: m's box, turned anyhow (its circumscribed ball), scaled and moved over the translation range
    if m.bounds is not None:
        blo, bhi = (np.asarray(b, dtype=float) for b in m.bounds)
        reach = 0.5 * float(np.linalg.norm(bhi - blo)) * (s_hi if scale else 1.0)
        reach += float(np.linalg.norm(0.5 * (blo + bhi))) * (s_hi if scale else 1.0)
        bounds = (tuple(lo - reach), tuple(hi + reach))
    else:
        bounds = None
    out = Model(fn, params, bounds=bounds, dim=dim)
    out.__name__ = fn.__name__
    out.__qualname__ = fn.__name__
    out.pose_base = m
    out.pose_names = names
    out.pose_scale = scale
    return out


def _pca(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid (d,), principal axes (d, d) as columns (a right-handed frame), spreads (d,) descending."""
    c = points.mean(0)
    cov = np.cov((points - c).T)
    w, v = np.linalg.eigh(cov)
    order = np.argsort(w)[::-1]
    w, v = np.maximum(w[order], 0.0), v[:, order]
    if np.linalg.det(v) < 0:
        v[:, -1] = -v[:, -1]
    return c, v, np.sqrt(w)


def _robust_cloud(points: np.ndarray, k: int = 8) -> np.ndarray:
    """The points without the stray ones: those whose mean distance to their ``k`` nearest neighbours
    exceeds twice the median of that distance (a scan's surface points lie densely on a surface,
    stray points sparsely in space: a statistical outlier filter).  Stray points would tilt the
    principal axes of a part whose spreads are alike."""
    from scipy.spatial import cKDTree

    if len(points) <= 4 * k:
        return points
    dist, _ = cKDTree(points).query(points, k=k + 1)
    spacing = dist[:, 1:].mean(1)
    kept = points[spacing <= 2.0 * np.median(spacing)]
    return kept if len(kept) > points.shape[1] else points


def _signed_permutations(d: int, groups: list[list[int]]) -> list[np.ndarray]:
    """Proper (det = +1) signed permutation matrices that only permute axes within each group."""
    import itertools

    out = []
    for perm in itertools.permutations(range(d)):
        if any(sorted(perm[i] for i in g) != sorted(g) for g in groups):
            continue
        for signs in itertools.product((1.0, -1.0), repeat=d):
            p = np.zeros((d, d))
            p[list(perm), range(d)] = signs  # column j picks axis perm[j] with its sign
            if np.linalg.det(p) > 0:
                out.append(p)
    return out


def _model_frame(m: Model, params: Mapping[str, float] | None, n: int, seed: int) -> tuple:
    """Centroid, principal axes and spreads of the model's own surface at ``params`` (sampled)."""
    from .sampling import sample_surface

    if m.dim != 3:
        raise ValueError("initial_pose: a model's own frame is measured for 3-D models; give model=None for 2-D")
    pts = sample_surface(m, n, params=dict(params or {}), seed=seed, resolution=48)
    return _pca(pts)


def initial_pose(
    points: Any,
    model: Model | None = None,
    *,
    params: Mapping[str, float] | None = None,
    scale: bool = False,
    symmetry_tol: float = 0.15,
    samples: int = 4000,
    seed: int = 0,
) -> list[dict[str, float]]:
    """Candidate starting poses of ``model`` for the cloud ``points`` (for :func:`posed`'s parameters).

    The cloud's centroid and principal axes (PCA, after setting aside the stray points: sparse
    where the surface's points are dense) are matched to the model's own (its
    surface sampled at ``params``, or the origin and the coordinate axes when ``model`` is None):
    ``R = U_cloud P U_model^T``, ``t = c_cloud - s R c_model``.  A principal axis has no sign, so P
    runs over the sign flips; axes whose spreads differ by less than ``symmetry_tol`` (relative) are
    also permuted (a part symmetric about them looks the same either way).  Only proper rotations
    (det = +1) are kept, each distinct rotation once, ordered as found (the identity-like match first).

    Parameters
    ----------
    points : (N, d) array or tensor (d = 3, or 2 with ``model=None`` or a planar model's frame).
    model : the (unposed) Model; None: the model's frame is taken to be the world's.
    params : the model's parameter values for its frame (default: its defaults).
    scale : add ``s``: the ratio of the cloud's spread to the model's (geometric mean of the axes).
    symmetry_tol : relative difference of two spreads below which their axes are permuted.
    samples : surface points drawn from the model to measure its frame.
    seed : seed of that draw.

    Returns
    -------
    list of dicts ``{"tx", "ty", "tz", "rx", "ry", "rz"[, "s"]}`` (``{"tx", "ty", "angle"}`` in 2-D),
    floats; between 4 and 24 candidates in 3-D (2 to 4 in 2-D).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> cloud = rng.normal(size=(4000, 3)) * (3.0, 1.0, 0.2) + (5.0, 0.0, 0.0)   # three distinct spreads
    >>> poses = initial_pose(cloud)
    >>> len(poses), round(poses[0]["tx"])
    (4, 5)
    """
    x, _ = as_tensor(points, "points", fn="initial_pose")
    if x.ndim != 2 or x.shape[1] not in (2, 3) or x.shape[0] < x.shape[1] + 1:
        raise ValueError(f"initial_pose: points must have shape (N, 2) or (N, 3) with N > d, got {tuple(x.shape)}")
    check_finite(x, "points", "initial_pose")
    if model is not None and not isinstance(model, Model):
        raise TypeError(f"initial_pose: model must be a Model or None, got {model!r}")
    if model is not None and model.dim != x.shape[1]:
        raise ValueError(f"initial_pose: points have {x.shape[1]} coordinates, {model.__name__} has dim={model.dim}")
    symmetry_tol = check_option(symmetry_tol, "symmetry_tol", "initial_pose", minimum=0.0, maximum=1.0)
    scale = check_option(scale, "scale", "initial_pose", "bool")
    pts = x.detach().cpu().to(torch.float64).numpy()
    d = pts.shape[1]
    c_d, u_d, s_d = _pca(_robust_cloud(pts))
    if model is None:
        c_m, u_m, s_m = np.zeros(d), np.eye(d), s_d
    else:
        c_m, u_m, s_m = _model_frame(model, params, samples, seed)
    # axes of near-equal spread (in both the cloud and the model) may be swapped
    ref = np.maximum(np.maximum(s_d, s_m), 1e-300)
    groups: list[list[int]] = [[0]]
    for i in range(1, d):
        close_d = abs(s_d[i] - s_d[i - 1]) <= symmetry_tol * ref[i - 1]
        close_m = abs(s_m[i] - s_m[i - 1]) <= symmetry_tol * ref[i - 1]
        if close_d or close_m:
            groups[-1].append(i)
        else:
            groups.append([i])
    s = float(np.exp(np.mean(np.log(np.maximum(s_d, 1e-300) / np.maximum(s_m, 1e-300))))) if scale else 1.0
    out: list[dict[str, float]] = []
    seen: list[np.ndarray] = []
    for p in _signed_permutations(d, groups):
        rot = u_d @ p @ u_m.T
        if any(np.abs(rot - r).max() < 1e-9 for r in seen):
            continue
        seen.append(rot)
        t = c_d - s * rot @ c_m
        if d == 3:
            r = rotation_vector(rot)
            pose = {"tx": t[0], "ty": t[1], "tz": t[2], "rx": r[0], "ry": r[1], "rz": r[2]}
        else:
            pose = {"tx": t[0], "ty": t[1], "angle": math.atan2(rot[1, 0], rot[0, 0])}
        if scale:
            pose["s"] = s
        out.append({k: float(v) for k, v in pose.items()})
    return out
