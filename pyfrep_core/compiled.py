"""Fused evaluation: a model run through ``torch.compile``, one loop over the points instead of one per operation.

Eager torch evaluates f(x) operation by operation: each of the Fig. 1 part's ~80 operations
(R-functions, squares, square roots) reads and writes the whole chunk of points, and at
2^15 points per chunk torch's per-operation dispatch is the cost.  ``torch.compile``
(Inductor) fuses the program into one generated C++ loop on the CPU (Triton on CUDA): the
Fig. 1 part on a 128^3 grid takes 10 ms on one core against 50 ms eager.  That is what the
workbench's live re-meshing runs on (``benchmarks/slider.py``).

The price is the compilation: a few seconds per variant the first time it is met (float32
grid values, float64 vertex values, float64 value and gradient), cached on
disk by Inductor for later processes.  :func:`warm_up` pays it ahead of time; the shape
panel does so on a background thread and re-meshes eagerly meanwhile.

What goes through the compiled kernel, and what stays eager
-----------------------------------------------------------
- values (no gradient wanted): compiled;
- first derivatives taken by the kernel's own passes (:func:`pyfrep_core.value_and_grad`,
  ``grad``): one fused kernel, the forward and backward passes traced together by
  ``torch.func.grad_and_value`` (:meth:`CompiledModel.value_and_grad`; no autograd at run time);
  inside :func:`first_order` (a loss over scalar parameters), the values' kernel and its compiled backward;
- anything else that differentiates (Hessians and curvature, ``create_graph``, a user's own
  ``torch.autograd.grad``, ``torch.func`` transforms, forward-mode AD), batched (B,)
  parameters, and fewer than two points: the eager model, so every result stays correct
  (torch.compile cannot differentiate its kernels twice).  ``compiled(model, second_order=True)``
  fuses curvature's passes instead: they are traced once into a graph without autograd
  (``make_fx``) and that graph is compiled (:meth:`CompiledModel.tangent_hessian`).  Per-point parameter derivatives
  (:func:`pyfrep_core.param_grad`, :func:`pyfrep_core.sensitivity.normal_velocity`, the
  fitting Jacobian) are taken per sample under ``torch.func.vmap``/``grad``, hence eagerly:
  the eager model's values, bit for bit;
- a model that fails to compile (an operation Inductor lacks, no C++ compiler): eager,
  with one RuntimeWarning naming the error.

Values agree with the eager model to rounding (fusion reorders operations: about 4 ulp in
float32, 1e-15 relative in float64).
"""

from __future__ import annotations

import functools
import inspect
import threading
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import torch
import torch.autograd.forward_ad as fwad

from ._graph_calls import capturing_backend, direct_call, probe
from ._threads import intra_op_threads
from .model import Model

__all__ = ["compiled", "first_order", "warm_up"]

CHUNK_POINTS = 1 << 18  # points per call: a fused loop keeps no temporaries, so larger chunks only save calls
RECOMPILE_LIMIT = 64  # variants per model (dtypes x values, grad f); set process-wide
DIRECT_CALLS = True  # values_kernel's calls after its first: the graph dynamo chose, called directly (_graph_calls)

_state = threading.local()

# Inductor's Python binding of a CPU kernel holds the GIL while the kernel's C++ loop runs, so
# kernels called from several threads (the chunks of pyfrep_core.diff's pool) run one at a time.
# The loop touches no Python object: its arguments are read first (with the GIL), the loop runs
# without it, and an exception it throws is re-raised once the GIL is back.  Patched only where
# the binding is the one this was written for (torch 2.13, pinned); elsewhere left alone (serial).
_HOLDS_GIL = "kernel({}); Py_RETURN_NONE;"
_RELEASES_GIL = (
    "auto call_args = std::make_tuple({}); std::exception_ptr error; "
    "Py_BEGIN_ALLOW_THREADS "
    "try {{ std::apply(kernel, call_args); }} catch (...) {{ error = std::current_exception(); }} "
    "Py_END_ALLOW_THREADS "
    "if (error) std::rethrow_exception(error); Py_RETURN_NONE;"
)


def _kernels_release_the_gil() -> bool:
    try:
        from torch._inductor.codecache import CppPythonBindingsCodeCache as Bindings
    except ImportError:
        return False
    if getattr(Bindings, "call_entry_function", None) == _HOLDS_GIL:
        Bindings.call_entry_function = _RELEASES_GIL
    return getattr(Bindings, "call_entry_function", None) == _RELEASES_GIL


@contextmanager
def first_order() -> Iterator[None]:
    """Declare that the block takes first derivatives only (one backward pass, no graph kept).

    The kernel's first-derivative passes wrap their forward evaluation in it; inside, a
    compiled model differentiates through its compiled kernel.  Outside, a compiled model
    evaluated with gradients on falls back to eager, which any order of derivative can use.

    >>> with first_order():
    ...     _first_order_active()
    True
    >>> _first_order_active()
    False
    """
    before = getattr(_state, "first_order", False)
    _state.first_order = True
    try:
        yield
    finally:
        _state.first_order = before


def _first_order_active() -> bool:
    return getattr(_state, "first_order", False)


def _needs_eager(x: torch.Tensor, params: dict[str, Any], graph: bool = True) -> bool:
    """True where the compiled kernel must not be used (see the module docstring); ``graph``: the
    result may join an autograd graph (False: it is taken without one, first derivatives included)."""
    if x.shape[:-1].numel() < 2 or torch._C._are_functorch_transforms_active():
        return True
    if type(x) is not torch.Tensor:  # a subclass (interval bounds over boxes): its own dispatch, not a kernel's
        return True
    tensors = [x, *(v for v in params.values() if isinstance(v, torch.Tensor))]
    if fwad._current_level >= 0 and any(fwad.unpack_dual(t).tangent is not None for t in tensors):
        return True
    if graph and torch.is_grad_enabled() and any(t.requires_grad for t in tensors) and not _first_order_active():
        return True
    return False


class CompiledModel(Model):
    """A :class:`~pyfrep_core.model.Model` whose values and first derivatives run fused.

    Built by :func:`compiled`; same parameters, bounds, dimension and name as the eager
    model (``.eager``).  ``chunk_points`` tells chunked evaluators (polygonize) the chunk
    size that suits it.
    """

    chunk_points = CHUNK_POINTS

    def __init__(self, eager: Model, dynamic: bool = True, second_order: bool = False):
        _kernels_release_the_gil()
        self.eager = eager
        self.second_order = second_order
        self.failure: BaseException | None = None
        # Inductor, recording its graphs, so that a caller's repeated calls can skip dynamo (values_kernel)
        self._kernel = torch.compile(eager.fn, dynamic=dynamic, backend=capturing_backend(dynamic))
        self._first_order_kernel = torch.compile(
            _first_derivatives(eager.fn), dynamic=dynamic, backend=capturing_backend(dynamic)
        )
        self._points_name = _first_parameter(eager.fn)
        self.first_order_failure: BaseException | None = None
        # variants are per code object (dtype, grad f): raise dynamo's limit, never lower it
        config = torch._dynamo.config
        config.recompile_limit = max(config.recompile_limit, RECOMPILE_LIMIT)
        self._lock = threading.Lock()
        # the variants (dtype, device, grad f, grad mode) called once: a variant's first call compiles it, and a
        # second thread meeting it meanwhile would compile it again (dynamo does not look again
        # once it holds its lock), so first calls take turns
        self._variants: set[tuple[torch.dtype, torch.device, bool, bool]] = set()
        self._first_call = threading.Lock()
        self._second_order_kernels: dict[tuple[torch.dtype, torch.device], Any] = {}
        self.second_order_failure: BaseException | None = None

        @functools.wraps(eager.fn)
        def fn(x: torch.Tensor, **params: Any) -> torch.Tensor:
            return self._evaluate(x, params)

        super().__init__(fn, eager.params, bounds=eager.bounds, dim=eager.dim)

    def __repr__(self) -> str:
        return "<compiled " + repr(self.eager)[1:]

    @staticmethod
    def _threads(x: torch.Tensor) -> int | None:
        return 1 if x.device.type == "cpu" else None

    def _arguments(self, flat: torch.Tensor, params: dict[str, Any]) -> dict[str, torch.Tensor] | None:
        """Parameters as 0-d tensors for the kernel; None when one is not a scalar."""
        out = {}
        for name, v in params.items():
            if isinstance(v, torch.Tensor):
                if v.ndim == 0:
                    out[name] = v.to(dtype=flat.dtype, device=flat.device)
                else:
                    return None  # a (B, 1, ...) batch: eager broadcasting
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                out[name] = torch.tensor(float(v), dtype=flat.dtype, device=flat.device)
            else:
                return None
        return out

    def _evaluate(self, x: torch.Tensor, params: dict[str, Any]) -> torch.Tensor:
        if self.failure is not None or _needs_eager(x, params):
            return self.eager.fn(x, **params)
        # one layout, component-first (x[:, 0] contiguous, so the fused loop vectorizes): strides are compiled in
        flat = x.reshape(-1, x.shape[-1])
        if flat.stride() != (1, flat.shape[0]):
            fresh = torch.empty_strided(flat.shape, (1, flat.shape[0]), dtype=flat.dtype, device=flat.device)
            # a view of a component-first base, as a reshaped component-first input is (dynamo guards a
            # view's base too: a transposed copy's would compile a variant of its own)
            flat = fresh.copy_(flat).view(flat.shape)  # differentiable, as the model
        if not flat.requires_grad:
            flat = flat.detach()  # not a view: guards would otherwise see the grid's 4-D base
        args = self._arguments(flat, params)
        if args is None:
            return self.eager.fn(x, **params)
        try:
            # the thread count is part of what a kernel is compiled for: one, whoever calls
            variant = (flat.dtype, flat.device, flat.requires_grad, torch.is_grad_enabled())
            with intra_op_threads(self._threads(flat)):
                if variant in self._variants:
                    out = self._kernel(flat, **args)
                else:
                    with self._first_call:
                        out = self._kernel(flat, **args)
                        self._variants.add(variant)
        except Exception as error:  # noqa: BLE001  (any compiler failure: the eager model decides)
            out = self.eager.fn(x, **params)  # a genuine error in the model raises here
            self._failed("failure", error, "torch.compile", "evaluating eagerly")
            return out
        if not isinstance(out, torch.Tensor) or out.shape != flat.shape[:1]:
            return self.eager.fn(x, **params)  # not one value per point: let the caller's check name it
        return out.reshape(x.shape[:-1])

    def _plain(self, x: torch.Tensor, variant: tuple) -> bool:
        """Whether points x go straight to a kernel already compiled for ``variant`` (:meth:`values_kernel`):
        a plain (N, d) tensor, N >= 2, component-first and not a view, without grad, outside any transform."""
        return (
            type(x) is torch.Tensor
            and x.ndim == 2
            and x.shape[0] >= 2
            and x.stride() == (1, x.shape[0])
            and x._base is None
            and not x.requires_grad
            and not torch._C._are_functorch_transforms_active()
            and fwad._current_level < 0
            and variant in self._variants
        )

    def values_kernel(self, **params: Any) -> Callable[[torch.Tensor], torch.Tensor]:
        """f at these parameters, for a caller's many calls on points it makes itself (a mesher's root finding).

        A call on plain (N, d) points, N >= 2, component-first (``x[:, 0]`` contiguous, not a view),
        that do not require grad, outside any transform, of a dtype and device met before, goes
        straight to the fused kernel with the parameters converted once.  The model's own call
        checks and converts on every call, in a few torch operations that each let another thread
        take the GIL: two threads calling the Fig. 1 part's kernel on 26,000 points side by side
        ran 1.6-1.7x as fast as one this way, 1.1-1.4x through the model's call.  Any other call,
        the first of each dtype and device, and every call after a failure take the model's call
        (same values).  Its ``value_and_grad(x)`` does the same for :meth:`value_and_grad`'s fused
        first-order kernel, whose gradient comes in the kernel's own layout (None where the model's
        :meth:`value_and_grad` declines).

        The next call of each dtype and device goes through dynamo, whose guards choose the graph
        for these parameters and the model's globals as they are; the later ones call that graph
        directly, without dynamo's frame hook, guards and their releases of the GIL, where
        :func:`._graph_calls.direct_call` finds that sound (one graph, fed by the points, their
        number of rows and these parameters, with the same result bit for bit).  The Fig. 1 part,
        float64 (``benchmarks/kernel_calls.py``): a call on 16 points takes 16 us instead of 65 us
        on one core, 47 us a pair instead of 355 us with two threads calling side by side; on
        26,000 points 175 us instead of 237 us, and 187 us a pair instead of 461 us (two threads
        through dynamo ran no faster than one).  The dual-contouring mesher's workers make about 17
        such calls at 128^3 (2.6-2.8 ms less per mesh, 5%; 12.6 ms at 256^3, 6%).  A kernel is made
        for one mesh: a model whose globals change between meshes gets a new one.

        Examples
        --------
        >>> from pyfrep_core.models import fig1_part
        >>> fast = compiled(fig1_part)
        >>> kernel = fast.values_kernel(r=0.4)
        >>> points = torch.tensor([[0.1, 0.3, 0.0], [0.2, 0.9, 0.1]], dtype=torch.float64)
        >>> x = torch.empty_strided((2, 3), (1, 2), dtype=torch.float64).copy_(points)  # component-first
        >>> bool(torch.allclose(kernel(x), fig1_part(x, r=0.4), rtol=1e-12, atol=1e-15))  # the model's call first
        True
        >>> bool(torch.allclose(kernel(x), fig1_part(x, r=0.4), rtol=1e-12, atol=1e-15))  # then the kernel's
        True
        >>> value, gradient = kernel.value_and_grad(x)
        >>> bool(torch.allclose(gradient, fast.value_and_grad(x, r=0.4)[1], rtol=1e-12, atol=1e-15))
        True
        """
        values = self.check(**params)
        prepared: dict[tuple[torch.dtype, torch.device], dict[str, torch.Tensor] | None] = {}
        directs: dict[tuple, tuple[Callable | None, int]] = {}  # per kernel, dtype and device: _direct's calls

        def kernel(x: torch.Tensor) -> torch.Tensor:
            key = (x.dtype, x.device)
            args = prepared.get(key)
            if args is None or self.failure is not None or not self._plain(x, (*key, False, torch.is_grad_enabled())):
                out = self._evaluate(x, values)  # checked, converted, compiled where first met
                if key not in prepared and type(x) is torch.Tensor:
                    prepared[key] = self._arguments(x, values)  # None for batched parameters: always this path
                return out
            try:
                with intra_op_threads(self._threads(x)):
                    return _direct(self._kernel, self._points_name, x, args, directs, key)
            except Exception:  # noqa: BLE001  (the model's call decides, as for its own failures: eager, one warning)
                return self._evaluate(x, values)

        first_order: dict[tuple[torch.dtype, torch.device], dict[str, torch.Tensor] | None] = {}

        def value_and_grad(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
            key = (x.dtype, x.device)
            args = first_order.get(key)
            failed = self.failure is not None or self.first_order_failure is not None
            if args is None or failed or not self._plain(x, ("first order", *key)):
                out = self.value_and_grad(x, **values)  # checked, converted, compiled where first met
                if key not in first_order and type(x) is torch.Tensor:
                    first_order[key] = self._arguments(x, values)
                return out
            try:
                with intra_op_threads(self._threads(x)), torch.no_grad():
                    return _direct(self._first_order_kernel, "x", x, args, directs, ("first order", *key))
            except Exception:  # noqa: BLE001  (the model's call decides: autograd's passes then, one warning)
                return self.value_and_grad(x, **values)

        kernel.value_and_grad = value_and_grad
        kernel.chunk_points = self.chunk_points
        kernel.__name__ = self.__name__
        return kernel

    def value_and_grad(self, x: torch.Tensor, **params: Any) -> tuple[torch.Tensor, torch.Tensor] | None:
        """f and grad f at points x (N, d), through one fused kernel; None where autograd's passes must decide.

        The forward and backward passes are traced together (``torch.func.grad_and_value``) and
        compiled into one loop: no autograd graph, saved buffers or backward engine at run time
        (the Fig. 1 part, float64, one core: 0.33 ms for 300 points, 1.4 ms for 26,000, against 0.53
        and 2.0 ms by autograd through the values' kernel; ``benchmarks/gradient.py``).
        :func:`pyfrep_core.value_and_grad` and :func:`pyfrep_core.grad` take it for a compiled model
        where no graph is kept, in calls of up to ``chunk_points`` points, one piece per thread.  Values
        and gradients are those of the autograd passes to rounding (bit for bit on the 2-core
        machine), in x's dtype, device and layout.

        Returns None (the caller differentiates as before) for a transform or forward-mode AD active,
        batched parameters, fewer than two points, anything but (N, d) points, a failed compile, or
        a model that does not give one value per point.

        Examples
        --------
        >>> from pyfrep_core.models import fig1_part
        >>> fast = compiled(fig1_part)
        >>> x = torch.tensor([[0.55, 0.55, 0.55], [0.9, 0.0, 0.1]], dtype=torch.float64)
        >>> v, g = fast.value_and_grad(x, r=0.4)
        >>> g.shape, bool(torch.allclose(v, fig1_part(x, r=0.4), rtol=1e-12, atol=1e-15))
        (torch.Size([2, 3]), True)
        """
        if self.failure is not None or self.first_order_failure is not None or x.ndim != 2:
            return None
        values = self.check(**params)
        if _needs_eager(x, values, graph=False):
            return None
        flat = x.detach()  # component-first, as the kernels are compiled for (not a view: one variant)
        if flat.stride() != (1, flat.shape[0]):
            flat = torch.empty_strided(flat.shape, (1, flat.shape[0]), dtype=flat.dtype, device=flat.device).copy_(flat)
        args = self._arguments(flat, {k: v.detach() if isinstance(v, torch.Tensor) else v for k, v in values.items()})
        if args is None:
            return None
        try:
            variant = ("first order", flat.dtype, flat.device)
            with intra_op_threads(self._threads(flat)), torch.no_grad():
                if variant in self._variants:
                    value, gradient = self._first_order_kernel(flat, **args)
                else:
                    with self._first_call:
                        value, gradient = self._first_order_kernel(flat, **args)
                        self._variants.add(variant)
        except Exception as error:  # noqa: BLE001  (any tracing or compiler failure: autograd's passes decide)
            self._failed("first_order_failure", error, "the first-order kernel", "differentiating through autograd")
            return None
        if value.shape != flat.shape[:1] or gradient.shape != flat.shape:
            return None  # not one value per point: the autograd passes' check names it
        return value, torch.empty_like(x).copy_(gradient)

    def _failed(self, attribute: str, error: BaseException, what: str, instead: str) -> None:
        """Keep the first failure of a kernel in ``attribute``, with one RuntimeWarning naming it."""
        with self._lock:
            if getattr(self, attribute) is None:
                setattr(self, attribute, error)
                warnings.warn(
                    f"compiled({self.__name__}): {what} failed ({type(error).__name__}: "
                    f"{str(error).splitlines()[0] if str(error) else ''}); {instead}",
                    RuntimeWarning,
                    stacklevel=5,  # the caller of the model
                )

    def tangent_hessian(self, x: torch.Tensor) -> tuple[torch.Tensor, ...] | None:
        """f, grad f, tangent frame and tangent Hessian at points (N, d), through one fused kernel.

        What :func:`pyfrep_core.diff.tangent_hessian` computes with 1 + (d-1) backward passes,
        at the model's default parameters: the passes are traced once per dtype and device into
        one graph (``make_fx``: no autograd at run time) and compiled by Inductor, then run on
        fixed chunks (the pieces the derivative passes take, :func:`pyfrep_core.diff._chunk_size`;
        a shorter one padded).  Returns None where
        the eager passes must decide (a graph to keep, a transform active, a failed compile).
        """
        from .diff import _chunk_size

        if (
            not self.second_order
            or self.failure is not None
            or self.second_order_failure is not None
            or x.ndim != 2
            or x.shape[0] < 2
            or x.requires_grad
            or torch._C._are_functorch_transforms_active()
        ):
            return None
        values = self.check()
        try:
            kernel = self._second_order_kernel(x.dtype, x.device, _chunk_size(x, None), values)
        except Exception as error:  # noqa: BLE001  (any tracing or compiler failure: the eager passes decide)
            self._failed("second_order_failure", error, "the second-order kernel", "differentiating eagerly")
            return None
        args = [torch.as_tensor(v, dtype=x.dtype, device=x.device) for v in values.values()]
        n, size = x.shape[0], _chunk_size(x, None)
        parts = []
        with intra_op_threads(self._threads(x)), torch.no_grad():
            for start in range(0, n, size):
                piece = x[start : start + size]
                if piece.shape[0] < size:  # the kernel's shapes are fixed: pad with copies of the first point
                    piece = torch.cat([piece, piece[:1].expand(size - piece.shape[0], -1)])
                piece = piece.t().contiguous().t()  # component-first, as traced: the fused loop vectorizes
                parts.append([t[: min(size, n - start)] for t in kernel(piece, *args)])
        return tuple(torch.cat(ts) for ts in zip(*parts))

    def _second_order_kernel(self, dtype: torch.dtype, device: torch.device, size: int, values: dict[str, Any]) -> Any:
        from torch.fx.experimental.proxy_tensor import make_fx

        from .diff import _tangent_hessian

        key = (dtype, device)
        with self._lock:  # one trace and compile per variant, whichever thread asks first
            kernel = self._second_order_kernels.get(key)
            if kernel is not None:
                return kernel
            names = list(values)

            def passes(x: torch.Tensor, *params: torch.Tensor) -> tuple[torch.Tensor, ...]:
                bound = dict(zip(names, params, strict=True))
                return _tangent_hessian(lambda p: self.eager.fn(p, **bound), x, False)

            example = torch.zeros(self.dim, size, dtype=dtype, device=device).t()
            args = [torch.as_tensor(v, dtype=dtype, device=device) for v in values.values()]
            graph = make_fx(passes, tracing_mode="real")(example, *args)
            kernel = torch.compile(graph, dynamic=False)
            with intra_op_threads(self._threads(example)), torch.no_grad():
                kernel(example, *args)  # compiles now, under the lock
            self._second_order_kernels[key] = kernel
            return kernel


def _direct(
    kernel: Callable, name: str | None, x: torch.Tensor, args: dict[str, torch.Tensor], directs: dict, key: tuple
) -> Any:
    """``kernel(x, **args)`` for :meth:`CompiledModel.values_kernel`: the first call of each ``key`` through
    dynamo, probed (:mod:`._graph_calls`); later ones call the graph it ran directly where that call
    was found sound (``directs[key]``: the call or None, and the points' width)."""
    entry = directs.get(key)
    if entry is None:
        with probe() as ran:
            out = kernel(x, **args)
        call = None
        if DIRECT_CALLS and name is not None:
            call = direct_call(ran, lambda y: kernel(y, **args), x, name, args)
        directs[key] = (call, x.shape[1])
        return out
    call, width = entry
    if call is not None and x.shape[1] == width and x.storage_offset() == 0:
        return call(x)
    return kernel(x, **args)


def _first_parameter(fn: Callable) -> str | None:
    """The name of fn's first parameter (a model's points), None where it has none that can be named."""
    try:
        first = next(iter(inspect.signature(fn).parameters.values()), None)
    except (TypeError, ValueError):
        return None
    if first is None or first.kind not in (first.POSITIONAL_ONLY, first.POSITIONAL_OR_KEYWORD):
        return None
    return first.name


def _first_derivatives(fn: Any) -> Any:
    """(x, **params) -> (f(x), grad f(x)) for points x (N, d): one pass of ``torch.func.grad_and_value``
    over sum f (each value depends on its own point only, as the model contract says)."""

    def first_derivatives(x: torch.Tensor, **params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        def total(y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            value = fn(y, **params)
            return value.sum(), value

        gradient, (_, value) = torch.func.grad_and_value(total, has_aux=True)(x)
        return value, gradient

    return first_derivatives


def compiled(model: Model, dynamic: bool = True, second_order: bool = False) -> CompiledModel:
    """The same model, evaluated through ``torch.compile`` (fused; see the module docstring).

    Parameters
    ----------
    model : a :class:`~pyfrep_core.model.Model` (declared with ``@model``).
    dynamic : compile for any number of points (True), so chunks of every size share one kernel.
    second_order : also fuse what curvature differentiates (:meth:`CompiledModel.tangent_hessian`,
        at the default parameters): 2-3x less CPU per curvature call, paid for by a long
        compilation on first use per dtype (the Fig. 1 part: about 1 min on 2 cores with an
        empty Inductor cache, 15 s from the on-disk cache); ``warm_up(..., second_order=...)``
        pays it ahead.

    Returns
    -------
    CompiledModel: call it like the model (numpy or torch points, parameter overrides).
    Compilation happens on first use of each variant; :func:`warm_up` does it ahead.

    Raises
    ------
    TypeError if ``model`` is not a Model.

    Examples
    --------
    >>> import numpy as np
    >>> from pyfrep_core.models import fig1_part
    >>> fast = compiled(fig1_part)
    >>> x = np.array([[0.55, 0.55, 0.55], [0.0, 0.0, 0.0], [0.9, 0.0, 0.1]])
    >>> bool(np.allclose(fast(x, r=0.4), fig1_part(x, r=0.4), rtol=1e-12, atol=1e-12))
    True
    """
    if isinstance(model, CompiledModel):
        if second_order and not model.second_order:
            return CompiledModel(model.eager, dynamic=dynamic, second_order=True)
        return model
    if not isinstance(model, Model):
        raise TypeError(f"compiled() takes a pyfrep_core Model (declared with @model), got {type(model).__name__}")
    return CompiledModel(model, dynamic=dynamic, second_order=second_order)


def warm_up(
    model: CompiledModel,
    params: dict[str, Any] | None = None,
    dtypes: tuple[torch.dtype, ...] = (torch.float32, torch.float64),
    gradients: tuple[torch.dtype, ...] = (torch.float64,),
    device: str | torch.device = "cpu",
    second_order: tuple[torch.dtype, ...] = (),
) -> float:
    """Compile the variants a re-mesh uses, ahead of time; returns the seconds it took.

    Values in each of ``dtypes`` (polygonize's grid in float32, its vertices in float64);
    value and grad f in each of ``gradients`` (the vertices' normals).  Per-point df/dp (the
    panel's colouring) needs no kernel: it runs eagerly under ``torch.func``.  Points are
    drawn inside the model's bounds.  ``second_order`` lists the dtypes whose curvature kernel
    to compile too (a model built with ``compiled(model, second_order=True)``).  The kernels then run at once
    on first real use.  Each variant compiles in a few seconds the first time on this
    machine (the Fig. 1 part: about 35 s in all with an empty Inductor cache, 3 s from
    the on-disk cache).

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part
    >>> fast = compiled(fig1_part)
    >>> seconds = warm_up(fast, dtypes=(torch.float64,))  # compiles, once per process
    >>> warm_up(fast, dtypes=(torch.float64,)) < 1.0  # compiled already
    True
    """
    import time

    from .diff import value_and_grad

    if not isinstance(model, CompiledModel):
        raise TypeError(f"warm_up takes a CompiledModel (see compiled()), got {type(model).__name__}")
    start = time.perf_counter()
    values = model.check(**(params or {}))
    lo, hi = model.bounds if model.bounds is not None else ((-1.0,) * model.dim, (1.0,) * model.dim)
    generator = torch.Generator().manual_seed(0)
    unit = torch.rand(64, model.dim, generator=generator, dtype=torch.float64)
    points = torch.as_tensor(lo, dtype=torch.float64) + unit * (
        torch.as_tensor(hi, dtype=torch.float64) - torch.as_tensor(lo, dtype=torch.float64)
    )
    for dtype in dtypes:
        with torch.no_grad():
            model(points.to(dtype=dtype, device=device), **values)
    for dtype in gradients:
        value_and_grad(lambda p: model(p, **values), points.to(dtype=dtype, device=device))
    for dtype in second_order:
        if not model.second_order:
            raise ValueError("warm_up: second_order needs a model built with compiled(model, second_order=True)")
        model.tangent_hessian(points.to(dtype=dtype, device=device))
    return time.perf_counter() - start
