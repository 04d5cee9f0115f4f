"""Curvatures of the level sets of f from its autograd derivatives (paper section 5.1).

No surface fitting: the curvatures of {f = c} through a point come from grad f and the
Hessian of f there.  Sign convention (f > 0 inside, n = grad f / |grad f| the inward normal):
convex solids have positive curvatures; a sphere of radius r has H = 1/r, K = 1/r^2.

Formulas, with g = grad f, Hf the Hessian, n = g/|g|:

- mean curvature, paper eq. for H: ``H = -1/2 div(n)``.  As
  ``div(g/|g|) = tr Hf / |g| - g^T Hf g / |g|^3``, in closed form
  ``H = (g^T Hf g - |g|^2 tr Hf) / (2 |g|^3)``.
  (Sphere f = r^2 - |x|^2: g = -2x, Hf = -2I, |g| = 2r gives H = (-8r^2 + 24r^2)/(16r^3) = 1/r.)
- Gaussian curvature, paper eq. for K (Goldman 2005, Th. 4.1): ``K = g adj(Hf) g^T / |g|^4``.
- Both are invariants of the shape operator ``S = -T Hf T^T / |g|`` written in an
  orthonormal tangent frame T (rows orthogonal to n): ``H = tr(S)/2``, ``K = det(S)``,
  because ``tr(T Hf T^T) = tr Hf - n^T Hf n`` and ``det(T Hf T^T) = n^T adj(Hf) n``
  (the (n, n) cofactor of Hf in the basis (n, T)).  The eigenvalues of S are the principal
  curvatures ``kmin <= kmax`` (= H -+ sqrt(H^2 - K), with H^2 - K >= 0 by construction) and
  its eigenvectors, mapped back by T, the principal directions.

The fast path (:func:`curvatures` and the single-quantity functions) needs only T Hf T^T:
2 Hessian-vector products after the gradient, i.e. 3 backward passes for everything, all
quantities from ONE evaluation of f (:func:`pyfrep_core.diff.tangent_hessian`).
:func:`curvatures_from_hessian` applies the paper's formulas to a full Hessian; the tests
check that both agree.  Each entry computes only the fields it returns (no eigenvectors for
:func:`gaussian_curvature`).  These are plain reverse passes over chunks of points, which
threads may run at once; per-point ``torch.func`` transforms were measured slower on the Fig. 1
part (``benchmarks/curvature.py``): ``vmap(jacrev(grad))`` about 1.5x the CPU time and
``vmap(hessian)`` (forward mode, which must also stay on one thread: its AD levels are
process-global in torch) 2-3x.

Undefined curvature.  The curvatures of the level set through x exist only where f is twice
differentiable with grad f != 0.  They do not at a critical point (grad f = 0: a sphere's or a
box's centre, a cylinder's axis), nor on a crease or a cone tip of the level set (f1 = f2 = 0 in
an R-function, the axis of a torus, a cone's apex), where the Hessian is unbounded: there
:func:`~pyfrep_core._array.safe_sqrt` makes it finite but of order 1/rho0 (rho0 = tiny^(1/4):
8e76 in float64, 3e9 in float32).  A point is reported *undefined* when

- grad f is 0 or not finite, or the shape operator ``S = -T Hf T^T / |g|`` is not finite; or
- the radius of curvature 1/max|S_ab| is below the resolution of the computation,
  ``eps |x| + sqrt(rho0)`` (eps, tiny of the dtype): the first term is the rounding of the point
  (a gradient that vanishes up to rounding gives a "curvature" of 1/(eps |x|)), the second the
  geometric mean of the regularization's length rho0 and 1 (1e-38 in float64, 2e-5 in float32),
  which keeps a margin of 1/sqrt(rho0) between real radii and those of creases.

At such points EVERY curvature field is NaN (never inf or a huge number) and
``Curvatures.defined`` is False; ``defined`` is True exactly where all fields are finite, so
``c.defined.sum()`` counts the points with a curvature and ``c.H[c.defined]`` leaves the others
out of a colour range.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch

from ._array import named_entry
from .diff import _flat_points, _map_chunks, _out, _tangent_hessian, tangent_frame

__all__ = [
    "Curvatures",
    "curvatures",
    "mean_curvature",
    "gaussian_curvature",
    "principal_curvatures",
    "principal_directions",
    "curvatures_from_hessian",
    "attach_curvatures",
]


class Curvatures(NamedTuple):
    """Curvatures at N points (numpy or torch, following the input).

    Every field is NaN where the curvature is undefined (see the module notes), and only there;
    ``defined`` marks the other points.
    """

    H: Any  # (N,) mean curvature (kmin + kmax) / 2
    K: Any  # (N,) Gaussian curvature kmin * kmax
    kmin: Any  # (N,) smaller principal curvature
    kmax: Any  # (N,) larger principal curvature
    dmin: Any  # (N, 3) unit principal direction of kmin (tangent to the surface)
    dmax: Any  # (N, 3) unit principal direction of kmax
    defined: Any  # (N,) bool: False where the curvature is undefined (all other fields NaN there)


def _shape_operator(g: torch.Tensor, th: torch.Tensor, x: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
    """The shape operator ``S = -th / |g|`` (N, d-1, d-1) and the mask (N,) of points where it is defined.

    Undefined: grad f zero or not finite, S not finite, or a radius of curvature 1/max|S_ab| below
    ``eps |x| + tiny^(1/8)`` (module notes); ``x`` None (no points known) drops the first term.
    """
    norm = torch.linalg.vector_norm(g, dim=-1)
    ok = torch.isfinite(norm) & (norm > 0)
    s = -th / torch.where(ok, norm, torch.ones_like(norm))[:, None, None]
    finfo = torch.finfo(s.dtype)
    resolution = finfo.tiny**0.125
    if x is not None:
        resolution = resolution + finfo.eps * torch.linalg.vector_norm(x.detach(), dim=-1)
    size = s.detach().abs().amax(dim=(-2, -1))
    defined = ok & torch.isfinite(size) & (size * resolution < 1.0)
    return s, defined


def _from_shape_operator(
    g: torch.Tensor,
    frame: torch.Tensor,
    th: torch.Tensor,
    x: torch.Tensor | None = None,
    fields: tuple[str, ...] = Curvatures._fields,
) -> tuple[torch.Tensor, ...]:
    """The ``fields`` of :class:`Curvatures` (in that order) from the tangent Hessian ``th = T Hf T^T``.

    ``th`` (N, 2, 2), the gradient (N, 3), the frame T (N, 2, 3) and the points; a call computes
    only what its fields need (the directions' trigonometry only for ``dmin``/``dmax``).
    """
    s, defined = _shape_operator(g, th, x)
    undefined = ~defined
    s = torch.where(undefined[:, None, None], torch.zeros_like(s), s)  # no inf/NaN in the arithmetic below
    a, b, c = s[:, 0, 0], s[:, 0, 1], s[:, 1, 1]
    nan = torch.full_like(a, float("nan"))
    out = {"defined": defined}
    if {"H", "kmin", "kmax"} & set(fields):
        out["H"] = 0.5 * (a + c)
    if "K" in fields:
        out["K"] = a * c - b * b
    if {"kmin", "kmax"} & set(fields):
        radius = torch.hypot(0.5 * (a - c), b)  # sqrt(H^2 - K) without cancellation, >= 0
        out["kmin"], out["kmax"] = out["H"] - radius, out["H"] + radius
    if {"dmin", "dmax"} & set(fields):
        # the eigenvector of kmax in the frame is (cos t, sin t) with tan 2t = 2b / (a - c)
        angle = 0.5 * torch.atan2(2.0 * b, a - c)
        cos, sin = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
        out["dmax"] = torch.where(undefined[:, None], nan[:, None], cos * frame[:, 0] + sin * frame[:, 1])
        out["dmin"] = torch.where(undefined[:, None], nan[:, None], -sin * frame[:, 0] + cos * frame[:, 1])
    for name in ("H", "K", "kmin", "kmax"):
        if name in out:
            out[name] = torch.where(undefined, nan, out[name])
    return tuple(out[name] for name in fields)


def _curvatures(
    f: Callable, x: Any, create_graph: bool, chunk: int | None, fields: tuple[str, ...] = Curvatures._fields
) -> tuple[tuple, bool, tuple]:
    """The ``fields`` of :class:`Curvatures` at x, chunk by chunk: one evaluation of f and 3 backward passes."""
    t, was_numpy, batch = _flat_points(x, dims=3)

    def one(c: torch.Tensor) -> tuple[torch.Tensor, ...]:
        _, g, frame, th = _tangent_hessian(f, c, create_graph)
        return _from_shape_operator(g, frame, th, c, fields)

    out = one(t) if create_graph else _map_chunks(one, t, chunk)
    return out, was_numpy, batch


@named_entry
def curvatures(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Curvatures:
    """Mean, Gaussian and principal curvatures and principal directions of the level sets of f at x.

    All from one evaluation of f: the gradient and two Hessian-vector products (3 backward
    passes), see the module notes for the formulas and the sign convention.

    Parameters
    ----------
    f : callable (N, 3) -> (N,), f > 0 inside.
    x : (N, 3) points (numpy or torch, float32 or float64, any device); usually on f = 0
        (mesh vertices projected onto the surface), else the curvatures are those of the
        level set through each point.
    create_graph : keep the graph (e.g. a curvature term in a loss); no chunking then.
    chunk : points per pass (default: see :mod:`pyfrep_core.diff`).

    Returns
    -------
    Curvatures(H, K, kmin, kmax, dmin, dmax, defined): every field NaN where the curvature is
    undefined (grad f = 0, a crease or a cone tip: module notes) and ``defined`` False there.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import sphere
    >>> c = curvatures(lambda p: sphere(p, r=2.0), np.array([[0.0, 0.0, 2.0], [1.2, 0.0, 1.6]]))
    >>> c.H, c.K, c.kmin, c.kmax
    (array([0.5, 0.5]), array([0.25, 0.25]), array([0.5, 0.5]), array([0.5, 0.5]))
    >>> c = curvatures(lambda p: sphere(p, r=2.0), np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0]]))
    >>> c.defined, c.H                      # the centre: grad f = 0, no curvature
    (array([False,  True]), array([nan, 0.5]))
    """
    out, was_numpy, batch = _curvatures(f, x, create_graph, chunk)
    return _out(Curvatures(*out), was_numpy, batch)


@named_entry
def mean_curvature(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Mean curvature H = -1/2 div(grad f / |grad f|) (paper eq. for H), shape (N,).

    For points in the plane (N, 2) this is the curvature of the curve f = c,
    ``-div(grad f / |grad f|)`` (a circle of radius r: 1/r).  NaN where the curvature is
    undefined (grad f = 0, a crease or a cone tip: the rule of :func:`curvatures`).

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import cylZ
    >>> mean_curvature(lambda p: cylZ(p, r=0.5), torch.tensor([[0.5, 0.0, 3.0]], dtype=torch.float64))
    tensor([1.], dtype=torch.float64)
    """
    t, was_numpy, batch = _flat_points(x, dims=(2, 3))

    def one(c: torch.Tensor) -> tuple[torch.Tensor]:
        _, g, _, th = _tangent_hessian(f, c, create_graph)
        s, defined = _shape_operator(g, th, c)
        # H = tr(S) / (d - 1) with the shape operator S = -T Hf T^T / |g|
        h = s.diagonal(dim1=-2, dim2=-1).sum(-1) / (c.shape[-1] - 1)
        return (torch.where(defined, h, torch.full_like(h, float("nan"))),)

    (h,) = one(t) if create_graph else _map_chunks(one, t, chunk)
    return _out(h, was_numpy, batch)


@named_entry
def gaussian_curvature(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Gaussian curvature K = grad f adj(Hf) grad f^T / |grad f|^4 (paper eq. for K), shape (N,).

    NaN where the curvature is undefined (the rule of :func:`curvatures`).

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import sphere
    >>> gaussian_curvature(lambda p: sphere(p, r=0.5), np.array([[0.0, 0.5, 0.0]]))
    array([4.])
    """
    (gauss,), was_numpy, batch = _curvatures(f, x, create_graph, chunk, ("K",))
    return _out(gauss, was_numpy, batch)


@named_entry
def principal_curvatures(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> tuple:
    """Principal curvatures (kmin, kmax), each (N,): ``H -+ sqrt(max(H^2 - K, 0))``.

    NaN where the curvature is undefined (the rule of :func:`curvatures`).

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import cylX
    >>> principal_curvatures(lambda p: cylX(p, r=0.25), np.array([[1.0, 0.0, 0.25]]))
    (array([0.]), array([4.]))
    """
    out, was_numpy, batch = _curvatures(f, x, create_graph, chunk, ("kmin", "kmax"))
    return _out(out, was_numpy, batch)


@named_entry
def principal_directions(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> tuple:
    """Unit principal directions (dmin, dmax), each (N, 3), tangent to the level set.

    They are the eigenvectors of the shape operator restricted to the tangent plane, for
    kmin and kmax.  At umbilic points (kmin = kmax) every tangent direction is principal and
    an arbitrary orthonormal pair is returned.  NaN where the curvature is undefined (the rule
    of :func:`curvatures`).

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import cylZ
    >>> dmin, dmax = principal_directions(lambda p: cylZ(p, r=1.0), np.array([[1.0, 0.0, 0.0]]))
    >>> np.abs(dmin).round(12), np.abs(dmax).round(12)
    (array([[0., 0., 1.]]), array([[0., 1., 0.]]))
    """
    out, was_numpy, batch = _curvatures(f, x, create_graph, chunk, ("dmin", "dmax"))
    return _out(out, was_numpy, batch)


@named_entry
def curvatures_from_hessian(g: Any, hess: Any, x: Any = None) -> Curvatures:
    """The paper's formulas applied to a gradient (N, 3) and a full Hessian (N, 3, 3).

    ``H = (g^T Hf g - |g|^2 tr Hf) / (2 |g|^3)``, ``K = g adj(Hf) g^T / |g|^4``,
    ``kmin, kmax = H -+ sqrt(max(H^2 - K, 0))``; directions from Hf projected on a tangent
    frame.  Use it with a Hessian from :func:`pyfrep_core.diff.hessian` (or any other
    source); :func:`curvatures` gets the same values with one backward pass less.
    Undefined points (NaN in every field, ``defined`` False) follow the rule of
    :func:`curvatures`; pass the points ``x`` (N, 3) for its rounding term ``eps |x|``.

    Examples
    --------
    >>> import numpy as np
    >>> g = np.array([[0.0, 0.0, -2.0]])   # sphere r = 1 at its north pole
    >>> c = curvatures_from_hessian(g, -2.0 * np.eye(3)[None])
    >>> c.H, c.K
    (array([1.]), array([1.]))
    """
    gt, was_numpy = (torch.from_numpy(np.asarray(g)), True) if not isinstance(g, torch.Tensor) else (g, False)
    ht = torch.from_numpy(np.asarray(hess)) if not isinstance(hess, torch.Tensor) else hess
    if gt.ndim != 2 or gt.shape[-1] != 3 or ht.shape != (gt.shape[0], 3, 3):
        raise ValueError(f"g must be (N, 3) and hess (N, 3, 3), got {tuple(gt.shape)} and {tuple(ht.shape)}")
    xt = None if x is None else torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x)
    if xt is not None and xt.shape != gt.shape:
        raise ValueError(f"x must be (N, 3) like g, got {tuple(xt.shape)} for g {tuple(gt.shape)}")
    ht = 0.5 * (ht + ht.transpose(1, 2))
    norm = torch.linalg.vector_norm(gt, dim=-1)
    safe = torch.where(torch.isfinite(norm) & (norm > 0), norm, torch.ones_like(norm))
    ghg = torch.einsum("ni,nij,nj->n", gt, ht, gt)
    trace = ht.diagonal(dim1=-2, dim2=-1).sum(-1)
    mean = (ghg - norm**2 * trace) / (2.0 * safe**3)
    gauss = torch.einsum("ni,nij,nj->n", gt, _adjugate3(ht), gt) / safe**4
    root = torch.sqrt(torch.clamp(mean * mean - gauss, min=0.0))
    frame = tangent_frame(gt / safe[:, None])
    th = torch.einsum("nai,nij,nbj->nab", frame, ht, frame)
    dmin, dmax, defined = _from_shape_operator(gt, frame, th, xt, ("dmin", "dmax", "defined"))
    nan = torch.full_like(mean, float("nan"))
    values = [torch.where(defined, v, nan) for v in (mean, gauss, mean - root, mean + root)]
    out = Curvatures(*values, dmin, dmax, defined)
    return _out(out, was_numpy)


def _adjugate3(m: torch.Tensor) -> torch.Tensor:
    """Adjugate (transposed cofactor matrix) of (N, 3, 3) matrices: adj(M) M = det(M) I."""
    rows = []
    for i in range(3):
        row = []
        for j in range(3):
            # cofactor C_ji, with the cyclic index trick: no sign bookkeeping
            a, b = (j + 1) % 3, (j + 2) % 3
            c, d = (i + 1) % 3, (i + 2) % 3
            row.append(m[:, a, c] * m[:, b, d] - m[:, a, d] * m[:, b, c])
        rows.append(torch.stack(row, dim=-1))
    return torch.stack(rows, dim=1)


CURVATURE_FIELDS = {
    "mean_curvature": "H",
    "gaussian_curvature": "K",
    "kmin": "kmin",
    "kmax": "kmax",
    "principal_direction_min": "dmin",
    "principal_direction_max": "dmax",
}


@named_entry
def attach_curvatures(mesh: Any, f: Callable, chunk: int | None = None) -> Any:
    """Curvatures of f at a mesh's vertices, stored in ``mesh.point_data`` (returns the mesh).

    The vertices are used as they are: :func:`pyfrep_core.polygonize` has already moved them
    onto f = 0.  Keys: ``mean_curvature``, ``gaussian_curvature``, ``kmin``, ``kmax`` (V,) and
    ``principal_direction_min``, ``principal_direction_max`` (V, 3), float64; they are written
    with the mesh (PLY/VTK) and colour it in the workbench.

    Examples
    --------
    >>> from pyfrep_core import polygonize, sphere
    >>> ball = lambda p: sphere(p, r=1.0)
    >>> m = attach_curvatures(polygonize(ball, ((-1.1,) * 3, (1.1,) * 3), 16), ball)
    >>> bool(abs(m.point_data["mean_curvature"] - 1.0).max() < 1e-9)
    True
    """
    if mesh.n_vertices == 0:
        raise ValueError("the mesh has no vertices")
    c = curvatures(f, torch.as_tensor(np.asarray(mesh.vertices, dtype=np.float64)), chunk=chunk)
    for key, field in CURVATURE_FIELDS.items():
        mesh.point_data[key] = getattr(c, field).cpu().numpy()
    return mesh
