"""Periodic coordinate maps: hand values, lattices of spheres, Fourier convergence and Gibbs."""

import math

import numpy as np
import pytest
import torch

from pyfrep_core import Param, model, rep, sawtooth, sawtoothFourier, sphere, triangleWave, triangleWaveFourier

F64 = torch.float64


def test_sawtooth_and_triangle_hand_values():
    x = torch.tensor([0.0, 0.2, 0.7, -1.2, 2.5, -0.5, 3.9], dtype=F64)
    saw = torch.tensor([0.0, 0.2, -0.3, -0.2, -0.5, -0.5, -0.1], dtype=F64)
    torch.testing.assert_close(sawtooth(x, 1.0), saw, rtol=0, atol=1e-12)
    torch.testing.assert_close(triangleWave(x, 1.0), saw.abs(), rtol=0, atol=1e-12)
    # period 2: x = 1.5 is 0.5 past the cell face at 1.0
    torch.testing.assert_close(
        sawtooth(torch.tensor([1.5, -0.4], dtype=F64), 2.0), torch.tensor([-0.5, -0.4], dtype=F64)
    )
    torch.testing.assert_close(
        triangleWave(torch.tensor([1.5, 3.0], dtype=F64), 2.0), torch.tensor([0.5, 1.0], dtype=F64)
    )


def test_per_axis_period():
    x = torch.tensor([[0.7, 0.7, 0.7], [-2.6, 3.1, 9.0]], dtype=F64)
    out = rep(x, (1.0, 2.0, 4.0))
    expected = torch.tensor([[-0.3, 0.7, 0.7], [0.4, -0.9, 1.0]], dtype=F64)
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-12)


def _lattice_sphere(p, period, r):
    """r^2 - distance^2 to the nearest lattice node (closed form, numpy)."""
    d = p - period * np.round(p / period)
    return r * r - (d * d).sum(-1)


def test_rep_and_triangle_give_a_lattice_of_spheres():
    rng = np.random.default_rng(0)
    p = rng.uniform(-5, 5, (2000, 3))
    expected = _lattice_sphere(p, 1.25, 0.4)
    np.testing.assert_allclose(sphere(rep(p, 1.25), r=0.4), expected, atol=1e-12)
    # a shape symmetric about the cell centre is repeated identically by the mirror map
    np.testing.assert_allclose(sphere(triangleWave(p, 1.25), r=0.4), expected, atol=1e-12)
    # the triangle-wave lattice is continuous: no jump across the cell faces
    face = np.array([[0.625 - 1e-9, 0.1, 0.2], [0.625 + 1e-9, 0.1, 0.2]])
    a, b = sphere(triangleWave(face, 1.25), center=(0.3, 0, 0), r=0.4)
    assert abs(a - b) < 1e-8
    # ... while the sawtooth cuts a shape that crosses the face
    a, b = sphere(sawtooth(face, 1.25), center=(0.3, 0, 0), r=0.4)
    assert abs(a - b) > 0.5


def test_fourier_series_converge_away_from_jumps():
    x = torch.linspace(-1.0, 1.0, 1601, dtype=F64)
    far = (x - 0.5 - torch.round(x - 0.5)).abs() >= 0.1  # distance >= 0.1 from the jumps at 1/2 + k
    saw_err, tri_err = [], []
    for n in (10, 40, 160):
        saw_err.append(float((sawtoothFourier(x, 1.0, n) - sawtooth(x, 1.0))[far].abs().max()))
        tri_err.append(float((triangleWaveFourier(x, 1.0, n) - triangleWave(x, 1.0)).abs().max()))
        assert tri_err[-1] <= 1.0 / (2 * math.pi**2 * n) + 1e-12  # uniform bound of the docstring
    assert saw_err[0] > saw_err[1] > saw_err[2]
    assert saw_err[2] < 1.0 / (2 * math.pi**2 * 160 * 0.1)  # p^2 / (2 pi^2 n d)
    assert tri_err[0] > tri_err[1] > tri_err[2]
    # values at the exact points: the series average the jump to 0, the triangle is exact at x = 0
    assert abs(float(sawtoothFourier(torch.tensor(0.5, dtype=F64), 1.0, 50))) < 1e-12
    assert abs(float(triangleWaveFourier(torch.tensor(0.5, dtype=F64), 1.0, 2000)) - 0.5) < 1e-4


def test_sawtooth_fourier_gibbs_overshoot_persists():
    x = torch.linspace(0.48, 0.5, 2001, dtype=F64)  # the peaks lie within ~1/(2n) of the jump
    peaks = [float(sawtoothFourier(x, 1.0, n).max()) for n in (50, 400)]
    si_pi = 1.851937051982466  # Si(pi): the limit of the maximum is p Si(pi) / pi ~ 0.5895 p
    assert 0.575 < peaks[0] < peaks[1] < si_pi / math.pi + 1e-9
    assert peaks[1] > si_pi / math.pi - 2e-3
    # the overshoot scales with the period
    assert abs(float(sawtoothFourier(2 * x, 2.0, 400).max()) - 2 * peaks[1]) < 1e-12


def test_fourier_derivatives_finite_at_jumps_and_kinks():
    n = 25
    x = torch.tensor([0.5, -0.5, 0.0, 0.25], dtype=F64, requires_grad=True)
    (ds,) = torch.autograd.grad(sawtoothFourier(x, 1.0, n).sum(), x)
    # d/dx at a jump: 2 sum (-1)^(k+1) cos(pi k) = -2 n; at 0 the partial sums 2 sum (-1)^(k+1)
    torch.testing.assert_close(ds[:2], torch.full((2,), -2.0 * n, dtype=F64), rtol=0, atol=1e-10)
    assert abs(float(ds[2]) - 2 * (n % 2)) < 1e-10
    (dt,) = torch.autograd.grad(triangleWaveFourier(x, 1.0, n).sum(), x)
    assert torch.isfinite(dt).all()
    assert abs(float(dt[2])) < 1e-12 and abs(float(dt[0])) < 1e-12  # smooth extrema at the kinks
    assert 0.9 < float(dt[3]) < 1.1  # slope ~ 1 between the kinks


def test_period_is_differentiable():
    x = torch.tensor([0.3, 1.7, -2.2], dtype=F64)
    p = torch.tensor(1.0, dtype=F64, requires_grad=True)
    (dp,) = torch.autograd.grad(sawtooth(x, p).sum(), p)
    # sawtooth = x - p floor(x / p + 1/2): d/dp = -floor(x / p + 1/2)
    assert abs(float(dp) - float(-torch.floor(x + 0.5).sum())) < 1e-12
    # the Fourier series is a smooth function of the period too
    (dp,) = torch.autograd.grad(triangleWaveFourier(x, p, 5).sum(), p)
    assert torch.isfinite(dp)


def test_batched_period_through_a_model():
    @model(p=Param(1.0, 0.5, 2.0))
    def spheres(x, p):
        return sphere(rep(x, p), r=0.2)

    x = torch.tensor([[1.0, 0.0, 0.0], [0.75, 0.75, 0.0]], dtype=F64)
    out = spheres(x, p=torch.tensor([1.0, 1.5, 0.75], dtype=F64))
    assert out.shape == (3, 2)
    for i, p in enumerate((1.0, 1.5, 0.75)):
        torch.testing.assert_close(out[i], torch.as_tensor(_lattice_sphere(x.numpy(), p, 0.2)), rtol=0, atol=1e-12)
    # per-axis periods for B sets: (B, 3)
    per_axis = rep(x, torch.tensor([[1.0, 2.0, 3.0], [0.5, 0.5, 0.5]], dtype=F64))
    assert per_axis.shape == (2, 2, 3)
    torch.testing.assert_close(per_axis[0], rep(x, (1.0, 2.0, 3.0)))


def test_numpy_io_float32_and_shapes():
    p = np.random.default_rng(1).uniform(-2, 2, (7, 3))
    for fn in (sawtooth, triangleWave, rep, sawtoothFourier, triangleWaveFourier):
        out = fn(p, 0.8)
        assert isinstance(out, np.ndarray) and out.shape == (7, 3) and out.dtype == np.float64
        out32 = fn(torch.from_numpy(p).float(), 0.8)
        assert out32.dtype == torch.float32
        np.testing.assert_allclose(out32.numpy(), out, atol=2e-5)


@pytest.mark.parametrize("period", [0.0, -1.0, float("nan"), (1.0, 0.0, 1.0)])
def test_bad_period_raises(period):
    with pytest.raises(ValueError, match="period"):
        sawtooth(torch.zeros(3), period)


def test_bad_n_terms_and_shape_raise():
    with pytest.raises(ValueError, match="n_terms"):
        sawtoothFourier(torch.zeros(3), 1.0, 0)
    with pytest.raises(ValueError, match="n_terms"):
        triangleWaveFourier(torch.zeros(3), 1.0, 2.5)
    with pytest.raises(ValueError, match="x must have shape"):
        rep(torch.zeros(4, 2), 1.0)
