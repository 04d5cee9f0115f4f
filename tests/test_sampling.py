"""sample_surface: points exactly on f = 0, area-weighted, seeded, with calibrated noise; the microstructure model."""

import math

import numpy as np
import pytest
import torch

from pyfrep_core import Mesh, Param, model, sample_surface, sphere
from pyfrep_core.models import microstructure
from pyfrep_core.sampling import plane_points, sample_mesh

BOX = ((-1.2,) * 3, (1.2,) * 3)


@model(bounds=BOX, r=Param(0.8, 0.5, 1.1))
def ball(x, r):
    return sphere(x, r=r)


def test_points_lie_on_the_surface_at_the_given_parameters():
    pts = sample_surface(ball, 3000, params={"r": 0.9}, seed=0, resolution=40)
    assert pts.shape == (3000, 3) and pts.dtype == np.float64
    assert np.abs(np.linalg.norm(pts, axis=1) - 0.9).max() < 1e-12


def test_area_weighted_uniform_on_a_sphere():
    # Archimedes: the cap z > h of a unit sphere holds (1 - h) / 2 of the area, whatever h
    n = 20000
    pts = sample_surface(ball, n, params={"r": 1.0}, seed=3, resolution=40)
    for h in (-0.5, 0.0, 0.7):
        frac = (1 - h) / 2
        tol = 5 * math.sqrt(frac * (1 - frac) / n)  # 5 binomial standard deviations
        assert abs(np.mean(pts[:, 2] > h) - frac) < tol
    assert abs(pts.mean(0)).max() < 5 * math.sqrt(1 / 3 / n)  # coordinates: variance 1/3


def test_seed_reproducible_and_distinct():
    a = sample_surface(ball, 500, seed=7, resolution=32)
    b = sample_surface(ball, 500, seed=7, resolution=32)
    c = sample_surface(ball, 500, seed=8, resolution=32)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_noise_has_the_requested_standard_deviation():
    sigma, n = 0.01, 20000
    pts = sample_surface(ball, n, params={"r": 1.0}, noise=sigma, seed=1, resolution=40)
    radial = np.linalg.norm(pts, axis=1) - 1.0  # ~ N(0, sigma^2) for sigma << r
    assert abs(radial.std() / sigma - 1) < 5 / math.sqrt(2 * n) + 0.01  # std's standard error + curvature


def test_sample_mesh_stays_in_its_triangle():
    m = Mesh(np.array([[0.0, 0, 0], [2, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    p = sample_mesh(m, 5000, np.random.default_rng(0))
    assert (p[:, 0] >= 0).all() and (p[:, 1] >= 0).all() and (p[:, 0] / 2 + p[:, 1] <= 1 + 1e-12).all()
    assert abs(p[:, 0].mean() - 2 / 3) < 0.02 and abs(p[:, 1].mean() - 1 / 3) < 0.01  # centroid


def test_plain_callable_needs_bounds():
    pts = sample_surface(lambda x: sphere(x, r=0.5), 100, bounds=BOX, seed=0, resolution=32)
    assert np.abs(np.linalg.norm(pts, axis=1) - 0.5).max() < 1e-12
    with pytest.raises(ValueError, match="bounds"):
        sample_surface(lambda x: sphere(x, r=0.5), 100)
    with pytest.raises(TypeError, match="params"):
        sample_surface(lambda x: sphere(x, r=0.5), 100, params={"r": 1.0}, bounds=BOX)


@pytest.mark.parametrize(
    "kwargs, err, match",
    [
        ({"n": 0}, ValueError, "n must be"),
        ({"n": 2.5}, ValueError, "n must be"),
        ({"noise": -0.1}, ValueError, "noise"),
        ({"noise": float("nan")}, ValueError, "noise"),
        ({"params": {"radius": 1.0}}, TypeError, "radius"),
        ({"params": {"r": 2.0}}, ValueError, "outside"),
        ({"bounds": ((1, 1, 1), (0, 2, 2))}, ValueError, "inverted"),
    ],
)
def test_bad_input(kwargs, err, match):
    args = {"n": 10, "seed": 0, "resolution": 16, **kwargs}
    with pytest.raises(err, match=match):
        sample_surface(ball, **args)


def test_no_surface_in_bounds():
    with pytest.raises(ValueError, match="surface"), pytest.warns(RuntimeWarning):
        sample_surface(ball, 10, bounds=((2, 2, 2), (3, 3, 3)), resolution=8)


def test_microstructure_formula_and_batches():
    rng = np.random.default_rng(0)
    x = rng.uniform(-10, 10, (500, 3))
    p = dict(scale1=8.2, scale2=3.6, freq1=0.7, freq2=0.9)

    def inter(a, b):
        return a + b - np.sqrt(a * a + b * b)

    def uni(a, b):
        return a + b + np.sqrt(a * a + b * b)

    sp = 1 - (x**2).sum(1) / 100
    t = sp
    s = p["scale1"] * (1 - t) + p["scale2"] * t
    c = p["freq1"] * (1 - t) + p["freq2"] * t
    sx, sy, sz = (np.sin(x[:, k] * s) - c for k in range(3))
    xr, yr, zr = inter(sy, sz), inter(sx, sz), inter(sx, sy)
    blend = uni(xr, zr) + 1.0 / (1 + (xr / 3) ** 2 + (zr / 3) ** 2)
    expect = inter(uni(inter(sp, -(sp - 0.15)), inter(sp, uni(blend, yr))), x[:, 1])
    np.testing.assert_allclose(microstructure(x, **p), expect, rtol=1e-12, atol=1e-12)
    # a (B,) batch per parameter gives (B, N), each row the single evaluation
    xt = torch.from_numpy(x)
    batch = {k: torch.tensor([v, v * 1.05, v * 0.95], dtype=torch.float64) for k, v in p.items()}
    out = microstructure(xt, **batch)
    assert out.shape == (3, 500)
    for i in range(3):
        torch.testing.assert_close(out[i], microstructure(xt, **{k: float(v[i]) for k, v in batch.items()}))
    assert set(microstructure.names) == {"scale1", "scale2", "freq1", "freq2"}
    assert microstructure.params["scale1"].lower == 1.0 and microstructure.params["freq2"].upper == 2.0


def test_microstructure_cloud_is_on_its_surface_only_at_its_parameters():
    p = dict(scale1=7.0, scale2=4.0, freq1=0.8, freq2=0.6)
    pts = sample_surface(microstructure, 2000, params=p, seed=0, resolution=96)
    assert np.abs(microstructure(pts, **p)).max() < 1e-9
    other = dict(p, scale1=7.5)
    assert np.sqrt(np.mean(microstructure(pts, **other) ** 2)) > 1e-2


@pytest.mark.parametrize("suffix", [".xyz", ".ply"])
def test_cloud_saved_and_loaded_exactly(tmp_path, suffix):
    from pyfrep_core.io import load_points, save_points

    p = dict(scale1=7.0, scale2=4.0, freq1=0.8, freq2=0.6)
    pts = sample_surface(microstructure, 500, params=p, noise=0.0, seed=4, resolution=64)
    save_points(pts, tmp_path / f"cloud{suffix}")
    cloud = load_points(tmp_path / f"cloud{suffix}")
    np.testing.assert_array_equal(cloud.points, pts)  # XYZ keeps every digit, PLY stores float64
    assert np.abs(microstructure(cloud.points, **p)).max() < 1e-9


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_plane_points_lie_on_the_plane_across_the_box(axis):
    bounds = ((-1.0, -2.0, 0.5), (3.0, 2.0, 1.5))
    pts, (u, v) = plane_points(bounds, axis=axis, offset=0.75, n=5)
    assert pts.shape == (5, 5, 3) and pts.dtype == np.float64
    np.testing.assert_array_equal(pts[..., axis], 0.75)
    first, second = (i for i in range(3) if i != axis)
    np.testing.assert_allclose(u, np.linspace(bounds[0][first], bounds[1][first], 5), rtol=0, atol=0)
    np.testing.assert_allclose(v, np.linspace(bounds[0][second], bounds[1][second], 5), rtol=0, atol=0)
    # rows follow v, columns u (an image's layout)
    np.testing.assert_array_equal(pts[2, 4, first], u[4])
    np.testing.assert_array_equal(pts[2, 4, second], v[2])
    # a planar model: its whole box, whatever the axis
    flat, (x, y) = plane_points(((-1.0, -0.5), (1.0, 0.5)), axis=axis, offset=9.0, n=4, dim=2)
    assert flat.shape == (4, 4, 2)
    np.testing.assert_array_equal(flat[3, 0], [x[0], y[3]])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"axis": 3}, "axis must be 0, 1 or 2, got 3"),
        ({"axis": True}, "axis must be 0, 1 or 2"),
        ({"offset": float("nan")}, "offset must be finite"),
        ({"n": 1}, "n must be an integer >= 2, got 1"),
        ({"n": 2.5}, "n must be an integer >= 2"),
        ({"dim": 4}, "dim must be 2 or 3, got 4"),
        ({"bounds": ((1.0, 0.0, 0.0), (0.0, 1.0, 1.0))}, "inverted or empty on axis 0"),
        ({"bounds": ((0.0, 0.0), (1.0, 1.0))}, "must give 3 lower and 3 upper values"),
    ],
)
def test_plane_points_names_a_bad_argument(kwargs, match):
    args = {"bounds": BOX, "axis": 2, "offset": 0.0, "n": 8, **kwargs}
    with pytest.raises(ValueError, match=match):
        plane_points(**args)
