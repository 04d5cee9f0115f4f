"""Transforms act on points: f(T(x)) is the moved/deformed solid.  Checked against explicit
forward motions (surface points of the original land on the surface of the result), scipy's
rotations, closed-form parameter derivatives and finite differences."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pyfrep_core import (
    bend,
    cylZ,
    ellipsoid,
    orient,
    rotate,
    rotate3DX,
    rotate3DY,
    rotate3DZ,
    scale,
    scale3D,
    shift3D,
    sphere,
    stretch3D,
    taperX,
    taperY,
    taperZ,
    translate,
    twistX,
    twistY,
    twistZ,
)

RNG = np.random.default_rng(0)
AXES = (2.0, 0.5, 0.8)  # an ellipsoid with three different semi-axes: every rotation shows


def ellipsoid_surface(n=400, axes=AXES):
    u = RNG.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * np.array(axes)


def f_ell(x):
    return ellipsoid(x, a=AXES[0], b=AXES[1], c=AXES[2])


def turn(u, v, theta):  # the motion: rotate (u, v) by +theta from u towards v
    c, s = np.cos(theta), np.sin(theta)
    return u * c - v * s, u * s + v * c


def test_rotate3D_turns_the_solid_by_plus_theta_right_hand_rule():
    half = math.pi / 2
    ball = dict(r=0.1)
    # a ball at +x turned about z lands at +y; at +y about x lands at +z; at +z about y lands at +x
    for rot, start, end in (
        (rotate3DZ, (1, 0, 0), (0, 1, 0)),
        (rotate3DX, (0, 1, 0), (0, 0, 1)),
        (rotate3DY, (0, 0, 1), (1, 0, 0)),
    ):
        x = torch.tensor([end, start], dtype=torch.float64)
        f = sphere(rot(x, half), center=start, **ball)
        assert abs(f[0].item() - 0.01) < 1e-15 and f[1] < 0
    out = rotate3DZ(torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64), half)
    torch.testing.assert_close(out, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64), rtol=0, atol=1e-15)


def test_rotate_any_axis_matches_scipy_and_the_axis_rotations():
    x = RNG.uniform(-1, 1, (200, 3))
    axis = np.array([0.3, -1.2, 0.7])
    angle = 1.1
    motion = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis))
    np.testing.assert_allclose(rotate(x, angle, axis), motion.inv().apply(x), atol=1e-14)
    for rot, e in ((rotate3DX, (1, 0, 0)), (rotate3DY, (0, 1, 0)), (rotate3DZ, (0, 0, 1))):
        np.testing.assert_allclose(rotate(x, angle, e), rot(x, angle), atol=1e-15)
        np.testing.assert_allclose(rot(x, angle), Rotation.from_rotvec(angle * np.array(e)).inv().apply(x), atol=1e-14)
    # rotated ellipsoid: surface points moved by the motion stay on the surface
    p = ellipsoid_surface()
    assert np.abs(f_ell(rotate(motion.apply(p), angle, axis))).max() < 1e-12


def test_orient_lays_the_z_axis_along_a_direction():
    d = np.array([1.0, 2.0, -2.0]) / 3.0
    perp = np.cross(d, [1.0, 0.0, 0.0])
    perp /= np.linalg.norm(perp)
    t = RNG.uniform(-3, 3, (50, 1))
    on = t * d + 0.4 * perp  # on the cylinder of radius 0.4 around the line t d
    assert np.abs(cylZ(orient(on, 3 * d), r=0.4)).max() < 1e-12
    assert cylZ(orient(t * d, d), r=0.4).min() > 0.16 - 1e-12
    flipped = orient(np.array([[1.0, 2.0, 3.0]]), (0.0, 0.0, -1.0))
    np.testing.assert_allclose(flipped, [[1.0, -2.0, -3.0]])
    q = RNG.uniform(-1, 1, (20, 3))
    np.testing.assert_allclose(np.linalg.norm(orient(q, d), axis=1), np.linalg.norm(q, axis=1), atol=1e-14)


def test_translations_and_scalings_invert_their_motion():
    p = ellipsoid_surface()
    off = np.array([0.3, -1.0, 2.0])
    assert np.abs(f_ell(translate(p + off, off))).max() < 1e-12
    assert np.abs(f_ell(shift3D(p + off, *off))).max() < 1e-12
    s = np.array([1.5, 0.5, 2.0])
    assert np.abs(f_ell(scale3D(p * s, *s))).max() < 1e-12
    assert np.abs(f_ell(scale(p * 1.7, 1.7))).max() < 1e-12
    c = np.array([1.0, -1.0, 0.5])
    assert np.abs(f_ell(stretch3D(c + (p - c) * s, c, *s))).max() < 1e-12
    np.testing.assert_allclose(translate(np.array([[1.0, 2.0, 3.0]]), (1, 1, 1)), [[0.0, 1.0, 2.0]])


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_twist_maps_surface_to_surface(axis):
    twist = (twistX, twistY, twistZ)[axis]
    i, j = [(1, 2), (2, 0), (0, 1)][axis]  # the pair turned, in right-hand order
    p = ellipsoid_surface()
    t1, t2, th1, th2 = -1.0, 1.5, 0.3, 2.0
    theta = th1 + (p[:, axis] - t1) / (t2 - t1) * (th2 - th1)
    q = p.copy()
    q[:, i], q[:, j] = turn(p[:, i], p[:, j], theta)
    assert np.abs(f_ell(twist(q, t1, t2, th1, th2))).max() < 1e-12
    # constant angle = a plain rotation
    rot = (rotate3DX, rotate3DY, rotate3DZ)[axis]
    np.testing.assert_allclose(twist(q, t1, t2, 0.8, 0.8), rot(q, 0.8), atol=1e-15)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_taper_maps_surface_to_surface(axis):
    taper = (taperX, taperY, taperZ)[axis]
    p = ellipsoid_surface()
    lo, hi, s1, s2 = -0.2, 0.3, 1.0, 0.4
    u = np.clip((p[:, axis] - lo) / (hi - lo), 0, 1)
    s = (1 - u) * s1 + u * s2
    q = p * s[:, None]
    q[:, axis] = p[:, axis]
    assert np.abs(f_ell(taper(q, lo, hi, s1, s2))).max() < 1e-12
    # outside [lo, hi] the scale is constant
    far = np.array([[5.0, 5.0, 5.0]])
    expected = far / s2
    expected[0, axis] = 5.0
    np.testing.assert_allclose(taper(far, lo, hi, s1, s2), expected)


def bend_forward(p, k):  # the deformation itself: the x axis onto the circle of radius 1/k
    theta, rho = k * p[:, 0], 1 / k - p[:, 1]
    # 1/k - rho cos(theta), written without cancellation for tiny k
    y = p[:, 1] * np.cos(theta) + 2 * np.sin(theta / 2) ** 2 / k
    return np.stack([rho * np.sin(theta), y, p[:, 2]], -1)


@pytest.mark.parametrize("k", [0.6, -0.4, 1.4])
def test_bend_maps_surface_to_surface(k):
    axes = (2.0, 0.3, 0.4)  # a bar along x; k = 1.4 bends it by 2.8 rad (> pi/2) at the tips
    p = ellipsoid_surface(axes=axes)
    q = bend_forward(p, k)
    f = ellipsoid(bend(q, k), a=axes[0], b=axes[1], c=axes[2])
    assert np.abs(f).max() < 1e-12
    np.testing.assert_allclose(bend(q, k), p, atol=1e-13)


def test_bend_at_zero_curvature_is_identity_with_exact_derivative():
    x = torch.from_numpy(RNG.uniform(-1, 1, (100, 3)))
    k = torch.tensor(0.0, dtype=torch.float64, requires_grad=True)
    out = bend(x, k)
    torch.testing.assert_close(out, x, rtol=0, atol=0)
    # d/dk at 0: (x y, -x^2 / 2, 0) from the series of the inverse map
    dk = torch.autograd.grad(out.sum(), k)[0]
    expected = (x[:, 0] * x[:, 1] - x[:, 0] ** 2 / 2).sum()
    assert math.isclose(dk.item(), expected.item(), rel_tol=1e-12)
    # tiny curvatures: no cancellation (compare with the forward map)
    p = ellipsoid_surface(axes=(2.0, 0.3, 0.4))
    np.testing.assert_allclose(bend(bend_forward(p, 1e-7), 1e-7), p, atol=1e-12)
    center = torch.tensor([[0.0, 2.0, 0.0]], dtype=torch.float64, requires_grad=True)  # the bend center
    bend(center, 0.5).sum().backward()
    assert torch.isfinite(center.grad).all()


def fd_check(fn, value, h=1e-6):
    """Autograd d(sum fn(p))/dp against a central difference at p = value."""
    p = torch.tensor(value, dtype=torch.float64, requires_grad=True)
    auto = torch.autograd.grad(fn(p).sum(), p)[0]
    num = (fn(torch.tensor(value + h, dtype=torch.float64)) - fn(torch.tensor(value - h, dtype=torch.float64))).sum()
    assert math.isclose(auto.item(), num.item() / (2 * h), rel_tol=1e-6, abs_tol=1e-8), (auto, num / (2 * h))


def test_derivatives_wrt_parameters_match_finite_differences():
    x = torch.from_numpy(RNG.uniform(-1.5, 1.5, (300, 3)))
    fd_check(lambda a: f_ell(rotate3DZ(x, a)), 0.7)
    fd_check(lambda a: f_ell(rotate3DX(x, a)), -0.3)
    fd_check(lambda a: f_ell(rotate(x, a, (1.0, 2.0, 0.5))), 0.4)
    fd_check(lambda t: f_ell(twistX(x, -1.0, 1.0, 0.2, t)), 1.3)
    fd_check(lambda s: f_ell(taperZ(x, -1.0, 1.0, 1.0, s)), 0.6)
    fd_check(lambda k: f_ell(bend(x, k)), 0.5)
    fd_check(lambda k: f_ell(bend(x, k)), 0.0)
    fd_check(lambda s: f_ell(scale3D(x, 1.0, s, 1.0)), 1.3)
    # the rotation axis is a differentiable parameter too
    axis = torch.tensor([1.0, 2.0, 0.5], dtype=torch.float64, requires_grad=True)
    f_ell(rotate(x, 0.4, axis)).sum().backward()
    assert torch.isfinite(axis.grad).all() and abs(torch.dot(axis.grad, axis.detach())) < 1e-9  # scale-invariant


def test_batched_parameters_numpy_and_float32():
    x = torch.from_numpy(RNG.uniform(-1, 1, (30, 3)))
    angles = torch.tensor([[0.1], [0.5], [1.0]], dtype=torch.float64)
    for tr in (
        lambda p, a: rotate3DZ(p, a),
        lambda p, a: rotate(p, a, (1.0, 1.0, 0.0)),
        lambda p, a: twistY(p, 0.0, 1.0, 0.0, a),
        lambda p, a: taperX(p, -1.0, 1.0, 1.0, 1.0 + a),
        lambda p, a: bend(p, a),
        lambda p, a: shift3D(p, a, 0.0, a),
        lambda p, a: scale(p, 1.0 + a),
    ):
        out = tr(x, angles)
        assert out.shape == (3, 30, 3)
        torch.testing.assert_close(out[2], tr(x, 1.0))
        assert f_ell(out).shape == (3, 30)
        np_out = tr(x.numpy(), 1.0)
        assert isinstance(np_out, np.ndarray) and np_out.shape == (30, 3)
        out32 = tr(x.float(), 1.0)
        assert out32.dtype == torch.float32
        torch.testing.assert_close(out32.double(), tr(x, 1.0), rtol=1e-5, atol=1e-5)
    offsets = torch.tensor([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]], dtype=torch.float64)
    assert translate(x, offsets).shape == (2, 30, 3)


def test_points_must_be_3d():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        rotate3DZ(np.zeros((4, 2)), 0.3)
