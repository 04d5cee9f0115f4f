"""Derivative operators of pyfrep_core.diff against closed forms and finite differences (float64)."""

import math
import warnings

import numpy as np
import pytest
import torch

from pyfrep_core import block, cylZ, intersection, polygonize, sphere, torusZ, union
from pyfrep_core.diff import (
    div,
    grad,
    hessian,
    laplacian,
    p_laplacian,
    param_grad,
    project_to_surface,
    tangent_frame,
    tangent_hessian,
    value_and_grad,
    value_grad_hessian,
)
from pyfrep_core.models import fig1_part


def ball(x):
    return sphere(x, r=1.0)


def part(x):
    return fig1_part(x)


def random_points(n=500, seed=0, scale=1.0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-scale, scale, size=(n, 3))


def fd_grad(f, x, h=1e-6):
    """Central differences of f at x (N, d), numpy."""
    out = np.empty_like(x)
    for i in range(x.shape[1]):
        e = np.zeros(x.shape[1])
        e[i] = h
        out[:, i] = (f(x + e) - f(x - e)) / (2 * h)
    return out


def test_grad_matches_closed_form_and_finite_differences():
    x = random_points()
    np.testing.assert_allclose(grad(ball, x), -2 * x, rtol=0, atol=1e-14)
    g = grad(part, x)
    fd = fd_grad(lambda p: fig1_part(p), x)
    np.testing.assert_allclose(g, fd, rtol=1e-6, atol=1e-7)


def test_hessian_matches_closed_forms():
    x = random_points(50)
    h = hessian(ball, x)
    np.testing.assert_allclose(h, np.broadcast_to(-2 * np.eye(3), h.shape), atol=1e-14)
    # f = x y^2 z^3: every entry by hand
    px, py, pz = x.T
    h = hessian(lambda p: p[:, 0] * p[:, 1] ** 2 * p[:, 2] ** 3, x)
    want = np.stack(
        [
            np.stack([0 * px, 2 * py * pz**3, 3 * py**2 * pz**2], -1),
            np.stack([2 * py * pz**3, 2 * px * pz**3, 6 * px * py * pz**2], -1),
            np.stack([3 * py**2 * pz**2, 6 * px * py * pz**2, 6 * px * py**2 * pz], -1),
        ],
        1,
    )
    np.testing.assert_allclose(h, want, rtol=1e-13, atol=1e-13)


def test_hessian_matches_finite_differences_of_the_gradient_on_the_fig1_part():
    x = random_points(300, seed=1)
    h = hessian(part, x)
    fd = np.stack([fd_grad(lambda p, i=i: grad(part, p)[:, i], x) for i in range(3)], axis=1)
    np.testing.assert_allclose(h, fd, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(h, np.swapaxes(h, 1, 2), atol=1e-12)


def test_value_grad_hessian_one_call_and_chunking_and_threads_agree():
    x = torch.as_tensor(random_points(3000, seed=2))
    v, g, h = value_grad_hessian(part, x)
    v1, g1, h1 = value_grad_hessian(part, x, chunk=7)  # many chunks, threads
    v2, g2, h2 = value_grad_hessian(part, x, chunk=10**6)  # one piece
    for a, b, c in ((v, v1, v2), (g, g1, g2), (h, h1, h2)):
        torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-13)
        torch.testing.assert_close(a, c, rtol=1e-13, atol=1e-13)
    assert torch.equal(v, fig1_part(x))


def test_kinds_dtypes_and_batch_shapes_follow_the_input():
    x = random_points(10)
    assert isinstance(hessian(ball, x), np.ndarray)
    t32 = torch.as_tensor(x, dtype=torch.float32)
    h32 = hessian(ball, t32)
    assert h32.dtype == torch.float32 and h32.shape == (10, 3, 3)
    assert laplacian(ball, t32).dtype == torch.float32
    # points of shape (..., d) give results of shape (...)
    grid = torch.zeros(2, 5, 3, dtype=torch.float64)
    assert grad(ball, grid).shape == (2, 5, 3)
    assert hessian(ball, grid).shape == (2, 5, 3, 3)
    assert laplacian(ball, grid).shape == (2, 5)
    # 2-D points
    assert hessian(lambda p: p[:, 0] ** 2 * p[:, 1], np.array([[1.0, 2.0]])).shape == (1, 2, 2)


def test_create_graph_keeps_derivatives_differentiable():
    r = torch.tensor(0.7, dtype=torch.float64, requires_grad=True)
    x = torch.tensor([[0.1, 0.2, 0.3]], dtype=torch.float64, requires_grad=True)
    g = grad(lambda p: sphere(p, r=r) * r, x, create_graph=True)  # grad = -2 r x
    (dr,) = torch.autograd.grad(g.sum(), r, retain_graph=True)
    assert math.isclose(dr.item(), -2 * 0.6, rel_tol=1e-12)
    (dx,) = torch.autograd.grad(g.sum(), x)
    torch.testing.assert_close(dx, torch.full_like(x, -2 * 0.7))
    # the Laplacian of |x|^4 is 20 |x|^2: its x-gradient is 40 x
    lap = laplacian(lambda p: ((p * p).sum(-1)) ** 2, x, create_graph=True)
    (dx,) = torch.autograd.grad(lap.sum(), x)
    torch.testing.assert_close(dx, 40 * x.detach())


def test_div_laplacian_and_p_laplacian_closed_forms():
    x = random_points(100, seed=3)
    np.testing.assert_allclose(div(lambda p: p * p, x), 2 * x.sum(1), atol=1e-14)
    np.testing.assert_allclose(div(lambda p: grad(part, p, create_graph=True), x), laplacian(part, x), atol=1e-10)
    np.testing.assert_allclose(laplacian(ball, x), -6.0, atol=1e-14)
    # sphere: div(|g|^(p-2) g) = -2 (p + 1) (2 |x|)^(p - 2)
    rho = np.linalg.norm(x, axis=1)
    for p in (1.5, 2.0, 3.0, 4.5):
        np.testing.assert_allclose(p_laplacian(ball, x, p), -2 * (p + 1) * (2 * rho) ** (p - 2), rtol=1e-12)

    # against the divergence of the flux, by autograd
    def flux(q):
        g = grad(part, q, create_graph=True)
        return g * g.norm(dim=-1, keepdim=True)

    np.testing.assert_allclose(p_laplacian(part, x, 3.0), div(flux, x), rtol=1e-10, atol=1e-10)


def test_p_laplacian_at_zero_gradient_is_documented():
    origin = np.zeros((1, 3))
    assert p_laplacian(ball, origin, 2.0)[0] == -6.0
    assert p_laplacian(ball, origin, 3.0)[0] == 0.0
    assert np.isnan(p_laplacian(ball, origin, 1.5)[0])
    with pytest.raises(ValueError, match="p must be"):
        p_laplacian(ball, origin, 1.0)


def test_param_grad_closed_forms():
    x = random_points(200, seed=4)
    # d/dr (r^2 - |x|^2) = 2 r for a model with a radius
    from pyfrep_core import Param, model

    @model(r=Param(0.5, 0.1, 1.0), cz=Param(0.0, -1.0, 1.0))
    def moving_ball(p, r, cz):
        return sphere(p, center=(0.0, 0.0, cz), r=r)

    d = param_grad(moving_ball, x, {"r": 0.75, "cz": 0.25})
    assert list(d) == ["r", "cz"]
    np.testing.assert_allclose(d["r"], 1.5, rtol=1e-14)
    np.testing.assert_allclose(d["cz"], 2 * (x[:, 2] - 0.25), rtol=1e-13, atol=1e-14)
    # the Fig. 1 part: against a central difference in r
    h = 1e-6
    fd = (fig1_part(x, r=0.5 + h) - fig1_part(x, r=0.5 - h)) / (2 * h)
    np.testing.assert_allclose(param_grad(fig1_part, x)["r"], fd, rtol=1e-6, atol=1e-8)
    # chunked in threads = one piece
    t = torch.as_tensor(random_points(5000, seed=5))
    torch.testing.assert_close(param_grad(fig1_part, t, chunk=100)["r"], param_grad(fig1_part, t, chunk=10**6)["r"])


def test_param_grad_keeps_the_graph_and_checks_names():
    r = torch.tensor(0.5, dtype=torch.float64, requires_grad=True)
    x = torch.tensor([[0.6, 0.0, 0.0]], dtype=torch.float64)
    d = param_grad(fig1_part, x, {"r": r}, create_graph=True)["r"]
    # outside the drilled cylinders d/dr of the R-difference depends on r: its derivative exists
    (dd,) = torch.autograd.grad(d.sum(), r)
    assert torch.isfinite(dd)
    with pytest.raises(TypeError, match="radius"):
        param_grad(fig1_part, x, {"radius": 0.3})
    with pytest.raises(ValueError, match="outside"):
        param_grad(fig1_part, x, {"r": 5.0})
    with pytest.raises(TypeError, match="Model"):
        param_grad(ball, x)


def test_non_differentiable_points_give_finite_derivatives():
    # R-intersection and R-union exactly at f1 = f2 = 0: the sub-gradient grad f1 + grad f2
    x = torch.tensor([[0.0, 0.0, 0.5], [0.0, 0.0, 0.0]], dtype=torch.float64)
    for op in (intersection, union):
        v, g, h = value_grad_hessian(lambda p, op=op: op(p[:, 0], p[:, 1]), x)
        torch.testing.assert_close(g, torch.tensor([[1.0, 1.0, 0.0]] * 2, dtype=torch.float64))
        assert torch.isfinite(h).all()
    # the edge of the Fig. 1 cube (two block slabs vanish) and the torus axis (safe_sqrt at 0)
    edge = torch.tensor([[0.75, 0.75, 0.1]], dtype=torch.float64)
    cube = lambda p: block(p, vertex=(-0.75,) * 3, dx=1.5, dy=1.5, dz=1.5)  # noqa: E731
    assert torch.isfinite(grad(cube, edge)).all() and torch.isfinite(hessian(cube, edge)).all()
    axis = torch.tensor([[0.0, 0.0, 0.3]], dtype=torch.float64)
    assert torch.isfinite(grad(lambda p: torusZ(p, R=1.0, r=0.25), axis)).all()


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="non-finite"):
        grad(ball, np.array([[0.0, np.nan, 0.0]]))
    with pytest.raises(ValueError, match="non-finite"):
        hessian(ball, torch.tensor([[np.inf, 0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        param_grad(fig1_part, np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"a model must map points \(N, d\) to values \(N,\).*returned shape \(4, 3\)"):
        hessian(lambda p: p, np.zeros((4, 3)))
    with pytest.raises(ValueError, match="v must map"):
        div(lambda p: p[:, 0], np.zeros((4, 3)))
    with pytest.raises(ValueError, match="chunk"):
        grad(ball, np.zeros((4, 3)), chunk=0)
    with pytest.raises(TypeError):
        grad(ball, "points")
    with pytest.raises(ValueError, match="empty"):
        hessian(ball, np.zeros((0, 3)))


def test_constant_and_linear_functions_have_zero_higher_derivatives():
    x = random_points(5)
    np.testing.assert_array_equal(grad(lambda p: torch.ones(p.shape[0], dtype=p.dtype), x), 0.0)
    np.testing.assert_array_equal(hessian(lambda p: p[:, 0] + 2 * p[:, 1], x), 0.0)


def test_tangent_frame_is_orthonormal_and_tangent():
    rng = np.random.default_rng(6)
    n = torch.as_tensor(rng.normal(size=(10000, 3)))
    n = torch.cat([n, torch.tensor([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0], [0, 1e-300, -1.0]])])
    n = n / n.norm(dim=1, keepdim=True)
    t = tangent_frame(n)
    basis = torch.cat([t, n[:, None]], dim=1)  # (N, 3, 3): rows t0, t1, n
    torch.testing.assert_close(basis @ basis.transpose(1, 2), torch.eye(3, dtype=n.dtype).expand(len(n), 3, 3))
    torch.testing.assert_close(torch.linalg.cross(t[:, 0], t[:, 1]), n)
    t2 = tangent_frame(torch.tensor([[0.6, 0.8]]))
    torch.testing.assert_close(t2, torch.tensor([[[-0.8, 0.6]]]))


def test_tangent_hessian_is_the_projected_hessian():
    x = random_points(400, seed=7)
    _, g, frame, th = tangent_hessian(part, x)
    h = hessian(part, x)
    np.testing.assert_allclose(th, np.einsum("nai,nij,nbj->nab", frame, h, frame), rtol=1e-12, atol=1e-12)
    n = g / np.linalg.norm(g, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("nai,ni->na", frame, n), 0.0, atol=1e-15)


def test_projection_onto_sphere_torus_and_the_fig1_part():
    rng = np.random.default_rng(8)
    x = rng.normal(size=(2000, 3))
    x = x / np.linalg.norm(x, axis=1, keepdims=True) * rng.uniform(0.7, 1.3, size=(2000, 1))
    p = project_to_surface(ball, x)
    assert p.converged.all()
    np.testing.assert_allclose(np.linalg.norm(p.points, axis=1), 1.0, atol=1e-14)
    # Newton along grad f keeps a sphere's points on their ray
    np.testing.assert_allclose(np.cross(p.points, x), 0.0, atol=1e-14)
    torus = lambda q: torusZ(q, R=1.0, r=0.3)  # noqa: E731
    start = polygonize(torus, ((-1.4, -1.4, -0.4), (1.4, 1.4, 0.4)), 32, project=False).vertices
    t = project_to_surface(torus, start)
    assert t.converged.all()
    rho = np.hypot(t.points[:, 0], t.points[:, 1])
    np.testing.assert_allclose(np.hypot(rho - 1.0, t.points[:, 2]), 0.3, atol=1e-13)
    assert np.abs(t.points - start).max() < 2.8 / 31  # within a grid cell of marching cubes
    start = polygonize(fig1_part, resolution=48, project=False).vertices
    q = project_to_surface(part, start, max_step=0.1, max_distance=0.1, warn=False)
    assert q.converged.mean() > 0.999
    assert np.abs(fig1_part(q.points[q.converged])).max() < 1e-12


def test_projection_reports_points_that_cannot_converge():
    x = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])  # the second has grad f = 0
    with pytest.warns(RuntimeWarning, match="1 of 2 points did not converge"):
        p = project_to_surface(ball, x)
    assert p.converged.tolist() == [True, False]
    np.testing.assert_array_equal(p.points[1], x[1])  # kept where it was, and said so
    # f without a zero: every point is reported after max_iter steps
    with pytest.warns(RuntimeWarning, match="3 of 3"):
        p = project_to_surface(lambda q: 1.0 + (q * q).sum(-1), random_points(3), max_iter=5)
    assert not p.converged.any()
    # points farther than max_distance are not accepted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = project_to_surface(ball, np.array([[3.0, 0.0, 0.0]]), max_distance=1.0)
    assert not p.converged[0]
    with pytest.raises(ValueError, match="shape"):
        project_to_surface(ball, np.zeros((2, 2, 3)))


def test_value_and_grad_of_a_cylinder_in_float32():
    x = torch.tensor([[0.5, 0.0, 4.0]], dtype=torch.float32)
    v, g = value_and_grad(lambda p: cylZ(p, r=0.5), x)
    assert v.dtype == g.dtype == torch.float32
    torch.testing.assert_close(g, torch.tensor([[-1.0, 0.0, 0.0]]))


def test_an_f_that_differentiates_inside_the_chunked_threads_does_not_deadlock():
    x = torch.as_tensor(random_points(64, seed=9))

    def f(p):
        # a field built from a chunked derivative of another field, evaluated in the pool's threads
        inner = grad(ball, p.detach(), chunk=8)
        return (p * inner).sum(-1)

    g = grad(f, x, chunk=16)
    torch.testing.assert_close(g, -2 * x)
