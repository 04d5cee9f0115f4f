"""Normalizations (paper section 5.2): boundary conditions and the ellipse of Fig. 4 against its true distance."""

import math

import numpy as np
import pytest
import torch

from pyfrep_core import operations, polygonize, sphere, torusZ
from pyfrep_core.models import ellipse, ellipse_distance, fig1_part
from pyfrep_core.normalization import delta_1, normal_derivative, normalized, omega_1, omega_k

A, B = 5.0, 2.0


def on_ellipse(n=400):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + 0.01
    return np.column_stack([A * np.cos(t), B * np.sin(t)])


def test_omega_1_and_delta_1_vanish_on_the_curve_with_unit_normal_derivative():
    x = on_ellipse()
    for kind, fn in (("omega1", omega_1), ("delta1", delta_1)):
        assert np.abs(fn(ellipse, x)).max() < 1e-15
        d1 = normal_derivative(ellipse, x, 1, of=normalized(ellipse, kind))
        np.testing.assert_allclose(d1, 1.0, atol=1e-12)
    # f itself is not normalized: its normal derivative is |grad f|, far from 1 on this ellipse
    raw = normal_derivative(ellipse, x, 1)
    assert raw.min() < 0.45 and raw.max() > 0.95


def test_omega_k_boundary_conditions_of_the_recursion():
    x = on_ellipse(200)
    w1, w2, w3 = (normalized(ellipse, f"omega{k}") for k in (1, 2, 3))
    # omega_1's second normal derivative does not vanish on the ellipse: the conditions below can fail
    assert np.abs(normal_derivative(ellipse, x, 2, of=w1)).max() > 0.1
    for w, k in ((w2, 2), (w3, 3)):
        assert np.abs(w(x)).max() < 1e-14
        np.testing.assert_allclose(normal_derivative(ellipse, x, 1, of=w), 1.0, atol=1e-12)
        for order in range(2, k + 1):
            assert np.abs(normal_derivative(ellipse, x, order, of=w)).max() < 1e-10, (k, order)


def test_omega_k_in_three_dimensions():
    f = lambda p: torusZ(p, R=1.0, r=0.3)  # noqa: E731
    v = polygonize(f, ((-1.4, -1.4, -0.4), (1.4, 1.4, 0.4)), 24).vertices
    w2 = normalized(f, "omega2")
    assert np.abs(w2(v)).max() < 1e-14
    np.testing.assert_allclose(normal_derivative(f, v, 1, of=w2), 1.0, atol=1e-12)
    assert np.abs(normal_derivative(f, v, 2, of=w2)).max() < 1e-10
    # the Fig. 1 part on the smooth patches of its sphere (away from the creases of the R-functions)
    v = polygonize(fig1_part, resolution=32).vertices
    v = v[(np.abs(np.linalg.norm(v, axis=1) - 1) < 1e-9) & (np.abs(v).max(axis=1) < 0.7)]
    assert len(v) > 50
    np.testing.assert_allclose(normal_derivative(fig1_part, v, 1, of=normalized(fig1_part, "omega1")), 1.0, atol=1e-9)


def test_sphere_omega_1_and_delta_1_closed_forms():
    # f = r^2 - |x|^2: omega_1 = f / sqrt(f^2 + 4|x|^2), delta_1 = f / (2|x|)
    x = np.random.default_rng(0).uniform(-1, 1, size=(100, 3))
    f = sphere(x, r=0.7)
    rho = np.linalg.norm(x, axis=1)
    np.testing.assert_allclose(omega_1(lambda p: sphere(p, r=0.7), x), f / np.sqrt(f**2 + 4 * rho**2), rtol=1e-14)
    np.testing.assert_allclose(delta_1(lambda p: sphere(p, r=0.7), x), f / (2 * rho), rtol=1e-14)


def test_ellipse_of_fig4_distance_errors_near_the_curve():
    xs, ys = np.meshgrid(np.linspace(-7, 7, 141), np.linspace(-4, 4, 81))
    p = np.column_stack([xs.ravel(), ys.ravel()])
    d = ellipse_distance(p, A, B)
    band = np.abs(d) < 0.1
    assert band.sum() > 100
    errors = {
        name: np.abs(fn(p[band]) - d[band]).max()
        for name, fn in {
            "f": lambda q: ellipse(q),
            "omega_1": lambda q: omega_1(ellipse, q),
            "omega_2": lambda q: omega_k(ellipse, q, 2),
            "delta_1": lambda q: delta_1(ellipse, q),
        }.items()
    }
    print("max |approx - distance| for |distance| < 0.1:", {k: f"{v:.2e}" for k, v in errors.items()})
    # measured: f 6.0e-2, omega_1 3.2e-3, omega_2 1.0e-3, delta_1 3.1e-3
    assert errors["omega_2"] < 0.5 * errors["omega_1"]
    assert errors["omega_1"] < 0.1 * errors["f"] and errors["delta_1"] < 0.1 * errors["f"]
    assert errors["omega_2"] < 2e-3


def test_ellipse_distance_is_exact():
    x = on_ellipse(50)
    np.testing.assert_allclose(ellipse_distance(x), 0.0, atol=1e-12)
    # on the axes: beyond the centre of curvature of a vertex (x > a - b^2/a = 4.2) the vertex is
    # closest; nearer the centre the closest point has cos t = a x / (a^2 - b^2) (here 20/21)
    p = np.array([[0.0, 0.0], [6.0, 0.0], [0.0, -3.5], [4.5, 0.0], [4.0, 0.0]])
    want = [2.0, -1.0, -1.5, 0.5, math.sqrt(420) / 21]
    np.testing.assert_allclose(ellipse_distance(p), want, atol=1e-12)
    with pytest.raises(ValueError, match="shape"):
        ellipse_distance(np.zeros((3, 3)))


def test_zero_gradient_points():
    centre = np.array([[0.0, 0.0], [1.0, 0.5]])  # grad f = 0 at the centre of the ellipse
    w1 = omega_1(ellipse, centre)
    assert w1[0] == 1.0 and np.isfinite(w1).all()  # sign(f) there, as documented
    for fn in (lambda q: omega_k(ellipse, q, 2), lambda q: delta_1(ellipse, q)):
        v = fn(centre)
        assert np.isnan(v[0]) and np.isfinite(v[1])


def test_normalized_callable_meshes_slices_and_differentiates():
    w = normalized(fig1_part, "omega1")
    assert w.bounds == fig1_part.bounds and w.kind == "omega" and w.order == 1
    mesh = polygonize(w, resolution=24)  # called on (k, ny, nz, 3) grids under no_grad
    ref = polygonize(fig1_part, resolution=24)
    assert math.isclose(mesh.volume(), ref.volume(), rel_tol=1e-3)
    grid = torch.zeros(4, 5, 3, dtype=torch.float64)
    assert w(grid).shape == (4, 5)
    # differentiable when the points require grad: d delta_1 / dx of a sphere's field
    x = torch.tensor([[0.3, 0.0, 0.0]], dtype=torch.float64, requires_grad=True)
    v = normalized(lambda p: sphere(p, r=1.0), "delta1")(x)  # (1 - rho^2) / (2 rho)
    (g,) = torch.autograd.grad(v.sum(), x)
    assert math.isclose(g[0, 0].item(), -(1 / 0.3**2 + 1) / 2, rel_tol=1e-12)
    for bad in ("omega0", "delta2", "gauss", 3):
        with pytest.raises(ValueError, match="kind"):
            normalized(fig1_part, bad)
    with pytest.raises(ValueError, match="k must"):
        omega_k(ellipse, on_ellipse(3), 0)
    with pytest.raises(ValueError, match="non-finite"):
        omega_1(ellipse, np.array([[np.nan, 0.0]]))


def test_float32_and_torch_in_torch_out():
    x = torch.tensor(on_ellipse(10), dtype=torch.float32)
    for fn in (omega_1, delta_1, lambda f, q: omega_k(f, q, 2)):
        v = fn(ellipse, x)
        assert isinstance(v, torch.Tensor) and v.dtype == torch.float32 and v.abs().max() < 1e-5


def test_omega_2_of_a_sphere_equals_its_closed_form():
    # f = r^2 - |x|^2 is radial: omega_1(rho) = (r^2 - rho^2) / sqrt((r^2 - rho^2)^2 + 4 rho^2), the
    # normal n = -x/rho is constant along a ray, so d^2/dn^2 = d^2/drho^2 and omega_2 = w1 - w1^2 w1'' / 2
    sympy = pytest.importorskip("sympy")
    r, rho_ = 0.8, sympy.Symbol("rho", positive=True)
    w1 = (r**2 - rho_**2) / sympy.sqrt((r**2 - rho_**2) ** 2 + 4 * rho_**2)
    w2 = sympy.lambdify(rho_, w1 - w1**2 * sympy.diff(w1, rho_, 2) / 2)
    rng = np.random.default_rng(3)
    directions = rng.normal(size=(200, 3))
    rho = rng.uniform(0.1, 1.6, 200)
    x = directions / np.linalg.norm(directions, axis=1, keepdims=True) * rho[:, None]
    np.testing.assert_allclose(omega_k(lambda p: sphere(p, r=r), x, 2), w2(rho), rtol=1e-11, atol=1e-14)


F1 = lambda p: p[..., 0] + 0.5 * p[..., 2] ** 2  # noqa: E731
F2 = lambda p: p[..., 1] - 0.3 * p[..., 2]  # noqa: E731
CREASE = (-0.125, 0.15, 0.5)  # F1 = F2 = 0 there; the gradients (1, 0, 0.5) and (0, 1, -0.3) differ
ON_SURFACE = {  # the crease lies on f = 0
    "union": lambda p: operations.union(F1(p), F2(p)),
    "intersection": lambda p: operations.intersection(F1(p), F2(p)),
    "difference": lambda p: operations.difference(F1(p), F2(p)),
    "union_m": lambda p: operations.union_m(F1(p), F2(p)),
    "intersection_m": lambda p: operations.intersection_m(F1(p), F2(p)),
    "difference_m": lambda p: operations.difference_m(F1(p), F2(p)),
}
OFF_SURFACE = {  # the crease lies inside the solid (f = a0 there)
    "blendUnion": lambda p: operations.blendUnion(F1(p), F2(p), 0.5, 1.0, 1.0),
    "blendIntersection": lambda p: operations.blendIntersection(F1(p), F2(p), 0.5, 1.0, 1.0),
    "blendDifference": lambda p: operations.blendDifference(F1(p), -F2(p), 0.5, 1.0, 1.0),
    "boundBlendUnion": lambda p: operations.boundBlendUnion(F1(p), F2(p), p[..., 2] + 1.0, 0.5),
    "boundBlendIntersection": lambda p: operations.boundBlendIntersection(F1(p), F2(p), p[..., 2] + 1.0, 0.5),
}


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_omega_2_is_finite_on_the_creases_of_r_functions(dtype):
    rho0 = torch.finfo(dtype).tiny ** 0.25  # safe_sqrt(0): the value of an R-function on its crease
    # a crease on the surface: omega_2 = omega_1 = 0 up to rho0 (fig1_part: a block face meets a cylinder)
    fig1_creases = torch.tensor([[0.75, 0.5, 0.0], [0.5, 0.75, 0.0]], dtype=dtype)
    assert float(fig1_part(fig1_creases).abs().max()) <= rho0
    for kind in ("omega2", "omega1", "delta1"):
        assert float(normalized(fig1_part, kind)(fig1_creases).abs().max()) <= rho0, kind
    x = torch.tensor([CREASE], dtype=dtype)
    for name, f in ON_SURFACE.items():
        assert float(f(x).abs()) <= rho0, name
        for k in (1, 2):
            assert float(omega_k(f, x, k).abs()) <= 2 * rho0, (name, k)
    # a crease off the surface (a blend's edge, the Fig. 1 cube's edge outside the part): finite; there
    # the second normal derivative of omega_1 is unbounded and omega_2 huge (module notes)
    for name, f in OFF_SURFACE.items():
        assert float(f(x)) == pytest.approx(0.5, abs=2 * rho0), name
        assert torch.isfinite(omega_k(f, x, 2)).all(), name
        # omega_1 = f / sqrt(f^2 + |g|^2) with the sub-gradient g = (1, 0, 0.5) + (0, 1, -0.3)
        assert float(omega_1(f, x)) == pytest.approx(0.5 / math.sqrt(0.25 + 2.04), rel=1e-6), name
    assert torch.isfinite(omega_k(fig1_part, torch.tensor([[0.75, 0.75, 0.2]], dtype=dtype), 2)).all()
