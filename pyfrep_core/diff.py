"""Spatial and parameter derivatives of defining functions by reverse-mode autodiff (paper section 4).

This module is the only place that calls autograd for spatial derivatives: the gradient
(paper Fig. 5), the divergence of a vector field (Fig. 6), the Laplacian, the p-Laplacian,
the Hessian, derivatives with respect to a model's named parameters, and the Newton
projection of points onto f = 0.  :mod:`pyfrep_core.curvature` and
:mod:`pyfrep_core.normalization` build on it.

Conventions shared by every function here:

- ``f`` maps points (N, d) to values (N,); a vector field ``v`` maps (N, d) to (N, d).
- numpy in gives numpy out, torch in gives torch out (same dtype and device); float32 and
  float64 both work.  Points with NaN or inf raise ValueError.
- ``create_graph=True`` keeps the autograd graph so the result can enter a loss (then the
  points are processed in one piece).  Otherwise points are processed in chunks: on the CPU
  chunks whose (N, 3) temporaries take 192 KiB (8192 points in float64, 16384 in float32) and
  stay in cache, spread over ``torch.get_num_threads()``
  threads (autograd releases the GIL), which is 1.5-2x faster than one big batch even on one
  thread (measured by ``benchmarks/curvature.py``); on other devices chunks of 2^18 points.
- Points are independent, so one backward pass gives a derivative at all points at once:
  the gradient costs one pass, the Hessian one more pass per row, the divergence one pass
  per component.  No loop runs over points.
- Where an R-function has f1 = f2 = 0, ``safe_sqrt`` keeps first derivatives finite (the
  sub-gradient); second derivatives there are finite but huge (~1/sqrt(tiny)), as the
  surface has a crease.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import math
import threading
import warnings
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import torch

from ._array import as_tensor, check_finite, check_memory, check_option, check_points, named_entry, validated_inputs
from .compiled import CompiledModel, first_order
from .evaluate import call, call_budget, name_of, remember_refusal, vmap_refused

__all__ = [
    "value_and_grad",
    "grad",
    "value_grad_hessian",
    "hessian",
    "tangent_frame",
    "tangent_hessian",
    "div",
    "laplacian",
    "p_laplacian",
    "param_grad",
    "Projection",
    "project_to_surface",
]

CHUNK = 1 << 18  # points per autograd pass on accelerators: bounds memory
CPU_CHUNK_BYTES = 8192 * 3 * 8  # an (N, 3) temporary of a pass on the CPU: the temporaries stay in cache

_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


# ----------------------------------------------------------------------------- plumbing


def _workers() -> ThreadPoolExecutor:
    """A process-wide pool of ``torch.get_num_threads()`` threads for chunked CPU passes."""
    global _pool
    n = max(1, torch.get_num_threads())
    with _pool_lock:
        if _pool is None or _pool._max_workers != n:
            _pool = ThreadPoolExecutor(max_workers=n, thread_name_prefix="pyfrep-diff")
        return _pool


def _chunk_size(x: torch.Tensor, chunk: int | None) -> int:
    if chunk is None:
        return CPU_CHUNK_BYTES // (3 * x.element_size()) if x.device.type == "cpu" else CHUNK
    if isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    return chunk


def _map_chunks(fn: Callable, x: torch.Tensor, chunk: int | None, parallel: bool = True) -> tuple:
    """``fn(x[i:i+chunk])`` over chunks of rows of ``x``; the outputs (tuples of tensors) concatenated."""
    size = _chunk_size(x, chunk)
    n = x.shape[0]
    # the entries check x once (_flat_points); the primitives of f do not read it again, here or in a worker
    with validated_inputs():
        if n <= size:
            return fn(x)
        # not from inside a worker (an f that itself differentiates): waiting on the pool could deadlock
        nested = threading.current_thread().name.startswith("pyfrep-diff")
        threads = torch.get_num_threads()
        pooled = parallel and not nested and x.device.type == "cpu" and threads > 1
        if pooled:  # a multiple of the threads in equal pieces (none larger than asked): no thread idles at the end
            count = -(-n // size)
            size = -(-n // (-(-count // threads) * threads))
        pieces = [x[i : i + size] for i in range(0, n, size)]
        if pooled:
            contexts = [contextvars.copy_context() for _ in pieces]  # one copy per task: a context runs once at a time
            results = list(_workers().map(lambda c, p: c.run(fn, p), contexts, pieces))
        else:
            results = [fn(p) for p in pieces]
    return tuple(torch.cat(parts) for parts in zip(*results))


def _flat_points(
    x: Any, name: str = "x", dims: int | Sequence[int] = (1, 2, 3, 4), flat: bool = True
) -> tuple[torch.Tensor, bool, tuple[int, ...]]:
    """Validated floating tensor of points as (N, d), whether it came in as numpy, and its batch shape.

    Points of shape (..., d) are flattened to (N, d) when ``flat`` (results are reshaped back
    by :func:`_out`); otherwise exactly (N, d) is required.
    """
    t, was_numpy = as_tensor(x, name)
    check_points(t, dim=dims, name=name)
    if t.ndim != 2 and not flat:
        raise ValueError(f"{name} must have shape (N, d), got {tuple(t.shape)}")
    check_finite(t.detach(), name)
    batch = tuple(t.shape[:-1])
    return t.reshape(-1, t.shape[-1]), was_numpy, batch


def _out(value: Any, was_numpy: bool, batch: tuple[int, ...] | None = None) -> Any:
    """Reshape per-point results (N, ...) to ``batch + (...)``; numpy when the input was numpy."""
    if isinstance(value, torch.Tensor):
        if batch is not None and len(batch) != 1:
            value = value.reshape(*batch, *value.shape[1:])
        return value.detach().cpu().numpy() if was_numpy else value
    if isinstance(value, tuple):
        items = [_out(v, was_numpy, batch) for v in value]
        return type(value)(*items) if hasattr(value, "_fields") else tuple(items)
    if isinstance(value, dict):
        return {k: _out(v, was_numpy, batch) for k, v in value.items()}
    return value


def _leaf(x: torch.Tensor, create_graph: bool) -> torch.Tensor:
    """The tensor to differentiate with respect to: ``x`` itself when a graph is kept to it."""
    return x if (create_graph and x.requires_grad) else x.detach().requires_grad_(True)


def _vjp(
    y: torch.Tensor,
    xr: torch.Tensor,
    cotangent: torch.Tensor | None = None,
    create_graph: bool = True,
    retain_graph: bool = True,
):
    """sum_i cotangent_i * d y_i / d x, one backward pass; zeros where y does not depend on x.

    The graph of ``y`` is kept (``retain_graph``) so further passes can follow; a last pass
    frees it (a compiled model's backward, which reuses its saved buffers, requires that).
    """
    if not y.requires_grad:
        return torch.zeros_like(xr)
    if cotangent is None:
        y, cotangent = y.sum(), None
    (g,) = torch.autograd.grad(
        y, xr, cotangent, retain_graph=retain_graph, create_graph=create_graph, allow_unused=True
    )
    return torch.zeros_like(xr) if g is None else g


def _derivatives(f: Callable, x: torch.Tensor, order: int, create_graph: bool) -> tuple[torch.Tensor, ...]:
    """f, grad f and (order 2) the Hessian at x (N, d): 1 backward pass + d for the Hessian rows."""
    if order == 1 and not create_graph:
        fused = _fused_first_order(f, x)
        if fused is not None:
            return fused
    # one backward pass and no graph kept: a compiled model may differentiate its fused kernel
    once = first_order() if order == 1 and not create_graph else contextlib.nullcontext()
    with torch.enable_grad():
        xr = _leaf(x, create_graph)
        with once:
            y = call(f, xr, label=name_of(f))
        last = order == 1 and not create_graph  # the only pass: nothing needs the graph after it
        g = _vjp(y, xr, create_graph=create_graph or order > 1, retain_graph=not last)
        if order == 1:
            out = (y, g)
        else:
            rows = [_vjp(g[:, i], xr, torch.ones_like(g[:, i]), create_graph) for i in range(x.shape[-1])]
            out = (y, g, torch.stack(rows, dim=1))
    return out if create_graph else tuple(t.detach() for t in out)


def _compiled_of(f: Callable) -> tuple[CompiledModel, dict[str, Any]] | None:
    """The compiled model f is, or that ``functools.partial(model, **params)`` binds, with the params."""
    params: dict[str, Any] = {}
    if isinstance(f, functools.partial) and not f.args:
        f, params = f.func, dict(f.keywords)
    return (f, params) if isinstance(f, CompiledModel) else None


def _fused_first_order(f: Callable, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
    """f and grad f from a compiled model's fused kernel (:meth:`CompiledModel.value_and_grad`), for the
    model itself or ``functools.partial(model, **params)``; None for any other f, or where it declines."""
    found = _compiled_of(f)
    return None if found is None else found[0].value_and_grad(x, **found[1])


# ----------------------------------------------------------------------------- first derivatives


def _value_and_grad(f: Callable, x: torch.Tensor, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """f(x) and grad f(x) for x (N, d); one backward pass.  Keeps the graph if asked."""
    return _derivatives(f, x, 1, create_graph)


@named_entry
def value_and_grad(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> tuple[Any, Any]:
    """f(x) and its spatial gradient (one backward pass), evaluated in chunks.

    Parameters
    ----------
    f : callable, (N, d) -> (N,)
    x : (N, d) points, numpy or torch, float32 or float64, any device.
    create_graph : keep the graph (for use inside a loss); then no chunking is done.
    chunk : points per pass; default on the CPU 8192 in float64, 16384 in float32 (in parallel threads), for a
        compiled model up to its ``chunk_points`` (one piece per thread); 2^18 elsewhere.

    Returns
    -------
    values (N,), gradients (N, d): same kind (numpy/torch), dtype and device as ``x``.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import sphere
    >>> v, g = value_and_grad(lambda p: sphere(p, r=1.0), np.array([[0.5, 0.0, 0.0]]))
    >>> v, g
    (array([0.75]), array([[-1., -0., -0.]]))
    """
    t, was_numpy, batch = _flat_points(x)
    if create_graph:
        y, g = _value_and_grad(f, t, True)
    else:
        found = _compiled_of(f) if chunk is None and t.device.type == "cpu" else None
        if found is not None:  # a fused kernel: calls as large as its chunk, one piece per thread
            per_thread = -(-t.shape[0] // max(1, torch.get_num_threads()))
            chunk = max(_chunk_size(t, None), min(found[0].chunk_points, per_thread))
        y, g = _map_chunks(lambda c: _value_and_grad(f, c), t, chunk)
    return _out((y, g), was_numpy, batch)


@named_entry
def grad(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Spatial gradient grad f(x), shape (N, d) (paper Fig. 5).

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> grad(lambda p: sphere(p, r=1.0), torch.tensor([[0.0, 1.0, 0.0]]))
    tensor([[-0., -2., -0.]])
    """
    return value_and_grad(f, x, create_graph=create_graph, chunk=chunk)[1]


# ----------------------------------------------------------------------------- second derivatives


def _vgh(f: Callable, t: torch.Tensor, create_graph: bool, chunk: int | None) -> tuple[torch.Tensor, ...]:
    if create_graph:
        return _derivatives(f, t, 2, True)
    return _map_chunks(lambda c: _derivatives(f, c, 2, False), t, chunk)


@named_entry
def value_grad_hessian(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> tuple:
    """f, grad f (N, d) and the Hessian (N, d, d) from one evaluation of f: 1 + d backward passes.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> v, g, h = value_grad_hessian(lambda p: sphere(p, r=1.0), torch.tensor([[0.0, 0.5, 0.0]]))
    >>> v, h[0]
    (tensor([0.7500]), tensor([[-2., 0., 0.],
            [0., -2., 0.],
            [0., 0., -2.]]))
    """
    t, was_numpy, batch = _flat_points(x)
    return _out(tuple(_vgh(f, t, create_graph, chunk)), was_numpy, batch)


@named_entry
def hessian(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """The Hessian of f at each point, (N, d, d): row i is grad (df/dx_i), one backward pass per row.

    Examples
    --------
    >>> import numpy as np
    >>> hessian(lambda p: p[:, 0] * p[:, 1] ** 2, np.array([[1.0, 3.0]]))
    array([[[0., 6.],
            [6., 2.]]])
    """
    return value_grad_hessian(f, x, create_graph=create_graph, chunk=chunk)[2]


@named_entry
def laplacian(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Laplacian ``div grad f`` (N,), the trace of the Hessian (paper section 4).

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> laplacian(lambda p: sphere(p, r=1.0), torch.zeros(2, 3))
    tensor([-6., -6.])
    """
    t, was_numpy, batch = _flat_points(x)
    h = _vgh(f, t, create_graph, chunk)[2]
    return _out(h.diagonal(dim1=-2, dim2=-1).sum(-1), was_numpy, batch)


@named_entry
def p_laplacian(f: Callable, x: Any, p: float, create_graph: bool = False, chunk: int | None = None) -> Any:
    """p-Laplacian ``div(|grad f|^(p-2) grad f)`` (N,), in closed form from grad f and the Hessian.

    With g = grad f, Hf its Hessian and n = g/|g|:
    ``div(|g|^(p-2) g) = |g|^(p-2) (tr Hf + (p - 2) n^T Hf n)``.  p = 2 is the Laplacian.
    Where g = 0 the value is 0 for p > 2, the Laplacian for p = 2 and NaN for p < 2
    (the operator is singular there).

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> p_laplacian(lambda q: sphere(q, r=1.0), torch.tensor([[0.5, 0.0, 0.0]]), p=3)
    tensor([-8.])
    """
    if isinstance(p, bool) or not isinstance(p, int | float) or not math.isfinite(p) or p <= 1:
        raise ValueError(f"p must be a finite number > 1, got {p!r}")
    t, was_numpy, batch = _flat_points(x)
    _, g, h = _vgh(f, t, create_graph, chunk)
    norm = torch.linalg.vector_norm(g, dim=-1)
    zero = norm == 0
    safe = torch.where(zero, torch.ones_like(norm), norm)
    n = g / safe.unsqueeze(-1)
    trace = h.diagonal(dim1=-2, dim2=-1).sum(-1)
    nhn = torch.einsum("ni,nij,nj->n", n, h, n)
    value = safe ** (p - 2) * (trace + (p - 2) * nhn)
    at_zero = trace if p == 2 else torch.full_like(trace, 0.0 if p > 2 else math.nan)
    return _out(torch.where(zero, at_zero, value), was_numpy, batch)


def tangent_frame(n: torch.Tensor) -> torch.Tensor:
    """Orthonormal bases (N, d-1, d) of the planes orthogonal to unit vectors ``n`` (N, d), d = 2 or 3.

    2-D: the normal turned by +90 degrees.  3-D: the branchless construction of Duff et al.,
    "Building an orthonormal basis, revisited" (JCGT 2017), continuous except across n_z = 0
    and exact to rounding for every unit ``n``.  Rows ``t_a`` satisfy ``t_a . n = 0``,
    ``t_a . t_b = delta_ab``, and (for d = 3) ``t_0 x t_1 = n``.

    Examples
    --------
    >>> import torch
    >>> tangent_frame(torch.tensor([[0.0, 0.6, 0.8]])).abs()
    tensor([[[1.0000, 0.0000, 0.0000],
             [0.0000, 0.8000, 0.6000]]])
    """
    d = n.shape[-1]
    if d == 2:
        return torch.stack([-n[:, 1], n[:, 0]], dim=-1).unsqueeze(1)
    if d != 3:
        raise ValueError(f"tangent frames are built for d = 2 or 3, got points of dimension {d}")
    nx, ny, nz = n.unbind(-1)
    s = torch.where(nz >= 0, torch.ones_like(nz), -torch.ones_like(nz))
    a = -1.0 / (s + nz)
    b = nx * ny * a
    t0 = torch.stack([1.0 + s * nx * nx * a, s * b, -s * nx], dim=-1)
    t1 = torch.stack([b, s + ny * ny * a, -ny], dim=-1)
    return torch.stack([t0, t1], dim=1)


def _tangent_hessian(f: Callable, x: torch.Tensor, create_graph: bool) -> tuple[torch.Tensor, ...]:
    """f, grad f, a tangent frame T (N, d-1, d) and T Hf T^T (N, d-1, d-1): 1 + (d-1) backward passes."""
    if not create_graph and isinstance(f, CompiledModel):
        fused = f.tangent_hessian(x)  # the same passes, traced and compiled once
        if fused is not None:
            return fused
    with torch.enable_grad():
        xr = _leaf(x, create_graph)
        y = call(f, xr, label=name_of(f))
        g = _vjp(y, xr, create_graph=True)
        # the frame follows x inside a kept graph, so curvature derivatives see the turning normal
        gn = g if create_graph else g.detach()
        norm = torch.linalg.vector_norm(gn, dim=-1, keepdim=True)
        frame = tangent_frame(gn / torch.where(norm > 0, norm, torch.ones_like(norm)))
        # stored component-major (each of the 2 x 3 entries a contiguous column of N): the loops of
        # a fused kernel (CompiledModel.tangent_hessian) that read it then vectorize
        frame = frame.permute(1, 2, 0).contiguous().permute(2, 0, 1)
        # Hessian-vector products H t_a: one backward pass each (H is symmetric)
        hv = torch.stack([_vjp(g, xr, frame[:, a], create_graph) for a in range(frame.shape[1])], dim=1)
        proj = torch.einsum("nad,nbd->nab", frame, hv)
        proj = 0.5 * (proj + proj.transpose(1, 2))
    out = (y, g, frame, proj)
    return out if create_graph else tuple(t.detach() for t in out)


@named_entry
def tangent_hessian(f: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> tuple:
    """The Hessian of f restricted to the tangent space of its level set, for curvatures.

    With n = grad f / |grad f| and an orthonormal tangent frame T (rows t_a orthogonal to n,
    :func:`tangent_frame`), returns ``T Hf T^T``: its entries ``t_a . Hf t_b`` come from
    d - 1 Hessian-vector products (one backward pass each) instead of the d passes of the
    full Hessian.  This is all curvature needs: the shape operator of the level set in the
    frame is ``-T Hf T^T / |grad f|`` (:mod:`pyfrep_core.curvature`).

    Parameters
    ----------
    f : callable (N, d) -> (N,), d = 2 or 3.
    x : (N, d) points.

    Returns
    -------
    value (N,), gradient (N, d), frame (N, d-1, d), tangent Hessian (N, d-1, d-1), symmetric.
    Where grad f = 0 the frame is arbitrary (that of n = 0).

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> _, g, frame, th = tangent_hessian(lambda p: sphere(p, r=1.0), torch.tensor([[0.0, 0.0, 1.0]]))
    >>> th
    tensor([[[-2.,  0.],
             [ 0., -2.]]])
    """
    t, was_numpy, batch = _flat_points(x, dims=(2, 3))
    if create_graph:
        out = _tangent_hessian(f, t, True)
    else:
        out = _map_chunks(lambda c: _tangent_hessian(f, c, False), t, chunk)
    return _out(tuple(out), was_numpy, batch)


def _div(v: Callable, x: torch.Tensor, create_graph: bool) -> tuple[torch.Tensor]:
    with torch.enable_grad():
        xr = _leaf(x, create_graph)
        y = v(xr)
        if not isinstance(y, torch.Tensor) or y.shape != xr.shape:
            shape = tuple(y.shape) if isinstance(y, torch.Tensor) else type(y).__name__
            raise ValueError(f"v must map points {tuple(xr.shape)} to vectors {tuple(xr.shape)}, got {shape}")
        total = sum(_vjp(y[:, i], xr, torch.ones_like(y[:, i]), create_graph)[:, i] for i in range(x.shape[-1]))
    return (total if create_graph else total.detach(),)


@named_entry
def div(v: Callable, x: Any, create_graph: bool = False, chunk: int | None = None) -> Any:
    """Divergence of a vector field ``v`` (N, d) -> (N, d) at x (paper Fig. 6): one pass per component.

    Examples
    --------
    >>> import torch
    >>> div(lambda p: p * p, torch.tensor([[1.0, 2.0, 3.0]]))
    tensor([12.])
    """
    t, was_numpy, batch = _flat_points(x)
    if create_graph:
        (out,) = _div(v, t, True)
    else:
        (out,) = _map_chunks(lambda c: _div(v, c, False), t, chunk)
    return _out(out, was_numpy, batch)


# ----------------------------------------------------------------------------- shape parameters

# a per-sample pass's (n,) temporaries stay under glibc's 128 KiB mmap threshold: heap blocks, not a fresh
# mmap and page faults per temporary (2^14 points in float64: 2x faster than 2^15 with the threshold fixed,
# as benchmarks/sensitivity.py runs; 1.2x slower without; 8192 pays vmap's per-call cost)
PARAM_CPU_CHUNK_BYTES = 124 << 10
PARAM_POINT_BYTES = 16 << 10  # bytes one point may take in a per-sample pass (its share of the model's graph)


def _param_chunk(x: torch.Tensor, chunk: int | None) -> int:
    """Points per per-sample pass: ``chunk`` if given, else the default chunk capped by the memory budget.

    The budget is the kernel's one call budget (:func:`pyfrep_core.evaluate.call_budget`, on the
    points' device) at ``PARAM_POINT_BYTES`` a point: a chunk's working set is O(chunk x P) plus
    its share of the model's graph, never O(N^2).
    """
    if chunk is not None:
        return _chunk_size(x, chunk)
    size = PARAM_CPU_CHUNK_BYTES // x.element_size() if x.device.type == "cpu" else CHUNK
    return max(64, min(size, call_budget(x.device) // PARAM_POINT_BYTES))


def _param_jacobian(
    fn: Callable,
    x: torch.Tensor,
    values: Mapping[str, Any],
    names: Sequence[str],
    create_graph: bool = False,
    chunk: int | None = None,
    label: str = "model",
    spatial: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """df(x_i)/dp_j, (N, P): the one implementation of per-point parameter derivatives.

    Per-sample reverse mode over chunks of points: ``f_one_point(x_i, *p)`` calls
    ``fn(x_i[None], **params)`` (a (1, d) tensor and 0-d parameters: the model contract) and
    returns the scalar; ``torch.func.vmap`` runs it over the chunk's points with each
    differentiated parameter given per sample (``p + delta_i``, ``delta`` an (n,) zero leaf, so
    inside the model every parameter is 0-d), and one reverse pass of ``sum_i f_i`` gives
    ``d f_i / d delta_i = df(x_i)/dp`` for all P parameters at once (sample i depends on its own
    delta_i only: vmap guarantees it, whatever the model's code does with its parameters, so
    nothing can broadcast to N x N).  This is ``vmap(grad(f_one_point))`` (``jacrev`` for the
    N x P Jacobian) with the reverse pass taken once outside the vmap: the same values bit for
    bit, 1.1-1.7x faster on the paper's models (``benchmarks/sensitivity.py``).  Memory is
    O(chunk x P) plus a chunk's graph (:func:`_param_chunk`).  Reverse mode keeps no
    process-global state, so calls from several threads at once are exact (forward-mode AD
    levels are global in torch).

    A model that ``vmap`` cannot run (``.item()`` on a point's value, Python ``if`` on a value)
    falls back to one reverse pass per point, with one RuntimeWarning naming the model.  A
    :class:`~pyfrep_core.compiled.CompiledModel` evaluates eagerly under ``torch.func`` (see
    :mod:`pyfrep_core.compiled`), so the derivative is the eager model's.

    ``values`` holds every parameter (floats or 0-d tensors), ``names`` those to differentiate
    by.  With ``create_graph`` the result stays attached to tensors in ``values`` (and to ``x``)
    that require grad, in one piece; otherwise it is detached and chunks run in parallel threads.
    ``spatial``: also grad f (N, d), from the same forward and reverse pass (the points are
    differentiated by too: sample i depends on x_i only), returned as ``(df/dp, grad f)``.
    """
    names = list(names)
    n = x.shape[0]
    if not names and not spatial:
        return x.new_zeros(n, 0)
    check_memory(
        2.0 * n * len(names) * x.element_size(),
        label,
        f"df/dp at {n} points for {len(names)} parameters",
        "pass fewer points at a time",
    )

    def as_primal(name: str, v: Any) -> torch.Tensor:
        if isinstance(v, torch.Tensor):
            if v.ndim != 0:
                raise ValueError(f"{label}: parameter {name} must be a scalar, got shape {tuple(v.shape)}")
            v = v.to(dtype=x.dtype, device=x.device)
            return v if create_graph else v.detach()
        return torch.tensor(float(v), dtype=x.dtype, device=x.device)

    # the parameters differentiated by are 0-d tensors; the others reach the model as they came
    primals = tuple(as_primal(name, values[name]) for name in names)
    fixed = {k: (v if create_graph or not isinstance(v, torch.Tensor) else v.detach()) for k, v in values.items()}
    for name in names:
        del fixed[name]

    def f_one_point(xi: torch.Tensor, *pv: torch.Tensor) -> torch.Tensor:
        y = call(fn, xi.unsqueeze(0), {**fixed, **dict(zip(names, pv))}, label=label)
        return y.reshape(()).to(xi.dtype)

    per_sample = torch.func.vmap(f_one_point)

    def jacobian(xc: torch.Tensor, batched: bool) -> tuple[torch.Tensor, ...]:
        deltas = [torch.zeros(xc.shape[0], dtype=xc.dtype, device=xc.device, requires_grad=True) for _ in names]
        with torch.enable_grad():
            xs = _leaf(xc, create_graph) if spatial else xc
            wrt = [*deltas, xs] if spatial else deltas
            pv = [p + d for p, d in zip(primals, deltas)]  # p exactly; sample i's own copy to differentiate by
            if batched:
                y = per_sample(xs, *pv)
            else:  # one point at a time, for models vmap cannot run
                y = torch.stack([f_one_point(xs[i], *(q[i] for q in pv)) for i in range(xc.shape[0])])
            if not y.requires_grad:
                g = [None] * len(wrt)
            else:
                g = torch.autograd.grad(y.sum(), wrt, create_graph=create_graph, allow_unused=True)
        g = [torch.zeros_like(w) if gj is None else gj for gj, w in zip(g, wrt)]
        jac = torch.stack(g[: len(names)], dim=1) if names else xc.new_zeros(xc.shape[0], 0)
        return (jac, g[-1]) if spatial else (jac,)

    def chunk_fn(xc: torch.Tensor) -> tuple[torch.Tensor, ...]:
        xin = xc if create_graph else xc.detach()
        if vmap_refused(fn):
            out = jacobian(xin, False)
        else:
            try:
                out = jacobian(xin, True)
            except RuntimeError as err:  # vmap cannot run this model: per point, with one warning per model
                remember_refusal(fn, label, str(err).splitlines()[0] if str(err) else type(err).__name__)
                out = jacobian(xin, False)
        return out if create_graph else tuple(t.detach() for t in out)

    out = chunk_fn(x) if create_graph else _map_chunks(chunk_fn, x, _param_chunk(x, chunk))
    return out if spatial else out[0]


@named_entry
def param_grad(
    model: Any, x: Any, params: Mapping[str, Any] | None = None, create_graph: bool = False, chunk: int | None = None
) -> dict[str, Any]:
    """d f / d p at each point for every named parameter p of a Model (paper section 4).

    Per-sample reverse mode (:func:`torch.func.vmap` of :func:`torch.func.grad` over the
    points, the model called with one point (1, d) and 0-d parameters at a time): one reverse
    pass gives all parameters' derivatives at a chunk of points.  Any model that maps (N, d) to
    (N,) works, whether or not it broadcasts parameters (tuples of parameters as centres,
    ``p[:, i]`` indexing ...); memory is O(N x P), chunked by a memory budget; calls from
    several threads at once give the serial result exactly.  A compiled model
    (:func:`pyfrep_core.compiled.compiled`) is differentiated eagerly.

    Parameters
    ----------
    model : :class:`pyfrep_core.model.Model`
    x : (N, dim) points.
    params : name -> value overriding the defaults (validated against the declared ranges);
        tensors keep their graph when ``create_graph`` is set.
    create_graph : keep the graph to ``x`` and to parameter tensors that require grad (the
        derivatives can then enter a loss); all points are processed in one piece.
    chunk : points per pass; default on the CPU 15872 in float64, 31744 in float32 (in parallel
        threads), 2^18 elsewhere, fewer when the available memory is short.

    Returns
    -------
    dict name -> (N,) derivative, same kind/dtype/device as ``x``; in declaration order.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core import model, Param, sphere
    >>> @model(r=Param(0.5, 0.1, 1.0), cx=Param(0.0, -1.0, 1.0))
    ... def ball(x, r, cx):
    ...     return sphere(x, center=(cx, 0.0, 0.0), r=r)  # r^2 - |x - c|^2
    >>> param_grad(ball, np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), {"r": 0.75})
    {'r': array([1.5, 1.5]), 'cx': array([0., 2.])}
    """
    from .model import Model

    if not isinstance(model, Model):
        raise TypeError(f"model must be a pyfrep_core Model (declared with @model), got {type(model).__name__}")
    values = model.check(**dict(params or {}))
    t, was_numpy, batch = _flat_points(x, dims=model.dim)
    names = list(values)
    if not names:
        return {}
    jac = _param_jacobian(model.fn, t, values, names, create_graph, chunk, model.__name__)
    return _out({name: jac[:, j].contiguous() for j, name in enumerate(names)}, was_numpy, batch)


# ----------------------------------------------------------------------------- projection onto f = 0


class Projection(NamedTuple):
    """Result of :func:`project_to_surface` (kind of arrays follows the input)."""

    points: Any  # (N, d) projected points; points that did not converge keep their input position
    converged: Any  # (N,) bool
    gradient: Any  # (N, d) grad f at the returned points
    value: Any  # (N,) f at the returned points


@named_entry
def project_to_surface(
    f: Callable,
    points: Any,
    tol: float | None = None,
    max_iter: int = 20,
    max_step: float | None = None,
    max_distance: float | None = None,
    chunk: int | None = None,
    warn: bool = True,
) -> Projection:
    """Move points onto f = 0 by Newton steps ``x <- x - f grad f / |grad f|^2``.

    A point has converged when its first-order distance ``|f| / |grad f|`` is below
    ``tol``.  Points whose gradient vanishes, that do not converge in ``max_iter`` steps
    or that would move farther than ``max_distance`` keep their input position and are
    reported in ``converged`` (and by a warning unless ``warn=False``), never kept silently.
    Each step evaluates f and grad f (one backward pass) only at the points still moving.

    Parameters
    ----------
    f : callable (N, d) -> (N,)
    points : (N, d) array or tensor, finite (ValueError otherwise).
    tol : distance tolerance in length units; default ``100 * eps * max(1, max|x|)``.
    max_iter : Newton steps at most.
    max_step : longest single step (length units); None for unlimited.
    max_distance : longest total displacement accepted; None for unlimited.

    Returns
    -------
    Projection(points, converged, gradient, value), same kind as ``points``.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> p = project_to_surface(lambda x: sphere(x, r=1.0), torch.tensor([[0.9, 0.0, 0.0]], dtype=torch.float64))
    >>> p.points, bool(p.converged[0])
    (tensor([[1., 0., 0.]], dtype=torch.float64), True)
    """
    x0, was_numpy, _ = _flat_points(points, "points", flat=False)
    x0 = x0.detach()
    eps = torch.finfo(x0.dtype).eps
    if tol is None:
        tol = 100.0 * eps * max(1.0, float(x0.abs().max()))
    tol = check_option(tol, "tol", "project_to_surface", positive=True)
    max_iter = check_option(max_iter, "max_iter", "project_to_surface", "int", minimum=0)
    # a step or distance limit of 0 or less would leave every point where it is, reported unconverged
    max_step = check_option(max_step, "max_step", "project_to_surface", positive=True, none=True)
    max_distance = check_option(max_distance, "max_distance", "project_to_surface", positive=True, none=True)
    x = x0.clone()
    n = x.shape[0]
    value = torch.empty(n, dtype=x.dtype, device=x.device)
    gradient = torch.empty_like(x)
    converged = torch.zeros(n, dtype=torch.bool, device=x.device)
    active = torch.arange(n, device=x.device)
    for step in range(int(max_iter) + 1):
        if active.numel() == 0:
            break
        y, g = _map_chunks(lambda c: _value_and_grad(f, c), x[active], chunk)
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
        y, g = _map_chunks(lambda c: _value_and_grad(f, c), x[failed], chunk)
        value[failed], gradient[failed] = y, g
        if warn:
            warnings.warn(
                f"project_to_surface: {n_failed} of {n} points did not converge "
                f"(tol={tol:.3g}, max_iter={max_iter}); they keep their input position",
                RuntimeWarning,
                stacklevel=2,
            )
    return _out(Projection(x, converged, gradient, value), was_numpy)
