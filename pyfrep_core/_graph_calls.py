"""A compiled kernel's graph called straight from its inputs, after one call through dynamo has chosen it.

A call of a ``torch.compile`` function goes through dynamo: its frame hook, its guards (Python
code reading a model's parameters) and AOTAutograd's wrappers, about 25 us of Python on one
core before and after the fused loop, and 8 (values) to 21 (value and gradient) releases of
the GIL in a mesher's call on a few points (a breakpoint on ``PyEval_SaveThread``: each freed
tensor, each small torch call, the guard reading a parameter).  From two threads, each release
can hand the GIL to the other thread, which it must then wait to get back: on 26,000 points two
threads calling side by side through dynamo ran no faster than one, and directly nearly twice
as fast (``benchmarks/kernel_calls.py``; figures in :meth:`.CompiledModel.values_kernel`).

:func:`capturing_backend` is Inductor's ``torch.compile`` backend, unchanged, that also records
each graph it compiled (:class:`Graph`: where dynamo takes each input from, and the symbolic
sizes that carry its shape guards).  A kernel's caller probes one call through dynamo
(:func:`probe`): the graph that dynamo's guards chose for these parameters and globals is the
one it ran.  :func:`direct_call` then gives a call of that graph on new points, where that is
sound: one graph (no graph break), inputs that are the points, their number of rows and
columns and the caller's own parameters, no guard on the number of rows but ``N >= 2``, and on
a copy of a few of the points, the graph that dynamo runs and the same result, bit for bit.
Otherwise None, and the caller goes through dynamo every time.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import sympy
import torch

_probed = threading.local()  # .open: the lists of the current thread's open probes


class Graph:
    """One graph of a kernel as Inductor compiled it (callable as dynamo calls it), with its inputs'
    sources (dynamo's) and the symbolic shapes' environment of its compilation."""

    def __init__(self, fn: Callable, gm: torch.fx.GraphModule) -> None:
        self.fn = fn
        self.plans: dict[tuple, tuple | None] = {}  # direct_call's checked plans (None: not callable directly)
        inputs = [node for node in gm.graph.nodes if node.op == "placeholder"]
        # dynamo's sources (not its graph arguments, which may hold the first call's points) and the
        # symbolic sizes (whose shape environment holds the compilation's guards)
        self.sources = [getattr(node.meta.get("grapharg"), "source", None) for node in inputs]
        self.sizes = [v if isinstance(v := node.meta.get("example_value"), torch.SymInt) else None for node in inputs]

    def __call__(self, *args: Any) -> Any:
        for ran in getattr(_probed, "open", ()):
            ran.append(self)
        return self.fn(*args)


def capturing_backend(dynamic: bool) -> Any:
    """Inductor's backend for ``torch.compile(..., dynamic=dynamic)`` whose graphs are :class:`Graph`
    (the string "inductor" where this torch lacks the wrapper class it builds on)."""
    base = getattr(torch, "_TorchCompileInductorWrapper", None)
    if base is None:
        return "inductor"

    class Capturing(base):
        def __call__(self, model_: torch.fx.GraphModule, inputs_: Any, **kwargs: Any) -> Any:
            return Graph(super().__call__(model_, inputs_, **kwargs), model_)

    return Capturing(None, None, dynamic)


@contextmanager
def probe() -> Iterator[list[Graph]]:
    """The graphs that the block's calls in this thread run, in order.

    >>> kernel = torch.compile(lambda x: x * 2.0, dynamic=True, backend=capturing_backend(True))
    >>> with probe() as ran:
    ...     _ = kernel(torch.ones(3, 1))
    >>> len(ran)
    1
    """
    ran: list[Graph] = []
    before = getattr(_probed, "open", ())
    _probed.open = (*before, ran)  # probes nest: each sees the graphs its block runs
    try:
        yield ran
    finally:
        _probed.open = before


def direct_call(
    ran: list[Graph],
    through: Callable[[torch.Tensor], Any],
    x: torch.Tensor,
    x_name: str,
    params: dict[str, torch.Tensor],
) -> Callable[[torch.Tensor], Any] | None:
    """A call ``y -> result`` of the one graph in ``ran``, which the probed call ``through(x)``
    (``kernel(x, **params)``, ``x_name``: the kernel's name for the points) ran; None where that
    would not be the kernel's own result.

    Checked on a copy of a few of x's rows: dynamo must run the same graph there, and the graph
    called directly must give its result bit for bit.  The call holds for points y of x's dtype,
    device, width and layout (component-first, not a view), N >= 2 rows, and these ``params``;
    its caller checks y.

    >>> kernel = torch.compile(lambda x, r: (x * x).sum(1) - r, dynamic=True, backend=capturing_backend(True))
    >>> def points(n):  # component-first (n, 3), not a view
    ...     return torch.empty_strided((n, 3), (1, n)).copy_(torch.rand(n, 3))
    >>> x, r = points(5), torch.tensor(0.25)
    >>> with probe() as ran:
    ...     out = kernel(x, r=r)
    >>> call = direct_call(ran, lambda y: kernel(y, r=r), x, "x", {"r": r})
    >>> y = points(40)
    >>> torch.equal(call(y), kernel(y, r=r))
    True
    """
    if len(ran) != 1:
        return None  # graph breaks: Python between the graphs
    graph = ran[0]
    key = (x_name, tuple(sorted(params)), x.dtype, x.device, x.shape[1])
    plan = graph.plans.get(key, _UNCHECKED)
    if plan is _UNCHECKED:  # once per graph and kind of call: later probes of this graph reuse it
        plan = _plan(graph, through, x, x_name, params)
        graph.plans[key] = plan
    if plan is None:
        return None
    return _call(graph.fn, plan, params)


_UNCHECKED = object()


def _plan(
    graph: Graph, through: Callable[[torch.Tensor], Any], x: torch.Tensor, x_name: str, params: dict[str, Any]
) -> tuple | None:
    """Where each of the graph's inputs comes from ("points", "rows" or a parameter's name), where a
    direct call is sound (:func:`direct_call`), else None."""
    plan = []
    rows = None
    for source, size in zip(graph.sources, graph.sizes, strict=True):
        where = _source(source, x_name, params)
        if where is None:
            return None
        if where == _ROWS:
            rows = size
        plan.append(where)
    if rows is None or not _rows_unguarded(rows):
        return None  # a graph for one number of rows, or for some numbers only
    plan = tuple(plan)
    k = min(x.shape[0], 16)
    few = torch.empty_strided((k, x.shape[1]), (1, k), dtype=x.dtype, device=x.device).copy_(x[:k])
    try:
        with probe() as again:
            expected = through(few)
        got = _call(graph.fn, plan, params)(few)
    except Exception:  # noqa: BLE001  (not callable so: dynamo's way stays)
        return None
    if again != [graph] or not _same(got, expected):
        return None
    return plan


_POINTS, _ROWS, _WIDTH = ("points",), ("rows",), ("width",)  # a plan's entries other than a parameter's name


def _call(fn: Callable, plan: tuple, params: dict[str, Any]) -> Callable[[torch.Tensor], Any]:
    """The graph's ``fn`` on points y, its inputs taken as ``plan`` says."""
    getters = []
    for where in plan:
        if where == _POINTS:
            getters.append(lambda y: y)
        elif where == _ROWS:
            getters.append(lambda y: y.shape[0])
        elif where == _WIDTH:  # the probed call's (the caller checks it)
            getters.append(lambda y: y.shape[1])
        else:
            value = params[where]
            getters.append(lambda y, value=value: value)

    def call(y: torch.Tensor) -> Any:
        result = fn(*[get(y) for get in getters])
        return result[0] if len(result) == 1 else tuple(result)

    return call


def _source(source: Any, x_name: str, params: dict[str, Any]) -> tuple | str | None:
    """Where a graph input comes from (dynamo's ``source``): the points, their number of rows or
    columns, or one of the parameters (its name); None for anything else."""
    kind = type(source).__name__
    if kind == "LocalSource":
        name = source.local_name
        if name == x_name:
            return _POINTS
        return name if name in params else None
    base = getattr(source, "base", None)
    if type(base).__name__ != "LocalSource":
        return None
    if kind in ("GetItemSource", "DictGetItemSource"):  # an entry of the kernel's **params
        index = source.index
        return index if base.local_name != x_name and isinstance(index, str) and index in params else None
    if kind == "TensorPropertySource" and base.local_name == x_name:
        if source.prop.name == "SIZE" and source.idx in (0, 1):
            return _ROWS if source.idx == 0 else _WIDTH
        return None
    return None


def _rows_unguarded(rows: Any) -> bool:
    """Whether the compilation put no condition on the number of rows but that it is at least 2
    (dynamo specializes 0 and 1)."""
    node = getattr(rows, "node", None)
    env = getattr(node, "shape_env", None)
    symbol = getattr(node, "expr", None)
    if env is None or not isinstance(symbol, sympy.Symbol):
        return False
    for guard in env.guards:
        expr = guard.expr
        if symbol not in expr.free_symbols:
            continue
        lower = None  # expr as ``symbol >= lower``, where it is that simple
        if isinstance(expr, sympy.GreaterThan) and expr.lhs == symbol and expr.rhs.is_number:
            lower = expr.rhs
        elif isinstance(expr, sympy.LessThan) and expr.rhs == symbol and expr.lhs.is_number:
            lower = expr.lhs
        elif isinstance(expr, sympy.StrictGreaterThan) and expr.lhs == symbol and expr.rhs.is_number:
            lower = expr.rhs + 1
        elif isinstance(expr, sympy.StrictLessThan) and expr.rhs == symbol and expr.lhs.is_number:
            lower = expr.lhs + 1
        elif isinstance(expr, sympy.Ne) and symbol in (expr.lhs, expr.rhs):
            other = expr.rhs if expr.lhs == symbol else expr.lhs
            if other.is_number and other < 2:
                continue
        if lower is None or lower > 2:
            return False
    return True


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor):
        return (
            a.shape == b.shape
            and a.dtype == b.dtype
            and a.stride() == b.stride()
            and bool(torch.equal(torch.nan_to_num(a), torch.nan_to_num(b)))
            and bool(torch.equal(a.isnan(), b.isnan()))
        )
    if isinstance(a, tuple) and isinstance(b, tuple | list):
        return len(a) == len(b) and all(_same(u, v) for u, v in zip(a, b))
    return False
