"""pyfrep_core.sdf: exact distances (unit gradients, brute force on meshes, closed forms) and operations."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from pyfrep_core import polygonize, sdf
from pyfrep_core.diff import grad

A, B = (-0.5, -0.2, 0.1), (0.4, 0.3, -0.2)  # an oblique segment for capsule / capped shapes

# name -> (distance function, largest principal curvature of its smooth parts, has sharp edges)
SHAPES = {
    "sphere": (lambda p: sdf.sphere(p, (0.1, 0.0, 0.0), 0.8), 1 / 0.8, False),
    "plane": (lambda p: sdf.plane(p, (1.0, 2.0, 3.0), (0.1, 0.0, 0.0)), 0.0, False),
    "box": (lambda p: sdf.box(p, (0.8, 0.5, 0.3), (0.1, 0.0, 0.0)), 0.0, True),
    "block": (lambda p: sdf.block(p, (-0.5, -0.4, -0.3), 1.0, 0.8, 0.7), 0.0, True),
    "roundedBox": (lambda p: sdf.roundedBox(p, (0.6, 0.4, 0.3), 0.15), 1 / 0.15, False),
    "torus": (lambda p: sdf.torus(p, 0.7, 0.25, axis="y"), 1 / 0.25, False),
    "torusX": (lambda p: sdf.torusX(p, (0.0, 0.1, 0.0), 0.6, 0.2), 1 / 0.2, False),
    "capsule": (lambda p: sdf.capsule(p, A, B, 0.3), 1 / 0.3, False),
    "cylinder": (lambda p: sdf.cylinder(p, (0.1, 0.0, 0.0), (1.0, 1.0, 0.0), 0.4), 1 / 0.4, False),
    "cylX": (lambda p: sdf.cylX(p, (0.0, 0.1, 0.0), 0.4), 1 / 0.4, False),
    "cylinderZ": (lambda p: sdf.cylinderZ(p, (0.0, 0.1, 0.0), 0.4), 1 / 0.4, False),
    "coneZ": (lambda p: sdf.coneZ(p, (0.0, 0.0, 0.1), 0.5), math.inf, True),
    "cappedCylinder": (lambda p: sdf.cappedCylinder(p, A, B, 0.4), 1 / 0.4, True),
    # the cone side's principal curvature is cos(angle)/rho <= 1/rb
    "cappedCone": (lambda p: sdf.cappedCone(p, A, B, 0.6, 0.2), 1 / 0.2, True),
    "frame": (lambda p: sdf.frame(p, (1.6, 1.2, 1.0), 0.2), 0.0, True),
}


def random_points(n, seed, half=1.2):
    return torch.from_numpy(np.random.default_rng(seed).uniform(-half, half, (n, 3)))


# ----------------------------------------------------------------------------- |grad d| = 1


@pytest.mark.parametrize("name", list(SHAPES))
def test_unit_gradient_at_random_points(name):
    # The medial axis (points with two nearest surface points) has measure zero: uniform random
    # float64 points miss it, and an exact SDF has |grad d| = 1 everywhere else, inside and out.
    f = SHAPES[name][0]
    x = random_points(4000, 1)
    g = grad(f, x)
    np.testing.assert_allclose(g.norm(dim=1).numpy(), 1.0, rtol=0, atol=1e-6)


def test_gradient_is_the_inward_unit_normal_on_the_surface():
    # on a face the gradient must be the full unit normal (a sum of min(0, 0) would halve it)
    on_faces = torch.tensor([[0.9, 0.0, 0.1], [0.1, -0.5, 0.2], [0.3, 0.2, 0.3]], dtype=torch.float64)
    g = grad(SHAPES["box"][0], on_faces)
    np.testing.assert_allclose(g.numpy(), [[-1, 0, 0], [0, 1, 0], [0, 0, -1]], atol=1e-12)
    top_cap = torch.tensor([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0]], dtype=torch.float64)
    g = grad(lambda p: sdf.cappedCylinder(p, (0, 0, -1), (0, 0, 1), 0.5), top_cap)
    np.testing.assert_allclose(g.numpy(), [[0, 0, -1], [0, 0, -1]], atol=1e-12)
    rim = torch.tensor([[0.5, 0.0, 0.0], [0.0, -0.375, 0.5]], dtype=torch.float64)  # on the cone's side
    g = grad(lambda p: sdf.cappedCone(p, (0, 0, -1), (0, 0, 1), 0.75, 0.25), rim)
    s = 1 / math.sqrt(1 + 0.25**2)  # side normal (2, 0.5) / |(2, 0.5)| in (rho, z), pointing inward
    np.testing.assert_allclose(g.numpy(), [[-s, 0, -0.25 * s], [0, s, -0.25 * s]], atol=1e-12)


SPECIAL = {  # medial axes, edges, corners, apexes, axes: gradients must stay finite there
    "sphere": (lambda p: sdf.sphere(p, (0, 0, 0), 1.0), [[0, 0, 0], [1, 0, 0]]),
    "box": (lambda p: sdf.box(p, (1, 2, 3)), [[0, 0, 0], [1, 2, 3], [1, 2, 0], [1, 0, 0], [0.5, 1.5, 0], [2, 3, 0]]),
    "torus": (lambda p: sdf.torus(p, 1.0, 0.25), [[0, 0, 0], [0, 0, 2], [1, 0, 0], [0, 1, 0]]),
    "capsule": (lambda p: sdf.capsule(p, (0, 0, -1), (0, 0, 1), 0.5), [[0, 0, 0], [0, 0, 1], [0, 0, -1.5]]),
    "cylinder": (lambda p: sdf.cylinder(p, (0, 0, 0), (1, 1, 1), 0.5), [[0, 0, 0], [2, 2, 2]]),
    "cylY": (lambda p: sdf.cylY(p, (0, 0, 0), 0.5), [[0, 3, 0]]),
    "coneX": (lambda p: sdf.coneX(p, (0, 0, 0), 0.5), [[0, 0, 0], [1, 0, 0], [0, 1, 0]]),
    "cappedCylinder": (
        lambda p: sdf.cappedCylinder(p, (0, 0, -1), (0, 0, 1), 0.5),
        [[0, 0, 0], [0, 0, 1], [0.5, 0, 1]],
    ),
    "cappedCone": (lambda p: sdf.cappedCone(p, (0, 0, 0), (0, 0, 1), 0.5, 0.0), [[0, 0, 1], [0, 0, 0], [0, 0, 2]]),
    "frame": (lambda p: sdf.frame(p, 2.0, 0.2), [[0, 0, 0], [1, 1, 1], [1.1, 1.1, 1.1], [1, 1, 0]]),
    "roundedBox": (lambda p: sdf.roundedBox(p, 1.0, 0.2), [[0, 0, 0], [1, 1, 1]]),
}


@pytest.mark.parametrize("name", list(SPECIAL))
def test_gradients_finite_on_medial_axes_edges_and_axes(name):
    f, pts = SPECIAL[name]
    x = torch.tensor(pts, dtype=torch.float64)
    g = grad(f, x)
    assert torch.isfinite(g).all(), g
    assert (g.norm(dim=1) <= 1 + 1e-9).all(), g  # sub-gradients: never longer than 1


# ----------------------------------------------------------------------------- brute force on a mesh

RESOLUTION = 96
BOUNDS = ((-1.3, -1.3, -1.3), (1.3, 1.3, 1.3))
SUBDIV = 6  # barycentric grid: (SUBDIV + 1)(SUBDIV + 2) / 2 sample points per triangle
D_MIN, D_MAX = 0.1, 0.5  # query points at these distances from the surface (the frame's bars are 0.2 thick:
D_MIN_FRAME = 0.03  # it takes the loose tolerance anyway)


def barycentric_grid(n):
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    keep = i + j <= n
    a, b = i[keep] / n, j[keep] / n
    return np.stack([1 - a - b, a, b], axis=1)


def brute_force(f):
    """Mesh f = 0 and return (KD-tree over dense surface samples, longest mesh edge, cell size)."""
    mesh = polygonize(f, BOUNDS, RESOLUTION)
    tri = mesh.vertices[mesh.faces]  # (F, 3, 3)
    edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max()
    samples = np.einsum("sk,fkd->fsd", barycentric_grid(SUBDIV), tri).reshape(-1, 3)
    cell = (BOUNDS[1][0] - BOUNDS[0][0]) / (RESOLUTION - 1)
    return cKDTree(samples), edge, cell


@pytest.mark.parametrize("name", ["box", "torus", "capsule", "cappedCylinder", "cappedCone", "roundedBox", "frame"])
def test_distance_equals_brute_force_distance_to_a_fine_mesh(name):
    f, kappa, sharp = SHAPES[name]
    tree, edge, cell = brute_force(f)
    x = random_points(10000, 2).numpy()
    d = f(x)
    d_min = D_MIN_FRAME if name == "frame" else D_MIN
    band = (np.abs(d) > d_min) & (np.abs(d) < D_MAX)
    x, d = x[band], d[band]
    assert len(d) > 500 and (d > 0).sum() > 50
    brute = np.where(d > 0, 1.0, -1.0) * tree.query(x)[0]
    err = np.abs(d - brute)
    # Tolerance, from the mesh.  Its vertices are projected onto d = 0 (Newton, ~1e-13), so each
    # triangle (longest edge `edge`) is a chord of the surface.  (1) Where the surface is smooth
    # with principal curvatures <= kappa, a point of a triangle is at most (power of the point
    # w.r.t. the circumcircle) * kappa / 2 <= (edge^2 / 3) * kappa / 2 from the surface, and the
    # surface is as close to the mesh: deviation = kappa edge^2 / 6.  (2) The samples are a
    # barycentric grid: the foot of p on the mesh is within sigma = (edge / SUBDIV) / sqrt(3) of a
    # sample, a tangential offset that lengthens |p - s| by at most sigma^2 / (2 |d|).
    sigma = edge / SUBDIV / math.sqrt(3)
    tol = kappa * edge**2 / 6 + sigma**2 / (2 * d_min) + 1e-9
    # (3) At sharp edges marching cubes cuts a chamfer inside the cells the ridge crosses, so a
    # ridge point is up to one cell diagonal from the mesh: outside points (whose nearest point
    # may be on a ridge) get tol + sqrt(3) cell.  Inside a convex solid the nearest point is on a
    # face, at least D_MIN * cot(angle / 2) >= 0.7 * D_MIN = 0.07 > edge from any ridge
    # (the cone's widest angle is 110 deg), where the mesh is exact up to (1): the tight tolerance
    # holds there.  The frame also has concave ridges, seen from inside: loose tolerance throughout.
    loose = tol + math.sqrt(3) * cell
    bound = np.where(sharp & ((d < 0) | (name == "frame")), loose, tol)
    worst = np.argmax(err - bound)
    assert (err <= bound).all(), (
        f"{name}: |d - brute| = {err[worst]:.3g} > {bound[worst]:.3g} at {x[worst]}, d = {d[worst]:.4f}"
    )
    assert tol < 3e-3  # the tight bound really is tight at this resolution


# ----------------------------------------------------------------------------- closed forms

SQ = math.sqrt


def values(f, pts):
    return f(np.asarray(pts, dtype=np.float64))


def test_sphere_and_plane_closed_forms():
    np.testing.assert_allclose(values(lambda p: sdf.sphere(p, (1, 2, 3), 2.0), [[1, 2, 3], [4, 6, 3]]), [2, -3])
    n = np.array([1.0, 2.0, 2.0])
    pts = [[0, 0, 0], [2, 2, 2], [-2, 0, -2]]
    np.testing.assert_allclose(values(lambda p: sdf.plane(p, n, (1, 0, 0)), pts), [-1 / 3, 3, -7 / 3], atol=1e-15)


def test_box_corner_edge_face_and_inside_distances():
    c = np.array([0.5, -1.0, 2.0])
    f = lambda p: sdf.box(p, (1, 2, 3), c)  # noqa: E731
    pts = c + np.array([[2, 3, 5], [1.3, 2.4, 0], [0, 0, 3.5], [0.5, 0, 0], [0, 1.5, 2.9], [0, 0, 0]])
    expected = [-SQ(1 + 1 + 4), -0.5, -0.5, 0.5, 0.1, 1.0]  # corner, edge, face, inside x3
    np.testing.assert_allclose(values(f, pts), expected, atol=1e-12)
    b = lambda p: sdf.block(p, (0, 0, 0), 2, 4, 6)  # noqa: E731 - the same box by its corner
    np.testing.assert_allclose(values(b, pts - c + [1, 2, 3]), expected, atol=1e-12)
    rb = lambda p: sdf.roundedBox(p, (1, 2, 3), 0.25, c)  # noqa: E731
    np.testing.assert_allclose(values(rb, pts), np.array(expected) + 0.25, atol=1e-12)


def test_torus_tube_axis_and_orientation():
    R, r = 1.0, 0.25
    f = lambda p: sdf.torus(p, R, r)  # noqa: E731
    pts = [[1, 0, 0], [0, 2, 0], [0, 0, 0], [0, 0, 0.75], [1.1, 0, 0.1], [0.6, 0.8, 0.2]]
    expected = [r, -(1 - r), -(1 - r), -(1.25 - r), r - SQ(0.02), r - 0.2]
    np.testing.assert_allclose(values(f, pts), expected, atol=1e-12)
    # the axis choices are the same torus turned: torusX at (h, ., .) equals torusZ at (., ., h)
    x = random_points(50, 3).numpy()
    zx = values(lambda p: sdf.torusZ(p, (0, 0, 0), R, r), x)
    np.testing.assert_allclose(values(lambda p: sdf.torusX(p, (0, 0, 0), R, r), x[:, [2, 0, 1]]), zx, atol=1e-14)
    np.testing.assert_allclose(values(lambda p: sdf.torusY(p, (0, 0, 0), R, r), x[:, [0, 2, 1]]), zx, atol=1e-14)
    np.testing.assert_allclose(values(lambda p: sdf.torus(p, R, r, axis=0), x[:, [2, 0, 1]]), zx, atol=1e-14)


def test_capsule_ends_and_side():
    f = lambda p: sdf.capsule(p, (0, 0, -1), (0, 0, 1), 0.5)  # noqa: E731
    pts = [[0, 0, 2], [0, 0, -3], [0.8, 0, 0.3], [0.3, 0, 1.4], [0, 0.6, -1.8], [0, 0, 0]]
    expected = [-0.5, -1.5, -0.3, 0.0, 0.5 - 1.0, 0.5]
    np.testing.assert_allclose(values(f, pts), expected, atol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_capsule_with_a_equal_b_is_the_sphere(dtype):
    # a zero-length segment: the capsule is the ball of that radius (was 0/0 = NaN everywhere)
    c = (0.1, -0.2, 0.3)
    rng = np.random.default_rng(11)
    x = torch.tensor(np.vstack([rng.uniform(-1, 1, (200, 3)), [c, (0.1, -0.2, 0.8)]]), dtype=dtype, requires_grad=True)
    d = sdf.capsule(x, c, c, 0.5)
    want = sdf.sphere(x, c, 0.5)
    eps = torch.finfo(dtype).eps
    torch.testing.assert_close(d, want, rtol=0, atol=4 * eps)
    assert abs(float(d[-2].detach()) - 0.5) <= torch.finfo(dtype).tiny ** 0.25 and abs(float(d[-1].detach())) <= 4 * eps
    (g,) = torch.autograd.grad(d.sum(), x)
    (g_want,) = torch.autograd.grad(want.sum(), x)
    assert torch.isfinite(g).all()
    torch.testing.assert_close(g, g_want, rtol=0, atol=8 * eps)
    # the exact distance: unit gradient away from the centre, the sub-gradient 0 at it
    torch.testing.assert_close(g[:-2].norm(dim=1), torch.ones(200, dtype=dtype), rtol=0, atol=8 * eps)
    assert float(g[-2].abs().max()) == 0.0
    # a batch of segments where only some are points
    a = torch.tensor([c, (0.0, 0.0, -1.0)], dtype=dtype)
    b = torch.tensor([c, (0.0, 0.0, 1.0)], dtype=dtype)
    p = torch.tensor([[0.6, -0.2, 0.3], [0.0, 0.0, 2.0]], dtype=dtype)
    torch.testing.assert_close(sdf.capsule(p, a, b, 0.25)[[0, 1], [0, 1]], torch.tensor([-0.25, -0.75], dtype=dtype))


def test_capped_cylinder_and_cone_closed_forms():
    f = lambda p: sdf.cappedCylinder(p, (0, 0, -1), (0, 0, 1), 1.0)  # noqa: E731
    pts = [[2, 0, 3], [0, 0, 0.5], [0, 1.5, 0.2], [0, 0, -1.25], [0.6, 0.6, 0.0]]
    expected = [-SQ(5), 0.5, -0.5, -0.25, 1 - SQ(0.72)]
    np.testing.assert_allclose(values(f, pts), expected, atol=1e-12)
    g = lambda p: sdf.cappedCone(p, (0, 0, 0), (0, 0, 1), 1.0, 0.5)  # noqa: E731
    n = np.array([1.0, 0.5]) / SQ(1.25)  # outward normal of the side in (rho, z)
    side = np.array([0.75, 0.5]) + 0.2 * n  # 0.2 outside the middle of the side
    pts = [[0, 0, -2], [side[0], 0, side[1]], [2, 0, -1], [0, 0, 0.5], [0, 0.2, 1.1], [0.0, 0.0, 0.05]]
    expected = [-2.0, -0.2, -SQ(2), 0.5, -0.1, 0.05]
    np.testing.assert_allclose(values(g, pts), expected, atol=1e-12)


def test_cylinders_cones_and_frame_closed_forms():
    np.testing.assert_allclose(values(lambda p: sdf.cylX(p, (0, 1, 1), 0.5), [[7, 4, 5], [3, 1, 1]]), [-4.5, 0.5])
    general = lambda p: sdf.cylinder(p, (1, 0, 0), (0, 3, 4), 1.0)  # noqa: E731 - axis (0, .6, .8)
    np.testing.assert_allclose(values(general, [[1, 3, 4], [1, 4, -3], [3, 0, 0]]), [1, -4, -1], atol=1e-12)
    np.testing.assert_allclose(values(lambda p: sdf.coneZ(p, (0, 0, 0), 1.0), [[1, 0, 1], [0, 0, -2]]), [0, SQ(2)])
    fr = lambda p: sdf.frame(p, 2.0, 0.2)  # noqa: E731 - bars centered on |x_i| = 1, outer 1.1
    pts = [[1.4, 1.4, 1.4], [0, 0, 1], [1, 1, 0], [1, 0, 1.05], [1.2, 0.5, 1.0]]
    expected = [-0.3 * SQ(3), -0.9, 0.1, 0.05, -0.1]
    np.testing.assert_allclose(values(fr, pts), expected, atol=1e-12)


def test_parameters_broadcast_and_are_differentiable():
    x = random_points(20, 4)
    r = torch.tensor([[0.5], [0.7], [0.9]], dtype=torch.float64, requires_grad=True)
    d = sdf.sphere(x, (0, 0, 0), r)
    assert d.shape == (3, 20)
    for i in range(3):
        torch.testing.assert_close(d[i], sdf.sphere(x, (0, 0, 0), float(r.detach()[i, 0])))
    (dr,) = torch.autograd.grad(d.sum(), r)
    torch.testing.assert_close(dr, torch.full((3, 1), 20.0, dtype=torch.float64))  # d d / d r = 1
    centers = torch.tensor([[0, 0, 0], [0.1, 0.2, 0.3]], dtype=torch.float64)
    d = sdf.box(x, (0.5, 0.4, 0.3), centers)
    assert d.shape == (2, 20)
    torch.testing.assert_close(d[1], sdf.box(x, (0.5, 0.4, 0.3), (0.1, 0.2, 0.3)))
    d = sdf.cappedCone(x, A, B, torch.tensor([[0.5], [0.6]], dtype=torch.float64), 0.2)
    torch.testing.assert_close(d[1], sdf.cappedCone(x, A, B, 0.6, 0.2))
    # d d / d b_x = 1 at a point whose nearest face is x = b_x
    b = torch.tensor([0.8, 0.6, 0.7], dtype=torch.float64, requires_grad=True)
    (db,) = torch.autograd.grad(sdf.box(torch.tensor([[0.7, 0.0, 0.0]], dtype=torch.float64), b).sum(), b)
    torch.testing.assert_close(db, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))


# ----------------------------------------------------------------------------- operations


def test_sharp_operations_are_min_max():
    rng = np.random.default_rng(5)
    d1, d2 = rng.normal(size=100), rng.normal(size=100)
    np.testing.assert_array_equal(sdf.union(d1, d2), np.maximum(d1, d2))
    np.testing.assert_array_equal(sdf.intersection(d1, d2), np.minimum(d1, d2))
    np.testing.assert_array_equal(sdf.difference(d1, d2), np.minimum(d1, -d2))
    np.testing.assert_array_equal(sdf.negate(d1), -d1)
    # the union of two disjoint spheres is the exact distance outside both
    x = random_points(500, 6).numpy()
    u = sdf.union(sdf.sphere(x, (-0.6, 0, 0), 0.3), sdf.sphere(x, (0.6, 0, 0), 0.3))
    exact = 0.3 - np.minimum(np.linalg.norm(x - [-0.6, 0, 0], axis=1), np.linalg.norm(x - [0.6, 0, 0], axis=1))
    np.testing.assert_allclose(u, exact, atol=1e-12)


def test_smooth_operations_reduce_to_sharp_ones_far_from_the_junction():
    rng = np.random.default_rng(7)
    d1, d2 = rng.uniform(-1, 1, 2000), rng.uniform(-1, 1, 2000)
    k = 0.3
    far = np.abs(d1 - d2) >= k
    su, si, sd = sdf.smoothUnion(d1, d2, k), sdf.smoothIntersection(d1, d2, k), sdf.smoothDifference(d1, d2, k)
    np.testing.assert_allclose(su[far], np.maximum(d1, d2)[far], atol=1e-15)
    np.testing.assert_allclose(si[far], np.minimum(d1, d2)[far], atol=1e-15)
    far_diff = np.abs(d1 + d2) >= k
    np.testing.assert_allclose(sd[far_diff], np.minimum(d1, -d2)[far_diff], atol=1e-15)
    near = ~far
    assert (su[near] > np.maximum(d1, d2)[near]).all() and (si[near] < np.minimum(d1, d2)[near]).all()
    # the blend adds at most k/4, reached where d1 = d2
    assert (su - np.maximum(d1, d2)).max() <= k / 4 + 1e-15
    np.testing.assert_allclose(sdf.smoothUnion(np.array([0.2]), np.array([0.2]), k), [0.2 + k / 4])
    np.testing.assert_allclose(sdf.smoothIntersection(np.array([0.2]), np.array([0.2]), k), [0.2 - k / 4])
    # k = 0 is the sharp operation, continuous, no NaN (also in the gradient)
    np.testing.assert_array_equal(sdf.smoothUnion(d1, d2, 0.0), np.maximum(d1, d2))
    a = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    sdf.smoothUnion(a, torch.zeros(3, dtype=torch.float64), torch.zeros(1, dtype=torch.float64)).sum().backward()
    assert torch.isfinite(a.grad).all()
    with pytest.raises(ValueError, match="sdf.smoothUnion: k must be nonnegative"):
        sdf.smoothUnion(d1, d2, -0.1)


def test_dilate_erode_exact_for_a_sphere_and_shell_boundary():
    x = random_points(1000, 8).numpy()
    s = sdf.sphere(x, (0.1, 0, 0), 0.5)
    np.testing.assert_allclose(sdf.dilate(s, 0.2), sdf.sphere(x, (0.1, 0, 0), 0.7), atol=1e-14)
    np.testing.assert_allclose(sdf.erode(s, 0.2), sdf.sphere(x, (0.1, 0, 0), 0.3), atol=1e-14)
    e = 0.05  # shell of total thickness 2 e: its boundaries are the spheres of radius 0.5 +- e
    dirs = x / np.linalg.norm(x, axis=1, keepdims=True)
    for radius in (0.5 - e, 0.5 + e):
        on = np.array([0.1, 0, 0]) + radius * dirs
        np.testing.assert_allclose(sdf.shell(sdf.sphere(on, (0.1, 0, 0), 0.5), e), 0.0, atol=1e-14)
    rho = np.linalg.norm(x - [0.1, 0, 0], axis=1)  # exact distance to the hollow ball 0.5 - e <= rho <= 0.5 + e
    np.testing.assert_allclose(sdf.shell(s, e), np.minimum(rho - (0.5 - e), 0.5 + e - rho), atol=1e-14)
    with pytest.raises(ValueError, match="sdf.shell: e must be positive"):
        sdf.shell(s, -1.0)


# ----------------------------------------------------------------------------- array plumbing


def test_numpy_in_numpy_out_and_float32():
    x64 = random_points(200, 9).numpy()
    for name, (f, _, _) in SHAPES.items():
        out = f(x64)
        assert isinstance(out, np.ndarray) and out.shape == (200,) and out.dtype == np.float64, name
        out32 = f(torch.from_numpy(x64).float())
        assert out32.dtype == torch.float32, name
        np.testing.assert_allclose(out32.numpy(), out, atol=2e-6, err_msg=name)
    grid = np.zeros((4, 5, 6, 3))  # any leading shape
    assert sdf.torus(grid, 1.0, 0.2).shape == (4, 5, 6)


def test_bad_input_raises_naming_it():
    with pytest.raises(ValueError, match=r"\(5, 2\)"):
        sdf.box(np.zeros((5, 2)))
    assert sdf.sphere(np.zeros((0, 3))).shape == (0,)  # no points, no values (documented in _array)
    with pytest.raises(ValueError, match="center must have 3 components"):
        sdf.sphere(np.zeros((5, 3)), center=(0, 0))
    with pytest.raises(ValueError, match="axis"):
        sdf.torus(np.zeros((5, 3)), axis="w")
    with pytest.raises(ValueError, match="sdf.roundedBox: radius must be nonnegative"):
        sdf.roundedBox(np.zeros((5, 3)), 1.0, -0.1)
    with pytest.raises(TypeError, match="list"):
        sdf.capsule([[0.0, 0.0, 0.0]])
