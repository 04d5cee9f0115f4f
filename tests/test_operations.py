"""Blends, bounded blends, offset and shell against their formulas and their geometric effect."""

import math

import numpy as np
import pytest
import torch

from pyfrep_core import (
    blendDifference,
    blendIntersection,
    blendUnion,
    boundBlendIntersection,
    boundBlendUnion,
    difference_m,
    intersection_m,
    offset,
    shell,
    sphere,
    union_m,
)
from pyfrep_core.curvature import curvatures
from pyfrep_core.diff import value_grad_hessian
from pyfrep_core.normalization import delta_1, omega_1

RNG = np.random.default_rng(0)
F1, F2, F3 = (RNG.uniform(-2, 2, 300) for _ in range(3))


def r_union(a, b):
    return a + b + np.sqrt(a * a + b * b)


def r_inter(a, b):
    return a + b - np.sqrt(a * a + b * b)


def displacement(a, b, a0, a1, a2):
    return a0 / (1 + (a / a1) ** 2 + (b / a2) ** 2)


def bounded(a, b, c, a0, a1, a2, a3):  # the reference's piecewise form, written with numpy masks
    r1 = (a / a1) ** 2 + (b / a2) ** 2
    r2 = np.where(c > 0, (c / a3) ** 2, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(r1 > 0, r1 / (r1 + r2), 0.0)
    return np.where(r < 1, a0 * (1 - r) ** 3 / (1 + r), 0.0)


def test_blends_equal_the_formulas():
    a0, a1, a2 = 0.7, 0.5, 1.3
    np.testing.assert_allclose(
        blendUnion(F1, F2, a0, a1, a2), r_union(F1, F2) + displacement(F1, F2, a0, a1, a2), atol=1e-13
    )
    np.testing.assert_allclose(
        blendIntersection(F1, F2, a0, a1, a2), r_inter(F1, F2) + displacement(F1, F2, a0, a1, a2), atol=1e-13
    )
    np.testing.assert_allclose(
        blendDifference(F1, F2, -a0, a1, a2), r_inter(F1, -F2) + displacement(F1, -F2, -a0, a1, a2), atol=1e-13
    )
    np.testing.assert_allclose(
        boundBlendUnion(F1, F2, F3, a0, a1, a2, 0.8), r_union(F1, F2) + bounded(F1, F2, F3, a0, a1, a2, 0.8), atol=1e-13
    )
    np.testing.assert_allclose(
        boundBlendIntersection(F1, F2, F3, -a0, a1, a2, 0.8),
        r_inter(F1, F2) + bounded(F1, F2, F3, -a0, a1, a2, 0.8),
        atol=1e-13,
    )
    np.testing.assert_allclose(offset(F1, 0.3), F1 + 0.3, atol=0)
    np.testing.assert_allclose(shell(F1, 0.3), r_inter(F1 + 0.3, 0.3 - F1), atol=1e-13)


def test_blend_value_on_the_edge_is_a0_and_vanishes_far_away():
    z = torch.zeros(3, dtype=torch.float64)
    a0 = torch.tensor([0.2, 0.5, 1.0], dtype=torch.float64)
    torch.testing.assert_close(blendUnion(z, z, a0, 1.0, 1.0), a0, rtol=0, atol=1e-150)
    torch.testing.assert_close(blendIntersection(z, z, -a0, 1.0, 1.0), -a0, rtol=0, atol=1e-150)
    big = torch.tensor([1e4], dtype=torch.float64)
    far = (blendUnion(big, -big, 1.0, 1.0, 1.0) - big * math.sqrt(2)).item()  # displacement 1 / (1 + 2e8)
    assert abs(far - 1 / (1 + 2e8)) < 1e-11


def test_blend_union_fills_the_concave_corner():
    # half-spaces x >= 0 and y >= 0: their union misses the quadrant x, y < 0
    p = torch.tensor([[-0.1, -0.1, 0.0], [-1.0, -1.0, 0.0], [0.5, -2.0, 0.0]], dtype=torch.float64)
    f1, f2 = p[:, 0], p[:, 1]
    plain = r_union(f1.numpy(), f2.numpy())
    blended = blendUnion(f1, f2, 1.0, 1.0, 1.0)
    assert plain[0] < 0 and blended[0] > 0  # near the corner: filled
    assert blended[1] < 0  # far in the quadrant: still empty
    assert blended[2] > 0 and plain[2] > 0  # inside stays inside
    # blendIntersection with a0 < 0 rounds the convex corner of the quadrant x, y >= 0
    q = torch.tensor([[0.05, 0.05, 0.0], [2.0, 2.0, 0.0]], dtype=torch.float64)
    rounded = blendIntersection(q[:, 0], q[:, 1], -0.5, 1.0, 1.0)
    assert r_inter(0.05, 0.05) > 0 and rounded[0] < 0 and rounded[1] > 0


def test_bounded_blend_is_confined_to_the_bounding_solid():
    f1 = torch.from_numpy(F1)
    f2 = torch.from_numpy(F2)
    outside = -torch.from_numpy(np.abs(F3))  # f3 <= 0 everywhere
    torch.testing.assert_close(boundBlendUnion(f1, f2, outside, 1.0, 1.0, 1.0, 1.0), torch.from_numpy(r_union(F1, F2)))
    # on the edge f1 = f2 = 0 inside the bounding solid the displacement is a0
    z = torch.zeros(1, dtype=torch.float64)
    assert abs(boundBlendUnion(z, z, z + 1.0, 0.4).item() - 0.4) < 1e-12
    # continuous across the bounding surface f3 = 0
    e = 1e-9
    v = boundBlendUnion(f1, f2, torch.tensor([-e, e], dtype=torch.float64)[:, None], 1.0, 1.0, 1.0, 1.0)
    assert (v[0] - v[1]).abs().max() < 1e-6


@pytest.mark.parametrize(
    "op",
    [
        lambda a, b, c: blendUnion(a, b, 1.0, 0.5, 0.5),
        lambda a, b, c: blendIntersection(a, b, -1.0, 0.5, 0.5),
        lambda a, b, c: blendDifference(a, b, 1.0, 0.5, 0.5),
        lambda a, b, c: boundBlendUnion(a, b, c, 1.0, 0.5, 0.5, 0.5),
        lambda a, b, c: boundBlendIntersection(a, b, c, -1.0, 0.5, 0.5, 0.5),
        lambda a, b, c: shell(a, 0.1) + 0 * (b + c),
    ],
)
def test_gradients_finite_where_everything_vanishes(op):
    a, b, c = (torch.zeros(3, dtype=torch.float64, requires_grad=True) for _ in range(3))
    op(a, b, c).sum().backward()
    assert a.grad is not None and b.grad is not None
    for t in (a, b, c):
        assert t.grad is None or torch.isfinite(t.grad).all()


def test_blend_parameter_gradients_and_batches():
    f1 = torch.from_numpy(F1[:50])
    f2 = torch.from_numpy(F2[:50])
    a0 = torch.tensor(0.7, dtype=torch.float64, requires_grad=True)
    a1 = torch.tensor(0.5, dtype=torch.float64, requires_grad=True)
    blendUnion(f1, f2, a0, a1, 1.3).sum().backward()
    denom = 1 + (F1[:50] / 0.5) ** 2 + (F2[:50] / 1.3) ** 2
    assert math.isclose(a0.grad.item(), (1 / denom).sum(), rel_tol=1e-12)
    # d/da1 a0 / denom = a0 * 2 f1^2 / a1^3 / denom^2
    assert math.isclose(a1.grad.item(), (0.7 * 2 * F1[:50] ** 2 / 0.5**3 / denom**2).sum(), rel_tol=1e-12)
    batch = blendUnion(f1, f2, torch.tensor([[0.1], [0.7]], dtype=torch.float64), 0.5, 1.3)
    assert batch.shape == (2, 50)
    torch.testing.assert_close(batch[1], blendUnion(f1, f2, 0.7, 0.5, 1.3))


def test_numpy_and_float32():
    out = blendUnion(F1.astype(np.float32), F2.astype(np.float32), 0.5, 1.0, 1.0)
    assert isinstance(out, np.ndarray) and out.dtype == np.float32
    t = boundBlendUnion(*(torch.from_numpy(v).float() for v in (F1, F2, F3)), 0.5)
    assert t.dtype == torch.float32
    np.testing.assert_allclose(t.numpy(), boundBlendUnion(F1, F2, F3, 0.5), rtol=1e-5, atol=1e-5)


def test_shell_of_a_sphere_is_a_hollow_ball():
    r = np.array([0.0, 0.9, 1.0, 1.05, 1.3])
    x = np.stack([r, 0 * r, 0 * r], -1)
    f = shell(sphere(x, r=1.0), 0.2)  # |1 - r^2| <= 0.2  <=>  sqrt(0.8) <= r <= sqrt(1.2)
    np.testing.assert_array_equal(f > 0, [False, True, True, True, False])
    edge = np.array([[math.sqrt(1.2), 0, 0], [math.sqrt(0.8), 0, 0]])
    assert np.abs(shell(sphere(edge, r=1.0), 0.2)).max() < 1e-12
    grown = offset(sphere(np.array([[1.1, 0, 0]]), r=1.0), 0.3)  # level set 1 - r^2 = -0.3
    assert grown[0] > 0 and abs(offset(sphere(np.array([[math.sqrt(1.3), 0, 0]]), r=1.0), 0.3)[0]) < 1e-12


# ----------------------------------------------------------------------------- R_m functions


def r_m_closed_form(a, b, m, sign):
    """(value, d/da, d/db) of (a + b + sign rho) rho^m, rho = sqrt(a^2 + b^2) > 0 (numpy float64)."""
    rho = np.sqrt(a * a + b * b)
    value = (a + b + sign * rho) * rho**m
    da = (1 + sign * a / rho) * rho**m + (a + b + sign * rho) * m * rho ** (m - 2) * a
    db = (1 + sign * b / rho) * rho**m + (a + b + sign * rho) * m * rho ** (m - 2) * b
    return value, da, db


R_M = {
    "union_m": (union_m, 1.0, 1.0),
    "intersection_m": (intersection_m, -1.0, 1.0),
    "difference_m": (difference_m, -1.0, -1.0),
}


@pytest.mark.parametrize("m", [0.0, 0.5, 1.0, 2.0, 3.0])
@pytest.mark.parametrize("name", list(R_M))
def test_r_m_gradient_equals_the_closed_form_where_it_is_defined(name, m):
    op, sign, s2 = R_M[name]  # difference_m(f1, f2) = intersection_m(f1, -f2)
    # random points, and points on the axes (one argument 0, rho > 0: differentiable there)
    a = np.concatenate([F1[:100], np.zeros(5), [0.5, -1.5, 2.0, -0.25, 1e-3]])
    b = np.concatenate([F2[:100], [0.5, -1.5, 2.0, -0.25, 1e-3], np.zeros(5)])
    ta, tb = (torch.tensor(v, requires_grad=True) for v in (a, b))
    v = op(ta, tb, m=m)
    da, db = torch.autograd.grad(v.sum(), (ta, tb))
    want, wa, wb = r_m_closed_form(a, s2 * b, m, sign)
    np.testing.assert_allclose(v.detach().numpy(), want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(da.numpy(), wa, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(db.numpy(), s2 * wb, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("m", [0.0, 0.5, 1.0, 2.0])
@pytest.mark.parametrize("name", list(R_M))
def test_r_m_at_f1_equal_f2_equal_0_gives_finite_derivatives_and_the_sub_gradient(name, m, dtype):
    op, sign, s2 = R_M[name]
    rho0 = torch.finfo(dtype).tiny ** 0.25  # safe_sqrt(0)
    f = lambda p: op(p[..., 0] + 0.5 * p[..., 2], p[..., 1] - 0.3 * p[..., 2], m=m)  # noqa: E731
    x = torch.tensor([[0.0, 0.0, 0.0], [-0.25, 0.15, 0.5]], dtype=dtype)  # both on the crease f1 = f2 = 0
    value, g, h = value_grad_hessian(f, x)
    assert value.abs().max() <= 2 * rho0 ** (m + 1)
    # the sub-gradient: grad f1 + s2 grad f2 for m = 0 (the R_0 function, like union), else 0 (the R_m
    # function is homogeneous of degree m + 1 > 1 in (f1, f2): differentiable there with gradient 0)
    sub = torch.tensor([1.0, s2, 0.5 - 0.3 * s2], dtype=dtype) * (1.0 if m == 0 else 0.0)
    torch.testing.assert_close(g, sub.expand(2, 3), rtol=0, atol=2 * rho0**m if m else 4 * torch.finfo(dtype).eps)
    assert torch.isfinite(h).all()
    # on f = 0: omega_1 and delta_1 vanish (to rho0), the curvature is undefined (no curvature at a crease)
    assert omega_1(f, x).abs().max() <= rho0 and delta_1(f, x).abs().max() <= rho0
    c = curvatures(f, x)
    assert not c.defined.any() and all(torch.isnan(getattr(c, k)).all() for k in ("H", "K", "kmin", "kmax"))


def test_r_m_order_must_be_finite_and_nonnegative():
    for fn in (union_m, intersection_m, difference_m):
        for bad in (-1.0, math.nan, math.inf):
            with pytest.raises(ValueError, match=rf"{fn.__name__}: m must be"):
                fn(torch.zeros(2), torch.zeros(2), m=bad)
