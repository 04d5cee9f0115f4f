"""The primitive catalogue against closed forms: signs, exact zeros on known surface points,
finite gradients (also where a sqrt or a fractional power hits 0), numpy/torch, float32, batches."""

import math
from dataclasses import dataclass, field

import numpy as np
import pytest
import torch

from pyfrep_core import (
    blobby,
    block,
    circle,
    coneX,
    coneY,
    coneZ,
    cylX,
    cylY,
    cylZ,
    ellConeX,
    ellConeY,
    ellConeZ,
    ellCylX,
    ellCylY,
    ellCylZ,
    ellipse,
    ellipsoid,
    grad,
    metaBall,
    noiseG,
    rectangle,
    soft,
    sphere,
    superEll,
    superQuadric,
    torusX,
    torusY,
    torusZ,
)


def soft_weight(r, d):  # Wyvill's polynomial, the formula of the docstring
    q = (r / d) ** 2
    return 1 - 22 / 9 * q + 17 / 9 * q**2 - 4 / 9 * q**3


@dataclass
class Case:
    fn: object
    kwargs: dict
    inside: list
    outside: list
    surface: list
    special: list = field(default_factory=list)  # points where a sqrt/power argument is 0
    batch: tuple = ("r", [0.3, 0.5])  # a scalar parameter and two values for the (B, 1) test


Q = 2.0**-0.25  # superEll with exponent 4: 2 u^4 = 1 on the diagonal
R_SOFT = 0.5
CASES = {
    "sphere": Case(sphere, dict(center=(0.1, 0.2, 0.3), r=0.5), [(0.1, 0.2, 0.3)], [(1, 1, 1)],
                   [(0.6, 0.2, 0.3), (0.1, -0.3, 0.3), (0.1, 0.2, 0.8)]),
    "ellipsoid": Case(ellipsoid, dict(a=2.0, b=1.0, c=0.5), [(1.9, 0, 0)], [(0, 1.1, 0)],
                      [(2, 0, 0), (0, -1, 0), (0, 0, 0.5), (math.sqrt(2), math.sqrt(0.5), 0)], batch=("a", [1.0, 3.0])),
    "cylX": Case(cylX, dict(r=0.5), [(9, 0.1, 0.1)], [(0, 0.5, 0.5)], [(7, 0.3, 0.4), (-3, 0, -0.5)]),
    "cylY": Case(cylY, dict(r=0.5), [(0.1, 9, 0.1)], [(0.5, 0, 0.5)], [(0.3, 7, 0.4)]),
    "cylZ": Case(cylZ, dict(r=0.5), [(0.1, 0.1, 9)], [(0.5, 0.5, 0)], [(0.3, 0.4, 7)]),
    "block": Case(block, dict(vertex=(-1, -1, -1), dx=2, dy=2, dz=2), [(0, 0, 0)], [(2, 0, 0), (1.5, 1.5, 1.5)],
                  [(1, 0, 0), (0, -1, 0.5), (1, 1, 1), (-1, -1, 0)], batch=("dx", [1.0, 3.0])),
    "torusX": Case(torusX, dict(center=(0.5, 0, 0), R=1.0, r=0.25), [(0.5, 1, 0)], [(0.5, 0, 0), (0.5, 2, 0)],
                   [(0.5, 1.25, 0), (0.5, 0, -0.75), (0.75, 0, 1)], special=[(0.5, 0, 0), (3, 0, 0)]),
    "torusY": Case(torusY, dict(R=1.0, r=0.25), [(0, 0, 1)], [(0, 0, 0)], [(1.25, 0, 0), (0, 0.25, 1)],
                   special=[(0, 0, 0), (0, -2, 0)]),
    "torusZ": Case(torusZ, dict(R=1.0, r=0.25), [(0, 1, 0)], [(0, 0, 0)], [(0.75, 0, 0), (0, -1, 0.25)],
                   special=[(0, 0, 0), (0, 0, 5)]),
    "circle": Case(circle, dict(center=(0.5, 0.0), r=1.0), [(0.5, 0.0)], [(2.0, 0.0)], [(1.5, 0), (0.5, -1)]),
    "ellipse": Case(ellipse, dict(a=2.0, b=1.0), [(1.5, 0)], [(0, 1.5)],
                    [(2, 0), (0, 1), (-math.sqrt(2), math.sqrt(0.5))], batch=("a", [1.0, 3.0])),
    "rectangle": Case(rectangle, dict(vertex=(0, 0), dx=2.0, dy=1.0), [(1, 0.5)], [(3, 0.5), (1, -1)],
                      [(2, 0.5), (1, 0), (0, 1), (2, 1)], batch=("dx", [1.0, 3.0])),
    "ellCylX": Case(ellCylX, dict(a=2.0, b=1.0), [(5, 1.5, 0)], [(0, 0, 1.5)], [(7, 2, 0), (0, 0, -1)],
                    batch=("a", [1.0, 3.0])),
    "ellCylY": Case(ellCylY, dict(a=2.0, b=1.0), [(1.5, 5, 0)], [(0, 0, 1.5)], [(2, 7, 0), (0, 0, -1)],
                    batch=("a", [1.0, 3.0])),
    "ellCylZ": Case(ellCylZ, dict(a=2.0, b=1.0), [(1.5, 0, 5)], [(0, 1.5, 0)], [(2, 0, 7), (0, -1, 0)],
                    batch=("a", [1.0, 3.0])),
    "coneX": Case(coneX, dict(center=(1, 0, 0), R=0.5), [(3, 0, 0), (-1, 0.1, 0)], [(1, 1, 0), (2, 0.6, 0)],
                  [(3, 1, 0), (-1, 0, -1), (1, 0, 0)], batch=("R", [0.25, 1.0])),
    "coneY": Case(coneY, dict(R=0.5), [(0, 3, 0)], [(1, 0, 0)], [(1, 2, 0), (0, -2, 1)], batch=("R", [0.25, 1.0])),
    "coneZ": Case(coneZ, dict(R=0.5), [(0, 0, 3)], [(1, 0, 0)], [(1, 0, 2), (0, 1, -2)], batch=("R", [0.25, 1.0])),
    "ellConeX": Case(ellConeX, dict(a=2.0, b=1.0), [(1, 1.5, 0)], [(1, 0, 1.5)], [(1, 2, 0), (-2, 0, 2)],
                     batch=("a", [1.0, 3.0])),
    "ellConeY": Case(ellConeY, dict(a=2.0, b=1.0), [(1.5, 1, 0)], [(0, 1, 1.5)], [(2, 1, 0), (0, -2, 2)],
                     batch=("a", [1.0, 3.0])),
    "ellConeZ": Case(ellConeZ, dict(a=2.0, b=1.0), [(1.5, 0, 1)], [(0, 1.5, 1)], [(2, 0, -1), (0, 2, 2)],
                     batch=("a", [1.0, 3.0])),
    "superEll_box": Case(superEll, dict(center=(0, 0, 1), a=2.0, b=1.0, c=1.0, s1=0.5, s2=0.5),
                         [(1.6, 0.7, 1.6)], [(2.1, 0, 1), (1.9, 0.95, 1.9)],
                         [(2, 0, 1), (0, -1, 1), (0, 0, 2), (2 * Q, Q, 1), (0, Q, 1 + Q)],
                         special=[(0, 0, 1), (1, 0, 1), (0, 0.5, 1)], batch=("a", [1.0, 3.0])),
    "superEll_star": Case(superEll, dict(a=1.0, b=1.0, c=1.0, s1=3.0, s2=3.0),
                          [(0.05, 0.05, 0.05), (0.9, 0, 0)], [(0.3, 0.3, 0.3)], [(1, 0, 0), (0, 0, -1)],
                          special=[(0, 0, 0), (0.5, 0, 0), (0, 0, 0.5)], batch=("s1", [2.0, 3.0])),
    "superQuadric": Case(superQuadric, dict(e=(0.5, 0.5), a=(2.0, 1.0, 1.0), r=(math.pi / 2, 0, 0), t=(1, 0, 0)),
                         [(1, 0, 0), (1, 1.8, 0)], [(3, 0, 0), (1, 0, 1.2)], [(1, 2, 0), (0, 0, 0), (1, 0, 1)],
                         special=[(1, 0, 0)], batch=("e", [[0.5, 0.5], [1.0, 1.0]])),
    "blobby": Case(blobby, dict(x0=[0, 10], y0=[0, 0], z0=[0, 0], a=[2, 2], b=[1, 1], T=0.5),
                   [(0, 0, 0), (10, 0, 0)], [(5, 0, 0)],
                   [(math.sqrt(math.log(2) / 2), 0, 0), (10, 0, -math.sqrt(math.log(2) / 2))],
                   batch=("T", [0.3, 0.5])),
    "metaBall": Case(metaBall, dict(x0=[0, 5], y0=[0, 0], z0=[0, 0], b=[1, 1], d=[1, 1], T=0.375),
                     [(0, 0, 0), (5, 0.3, 0)], [(2.5, 0, 0), (0, 0.9, 0)], [(0.5, 0, 0), (5, 0, -0.5)],
                     special=[(0, 0, 0), (1 / 3, 0, 0), (1, 0, 0)], batch=("T", [0.3, 0.5])),
    "soft": Case(soft, dict(x0=[0, 5], y0=[0, 0], z0=[0, 0], d=[1, 1], T=soft_weight(R_SOFT, 1.0)),
                 [(0, 0, 0), (5, 0.3, 0)], [(2.5, 0, 0), (0, 0.9, 0)], [(R_SOFT, 0, 0), (5, 0, -R_SOFT)],
                 special=[(0, 0, 0), (1, 0, 0)], batch=("T", [0.3, 0.5])),
}  # fmt: skip


def pts(rows):
    return torch.tensor(rows, dtype=torch.float64)


@pytest.mark.parametrize("name", CASES)
def test_sign_and_exact_zero_on_surface(name):
    c = CASES[name]
    f_in = c.fn(pts(c.inside), **c.kwargs)
    f_out = c.fn(pts(c.outside), **c.kwargs)
    f_on = c.fn(pts(c.surface), **c.kwargs)
    assert (f_in > 0).all(), f_in
    assert (f_out < 0).all(), f_out
    assert f_on.abs().max() < 1e-12, f_on


@pytest.mark.parametrize("name", CASES)
def test_gradient_finite_and_matches_finite_differences(name):
    c = CASES[name]
    dim = len(c.inside[0])
    rng = np.random.default_rng(1)
    x = torch.from_numpy(rng.uniform(-1.5, 1.5, (40, dim)))
    g = grad(lambda p: c.fn(p, **c.kwargs), x)
    h = 1e-6
    eye = torch.eye(dim, dtype=torch.float64)
    fd = torch.stack([(c.fn(x + h * e, **c.kwargs) - c.fn(x - h * e, **c.kwargs)) / (2 * h) for e in eye], -1)
    torch.testing.assert_close(g, fd, rtol=1e-5, atol=1e-6)
    every = pts(c.inside + c.outside + c.surface + c.special)
    assert torch.isfinite(grad(lambda p: c.fn(p, **c.kwargs), every)).all()


@pytest.mark.parametrize("name", CASES)
def test_numpy_torch_float32(name):
    c = CASES[name]
    rows = c.inside + c.outside + c.surface
    ref = c.fn(pts(rows), **c.kwargs)
    out_np = c.fn(np.array(rows, dtype=np.float64), **c.kwargs)
    assert isinstance(out_np, np.ndarray) and out_np.dtype == np.float64 and out_np.shape == (len(rows),)
    np.testing.assert_allclose(out_np, ref.numpy(), atol=1e-14)
    assert isinstance(ref, torch.Tensor) and ref.shape == (len(rows),)
    out32 = c.fn(pts(rows).float(), **c.kwargs)
    assert out32.dtype == torch.float32
    torch.testing.assert_close(out32.double(), ref, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("name", CASES)
def test_batched_parameter_gives_b_by_n(name):
    c = CASES[name]
    pname, values = c.batch
    x = pts(c.inside + c.outside + c.surface)
    tv = torch.tensor(values, dtype=torch.float64)
    batched = tv if tv.ndim == 2 else tv[:, None]  # (B, 1), or (B, k) for vector parameters
    out = c.fn(x, **{**c.kwargs, pname: batched})
    assert out.shape == (len(values), x.shape[0])
    for i, v in enumerate(values):
        torch.testing.assert_close(out[i], c.fn(x, **{**c.kwargs, pname: v}))


def test_parameter_gradient_matches_closed_form():
    # d/dr torus = 2 r, d/dR torusZ = -2 R + 2 rho; d/da ellipse = 2 dx^2 / a^3
    x = torch.tensor([[0.3, 0.4, 0.1]], dtype=torch.float64)
    R = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    r = torch.tensor(0.25, dtype=torch.float64, requires_grad=True)
    torusZ(x, R=R, r=r).sum().backward()
    assert math.isclose(r.grad.item(), 0.5, abs_tol=1e-14)
    assert math.isclose(R.grad.item(), -2.0 + 2 * 0.5, abs_tol=1e-14)
    a = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    ellipse(x[:, :2], a=a, b=1.0).sum().backward()
    assert math.isclose(a.grad.item(), 2 * 0.09 / 8, rel_tol=1e-12)


def test_torus_equals_tube_around_circle():
    x = torch.from_numpy(np.random.default_rng(2).uniform(-2, 2, (500, 3)))
    rho = torch.sqrt(x[:, 0] ** 2 + x[:, 1] ** 2)
    expected = 0.3**2 - (rho - 1.2) ** 2 - x[:, 2] ** 2
    torch.testing.assert_close(torusZ(x, R=1.2, r=0.3), expected, rtol=0, atol=1e-12)
    perm = x[:, [2, 0, 1]]  # torusX sees (y, z) where torusZ sees (x, y)
    torch.testing.assert_close(torusX(perm, R=1.2, r=0.3), expected, rtol=0, atol=1e-12)


def test_superquadric_is_rotated_translated_superell():
    x = torch.from_numpy(np.random.default_rng(3).uniform(-2, 2, (300, 3)))
    angle = 0.7
    q = superQuadric(x, e=(0.8, 1.6), a=(1.0, 0.5, 1.5), r=(0, angle, 0), t=(0.2, 0.1, -0.3))
    d = x - torch.tensor([0.2, 0.1, -0.3], dtype=torch.float64)
    c, s = math.cos(angle), math.sin(angle)  # rotation about y by +angle: local = Ry(-angle) d
    local = torch.stack([c * d[:, 0] - s * d[:, 2], d[:, 1], s * d[:, 0] + c * d[:, 2]], -1)
    torch.testing.assert_close(q, superEll(local, a=1.0, b=0.5, c=1.5, s1=0.8, s2=1.6), rtol=0, atol=1e-12)


def test_multi_center_primitives_against_formulas():
    rng = np.random.default_rng(4)
    x = rng.uniform(-1, 2, (400, 3))
    c = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [0.5, 1.0, 0.8]])
    r = np.linalg.norm(x[:, None, :] - c[None], axis=-1)  # (N, 3)
    a, b, d = np.array([2.0, 3.0, 1.0]), np.array([1.0, 0.5, 2.0]), np.array([0.9, 1.2, 0.7])
    args = (c[:, 0], c[:, 1], c[:, 2])
    np.testing.assert_allclose(blobby(x, *args, a, b, 0.4), (b * np.exp(-a * r**2)).sum(1) - 0.4, atol=1e-13)
    meta = np.where(r <= d / 3, b * (1 - 3 * r**2 / d**2), np.where(r <= d, 1.5 * b * (1 - r / d) ** 2, 0.0))
    np.testing.assert_allclose(metaBall(x, *args, b, d, 0.4), meta.sum(1) - 0.4, atol=1e-13)
    w = np.where(r <= d, soft_weight(r, d), 0.0)
    np.testing.assert_allclose(soft(x, *args, d, 0.4), w.sum(1) - 0.4, atol=1e-13)
    # metaBall and soft are continuous at r = d / 3 and r = d (compact support)
    for radius in (1 / 3, 1.0):
        probe = np.array([[radius - 1e-9, 0, 0], [radius + 1e-9, 0, 0]])
        for fn in (
            lambda p: metaBall(p, [0], [0], [0], [1.0], [1.0], 0.0),
            lambda p: soft(p, [0], [0], [0], [1.0], 0.0),
        ):
            v = fn(probe)
            assert abs(v[0] - v[1]) < 1e-8


def test_multi_center_bad_lengths_raise():
    with pytest.raises(ValueError, match="different lengths"):
        blobby(np.zeros((2, 3)), [0, 1], [0, 1], [0, 1, 2], [1, 1], [1, 1], 0.5)


def test_multi_center_parameters_are_differentiable():
    b = torch.tensor([1.0, 2.0], dtype=torch.float64, requires_grad=True)
    x = torch.tensor([[0.5, 0.0, 0.0]], dtype=torch.float64)
    blobby(x, [0.0, 1.0], [0.0, 0.0], [0.0, 0.0], [1.0, 1.0], b, 0.5).sum().backward()
    torch.testing.assert_close(b.grad, torch.exp(torch.tensor([-0.25, -0.25], dtype=torch.float64)))


def test_noiseG_matches_hyperfun_formula_and_bound():
    rng = np.random.default_rng(5)
    x = rng.uniform(-3, 3, (500, 3))
    amp, freq, phase = 0.7, 2.3, 0.9
    X, Y, Z = (freq * x[:, i] for i in range(3))

    def h(u, w):
        return amp * np.sin(u) + amp / 1.17 * np.sin(u / 1.35 + phase * np.sin(w))

    expected = h(X, Z) * h(Y, X) * h(Z, Y)
    out = noiseG(x, amp, freq, phase)
    assert isinstance(out, np.ndarray)
    np.testing.assert_allclose(out, expected, atol=1e-13)
    np.testing.assert_array_equal(out, noiseG(x, amp, freq, phase))  # deterministic
    assert np.abs(out).max() <= (amp * (1 + 1 / 1.17)) ** 3
    xt = torch.from_numpy(x[:20]).requires_grad_(True)
    amp_t = torch.tensor(amp, dtype=torch.float64, requires_grad=True)
    noiseG(xt, amp_t, freq, phase).sum().backward()
    assert torch.isfinite(xt.grad).all()
    # the value is homogeneous of degree 3 in amp: d/d amp = 3 f / amp
    assert math.isclose(amp_t.grad.item(), 3 * expected[:20].sum() / amp, rel_tol=1e-10)
    assert noiseG(torch.zeros(4, 3, dtype=torch.float32), 1.0, 1.0, 1.0).dtype == torch.float32


def test_2d_primitives_accept_3d_points_as_prisms():
    p2 = torch.tensor([[0.2, 0.3], [1.5, 0.0]], dtype=torch.float64)
    p3 = torch.cat([p2, torch.tensor([[7.0], [-3.0]], dtype=torch.float64)], -1)
    for fn, kw in ((circle, dict(r=1.0)), (ellipse, dict(a=2, b=1)), (rectangle, dict(dx=1, dy=1))):
        torch.testing.assert_close(fn(p3, **kw), fn(p2, **kw))
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        circle(torch.zeros(3, 4))
