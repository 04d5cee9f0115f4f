"""Curvatures at projected mesh vertices against closed forms (float64), Schwarz D, edge cases."""

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from pyfrep_core import block, coneZ, cylZ, ellipsoid, intersection, polygonize, sdf, sphere, torusZ
from pyfrep_core.curvature import (
    attach_curvatures,
    curvatures,
    curvatures_from_hessian,
    gaussian_curvature,
    mean_curvature,
    principal_curvatures,
    principal_directions,
)
from pyfrep_core.diff import value_grad_hessian
from pyfrep_core.models import fig1_part, schwarz_d

QUICK = os.environ.get("PYFREP_QUICK", "0") not in ("", "0")
RES = 32 if QUICK else 64


def on_surface(f, bounds, resolution=RES):
    """Vertices of the marching-cubes mesh, projected onto f = 0 by polygonize."""
    mesh = polygonize(f, bounds, resolution)
    assert np.abs(f(mesh.vertices)).max() < 1e-12
    return mesh


def rel(a, b):
    return np.abs(a - b) / np.abs(b)


def test_sphere_has_h_1_over_r_and_k_1_over_r2():
    r = 0.8
    f = lambda x: sphere(x, center=(0.1, -0.2, 0.05), r=r)  # noqa: E731
    v = on_surface(f, ((-1, -1.1, -1), (1.1, 1, 1))).vertices
    c = curvatures(f, v)
    assert rel(c.H, 1 / r).max() < 1e-6 and rel(c.K, 1 / r**2).max() < 1e-6
    assert rel(c.kmin, 1 / r).max() < 1e-6 and rel(c.kmax, 1 / r).max() < 1e-6
    # sign convention: f > 0 inside gives positive curvature; -f flips H and keeps K
    c_out = curvatures(lambda x: -f(x), v)
    np.testing.assert_allclose(c_out.H, -c.H, rtol=1e-12)
    np.testing.assert_allclose(c_out.K, c.K, rtol=1e-12)


def test_capped_cylinder_has_h_1_over_2r_and_k_0_away_from_the_caps():
    r = 0.4
    f = lambda x: intersection(cylZ(x, r=r), block(x, vertex=(-1, -1, -1), dx=2, dy=2, dz=2))  # noqa: E731
    v = on_surface(f, ((-0.6, -0.6, -1.2), (0.6, 0.6, 1.2))).vertices
    side = v[np.abs(v[:, 2]) < 0.8]
    assert len(side) > 100
    c = curvatures(f, side)
    assert rel(c.H, 1 / (2 * r)).max() < 1e-6
    assert np.abs(c.K).max() < 1e-6 / r**2
    assert np.abs(c.kmin).max() < 1e-6 / r and rel(c.kmax, 1 / r).max() < 1e-6
    # principal directions: kmin along the axis, kmax around it, both tangent and unit
    dmin, dmax = c.dmin, c.dmax
    np.testing.assert_allclose(np.abs(dmin[:, 2]), 1.0, atol=1e-9)
    radial = side[:, :2] / np.linalg.norm(side[:, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ni,ni->n", dmax[:, :2], radial), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(dmax, axis=1), 1.0, atol=1e-12)


def test_torus_closed_forms():
    R, r = 1.0, 0.35
    f = lambda x: torusZ(x, R=R, r=r)  # noqa: E731
    v = on_surface(f, ((-1.5, -1.5, -0.5), (1.5, 1.5, 0.5))).vertices
    c = curvatures(f, v)
    cos_v = (np.hypot(v[:, 0], v[:, 1]) - R) / r  # cosine of the angle around the tube
    K = cos_v / (r * (R + r * cos_v))
    H = (R + 2 * r * cos_v) / (2 * r * (R + r * cos_v))
    big = np.abs(K) > 1e-3  # relative error of K is meaningless where K ~ 0 (top and bottom circles)
    assert rel(c.K[big], K[big]).max() < 1e-6
    assert np.abs(c.K - K).max() < 1e-9
    assert rel(c.H, H).max() < 1e-6
    # kmax = 1/r (the tube), kmin = cos v / (R + r cos v)
    assert rel(c.kmax, 1 / r).max() < 1e-6
    np.testing.assert_allclose(c.kmin, cos_v / (R + r * cos_v), rtol=1e-6, atol=1e-9)


def test_ellipsoid_gaussian_and_mean_curvature_closed_forms():
    a, b, cc = 1.0, 0.7, 0.5
    f = lambda x: ellipsoid(x, a=a, b=b, c=cc)  # noqa: E731
    v = on_surface(f, ((-1.1, -0.8, -0.6), (1.1, 0.8, 0.6))).vertices
    x, y, z = v.T
    h2 = x**2 / a**4 + y**2 / b**4 + z**2 / cc**4
    K = 1.0 / (a**2 * b**2 * cc**2 * h2**2)
    H = (a**2 + b**2 + cc**2 - (x**2 + y**2 + z**2)) / (2 * a**2 * b**2 * cc**2 * h2**1.5)
    c = curvatures(f, v)
    assert rel(c.K, K).max() < 1e-6
    assert rel(c.H, H).max() < 1e-6
    np.testing.assert_allclose(c.kmin * c.kmax, c.K, rtol=1e-10)
    assert (c.kmin <= c.kmax).all() and (c.kmin > 0).all()


def test_fast_path_equals_the_papers_formulas_on_the_fig1_part():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, size=(3000, 3))
    fast = curvatures(fig1_part, x)
    _, g, h = value_grad_hessian(fig1_part, x)
    paper = curvatures_from_hessian(g, h)
    scale = 1.0 + np.abs(paper.kmax) + np.abs(paper.kmin)
    for name in ("H", "kmin", "kmax"):
        assert (np.abs(getattr(fast, name) - getattr(paper, name)) / scale).max() < 1e-9
    assert (np.abs(fast.K - paper.K) / scale**2).max() < 1e-9
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", fast.dmax, paper.dmax)), 1.0, atol=1e-6)
    # each single-quantity function is the same computation
    np.testing.assert_allclose(mean_curvature(fig1_part, x), fast.H, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(gaussian_curvature(fig1_part, x), fast.K)
    kmin, kmax = principal_curvatures(fig1_part, x)
    np.testing.assert_array_equal(kmin, fast.kmin)
    dmin, dmax = principal_directions(fig1_part, x)
    np.testing.assert_array_equal(dmax, fast.dmax)


def test_principal_directions_diagonalize_the_shape_operator():
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, size=(500, 3))
    c = curvatures(fig1_part, x)
    _, g, h = value_grad_hessian(fig1_part, x)
    norm = np.linalg.norm(g, axis=1)
    n = g / norm[:, None]
    for d, k in ((c.dmin, c.kmin), (c.dmax, c.kmax)):
        # S d = k d on the tangent plane, with S = -P Hf P / |g|, P = I - n n^T
        hd = -np.einsum("nij,nj->ni", h, d) / norm[:, None]
        sd = hd - np.einsum("ni,ni->n", hd, n)[:, None] * n
        scale = 1 + np.abs(c.kmax) + np.abs(c.kmin)
        assert (np.linalg.norm(sd - k[:, None] * d, axis=1) / scale).max() < 1e-9
        np.testing.assert_allclose(np.einsum("ni,ni->n", d, n), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ni,ni->n", c.dmin, c.dmax), 0.0, atol=1e-12)


def test_schwarz_d_mean_curvature_is_small_relative_to_the_principal_curvatures():
    mesh = on_surface(schwarz_d, None)
    c = curvatures(schwarz_d, mesh.vertices)
    ratio = np.abs(c.H) / np.maximum(np.abs(c.kmin), np.abs(c.kmax))
    q = np.percentile(ratio, [50, 90, 99, 100])
    print(f"Schwarz D, {mesh.n_vertices} vertices: |H|/max|k| median {q[0]:.4f}, p90 {q[1]:.4f}, max {q[3]:.4f}")
    # the paper's trigonometric formula approximates the minimal surface: measured median 0.025,
    # max 0.067 at resolutions 32..128 (independent of the mesh: the formula, not the numerics)
    assert q[0] < 0.04 and q[3] < 0.1
    assert np.abs(c.H).max() < 0.1 * np.median(np.abs(c.kmax))
    # an offset level set of the same field is not minimal, and the test sees it
    offset = lambda x: schwarz_d(x, c=0.2)  # noqa: E731
    v = polygonize(offset, schwarz_d.bounds, RES).vertices
    co = curvatures(offset, v)
    assert np.median(np.abs(co.H) / np.maximum(np.abs(co.kmin), np.abs(co.kmax))) > 0.08


def test_zero_gradient_gives_nan_there_only():
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.6, 0.0, 0.0]])
    c = curvatures(lambda p: sphere(p, r=1.0), x)
    for v in (c.H, c.K, c.kmin, c.kmax):
        assert np.isnan(v[0]) and np.isfinite(v[1:]).all()
    assert np.isnan(c.dmin[0]).all() and np.isfinite(c.dmin[1:]).all()
    assert np.isnan(mean_curvature(lambda p: sphere(p, r=1.0), x)[0])
    # the curvature of the level set through a point off the surface: the sphere of radius |x|
    np.testing.assert_allclose(c.H[2], 1 / 0.6, rtol=1e-12)


CUBE = lambda p: intersection(sphere(p, r=1.0), block(p, vertex=(-0.75,) * 3, dx=1.5, dy=1.5, dz=1.5))  # noqa: E731

# where the curvature of the level set does not exist: grad f = 0 (centres, axes, apexes), or f is not
# twice differentiable (the torus axis and the sdf axes: cone tips of the level sets; a crease)
UNDEFINED = {
    "sphere centre": (lambda p: sphere(p, r=1.0), (0.0, 0.0, 0.0)),
    "sdf.sphere centre": (lambda p: sdf.sphere(p, r=1.0), (0.0, 0.0, 0.0)),
    "block centre": (lambda p: block(p, vertex=(-0.75,) * 3, dx=1.5, dy=1.5, dz=1.5), (0.0, 0.0, 0.0)),
    "sdf.box centre": (lambda p: sdf.box(p, b=(0.5, 0.6, 0.7)), (0.0, 0.0, 0.0)),
    "cylZ axis": (lambda p: cylZ(p, r=0.5), (0.0, 0.0, 0.3)),
    "sdf.cylinderZ axis": (lambda p: sdf.cylinderZ(p, r=0.5), (0.0, 0.0, 0.3)),
    "torusZ axis": (lambda p: torusZ(p, R=1.0, r=0.25), (0.0, 0.0, 0.3)),
    "sdf.torusZ axis": (lambda p: sdf.torusZ(p, R=1.0, r=0.25), (0.0, 0.0, 0.3)),
    "coneZ apex": (lambda p: coneZ(p, R=1.0), (0.0, 0.0, 0.0)),
    "sdf.coneZ apex": (lambda p: sdf.coneZ(p, r=1.0), (0.0, 0.0, 0.0)),
    "sdf.coneZ axis": (lambda p: sdf.coneZ(p, r=1.0), (0.0, 0.0, 0.3)),
    "cube edge (crease)": (CUBE, (0.75, 0.75, 0.2)),
}


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("name", list(UNDEFINED))
def test_undefined_curvature_is_nan_in_every_field_and_masked(name, dtype):
    f, point = UNDEFINED[name]
    # the undefined point beside one that has a curvature: x = (0.6, 0, 0), off every axis and crease
    x = torch.tensor([point, (0.6, 0.0, 0.0)], dtype=dtype)
    c = curvatures(f, x)
    assert c.defined.tolist() == [False, True]
    for field in ("H", "K", "kmin", "kmax", "dmin", "dmax"):
        v = getattr(c, field)
        assert v.dtype == dtype and torch.isnan(v[0]).all() and torch.isfinite(v[1]).all(), field
    assert torch.isnan(mean_curvature(f, x)[0]) and torch.isnan(gaussian_curvature(f, x)[0])
    assert all(torch.isnan(k[0]) for k in principal_curvatures(f, x))
    # the paper's formulas on the full Hessian say the same
    _, g, h = value_grad_hessian(f, x)
    assert curvatures_from_hessian(g, h, x).defined.tolist() == [False, True]


def test_defined_points_keep_their_closed_form_curvatures_float64():
    # sphere: the level set through x is the sphere of radius |x| (H = 1/|x|, K = 1/|x|^2), centre undefined
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.6, 0.0, 0.0], [0.0, 1e-6, 0.0]])
    c = curvatures(lambda p: sphere(p, r=1.0), x)
    assert c.defined.tolist() == [False, True, True, True]
    np.testing.assert_allclose(c.H[1:], [1.0, 1 / 0.6, 1e6], rtol=1e-12)
    np.testing.assert_allclose(c.K[1:], [1.0, 1 / 0.36, 1e12], rtol=1e-12)
    np.testing.assert_allclose(c.kmin[1:], c.kmax[1:], rtol=1e-12)
    # torus: points on the surface (v = angle around the tube) and its axis, in one call
    R, r = 1.0, 0.25
    v = np.linspace(0.1, 2 * np.pi, 7, endpoint=False)
    on = np.column_stack([R + r * np.cos(v), np.zeros_like(v), r * np.sin(v)])
    for f in (lambda p: torusZ(p, R=R, r=r), lambda p: sdf.torusZ(p, R=R, r=r)):
        c = curvatures(f, np.vstack([on, [[0.0, 0.0, 0.3]]]))
        assert c.defined.tolist() == [True] * len(v) + [False]
        np.testing.assert_allclose(c.K[:-1], np.cos(v) / (r * (R + r * np.cos(v))), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(c.kmax[:-1], 1 / r, rtol=1e-12)
        np.testing.assert_allclose(c.H[:-1], (R + 2 * r * np.cos(v)) / (2 * r * (R + r * np.cos(v))), rtol=1e-12)


def test_the_mask_counts_the_undefined_points_of_a_grid():
    # a 5^3 grid over the cube: its creases are the 12 edges of [-0.75, 0.75]^3 and its centre a
    # critical point; grid points on an edge (two coordinates at +-0.75) and the centre have no curvature
    t = np.linspace(-0.75, 0.75, 5)
    x = np.stack(np.meshgrid(t, t, t, indexing="ij"), axis=-1).reshape(-1, 3)
    cube = lambda p: block(p, vertex=(-0.75,) * 3, dx=1.5, dy=1.5, dz=1.5)  # noqa: E731
    c = curvatures(cube, x)
    on_edge = (np.abs(np.abs(x) - 0.75) < 1e-12).sum(axis=1) >= 2
    centre = (x == 0).all(axis=1)
    np.testing.assert_array_equal(~c.defined, on_edge | centre)
    assert int((~c.defined).sum()) == 12 * 3 + 8 + 1  # 3 interior points per edge, 8 corners, the centre
    for field in ("H", "K", "kmin", "kmax"):
        np.testing.assert_array_equal(np.isfinite(getattr(c, field)), c.defined)


def test_plane_curves_and_kinds():
    # the curvature of a circle of radius 2 in the plane
    circle = lambda p: 4.0 - (p * p).sum(-1)  # noqa: E731
    np.testing.assert_allclose(mean_curvature(circle, np.array([[2.0, 0.0], [0.0, -2.0]])), 0.5, rtol=1e-14)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        curvatures(circle, np.zeros((2, 2)))
    t32 = torch.tensor([[0.0, 0.0, 0.5]])
    c = curvatures(lambda p: sphere(p, r=0.5), t32)
    assert c.H.dtype == torch.float32 and abs(float(c.H[0]) - 2.0) < 1e-5
    with pytest.raises(ValueError, match="non-finite"):
        curvatures(fig1_part, np.array([[np.nan, 0.0, 0.0]]))


def test_mean_curvature_with_create_graph_is_differentiable_in_x():
    # the level sets of r^2 - |x|^2 are spheres: H(x) = 1/|x|, dH/dx = -x/|x|^3
    x = torch.tensor([[0.3, -0.4, 1.2], [0.5, 0.1, 0.2]], dtype=torch.float64, requires_grad=True)
    h = mean_curvature(lambda p: sphere(p, r=1.0), x, create_graph=True)
    (dx,) = torch.autograd.grad(h.sum(), x)
    xd = x.detach()
    torch.testing.assert_close(dx, -xd / xd.norm(dim=1, keepdim=True) ** 3)
    k = curvatures(lambda p: sphere(p, r=1.0), x, create_graph=True).K
    (dx,) = torch.autograd.grad(k.sum(), x)
    torch.testing.assert_close(dx, -2 * xd / xd.norm(dim=1, keepdim=True) ** 4)


def test_attach_curvatures_writes_point_data_that_survives_a_file(tmp_path):
    from pyfrep_core.io import load_mesh, save_mesh

    f = lambda x: torusZ(x, R=1.0, r=0.3)  # noqa: E731
    mesh = attach_curvatures(polygonize(f, ((-1.4, -1.4, -0.4), (1.4, 1.4, 0.4)), 24), f)
    H = mesh.point_data["mean_curvature"]
    assert H.shape == (mesh.n_vertices,) and mesh.point_data["principal_direction_max"].shape == (mesh.n_vertices, 3)
    np.testing.assert_allclose(mesh.point_data["kmax"], 1 / 0.3, rtol=1e-9)
    path = tmp_path / "torus.vtk"
    save_mesh(mesh, path)
    back = load_mesh(path)
    np.testing.assert_allclose(back.point_data["mean_curvature"], H, rtol=1e-12)
    np.testing.assert_allclose(back.point_data["gaussian_curvature"], mesh.point_data["gaussian_curvature"])


# closed forms of the level set through each point (not only of the surface): points rounded to
# float32 lie off f = 0, and their curvature is that of the level set through them
def _sphere_forms(v, center=(0.1, -0.2, 0.05)):
    rho = np.linalg.norm(v - np.asarray(center), axis=1)
    return 1 / rho, 1 / rho**2, 1 / rho, 1 / rho


def _ellipsoid_forms(v, a=1.0, b=0.7, c=0.5):
    x, y, z = v.T
    s = np.sqrt(x**2 / a**2 + y**2 / b**2 + z**2 / c**2)  # the level set is the ellipsoid of semi-axes s (a, b, c)
    A, B, C = s * a, s * b, s * c
    h2 = x**2 / A**4 + y**2 / B**4 + z**2 / C**4
    K = 1 / (A**2 * B**2 * C**2 * h2**2)
    H = (A**2 + B**2 + C**2 - (x * x + y * y + z * z)) / (2 * A**2 * B**2 * C**2 * h2**1.5)
    root = np.sqrt(np.maximum(H * H - K, 0))
    return H, K, H - root, H + root


def _torus_forms(v, R=1.0):
    rho = np.hypot(v[:, 0], v[:, 1])
    tube = np.hypot(rho - R, v[:, 2])  # the level set is the torus of tube radius |(rho - R, z)|
    cos_v = (rho - R) / tube
    return (R + 2 * tube * cos_v) / (2 * tube * rho), cos_v / (tube * rho), cos_v / rho, 1 / tube


CLOSED_FORMS = {
    "sphere": (lambda p: sphere(p, center=(0.1, -0.2, 0.05), r=0.8), ((-1, -1.1, -1), (1.1, 1, 1)), _sphere_forms),
    "ellipsoid": (lambda p: ellipsoid(p, a=1.0, b=0.7, c=0.5), ((-1.1, -0.8, -0.6), (1.1, 0.8, 0.6)), _ellipsoid_forms),
    "torus": (lambda p: torusZ(p, R=1.0, r=0.35), ((-1.5, -1.5, -0.5), (1.5, 1.5, 0.5)), _torus_forms),
}


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("name", list(CLOSED_FORMS))
def test_closed_forms_in_each_dtype(name, dtype):
    f, bounds, forms = CLOSED_FORMS[name]
    x = torch.as_tensor(on_surface(f, bounds).vertices).to(dtype)
    xv = x.double().numpy()  # the points as computed on (exact in float64)
    H, K, kmin, kmax = forms(xv)
    scale = np.maximum(np.abs(kmin), np.abs(kmax))  # errors relative to the largest curvature (K may be 0)
    if dtype == torch.float64:
        tol = np.full(len(xv), 1e-10)
    else:
        # rounding: the entries of the shape operator come from Hf / |g| computed with a few dozen
        # roundings each, so its error is ~ eps ||Hf|| / |g|; relative to the curvature that is eps
        # times cond = ||Hf|| / (|g| max|k|) (1 for spheres and tori, 2 for this ellipsoid).  16 eps
        # cond bounds it (measured: at most 4 eps cond)
        _, g, h = value_grad_hessian(f, xv)
        cond = np.linalg.norm(h, 2, axis=(1, 2)) / (np.linalg.norm(g, axis=1) * scale)
        tol = 16 * torch.finfo(dtype).eps * cond
    c = curvatures(f, x)
    assert c.H.dtype == dtype and bool(c.defined.all())
    for got, want, power in ((c.H, H, 1), (c.K, K, 2), (c.kmin, kmin, 1), (c.kmax, kmax, 1)):
        err = np.abs(got.double().numpy() - want) / scale**power
        assert (err < tol).all(), (name, float((err / tol).max()))
    # the single-quantity entries are the same computation, to the bit
    torch.testing.assert_close(mean_curvature(f, x), c.H, rtol=0, atol=0)
    torch.testing.assert_close(gaussian_curvature(f, x), c.K, rtol=0, atol=0)


def test_curvature_from_threads_equals_serial():
    # 4 threads x 10 calls each, chunks small enough that every call spreads over the worker pool
    rng = np.random.default_rng(3)
    x = torch.as_tensor(rng.uniform(-1, 1, size=(3000, 3)))
    calls = {
        "curvatures": lambda: tuple(curvatures(fig1_part, x, chunk=256)),
        "mean_curvature": lambda: (mean_curvature(fig1_part, x, chunk=256),),
        "gaussian_curvature": lambda: (gaussian_curvature(fig1_part, x, chunk=256),),
    }
    serial = {name: call() for name, call in calls.items()}
    names = list(calls) + ["curvatures"]  # one per thread

    def worker(name):
        return [calls[name]() for _ in range(10)]

    with ThreadPoolExecutor(4) as pool:
        results = list(pool.map(worker, names))
    for name, outs in zip(names, results):
        for out in outs:
            for got, want in zip(out, serial[name], strict=True):
                torch.testing.assert_close(got, want, rtol=0, atol=0, equal_nan=True)
