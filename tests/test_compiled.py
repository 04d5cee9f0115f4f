"""compiled(model): the torch.compile kernel against the eager model and closed forms, and its eager fallbacks.

Every variant (dtype, values or first derivatives) compiles once per process (dynamo keeps
the kernels on the model function's code object), so the compiled models are module-scoped
fixtures and the tests share their points and parameter values.  Each test also records
whether the compiled kernel ran (``kernel_calls``): agreement with eager proves nothing if
both results came from the eager model.
"""

import functools
import threading
import warnings
from contextlib import contextmanager

import numpy as np
import pytest
import torch
from rounding import ULPS_PER_OPERATION, condition_sum, float32_error_bound
from torch._dynamo.utils import counters

from pyfrep_core import (
    Param,
    curvatures,
    gaussian_curvature,
    grad,
    hessian,
    mean_curvature,
    model,
    param_grad,
    polygonize,
    sphere,
    torusZ,
    value_and_grad,
)
from pyfrep_core._graph_calls import probe
from pyfrep_core._threads import intra_op_threads
from pyfrep_core.compiled import CompiledModel, compiled, first_order, warm_up
from pyfrep_core.models import ellipse, fig1_part, microstructure, pawn, schwarz_d
from pyfrep_core.sensitivity import param_derivative

# (model, parameter values other than the defaults)
CASES = {
    "fig1_part": (fig1_part, {"r": 0.35}),
    "schwarz_d": (schwarz_d, {"c": 0.3}),
    "pawn": (pawn, {"head_radius": 0.35, "neck_radius": 0.2, "base_radius": 0.5, "collar_radius": 0.3}),
    "microstructure": (microstructure, {"scale1": 7.0, "scale2": 4.0, "freq1": 0.6, "freq2": 0.9}),
    "ellipse": (ellipse, {"a": 4.0, "b": 2.5}),
}


@model(bounds=((-2.0,) * 3, (2.0,) * 3), r=Param(1.0, 0.5, 1.5), cx=Param(0.0, -0.5, 0.5))
def ball(x, r, cx):
    """r^2 - |x - (cx, 0, 0)|^2: gradient -2 (x - c), df/dr = 2 r, df/dcx = 2 (x0 - cx), curvature 1 / r."""
    return sphere(x, center=(cx, 0.0, 0.0), r=r)


BALL = {"r": 1.25, "cx": 0.3}
BALL_CENTER = np.array([0.3, 0.0, 0.0])


def in_bounds(m, n, seed):
    lo, hi = (np.asarray(b) for b in m.bounds)
    return lo + np.random.default_rng(seed).random((n, m.dim)) * (hi - lo)


@contextmanager
def kernel_calls(fast, which=("_kernel", "_first_order_kernel")):
    """Record the number of points of every call that reaches ``fast``'s compiled kernels (``which``:
    the values' kernel, whose autograd passes give first derivatives too, and the fused first-order one)."""
    sizes = []
    kernels = {name: getattr(fast, name) for name in which}

    def counting(kernel):
        def count(flat, **params):
            sizes.append(flat.shape[0])
            return kernel(flat, **params)

        return count

    for name, kernel in kernels.items():
        setattr(fast, name, counting(kernel))
    try:
        yield sizes
    finally:
        for name, kernel in kernels.items():
            setattr(fast, name, kernel)


def compiled_graphs():
    """Graphs dynamo has compiled in this process (moves by one at each compile or recompile)."""
    return counters["stats"]["unique_graphs"]


def edge_counts(faces):
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)[1]


@pytest.fixture(scope="module")
def fast():
    """name -> compiled model, for every model of CASES, and the test ball."""
    out = {name: compiled(m) for name, (m, _) in CASES.items()}
    out["ball"] = compiled(ball)
    return out


# ----------------------------------------------------------------------------- values


@pytest.mark.parametrize("name", list(CASES))
def test_values_agree_with_eager_in_float64_numpy_and_torch(fast, name):
    m, params = CASES[name]
    x = in_bounds(m, 3000, seed=1)
    with kernel_calls(fast[name]) as sizes:
        got = fast[name](x, **params)
        got_torch = fast[name](torch.as_tensor(x), **params)
    assert sizes == [3000, 3000] and fast[name].failure is None  # the kernel computed both
    want = m(x, **params)
    assert isinstance(got, np.ndarray) and got.dtype == want.dtype == np.float64 and got.shape == (3000,)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    assert isinstance(got_torch, torch.Tensor) and got_torch.dtype == torch.float64
    np.testing.assert_array_equal(got_torch.numpy(), got)
    # the parameters reach the kernel: the defaults give other values
    assert np.abs(fast[name](x) - got).max() > 1e-3


@pytest.mark.parametrize("name", list(CASES))
def test_values_in_float32_are_within_the_rounding_error_bound_of_the_float64_truth(fast, name):
    """Compiled and eager float32 both err from the float64 value by less than the first-order bound.

    Fusion reorders and contracts operations, so compiled and eager float32 values need not agree
    bit for bit, and how far they differ depends on the machine's vector code.  What does not
    depend on the machine is the rounding-error bound of the program at each point (tests/rounding.py),
    which is large exactly where the model cancels big intermediate terms.
    """
    m, params = CASES[name]
    x = torch.as_tensor(in_bounds(m, 3000, seed=2), dtype=torch.float32)
    with kernel_calls(fast[name]) as sizes:
        got = fast[name](x, **params)
    assert sizes == [3000]
    assert got.dtype == torch.float32 and got.shape == (3000,)
    truth = m(x.double(), **params)
    bound = float32_error_bound(m, x, **params)
    for label, value in (("compiled", got), ("eager", m(x, **params))):
        err = (value.double() - truth).abs()
        worst = int((err / bound).argmax())
        assert (err <= bound).all(), (
            f"{label}: error {err[worst]:.3g} > bound {bound[worst]:.3g} at {x[worst].tolist()}"
        )
    # the bound is a real constraint, not a blanket: a relative error of 1e-4 exceeds it somewhere
    assert ((truth * 1e-4).abs() > bound).any()


def test_point_layouts_batch_shapes_and_parameter_kinds_give_the_eager_values(fast):
    """The kernel takes (N, 3) component-first; every other layout is brought to it and reshaped back."""
    f = fast["fig1_part"]
    grid = torch.as_tensor(in_bounds(fig1_part, 6 * 7 * 8, seed=3)).reshape(6, 7, 8, 3)
    layouts = {
        "grid (6, 7, 8, 3)": grid,
        "component-first view": grid.movedim(-1, 0).contiguous().movedim(0, -1),  # as polygonize passes
        "transposed (N, 3)": grid.reshape(-1, 3).t().contiguous().t(),
        "strided rows": grid.reshape(-1, 3)[::2],
    }
    for label, x in layouts.items():
        for r in (0.3, torch.tensor(0.3, dtype=torch.float64), torch.tensor(0.3, dtype=torch.float32)):
            with kernel_calls(f) as sizes:
                got = f(x, r=r)
            assert sizes == [x.shape[:-1].numel()], label
            assert got.shape == x.shape[:-1], label
            # the kernel takes parameters in the points' dtype (a float32 0.3 widened to float64)
            want = fig1_part(x, r=torch.as_tensor(r, dtype=torch.float64)).numpy()
            np.testing.assert_allclose(got.numpy(), want, rtol=1e-12, atol=1e-12, err_msg=label)


# ----------------------------------------------------------------------------- first derivatives


@pytest.mark.parametrize("name", ["fig1_part", "schwarz_d", "ellipse"])  # pawn, microstructure: 5-7 s more to compile
def test_value_and_grad_through_the_kernel_equals_eager(fast, name):
    m, params = CASES[name]
    x = in_bounds(m, 3000, seed=4)
    with kernel_calls(fast[name]) as sizes:
        value, gradient = value_and_grad(functools.partial(fast[name], **params), x)
        only_gradient = grad(functools.partial(fast[name], **params), torch.as_tensor(x))
    assert sizes == [3000, 3000] and fast[name].failure is None
    want_value, want_gradient = value_and_grad(functools.partial(m, **params), x)
    np.testing.assert_allclose(value, want_value, rtol=1e-12, atol=1e-12)
    scale = np.abs(want_gradient).max()
    np.testing.assert_allclose(gradient, want_gradient, rtol=1e-12, atol=1e-12 * scale)
    assert isinstance(only_gradient, torch.Tensor) and only_gradient.dtype == torch.float64
    np.testing.assert_array_equal(only_gradient.numpy(), gradient)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_first_derivatives_come_from_one_fused_kernel_with_autograds_values(fast, dtype):
    """value_and_grad and grad of a compiled model (no graph kept): the fused kernel alone, with the
    values and gradients of autograd's passes through the values' kernel (to rounding), in x's kind,
    dtype and layout."""
    f, params = fast["fig1_part"], CASES["fig1_part"][1]
    x = torch.as_tensor(in_bounds(fig1_part, 3000, seed=24), dtype=dtype)
    with kernel_calls(f, ("_kernel",)) as plain, kernel_calls(f, ("_first_order_kernel",)) as fused:
        value, gradient = value_and_grad(functools.partial(f, **params), x)
        only_gradient = grad(functools.partial(f, **params), x.numpy())
        value_t, gradient_t = value_and_grad(functools.partial(f, **params), x.t().contiguous().t())
    assert plain == [] and fused == [3000, 3000, 3000] and f.first_order_failure is None
    # autograd's backward through the values' kernel, as before the fused kernel
    xr = x.clone().requires_grad_(True)
    with first_order(), kernel_calls(f, ("_kernel",)) as before:
        want_value = f(xr, **params)
        (want_gradient,) = torch.autograd.grad(want_value.sum(), xr)
    assert before == [3000]
    assert value.dtype == gradient.dtype == dtype and gradient.stride() == (3, 1)
    # two compiled graphs of the same operations: equal to rounding (bit for bit here, but fusion may
    # order them otherwise on another CPU); 16 ulp of the values' and gradients' scale
    eps = 16 * torch.finfo(dtype).eps
    want_value = want_value.detach()
    torch.testing.assert_close(value, want_value, rtol=eps, atol=eps * float(want_value.abs().max()))
    torch.testing.assert_close(gradient, want_gradient, rtol=eps, atol=eps * float(want_gradient.abs().max()))
    assert isinstance(only_gradient, np.ndarray) and only_gradient.dtype == x.numpy().dtype
    np.testing.assert_array_equal(only_gradient, gradient.numpy())
    assert gradient_t.stride() == (1, 3000)  # a component-first x: a component-first gradient
    torch.testing.assert_close(gradient_t, gradient, rtol=0, atol=0)
    torch.testing.assert_close(value_t, value, rtol=0, atol=0)


def test_first_derivatives_of_a_compiled_model_come_in_large_calls_one_per_thread(fast):
    f = fast["fig1_part"]
    x = torch.as_tensor(in_bounds(fig1_part, 20_000, seed=26))
    want = value_and_grad(fig1_part, x, chunk=20_000)
    for threads, sizes_wanted in ((1, [20_000]), (2, [10_000, 10_000])):
        with intra_op_threads(threads), kernel_calls(f, ("_first_order_kernel",)) as sizes:
            value, gradient = value_and_grad(f, x)  # default chunk: not the eager passes' 8192
        assert sorted(sizes) == sizes_wanted, threads
        torch.testing.assert_close(value, want[0], rtol=1e-12, atol=1e-12)
        torch.testing.assert_close(gradient, want[1], rtol=1e-12, atol=1e-11)


def test_the_fused_first_order_kernel_declines_what_autograd_must_do(fast):
    """None (autograd's passes decide) for batched parameters, one point, a transform or forward AD."""
    f = fast["ball"]
    x = torch.as_tensor(in_bounds(ball, 300, seed=25))
    assert f.value_and_grad(x, r=torch.tensor([0.6, 1.0]), cx=0.3) is None
    assert f.value_and_grad(x[:1], **BALL) is None
    assert f.value_and_grad(x[0], **BALL) is None
    assert torch.func.vmap(lambda p: torch.tensor(f.value_and_grad(p[None].expand(2, 3), **BALL) is None))(x[:3]).all()
    import torch.autograd.forward_ad as fwad

    with fwad.dual_level():
        dual = fwad.make_dual(x, torch.ones_like(x))
        assert f.value_and_grad(dual, **BALL) is None
    # and where it runs, the ball's closed forms
    value, gradient = f.value_and_grad(x, **BALL)
    d = x.numpy() - BALL_CENTER
    np.testing.assert_allclose(value.numpy(), BALL["r"] ** 2 - (d * d).sum(1), rtol=0, atol=1e-14)
    np.testing.assert_allclose(gradient.numpy(), -2 * d, rtol=0, atol=1e-14)


def test_param_derivative_of_a_compiled_model_is_the_eager_one(fast):
    x = in_bounds(fig1_part, 3000, seed=5)
    for name in fig1_part.names:
        with kernel_calls(fast["fig1_part"]) as sizes:
            got = param_derivative(fast["fig1_part"], x, name, {"r": 0.35})
        assert sizes == [], name  # per-sample reverse mode runs under torch.func: the eager model
        want = param_derivative(fig1_part, x, name, {"r": 0.35})
        assert np.abs(want).max() > 0.1  # the cylinders move with r
        np.testing.assert_array_equal(got, want, err_msg=name)


def test_sphere_value_and_gradient_match_the_closed_form(fast):
    f = fast["ball"]
    x = in_bounds(ball, 2000, seed=6)
    d = x - BALL_CENTER
    with kernel_calls(f) as sizes:
        value, gradient = value_and_grad(functools.partial(f, **BALL), x)
    assert sizes == [2000]
    np.testing.assert_allclose(value, BALL["r"] ** 2 - (d * d).sum(1), rtol=0, atol=1e-14)
    np.testing.assert_allclose(gradient, -2 * d, rtol=0, atol=1e-14)


def test_sphere_parameter_derivatives_match_the_closed_forms(fast):
    f = fast["ball"]
    x = in_bounds(ball, 2000, seed=6)
    with kernel_calls(f) as sizes:
        df_dr = param_derivative(f, x, "r", BALL)
        # a parameter inside the centre vector: one point and 0-d parameters per sample, no broadcasting
        df_dcx = param_derivative(f, x, "cx", BALL)
    assert sizes == []  # under torch.func: eager
    np.testing.assert_allclose(df_dr, np.full(2000, 2 * BALL["r"]), rtol=0, atol=1e-14)
    np.testing.assert_allclose(df_dcx, 2 * (x[:, 0] - BALL["cx"]), rtol=0, atol=1e-14)


def test_first_order_parameter_gradients_of_a_loss_through_the_kernel(fast):
    """Scalar parameters that require grad (a fit's loss), differentiated by the kernel's backward."""
    f = fast["ball"]
    x = torch.as_tensor(in_bounds(ball, 2000, seed=7))
    r = torch.tensor(BALL["r"], dtype=torch.float64, requires_grad=True)
    cx = torch.tensor(BALL["cx"], dtype=torch.float64, requires_grad=True)
    with kernel_calls(f) as sizes, first_order():
        loss = f(x, r=r, cx=cx).sum()
    assert sizes == [2000]
    loss.backward()
    assert r.grad.item() == pytest.approx(2000 * 2 * BALL["r"], rel=1e-13)
    assert cx.grad.item() == pytest.approx(2 * (x[:, 0] - BALL["cx"]).sum().item(), rel=1e-12, abs=1e-10)


# ----------------------------------------------------------------------------- eager fallbacks


def test_hessian_and_curvatures_fall_back_to_eager_and_are_exact(fast):
    f = functools.partial(fast["ball"], **BALL)
    x = in_bounds(ball, 500, seed=8)
    with kernel_calls(fast["ball"]) as sizes:
        h = hessian(f, x)
        directions = np.random.default_rng(9).normal(size=(500, 3))
        on_sphere = BALL_CENTER + BALL["r"] * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        c = curvatures(f, on_sphere)
    assert sizes == []  # second derivatives: never the kernel (it cannot be differentiated twice)
    np.testing.assert_allclose(h, np.broadcast_to(-2 * np.eye(3), (500, 3, 3)), rtol=0, atol=1e-13)
    for k in (c.H, c.kmin, c.kmax):
        np.testing.assert_allclose(k, 1 / BALL["r"], rtol=1e-12)
    np.testing.assert_allclose(c.K, 1 / BALL["r"] ** 2, rtol=1e-12)


def test_create_graph_and_a_users_own_second_derivative_fall_back_to_eager(fast):
    f = fast["ball"]
    x = torch.as_tensor(in_bounds(ball, 400, seed=10)).requires_grad_(True)
    d = (x - torch.as_tensor(BALL_CENTER)).detach()
    with kernel_calls(f) as sizes:
        # value_and_grad keeping the graph: |grad f|^2 = 4 |x - c|^2 has gradient 8 (x - c)
        _, g = value_and_grad(functools.partial(f, **BALL), x, create_graph=True)
        (dloss,) = torch.autograd.grad((g * g).sum(), x)
        # a user's own autograd with create_graph: the Laplacian of r^2 - |x - c|^2 is -6
        y = f(x, **BALL)
        (g2,) = torch.autograd.grad(y.sum(), x, create_graph=True)
        laplacian = sum(torch.autograd.grad(g2[:, i].sum(), x, retain_graph=True)[0][:, i] for i in range(3))
    assert sizes == []
    torch.testing.assert_close(g.detach(), -2 * d, rtol=0, atol=1e-14)
    torch.testing.assert_close(dloss, 8 * d, rtol=0, atol=1e-13)
    torch.testing.assert_close(g2.detach(), -2 * d, rtol=0, atol=1e-14)
    torch.testing.assert_close(laplacian, torch.full((400,), -6.0, dtype=torch.float64), rtol=0, atol=1e-14)


def test_param_grad_under_torch_func_falls_back_to_eager(fast):
    f = fast["ball"]
    x = in_bounds(ball, 400, seed=11)
    with kernel_calls(f) as sizes:
        got = param_grad(f, x, BALL)
    assert sizes == []  # per-sample reverse mode inside torch.func: eager
    np.testing.assert_allclose(got["r"], np.full(400, 2 * BALL["r"]), rtol=0, atol=1e-14)
    np.testing.assert_allclose(got["cx"], 2 * (x[:, 0] - BALL["cx"]), rtol=0, atol=1e-14)
    want = param_grad(fig1_part, x, {"r": 0.35})
    np.testing.assert_allclose(param_grad(fast["fig1_part"], x, {"r": 0.35})["r"], want["r"], rtol=0, atol=0)


def test_batched_parameters_and_a_single_point_fall_back_to_eager(fast):
    f = fast["ball"]
    x = in_bounds(ball, 300, seed=12)
    radii = torch.tensor([0.6, 1.0, 1.4, 0.8])
    with kernel_calls(f) as sizes:
        batch = f(torch.as_tensor(x), r=radii, cx=0.3)
        one = f(x[:1], **BALL)
        bare = f(torch.as_tensor(x[0]), **BALL)
    assert sizes == []
    d2 = ((x - BALL_CENTER) ** 2).sum(1)
    assert batch.shape == (4, 300)
    np.testing.assert_allclose(batch.numpy(), radii.double().numpy()[:, None] ** 2 - d2, rtol=0, atol=1e-14)
    assert isinstance(one, np.ndarray) and one.shape == (1,)
    np.testing.assert_allclose(one, BALL["r"] ** 2 - d2[:1], rtol=0, atol=1e-14)
    assert bare.shape == () and bare.item() == pytest.approx(BALL["r"] ** 2 - d2[0], abs=1e-14)
    # a batch of the fig1 part: each row is the eager model at that radius
    got = fast["fig1_part"](x, r=np.array([0.3, 0.5]))
    np.testing.assert_allclose(got, fig1_part(x, r=np.array([0.3, 0.5])), rtol=0, atol=0)
    np.testing.assert_allclose(got[1], fig1_part(x, r=0.5), rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------- compile failure, model errors


@torch.library.custom_op("pyfrep_test_compiled::opaque_copy", mutates_args=())
def opaque_copy(x: torch.Tensor) -> torch.Tensor:
    """A custom operator without a fake (meta) implementation: dynamo cannot trace it, eager runs it."""
    return x.clone()


opaque_copy.register_autograd(lambda ctx, cotangent: cotangent)  # the identity's derivative


@model(bounds=((-2.0,) * 3, (2.0,) * 3), r=Param(1.0, 0.5, 1.5))
def opaque_ball(x, r):
    return sphere(opaque_copy(x), r=r)


@model(bounds=((-2.0,) * 3, (2.0,) * 3), r=Param(1.0, 0.5, 1.5))
def checked_ball(x, r):
    if bool((x.abs() > 2.0).any()):  # data-dependent: dynamo breaks the graph here and runs it in Python
        raise ValueError("checked_ball: a point lies outside [-2, 2]^3")
    return sphere(x, r=r)


@contextmanager
def model_calls(fast, name):
    """Record the number of points of every call of ``fast``'s method ``name`` (its checked path)."""
    sizes, method = [], getattr(fast, name)

    def count(x, *args, **kwargs):
        sizes.append(x.shape[0])
        return method(x, *args, **kwargs)

    setattr(fast, name, count)
    try:
        yield sizes
    finally:
        delattr(fast, name)  # the class's method again


def component_first(x, dtype=torch.float64):
    """Points (N, d) as a tensor of their own laid out component-first (x[:, 0] contiguous)."""
    x = torch.as_tensor(x, dtype=dtype)
    return torch.empty_strided(x.shape, (1, x.shape[0]), dtype=dtype).copy_(x)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_a_values_kernel_goes_straight_to_the_kernel_with_the_models_values(fast, dtype):
    f = fast["fig1_part"]
    kernel = f.values_kernel(r=0.35)
    x = component_first(in_bounds(fig1_part, 3000, seed=20), dtype)
    want = f(x, r=0.35)  # the model's call: the same compiled kernel
    with kernel_calls(f, ("_kernel",)) as sizes, model_calls(f, "_evaluate") as checked, torch.no_grad():
        first = kernel(x)  # the first of this dtype: through the model's call
        second = kernel(x)  # the second through dynamo, whose guards choose the graph
        with warnings.catch_warnings(), probe() as through_dynamo:
            warnings.simplefilter("error")
            again = [kernel(x) for _ in range(3)]
    # the model's checks once, dynamo once (and on a copy of 16 rows, the first time this graph is
    # called directly: the same result), then the graph alone
    assert checked == [3000] and sizes[:2] == [3000, 3000] and sizes[2:] in ([], [16])
    assert through_dynamo == []
    for got in [first, second, *again]:
        assert got.dtype == dtype and torch.equal(got, want)
    # the rest take the model's call, with its values: a row-major layout, a view, a graph, one point
    rows = x.contiguous()
    torch.testing.assert_close(kernel(rows), want, rtol=0, atol=0)
    torch.testing.assert_close(kernel(x[:100]), want[:100], rtol=0, atol=0)
    xg = x.clone().requires_grad_(True)
    (g,) = torch.autograd.grad(kernel(xg).sum(), xg)
    (want_g,) = torch.autograd.grad(fig1_part(xg, r=0.35).sum(), xg)
    scale = float(want_g.abs().max())
    tol = 1e-12 if dtype == torch.float64 else 1e-4  # autograd's passes, eager and compiled, to rounding
    torch.testing.assert_close(g, want_g, rtol=tol, atol=tol * scale)
    torch.testing.assert_close(kernel(x[:1].clone()), fig1_part(x[:1], r=0.35), rtol=1e-6, atol=1e-6)


def test_a_values_kernels_first_derivatives_are_the_fused_kernels_and_keep_the_callers_layout(fast):
    from pyfrep_core.meshing.roots import _bound
    from pyfrep_core.meshing.roots import _value_and_grad as mesher_value_and_grad

    f = fast["fig1_part"]
    kernel = f.values_kernel(r=0.35)
    x = component_first(in_bounds(fig1_part, 3000, seed=23))
    want_value, want_gradient = f.value_and_grad(x, r=0.35)
    with kernel_calls(f, ("_kernel", "_first_order_kernel")) as sizes, model_calls(f, "value_and_grad") as checked:
        got = [kernel.value_and_grad(x) for _ in range(2)]  # the first through the model's method, then dynamo
        with probe() as through_dynamo:
            got += [kernel.value_and_grad(x) for _ in range(2)]  # the graph dynamo chose, called directly
    assert checked == [3000] and sizes[:2] == [3000, 3000] and sizes[2:] in ([], [16]) and through_dynamo == []
    for value, gradient in got:
        assert torch.equal(value, want_value) and torch.equal(gradient, want_gradient)
    assert kernel.value_and_grad(x[:1].clone()) is None  # one point: the model's method declines
    # the mesher's gradients through it: the values of diff's passes, in the caller's layout
    bound = _bound(f, "cpu")  # at the default parameters
    for points in (x.numpy(), np.ascontiguousarray(x.numpy())):
        value, gradient = mesher_value_and_grad(bound, points, "cpu")
        generic = value_and_grad(functools.partial(f, r=fig1_part.check()["r"]), points)
        np.testing.assert_array_equal(value, generic[0])
        np.testing.assert_array_equal(gradient, generic[1])
        assert gradient.flags.c_contiguous == points.flags.c_contiguous
        assert gradient.flags.f_contiguous == points.flags.f_contiguous


@model(bounds=((-2.0,) * 3, (2.0,) * 3), r=Param(1.0, 0.5, 1.5))
def rows_ball(x, r):
    """A ball whose formula depends on how many points come at once (the kernel must not reuse a graph
    across that condition): r^2 - |x|^2 for fewer than 50 points, 2 (r^2 - |x|^2) for more."""
    scale = 1.0 if x.shape[0] < 50 else 2.0
    return scale * sphere(x, r=r)


SHIFT = [0.0]  # a global a model reads


@model(bounds=((-2.0,) * 3, (2.0,) * 3), r=Param(1.0, 0.5, 1.5))
def shifted_ball(x, r):
    """r^2 - |x|^2 + SHIFT[0]: a model reading a global (dynamo guards its value)."""
    return sphere(x, r=r) + SHIFT[0]


def ball_values(x):
    """ball at BALL, in closed form (numpy)."""
    return BALL["r"] ** 2 - ((x - BALL_CENTER) ** 2).sum(1)


def rounding_bound(m, x, dtype, **params):
    """|f_dtype - f_numpy| at points x (N,) float64: the first-order rounding bound of model ``m`` in ``dtype``
    plus that of the float64 closed form it is compared with."""
    eps = torch.finfo(dtype).eps + torch.finfo(torch.float64).eps
    return (ULPS_PER_OPERATION * eps * condition_sum(m, x.double(), **params)).numpy()


def _direct_and_right(kernel, m, params, want, sizes, dtype=torch.float64, seed=40):
    """For each number of points: kernel's values against want(x) (numpy, float64) within the rounding
    bound of model ``m`` in ``dtype``, and whether the call reached the graph directly (no graph run
    through dynamo)."""
    direct = []
    for k, n in enumerate(sizes):
        x = component_first(in_bounds(m, n, seed=seed + k), dtype)
        with probe() as through_dynamo:
            got = kernel(x)
        assert got.dtype == dtype and got.shape == (n,)
        exact = want(x.double().numpy())
        assert (np.abs(got.double().numpy() - exact) <= rounding_bound(m, x, dtype, **params)).all()
        direct.append(through_dynamo == [])
    return direct


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_a_values_kernel_calls_the_graph_dynamo_chose_directly_for_any_number_of_points(dtype):
    f = compiled(ball)
    kernel = f.values_kernel(**BALL)
    sizes = [3000, 3000, 2, 3, 16, 17, 1000, 70_000]

    direct = _direct_and_right(kernel, ball, BALL, ball_values, sizes, dtype)
    assert direct == [False, False] + [True] * 6  # the model's call, dynamo's, then the graph alone
    # first derivatives: the same, through the fused first-order kernel's graph
    x = component_first(in_bounds(ball, 500, seed=41), dtype)
    calls = []
    for _ in range(3):
        with probe() as through_dynamo:
            value, gradient = kernel.value_and_grad(x)
        calls.append(through_dynamo == [])
        exact = ball_values(x.double().numpy())
        assert (np.abs(value.double().numpy() - exact) <= rounding_bound(ball, x, dtype, **BALL)).all()
        want_gradient = -2 * (x.double().numpy() - BALL_CENTER)  # one rounding of x - c, doubled
        np.testing.assert_allclose(
            gradient.numpy(), want_gradient, rtol=0, atol=1e-6 if dtype == torch.float32 else 1e-15
        )
    assert calls == [False, False, True]


def test_a_values_kernel_keeps_going_through_dynamo_where_a_graph_alone_would_be_wrong():
    # a formula that depends on the number of points: the graph has a guard on it
    f = compiled(rows_ball)
    kernel = f.values_kernel(r=1.2)

    def scaled(x):
        return (1.0 if len(x) < 50 else 2.0) * (1.2**2 - (x * x).sum(1))

    direct = _direct_and_right(kernel, rows_ball, {"r": 1.2}, scaled, [3000, 3000, 20, 3000, 10, 100])
    assert not any(direct)
    # a graph break (a check in Python on the points' values): two graphs, Python between them
    f = compiled(checked_ball)
    kernel = f.values_kernel(r=1.2)
    direct = _direct_and_right(kernel, checked_ball, {"r": 1.2}, lambda x: 1.2**2 - (x * x).sum(1), [500, 500, 700, 30])
    assert not any(direct)
    # compiled for one number of points (dynamic=False): no graph for any other
    f = compiled(ball, dynamic=False)
    kernel = f.values_kernel(**BALL)
    direct = _direct_and_right(kernel, ball, BALL, ball_values, [300, 300, 300, 40])
    assert not any(direct[:2]) and not direct[3]


def test_a_values_kernel_made_after_a_global_changes_sees_the_new_value():
    f = compiled(shifted_ball)
    x = component_first(in_bounds(shifted_ball, 400, seed=42))
    want = 1.1**2 - (x.numpy() ** 2).sum(1)
    try:
        for shift in (0.0, 0.5, -0.25):  # a mesh, the global changed, another mesh, ...
            SHIFT[0] = shift
            kernel = f.values_kernel(r=1.1)
            bound = rounding_bound(shifted_ball, x, torch.float64, r=1.1)
            for _ in range(4):
                assert (np.abs(kernel(x).numpy() - (want + shift)) <= bound).all()
    finally:
        SHIFT[0] = 0.0


def test_a_values_kernel_from_two_threads_and_after_a_failure_gives_the_models_values(fast):
    f = compiled(ball)
    kernel = f.values_kernel(**BALL)
    xs = [component_first(in_bounds(ball, 2000, seed=s)) for s in (21, 22)]
    want = [BALL["r"] ** 2 - ((x.numpy() - BALL_CENTER) ** 2).sum(1) for x in xs]
    kernel(xs[0])  # compiled here
    start, got, errors = threading.Barrier(2), {}, []

    def run(i):
        try:
            start.wait()
            got[i] = [kernel(xs[i]) for _ in range(20)]
        except Exception as error:  # reported below
            errors.append(error)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors, errors
    for i in range(2):
        for values in got[i]:
            np.testing.assert_allclose(values.numpy(), want[i], rtol=0, atol=1e-14)

    def broken(flat, **params):
        raise RuntimeError("no C++ compiler found")

    f._kernel = broken  # a failure: the kernel is not called again, the eager model answers
    kernel = f.values_kernel(**BALL)  # (the kernel above calls the graph it found directly: unbroken)
    with pytest.warns(RuntimeWarning, match="no C\\+\\+ compiler found"):
        np.testing.assert_allclose(kernel(xs[0]).numpy(), want[0], rtol=0, atol=1e-14)
    assert f.failure is not None
    np.testing.assert_allclose(kernel(xs[1]).numpy(), want[1], rtol=0, atol=1e-14)


def test_a_model_that_fails_to_compile_warns_once_and_evaluates_eagerly():
    fast_opaque = compiled(opaque_ball)
    x = in_bounds(opaque_ball, 200, seed=13)
    want = (1.1**2 - (x * x).sum(1), -2 * x)
    with pytest.warns(RuntimeWarning, match=r"compiled\(opaque_ball\): torch\.compile failed") as record:
        got = fast_opaque(x, r=1.1)
    assert len([w for w in record if issubclass(w.category, RuntimeWarning)]) == 1
    assert fast_opaque.failure is not None
    np.testing.assert_allclose(got, want[0], rtol=0, atol=1e-14)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once: later calls, values or gradients, stay silent
        again = fast_opaque(torch.as_tensor(x), r=1.1)
        value, gradient = value_and_grad(functools.partial(fast_opaque, r=1.1), x)
    np.testing.assert_allclose(again.numpy(), want[0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(value, want[0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(gradient, want[1], rtol=0, atol=1e-14)


def test_a_kernel_that_raises_is_replaced_by_the_eager_model_with_one_warning():
    fast_ball = compiled(ball)

    def broken(flat, **params):
        raise RuntimeError("no C++ compiler found")

    fast_ball._kernel = broken
    x = in_bounds(ball, 100, seed=14)
    with pytest.warns(RuntimeWarning, match=r"compiled\(ball\).*RuntimeError: no C\+\+ compiler found"):
        got = fast_ball(x, **BALL)
    np.testing.assert_allclose(got, BALL["r"] ** 2 - ((x - BALL_CENTER) ** 2).sum(1), rtol=0, atol=1e-14)
    assert isinstance(fast_ball.failure, RuntimeError)


def test_a_genuine_error_of_the_model_propagates_and_is_not_taken_for_a_compile_failure():
    fast_checked = compiled(checked_ball)
    x = in_bounds(checked_ball, 100, seed=15)
    outside = x.copy()
    outside[17] = (0.0, 2.5, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        with kernel_calls(fast_checked) as tried, pytest.raises(ValueError, match="a point lies outside"):
            fast_checked(outside)
        assert tried == [100]  # raised inside the kernel, then again by the eager model
        assert fast_checked.failure is None
        with kernel_calls(fast_checked) as sizes:
            got = fast_checked(x, r=0.9)  # still compiled afterwards
    assert sizes == [100] and fast_checked.failure is None
    np.testing.assert_allclose(got, 0.81 - (x * x).sum(1), rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------- meshing, warm-up, threads


@pytest.fixture(scope="module")
def warmed(fast):
    """fig1_part's compiled model after warm_up at its default parameters."""
    warm_up(fast["fig1_part"])
    return fast["fig1_part"]


def test_polygonize_through_the_kernel_gives_the_eager_mesh(warmed):
    with kernel_calls(warmed) as sizes:
        mesh = polygonize(functools.partial(warmed, r=0.4), fig1_part.bounds, 64)
    assert max(sizes) == min(64**3, warmed.chunk_points)  # the grid in the compiled model's chunk size
    want = polygonize(functools.partial(fig1_part, r=0.4), fig1_part.bounds, 64)
    assert mesh.n_faces > 10_000
    np.testing.assert_array_equal(mesh.faces, want.faces)
    np.testing.assert_allclose(mesh.vertices, want.vertices, rtol=0, atol=1e-12)
    # normals are -grad f: on the part's sharp edges grad f jumps, and a vertex there takes one
    # side's gradient or the other's by the last bit of its position; elsewhere they agree
    differ = np.abs(mesh.normals - want.normals).max(axis=1) > 1e-9
    assert differ.mean() < 0.01, differ.sum()
    assert (edge_counts(mesh.faces) == 2).all()  # closed: every edge in exactly two faces
    np.testing.assert_allclose(fig1_part(mesh.vertices, r=0.4), 0.0, atol=1e-12)


def test_the_graph_counter_moves_on_a_compile_and_on_a_recompile():
    """What the next test relies on: ``compiled_graphs`` counts a new function and a new dtype of it."""

    @model(bounds=((-1.0,) * 3, (1.0,) * 3), h=Param(0.0, -0.5, 0.5))
    def plane(x, h):
        return x[..., 2] - h

    fast_plane = compiled(plane)
    before = compiled_graphs()
    fast_plane(torch.zeros(5, 3, dtype=torch.float64))
    assert compiled_graphs() == before + 1
    fast_plane(torch.zeros(5, 3, dtype=torch.float32))
    assert compiled_graphs() == before + 2


def test_polygonize_and_param_derivative_compile_nothing_after_warm_up(warmed):
    before = compiled_graphs()
    with kernel_calls(warmed) as sizes:
        mesh = polygonize(functools.partial(warmed, r=0.3), fig1_part.bounds, 48)  # other r, other grid size
        df_dr = param_derivative(warmed, mesh.vertices, "r", {"r": 0.3})  # eager, under torch.func
        first_777 = param_derivative(warmed, mesh.vertices[:777], "r", {"r": 0.3})
    assert len(sizes) >= 3  # grid, root finding, gradient: all through the kernel
    assert compiled_graphs() == before, "a variant was compiled after warm_up"
    np.testing.assert_allclose(df_dr, param_derivative(fig1_part, mesh.vertices, "r", {"r": 0.3}), rtol=1e-12)
    np.testing.assert_array_equal(first_777, df_dr[:777])  # another number of points, no recompile


def test_two_threads_share_a_compiled_model(fast):
    """One thread takes gradients through the kernel while the other differentiates twice eagerly."""
    f, ball_fast = fast["fig1_part"], fast["ball"]
    x = in_bounds(fig1_part, 4000, seed=16)
    radii = (0.3, 0.45, 0.6)
    want = {r: value_and_grad(functools.partial(fig1_part, r=r), x) for r in radii}
    xb = torch.as_tensor(in_bounds(ball, 500, seed=17))
    start = threading.Barrier(2)
    results, errors = {}, []

    def values_and_gradients():
        try:
            start.wait()
            for r in radii:
                results[r] = (f(x, r=r), value_and_grad(functools.partial(f, r=r), x)[1])
        except Exception as error:  # reported below with the thread's traceback
            errors.append(error)

    def second_derivatives():
        try:
            start.wait()
            for _ in range(5):
                xr = xb.clone().requires_grad_(True)
                (g,) = torch.autograd.grad(ball_fast(xr, **BALL).sum(), xr, create_graph=True)
                (row,) = torch.autograd.grad(g[:, 0].sum(), xr)
                results.setdefault("rows", []).append(row)
        except Exception as error:
            errors.append(error)

    threads = [threading.Thread(target=values_and_gradients), threading.Thread(target=second_derivatives)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert not errors, errors
    for r in radii:
        np.testing.assert_allclose(results[r][0], want[r][0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(results[r][1], want[r][1], rtol=1e-12, atol=1e-12 * np.abs(want[r][1]).max())
    expected_row = torch.zeros_like(xb)
    expected_row[:, 0] = -2.0
    assert len(results["rows"]) == 5
    for row in results["rows"]:
        torch.testing.assert_close(row, expected_row, rtol=0, atol=0)


# ----------------------------------------------------------------------------- construction


def test_compiled_takes_only_models_is_idempotent_and_says_what_it_is(fast):
    with pytest.raises(TypeError, match="function"):
        compiled(lambda x: x[..., 0])
    with pytest.raises(TypeError, match="CompiledModel.*Model"):
        warm_up(fig1_part)
    f = fast["fig1_part"]
    assert isinstance(f, CompiledModel) and compiled(f) is f and f.eager is fig1_part
    assert repr(f).startswith("<compiled model fig1_part(r=0.5")
    assert (f.__name__, f.names, f.bounds, f.dim, f.defaults()) == (
        "fig1_part",
        fig1_part.names,
        fig1_part.bounds,
        3,
        fig1_part.defaults(),
    )
    assert fast["ellipse"].dim == 2 and fast["ellipse"].bounds == ellipse.bounds
    with pytest.raises(ValueError, match="outside its range"):
        f.check(r=2.0)


# ----------------------------------------------------------------------------- fused second order


@model(bounds=((-1.5, -1.5, -0.5), (1.5, 1.5, 0.5)), R=Param(1.0, 0.6, 1.4), r=Param(0.3, 0.1, 0.5))
def ring(x, R, r):
    """A torus written the way people write it: principal curvatures 1/r and cos v / (R + r cos v)."""
    return torusZ(x, center=(0.0, 0.0, 0.0), R=R, r=r)


def on_ring(n, seed, R=1.0, r=0.3):
    """Points on the torus and the tube angle v of each (v = 0 on the outer equator)."""
    u, v = np.random.default_rng(seed).uniform(0, 2 * np.pi, (2, n))
    rho = R + r * np.cos(v)
    return np.stack([rho * np.cos(u), rho * np.sin(u), r * np.sin(v)], axis=1), v


@pytest.fixture(scope="module")
def fused_ring():
    return compiled(ring, second_order=True)


def test_fused_curvatures_are_the_torus_closed_forms_and_the_eager_values(fused_ring):
    # 20,001 points: several pooled pieces, the last one shorter than the kernel's fixed chunk (padded)
    x, v = on_ring(20_001, seed=30)
    calls = []
    kernel = fused_ring.tangent_hessian
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(fused_ring, "tangent_hessian", lambda t: calls.append(t.shape[0]) or kernel(t))
        c = curvatures(fused_ring, x)
        h = mean_curvature(fused_ring, x)
        k = gaussian_curvature(fused_ring, x)
    assert sum(calls) == 3 * len(x)  # every point went through the fused kernel, three times
    eager = curvatures(ring, x)
    k_outer = np.cos(v) / (1.0 + 0.3 * np.cos(v))
    # float64, points on the exact surface: only rounding separates them from the closed forms
    np.testing.assert_allclose(c.kmin, np.minimum(1 / 0.3, k_outer), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(c.kmax, np.maximum(1 / 0.3, k_outer), rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(c.K, k_outer / 0.3, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(h, (1 / 0.3 + k_outer) / 2, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(k, c.K, rtol=1e-12, atol=1e-12)
    for name in ("H", "K", "kmin", "kmax"):
        np.testing.assert_allclose(getattr(c, name), getattr(eager, name), rtol=1e-12, atol=1e-12)
    # directions up to sign
    np.testing.assert_allclose(np.abs(np.sum(c.dmax * eager.dmax, axis=1)), 1.0, atol=1e-9)


def test_fused_curvatures_in_float32_and_from_threads_give_the_serial_values(fused_ring):
    from pyfrep_core.compiled import _kernels_release_the_gil

    assert _kernels_release_the_gil()  # torch 2.13's kernel binding, patched: threads run kernels side by side
    x, v = on_ring(3000, seed=31)
    x32 = torch.as_tensor(x, dtype=torch.float32)
    serial = curvatures(fused_ring, x32).H
    assert serial.dtype == torch.float32
    # float32: the closed form within a few hundred ulp of the largest curvature (10/3)
    np.testing.assert_allclose(serial.numpy(), (1 / 0.3 + np.cos(v) / (1 + 0.3 * np.cos(v))) / 2, atol=2e-4)
    results, errors = [], []

    def work():
        try:
            for _ in range(10):
                results.append(curvatures(fused_ring, x32).H)
        except Exception as error:  # reported below
            errors.append(error)

    threads = [threading.Thread(target=work) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert len(results) == 40
    for h in results:
        torch.testing.assert_close(h, serial, rtol=0, atol=0)


def test_a_kept_graph_or_a_plain_compiled_model_differentiates_eagerly(fused_ring):
    x = torch.as_tensor(on_ring(50, seed=32)[0])
    assert compiled(ring).tangent_hessian(x) is None  # second_order not asked for
    assert fused_ring.tangent_hessian(x.clone().requires_grad_(True)) is None
    xr = x.clone().requires_grad_(True)
    h = mean_curvature(fused_ring, xr, create_graph=True)  # a curvature term in a loss: the graph is kept
    (dh,) = torch.autograd.grad(h.sum(), xr)
    assert torch.isfinite(dh).all() and dh.abs().max() > 0
    with pytest.raises(ValueError, match="second_order"):
        warm_up(compiled(ring), dtypes=(), gradients=(), second_order=(torch.float64,))


def test_interval_bounds_of_a_compiled_model_are_the_eager_ones_and_leave_its_kernel_in_use(fast):
    # boxes (interval arithmetic, a tensor subclass) go through the eager model; before, the kernel
    # was tried on them, failed, and the model stayed eager for good (dual contouring ran eagerly)
    from pyfrep_core.interval import bounds

    f = fast["fig1_part"]
    lo = in_bounds(f, 200, seed=11)
    hi = lo + 0.1
    flo, fhi = bounds(f, lo, hi, r=0.35)
    elo, ehi = bounds(fig1_part, lo, hi, r=0.35)
    np.testing.assert_array_equal(flo, elo)
    np.testing.assert_array_equal(fhi, ehi)
    assert f.failure is None
    x = in_bounds(f, 1000, seed=12)
    with kernel_calls(f) as sizes:
        values = f(x, r=0.35)
    assert sizes == [1000]
    np.testing.assert_allclose(values, fig1_part(x, r=0.35), rtol=1e-12, atol=1e-12)
    m = polygonize(f, ((-1.1,) * 3, (1.1,) * 3), 24, method="dc", progress=False)
    assert f.failure is None and m.n_faces > 0


def test_threads_meeting_a_new_variant_compile_it_once():
    @model()
    def plate(x):  # a code object of its own: no variant compiled yet
        return 0.2 - x[:, 2].abs()

    fast = compiled(plate)
    x = torch.rand(1000, 3, dtype=torch.float64) - 0.5
    start = threading.Barrier(4)

    def first_call():
        start.wait()  # the four threads meet the float64 variant at once
        with torch.no_grad():
            return fast(x)

    before = compiled_graphs()
    threads = [threading.Thread(target=first_call) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert compiled_graphs() - before == 1  # one compiled, three waited for it
    torch.testing.assert_close(fast(x), plate(x), rtol=0, atol=0)
