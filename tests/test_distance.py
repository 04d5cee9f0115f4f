"""True distance from projected surface samples, the error measure, and the FMM reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from pyfrep_core import sphere
from pyfrep_core.distance import distance_error, fmm_distance, surface_samples, true_distance
from pyfrep_core.meshing import grid_axes

BOUNDS = ((-1.5,) * 3, (1.5,) * 3)
R = 0.8


def ball(x):
    return sphere(x, r=R)


def exact(x):
    return R - np.linalg.norm(x, axis=-1)


def grid(res):
    return np.stack(np.meshgrid(*grid_axes(BOUNDS, res), indexing="ij"), axis=-1).reshape(-1, 3)


@pytest.fixture(scope="module")
def reference():
    return true_distance(ball, BOUNDS, resolution=32)


def test_samples_lie_on_the_surface(reference):
    s = reference.samples
    assert np.allclose(np.linalg.norm(s.points, axis=1), R, atol=1e-12)
    # outward normals of a sphere are x / |x|
    assert np.allclose(s.normals, s.points / R, atol=1e-9)


def test_nearest_sample_distance_within_covering_radius(reference):
    """Without refinement the error is between 0 and the samples' covering radius rho."""
    plain = true_distance(ball, BOUNDS, resolution=32, refine_steps=0)
    rng = np.random.default_rng(1)
    probe = rng.normal(size=(200_000, 3))
    probe *= R / np.linalg.norm(probe, axis=1, keepdims=True)
    rho = cKDTree(plain.samples.points).query(probe)[0].max()  # largest gap seen on the surface
    x = grid(24)
    err = np.abs(plain(x)) - np.abs(exact(x))
    assert err.min() > -1e-12  # samples lie on the surface: never below the true distance
    assert err.max() <= 1.05 * rho
    assert rho < 2 * plain.samples.spacing


def test_refined_distance_is_exact(reference):
    x = grid(24)
    d = reference(x)
    assert np.abs(d - exact(x)).max() < 1e-8
    assert np.all(np.sign(d) == np.sign(exact(x)))
    t = reference(torch.as_tensor(x[:10]))
    assert isinstance(t, torch.Tensor) and torch.allclose(t, torch.as_tensor(exact(x[:10])))


def test_distance_error_statistics(reference):
    # f / (2r) is the distance to first order at the surface: small in the band, larger away
    approx = lambda x: ball(x) / (2 * R)  # noqa: E731
    err = distance_error(approx, ball, BOUNDS, resolution=20, band=0.1, reference=reference)
    x = grid(20)
    e = np.abs(ball(x) / (2 * R) - exact(x))
    band = np.abs(exact(x)) < 0.1
    assert np.isclose(err.mean, e.mean()) and np.isclose(err.max, e.max())
    assert err.n_band == band.sum() and np.isclose(err.band_mean, e[band].mean())
    assert err.band_mean < err.mean
    assert err.errors.shape == (20, 20, 20)


def test_fmm_reference_on_a_sphere():
    res = 64
    d = fmm_distance(ball, BOUNDS, res)
    dx = 3.0 / (res - 1)
    e = np.abs(d.grid.ravel() - exact(grid(res)))
    # first-order scheme: errors of a fraction of a cell, at most about one cell
    assert e.mean() < 0.25 * dx and e.max() < dx
    inside = np.array([[0.1, 0.2, -0.3]])
    assert abs(d(inside)[0] - exact(inside)[0]) < dx
    assert isinstance(d(torch.tensor(inside)), torch.Tensor)
    with pytest.raises(ValueError, match="outside"):
        d(np.array([[2.0, 0.0, 0.0]]))
    err = distance_error(d, ball, BOUNDS, resolution=res, reference=exact(grid(res)).reshape((res,) * 3))
    assert np.isclose(err.mean, e.mean())


@pytest.mark.parametrize(
    "call, error, match",
    [
        (lambda: true_distance("ball", BOUNDS), TypeError, "callable"),
        (lambda: true_distance(ball, ((np.nan, 0, 0), (1, 1, 1))), ValueError, "finite"),
        (lambda: true_distance(ball, ((1, -1, -1), (-1, 1, 1))), ValueError, "inverted"),
        (lambda: true_distance(ball, ((1.0, 1.0, 1.0), (1.4, 1.4, 1.4))), ValueError, "zero set"),
        (lambda: surface_samples(ball, BOUNDS, resolution=100_000), ValueError, "resolution"),
        (lambda: distance_error(ball, ball, BOUNDS, band=-1.0), ValueError, "band"),
        (lambda: distance_error(ball, ball, BOUNDS, resolution=8, reference=np.zeros((4, 4, 4))), ValueError, "shape"),
        (
            lambda: distance_error(lambda x: x[..., 0] * np.nan, ball, BOUNDS, 8, reference=np.zeros((8,) * 3)),
            ValueError,
            "finite",
        ),  # fmt: skip
        (lambda: fmm_distance(ball, ((1.0, 1.0, 1.0), (1.4, 1.4, 1.4)), 16), ValueError, "zero set"),
    ],
)
def test_bad_input(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_point_errors(reference):
    with pytest.raises(ValueError, match="non-finite"):
        reference(np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match="shape"):
        reference(np.zeros((4, 2)))
