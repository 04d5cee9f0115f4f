"""TPMS and spinodoid fields against their closed forms: periodicity, zeros, symmetries, means."""

import math
import warnings

import numpy as np
import pytest
import torch

from pyfrep_core import Param, SchwarzD, SchwarzP, gyroid, gyroidSheet, intersection, lidinoid, model, spinodoid
from pyfrep_core.lattices import spinodoid_directions

TPMS = [gyroid, SchwarzP, SchwarzD, lidinoid]
FREQS = (1.0, 2.0, 0.5)


def _points(n=500, seed=0, scale=2.0):
    g = torch.Generator().manual_seed(seed)
    return scale * (2 * torch.rand(n, 3, generator=g, dtype=torch.float64) - 1)


def _grid(n=12):
    """A uniform n^3 grid over one unit period (endpoint excluded): exact means of trig polys."""
    t = torch.arange(n, dtype=torch.float64) / n
    return torch.stack(torch.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)


@pytest.mark.parametrize("tpms", TPMS)
def test_periodic_along_each_axis(tpms):
    x = _points()
    f = tpms(x, *FREQS)
    for axis, freq in enumerate(FREQS):
        shift = torch.zeros(3, dtype=torch.float64)
        shift[axis] = 1.0 / freq
        torch.testing.assert_close(tpms(x + shift, *FREQS), f, rtol=0, atol=1e-12)
    # half a period is not a period (the test above could not pass with a constant field)
    assert (tpms(x + torch.tensor([0.5, 0.0, 0.0], dtype=torch.float64), *FREQS) - f).abs().max() > 0.1


def test_closed_forms_at_random_points():
    x = _points()
    X, Y, Z = (2 * math.pi * fr * x[:, i] for i, fr in enumerate(FREQS))
    s, c = torch.sin, torch.cos
    g = -(s(X) * c(Y) + s(Y) * c(Z) + s(Z) * c(X))
    torch.testing.assert_close(gyroid(x, *FREQS), g, rtol=0, atol=1e-12)
    torch.testing.assert_close(SchwarzP(x, *FREQS), c(X) + c(Y) + c(Z), rtol=0, atol=1e-12)
    d = s(X) * s(Y) * s(Z) + s(X) * c(Y) * c(Z) + c(X) * s(Y) * c(Z) + c(X) * c(Y) * s(Z)
    torch.testing.assert_close(SchwarzD(x, *FREQS), d, rtol=0, atol=1e-12)
    # the offset c shifts every field by c
    for tpms in TPMS:
        torch.testing.assert_close(tpms(x, *FREQS, c=0.3), tpms(x, *FREQS) + 0.3, rtol=0, atol=1e-12)


def test_known_zeros_and_values():
    q = torch.tensor([[0.25, 0.25, 0.25]], dtype=torch.float64)
    o = torch.zeros(1, 3, dtype=torch.float64)
    assert abs(float(SchwarzP(q))) < 1e-15
    assert float(SchwarzP(o)) == 3.0
    assert float(gyroid(o)) == 0.0
    assert float(SchwarzD(o)) == 0.0
    # the paper's unscaled Schwarz D: sin x sin y sin z + ... at (pi/2, pi/2, pi/2) is 1
    a = 1 / (2 * math.pi)
    assert abs(float(SchwarzD(q * 2 * math.pi, a, a, a)) - 1.0) < 1e-14
    # gyroid extreme value -3/2 at X = Y = Z = pi/4
    assert abs(float(gyroid(q / 2)) + 1.5) < 1e-14
    # lidinoid at the origin: 0 - 0.5 * 3 + 0.15
    assert abs(float(lidinoid(o)) + 1.35) < 1e-14


def test_symmetries():
    x = _points(seed=1)
    half = torch.full((3,), 0.5, dtype=torch.float64)
    torch.testing.assert_close(gyroid(-x), -gyroid(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(gyroid(x[:, [1, 2, 0]]), gyroid(x), rtol=0, atol=1e-12)  # cyclic
    torch.testing.assert_close(gyroid(x + half), gyroid(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(SchwarzP(-x), SchwarzP(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(SchwarzP(x + half), -SchwarzP(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(SchwarzP(x[:, [2, 0, 1]]), SchwarzP(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(SchwarzD(-x), -SchwarzD(x), rtol=0, atol=1e-12)
    torch.testing.assert_close(SchwarzD(x[:, [1, 0, 2]]), SchwarzD(x), rtol=0, atol=1e-12)


def test_means_over_a_period():
    g = _grid()
    assert abs(float(gyroid(g).mean())) < 1e-14
    assert abs(float(SchwarzP(g).mean())) < 1e-14
    assert abs(float(SchwarzD(g).mean())) < 1e-14
    assert abs(float(lidinoid(g).mean()) - 0.15) < 1e-14
    # |G| <= 3/2 everywhere, reached on the grid's (1/8, 1/8, 1/8)-type points for n = 8
    assert abs(float(gyroid(_grid(8)).abs().max()) - 1.5) < 1e-14


def test_gyroid_sheet_is_the_band_between_levels():
    x = _points(2000, seed=3, scale=1.0)
    G = -gyroid(x)
    f = gyroidSheet(x, c1=0.8, c2=-0.8)
    inside = (G > -0.8) & (G < 0.8)
    margin = (G.abs() - 0.8).abs() > 1e-6
    assert torch.equal((f > 0)[margin], inside[margin])
    # frequencies pass through: sheet of a double-frequency gyroid
    f2 = gyroidSheet(x, 2.0, 2.0, 2.0, 0.3, -0.2)
    G2 = -gyroid(x, 2.0, 2.0, 2.0)
    torch.testing.assert_close(f2 > 0, (G2 < 0.3) & (G2 > -0.2))


@pytest.mark.parametrize("tpms", [*TPMS, gyroidSheet])
def test_gradients_finite_and_match_closed_form(tpms):
    x = _points(300, seed=4).requires_grad_(True)
    (g,) = torch.autograd.grad(tpms(x).sum(), x)
    assert torch.isfinite(g).all() and g.abs().max() > 0.1
    if tpms is SchwarzP:
        torch.testing.assert_close(g, -2 * math.pi * torch.sin(2 * math.pi * x.detach()), rtol=0, atol=1e-12)


def test_parameters_differentiable_and_batched():
    x = _points(50)
    alpha = torch.tensor(1.5, dtype=torch.float64, requires_grad=True)
    f = SchwarzP(x, alpha=alpha)
    (da,) = torch.autograd.grad(f.sum(), alpha)
    expected = (-torch.sin(2 * math.pi * 1.5 * x[:, 0]) * 2 * math.pi * x[:, 0]).sum()
    assert abs(float(da - expected)) < 1e-10
    batch = gyroid(x, c=torch.tensor([[0.0], [0.5]], dtype=torch.float64))
    assert batch.shape == (2, 50)
    torch.testing.assert_close(batch[1] - batch[0], torch.full((50,), 0.5, dtype=torch.float64))


def test_batches_through_a_model():
    @model(t=Param(0.5, 0.1, 1.2), rho=Param(0.4, 0.1, 0.9))
    def part(x, t, rho):
        return intersection(gyroidSheet(x, c1=t, c2=-t), spinodoid(x, wavenumber=8.0, numwaves=64, density=rho))

    x = _points(20, seed=9, scale=0.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # vmap runs it (the seeded draw shared by the sets), no loop
        out = part(
            x, t=torch.tensor([0.3, 0.9], dtype=torch.float64), rho=torch.tensor([0.2, 0.7], dtype=torch.float64)
        )
    assert out.shape == (2, 20)
    torch.testing.assert_close(out[1], part(x, t=0.9, rho=0.7), rtol=0, atol=1e-12)


def test_numpy_in_numpy_out_and_float32():
    x = np.random.default_rng(0).uniform(-1, 1, (10, 3))
    out = SchwarzD(x)
    assert isinstance(out, np.ndarray) and out.dtype == np.float64 and out.shape == (10,)
    out32 = gyroid(torch.from_numpy(x).float())
    assert out32.dtype == torch.float32
    np.testing.assert_allclose(out32.numpy(), gyroid(x), atol=1e-5)


def test_bad_shape_raises():
    with pytest.raises(ValueError, match="x must have shape"):
        gyroid(torch.zeros(4, 2))


def test_spinodoid_deterministic_and_volume_fraction():
    x = _grid(24) * 2.0  # 13824 points over [0, 2)^3
    f1 = spinodoid(x, wavenumber=12.0, numwaves=300, density=0.35, seed=7)
    f2 = spinodoid(x, wavenumber=12.0, numwaves=300, density=0.35, seed=7)
    assert torch.equal(f1, f2)
    assert not torch.equal(f1, spinodoid(x, wavenumber=12.0, numwaves=300, density=0.35, seed=8))
    assert abs(float((f1 >= 0).double().mean()) - 0.35) < 0.06
    # density 0.5 puts the level at phi = 0, and density shifts the field by a constant
    f_half = spinodoid(x, wavenumber=12.0, numwaves=300, density=0.5, seed=7)
    level = math.sqrt(2) * torch.erfinv(torch.tensor(2 * 0.35 - 1.0, dtype=torch.float64))
    torch.testing.assert_close(f1 - f_half, level.expand_as(f1), rtol=0, atol=1e-12)
    # the random field has variance ~ 1 (sqrt(2/N) normalisation)
    assert 0.7 < float(f_half.var()) < 1.3


def test_spinodoid_cones_restrict_directions():
    n, ph = spinodoid_directions(500, theta=(0.3, 0.0, 0.0), seed=1)
    assert n.shape == (500, 3) and ph.shape == (500,)
    assert bool((n[:, 0].abs() >= math.cos(0.3) - 1e-12).all())
    assert bool(((ph >= 0) & (ph < 2 * math.pi)).all())
    # a field made of waves along ~x varies much faster along x than along y:
    # E[(df/dx)^2] / E[(df/dy)^2] = E[n_x^2] / E[n_y^2] > 1 / tan(0.2)^2 ~ 24
    x = _points(400, seed=5).requires_grad_(True)
    (g,) = torch.autograd.grad(spinodoid(x, wavenumber=30.0, numwaves=100, theta=(0.2, 0.0, 0.0)).sum(), x)
    assert float((g[:, 0] ** 2).mean()) > 20 * float((g[:, 1] ** 2).mean())
    iso = _points(400, seed=5).requires_grad_(True)
    (g,) = torch.autograd.grad(spinodoid(iso, wavenumber=30.0, numwaves=400).sum(), iso)
    assert 0.5 < float((g[:, 0] ** 2).mean() / (g[:, 1] ** 2).mean()) < 2.0
    with pytest.raises(ValueError, match="theta"):
        spinodoid_directions(10, theta=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="numwaves"):
        spinodoid_directions(0)


def test_spinodoid_density_gradient():
    x = _points(100)
    rho = torch.tensor(0.4, dtype=torch.float64, requires_grad=True)
    f = spinodoid(x, wavenumber=10.0, numwaves=50, density=rho)
    (d,) = torch.autograd.grad(f.sum(), rho)
    # d/drho sqrt(2) erfinv(2 rho - 1) = sqrt(2 pi) exp(erfinv(2 rho - 1)^2)
    e = torch.erfinv(torch.tensor(2 * 0.4 - 1, dtype=torch.float64))
    assert abs(float(d) - 100 * math.sqrt(2 * math.pi) * float(torch.exp(e * e))) < 1e-8
