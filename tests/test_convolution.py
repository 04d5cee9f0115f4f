"""Cauchy-kernel convolution surfaces against numerical quadrature and closed-form limits."""

import math
import warnings

import numpy as np
import pytest
import torch

from pyfrep_core import Param, convArc, convCurve, convLine, convLineR, convMesh, convPoint, convTriangle, model

F64 = torch.float64


def kernel(r2, s):
    return 1.0 / (1.0 + s * s * r2) ** 2


def randn(*shape, seed=0, scale=1.0):
    return scale * torch.randn(*shape, generator=torch.Generator().manual_seed(seed), dtype=F64)


def quad_segment(x, b, e, s, n=100001):
    t = torch.linspace(0.0, 1.0, n, dtype=F64)
    pts = b + t[:, None] * (e - b)
    values = kernel(((x[:, None, :] - pts[None]) ** 2).sum(-1), s)
    return torch.trapezoid(values, t, dim=1) * (e - b).norm()


def quad_triangle(x, tri, s, n=601):
    """Area integral over the triangle, through the map (U, V) -> a + U (b - a) + U V (c - b)."""
    a, b, c = tri
    u = torch.linspace(0.0, 1.0, n, dtype=F64)
    U, V = torch.meshgrid(u, u, indexing="ij")
    pts = a + U[..., None] * (b - a) + (U * V)[..., None] * (c - b)
    jac = U * torch.linalg.cross(b - a, c - b).norm()
    out = [torch.trapezoid(torch.trapezoid(kernel(((pts - p) ** 2).sum(-1), s) * jac, u, dim=1), u) for p in x]
    return torch.stack(out)


def test_conv_point_is_the_sum_of_cauchy_kernels():
    centers = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.5, -0.2], [-0.3, 0.8, 0.4]], dtype=F64)
    s = torch.tensor([1.0, 2.0, 0.5], dtype=F64)
    x = randn(100, 3)
    expected = sum(kernel(((x - c) ** 2).sum(-1), si) for c, si in zip(centers, s)) - 0.3
    torch.testing.assert_close(convPoint(x, centers, s, 0.3), expected, rtol=0, atol=1e-14)
    torch.testing.assert_close(convPoint(x, centers.reshape(-1).tolist(), s.tolist(), 0.3), expected)
    # one point with T = K(R) is a sphere of radius R
    s0, radius = 1.5, 0.7
    T = 1.0 / (1.0 + s0 * s0 * radius * radius) ** 2
    on = torch.tensor([[0.7, 0.0, 0.0], [0.0, -0.7, 0.0], [0.0, 0.0, 0.5]], dtype=F64)
    f = convPoint(on, [0, 0, 0], s0, T)
    assert abs(float(f[0])) < 1e-15 and abs(float(f[1])) < 1e-15 and float(f[2]) > 0


def test_conv_line_matches_quadrature():
    begin = torch.tensor([[0.1, -0.2, 0.3], [-1.0, 0.0, 0.5]], dtype=F64)
    end = torch.tensor([[1.0, 0.5, -0.4], [-0.2, 1.0, 0.5]], dtype=F64)
    s = torch.tensor([1.7, 0.8], dtype=F64)
    x = torch.cat([randn(30, 3, seed=1), begin, end, 0.5 * (begin + end)])  # include points on the skeleton
    expected = quad_segment(x, begin[0], end[0], 1.7) + quad_segment(x, begin[1], end[1], 0.8)
    out = convLine(x, begin.reshape(-1), end.reshape(-1), s, 0.0)
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-6)


def test_conv_line_long_segment_tends_to_the_infinite_line():
    # int_R du / (p^2 + S^2 u^2)^2 = pi / (2 S p^3), p^2 = 1 + S^2 h^2, at distance h from the middle
    s, h = 2.0, 0.3
    p = math.sqrt(1 + s * s * h * h)
    f = convLine(torch.tensor([[0.0, h, 0.0]], dtype=F64), [-1e4, 0, 0], [1e4, 0, 0], s, 0.0)
    assert abs(float(f) - math.pi / (2 * s * p**3)) < 1e-9


def test_conv_curve_is_the_sum_of_its_segments():
    vertices = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 1.0, 1.0]], dtype=F64)
    s = torch.tensor([1.0, 2.0, 3.0], dtype=F64)
    x = randn(50, 3, seed=2)
    expected = sum(convLine(x, vertices[i], vertices[i + 1], s[i], 0.0) for i in range(3)) - 0.2
    torch.testing.assert_close(convCurve(x, vertices.reshape(-1), s, 0.2), expected, rtol=0, atol=1e-14)
    # the joint lies inside, a point far from the curve outside
    f = convCurve(torch.tensor([[1.0, 0.0, 0.0], [-1.0, 2.0, 0.0]], dtype=F64), vertices, 3.0, 0.2)
    assert float(f[0]) > 0 > float(f[1])


def test_conv_line_r_passes_at_distance_r_from_the_midpoint():
    begin = torch.tensor([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]], dtype=F64)
    end = torch.tensor([[1.0, 0.0, 0.0], [3.0, 2.0, 0.0]], dtype=F64)
    for s, r in ((2.0, 0.25), (0.5, 0.1)):
        on = torch.tensor([[0.5, r, 0.0], [0.5, 0.0, -r], [3.0 - r, 1.0, 0.0]], dtype=F64)
        single = convLineR(on[:2], begin[0], end[0], s, r)
        assert float(single.abs().max()) < 1e-12
        assert abs(float(convLineR(on[2:], begin[1], end[1], s, r))) < 1e-12
        # several segments: the calibrated fields add up (f + 1 is additive)
        both = convLineR(on, begin, end, s, r)
        parts = [convLineR(on, begin[i], end[i], s, r) + 1.0 for i in range(2)]
        torch.testing.assert_close(both + 1.0, parts[0] + parts[1], rtol=0, atol=1e-14)
        inside = convLineR(torch.tensor([[0.5, 0.5 * r, 0.0]], dtype=F64), begin[0], end[0], s, r)
        outside = convLineR(torch.tensor([[0.5, 2.0 * r, 0.0]], dtype=F64), begin[0], end[0], s, r)
        assert float(inside) > 0 > float(outside)
    # per-segment radii
    f = convLineR(torch.tensor([[0.5, 0.2, 0.0]], dtype=F64), begin[0], end[0], [3.0], [0.2])
    assert abs(float(f)) < 1e-12


@pytest.mark.parametrize("s", [0.7, 2.0, 5.0])
def test_conv_triangle_matches_quadrature(s):
    tri = torch.tensor([[0.0, 0.0, 0.0], [1.2, 0.1, 0.2], [0.3, 0.9, -0.1]], dtype=F64)
    x = torch.cat([randn(6, 3, seed=3, scale=0.8) + 0.4, tri.mean(0, keepdim=True)])
    out = convTriangle(x, tri.reshape(-1), s, 0.0)
    torch.testing.assert_close(out, quad_triangle(x, tri, s), rtol=0, atol=1e-6)
    # the result does not depend on the vertex order (the longest edge is found internally)
    torch.testing.assert_close(convTriangle(x, tri[[2, 0, 1]], s, 0.0), out, rtol=0, atol=1e-13)
    torch.testing.assert_close(convTriangle(x, tri[[1, 0, 2]], s, 0.0), out, rtol=0, atol=1e-13)


def test_conv_triangle_limits():
    s = 3.0
    big = torch.tensor([[-1e3, -1e3, 0.0], [1e3, -1e3, 0.0], [0.0, 1e3, 0.0]], dtype=F64)
    # deep inside a large triangle (edges >= 536 away, tail < pi / (S^4 536^2) ~ 1e-7): the
    # integral over the whole plane, pi / (S^2 (1 + S^2 w^2))
    for w in (0.0, 0.4):
        f = convTriangle(torch.tensor([[0.0, -200.0, w]], dtype=F64), big, s, 0.0)
        assert abs(float(f) - math.pi / (s * s * (1 + s * s * w * w))) < 1e-6
    # far away: area * K(distance to the centroid)
    small = torch.tensor([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]], dtype=F64)
    far = torch.tensor([[0.5, 0.3, 2.0]], dtype=F64)
    centroid = small.mean(0)
    approx = 0.5e-4 * kernel(((far - centroid) ** 2).sum(), s)
    assert abs(float(convTriangle(far, small, s, 0.0)) / float(approx) - 1) < 1e-4


def test_conv_mesh_equals_its_triangles():
    verts = torch.tensor([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0.7]], dtype=F64)
    faces = torch.tensor([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    s = torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=F64)
    x = randn(40, 3, seed=4)
    expected = sum(convTriangle(x, verts[f], s[i], 0.0) for i, f in enumerate(faces)) - 0.1
    out1 = convMesh(x, verts.reshape(-1), (faces + 1).reshape(-1), s, 0.1)  # reference: 1-based, flat
    out0 = convMesh(x, verts, faces, s, 0.1, base=0)
    torch.testing.assert_close(out1, expected, rtol=0, atol=1e-13)
    torch.testing.assert_close(out0, expected, rtol=0, atol=1e-13)
    # numpy in, numpy out, with integer faces
    out_np = convMesh(x.numpy(), verts.numpy(), faces.numpy(), s.numpy(), 0.1, base=0)
    assert isinstance(out_np, np.ndarray)
    np.testing.assert_allclose(out_np, expected.numpy(), atol=1e-13)
    with pytest.raises(ValueError, match="integer vertex indices"):
        convMesh(x, verts, [0.5, 1, 2], 1.0, 0.1, base=0)
    with pytest.raises(ValueError, match="base=0"):
        convMesh(x, verts, faces, s, 0.1)  # 0-based faces read as 1-based
    with pytest.raises(ValueError, match="tri indices"):
        convMesh(x, verts, faces + 5, s, 0.1, base=0)


def quad_arc(x, center, radius, theta_deg, rot, s, n=100001):
    phi = torch.linspace(0.0, math.radians(theta_deg), n, dtype=F64)
    local = torch.stack([radius * torch.cos(phi), radius * torch.sin(phi), torch.zeros_like(phi)], -1)
    world = center + local @ rot.T
    values = kernel(((x[:, None] - world[None]) ** 2).sum(-1), s)
    return torch.trapezoid(values, phi, dim=1) * radius


def rotation(axis, degrees):
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    a = math.radians(degrees)
    return torch.tensor(np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K, dtype=F64)


@pytest.mark.parametrize("theta", [45.0, 180.0, 270.0, 360.0])
def test_conv_arc_matches_quadrature(theta):
    center = torch.tensor([0.2, 0.1, -0.3], dtype=F64)
    axis, angle, radius, s = (1.0, 2.0, 0.5), 37.0, 0.8, 2.0
    x = torch.cat([randn(20, 3, seed=5), center[None]])  # include the centre (on the arc's axis)
    expected = quad_arc(x, center, radius, theta, rotation(axis, angle), s)
    out = convArc(x, center, radius, theta, axis, angle, s, 0.0)
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-9)


def test_conv_arc_full_circle_on_axis_and_several_arcs():
    r, s = 0.6, 1.5
    z = torch.tensor([0.0, 0.4, -1.0], dtype=F64)
    x = torch.stack([torch.zeros(3, dtype=F64), torch.zeros(3, dtype=F64), z], -1)
    f = convArc(x, [0, 0, 0], r, 360.0, [0, 0, 1], 0.0, s, 0.0)
    torch.testing.assert_close(f, 2 * math.pi * r * kernel(z * z + r * r, s), rtol=0, atol=1e-14)
    # two arcs in one call = the sum of the two calls
    y = randn(30, 3, seed=6)
    centers = [[0, 0, 0], [1, 0, 0]]
    both = convArc(y, centers, [0.5, 0.3], [90.0, 300.0], [[0, 0, 1], [1, 0, 0]], [0.0, 45.0], [2.0, 1.0], 0.1)
    one = convArc(y, centers[0], 0.5, 90.0, [0, 0, 1], 0.0, 2.0, 0.0)
    two = convArc(y, centers[1], 0.3, 300.0, [1, 0, 0], 45.0, 1.0, 0.0)
    torch.testing.assert_close(both, one + two - 0.1, rtol=0, atol=1e-14)


def test_iso_surface_signs():
    p = torch.tensor([[0.5, 0.0, 0.0], [0.5, 2.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=F64)
    f = convLine(p, [0, 0, 0], [1, 0, 0], 2.0, 0.2)
    assert float(f[0]) > 0 > float(f[1])
    # the torus of a full circle: inside on the circle, outside at its centre and far away
    f = convArc(p, [0, 0, 0], 1.0, 360.0, [0, 0, 1], 0.0, 4.0, 0.2)
    assert float(f[2]) > 0 > float(f[3]) and float(f[1]) < 0


def test_gradients_finite_on_the_skeleton():
    tri = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=F64)
    special = torch.cat([tri, 0.5 * (tri + tri.roll(1, 0)), tri.mean(0, keepdim=True), torch.zeros(1, 3, dtype=F64)])
    for fn in (
        lambda x: convPoint(x, tri, 2.0, 0.0),
        lambda x: convLine(x, tri[0], tri[1], 2.0, 0.0),
        lambda x: convCurve(x, tri, 2.0, 0.0),
        lambda x: convLineR(x, tri[0], tri[1], 2.0, 0.2),
        lambda x: convTriangle(x, tri, 2.0, 0.0),
        lambda x: convArc(x, [0, 0, 0], 1.0, 360.0, [0, 0, 1], 0.0, 2.0, 0.0),
    ):
        x = special.clone().requires_grad_(True)
        (g,) = torch.autograd.grad(fn(x).sum(), x)
        assert torch.isfinite(g).all()


def test_parameters_are_differentiable():
    x = randn(10, 3, seed=7)
    s = torch.tensor(1.3, dtype=F64, requires_grad=True)
    (ds,) = torch.autograd.grad(convPoint(x, [0, 0, 0], s, 0.0).sum(), s)
    r2 = (x * x).sum(-1)
    expected = (-4 * 1.3 * r2 / (1 + 1.69 * r2) ** 3).sum()
    assert abs(float(ds - expected)) < 1e-12
    end = torch.tensor([1.0, 0.2, 0.0], dtype=F64, requires_grad=True)
    (de,) = torch.autograd.grad(convLine(x, [0, 0, 0], end, 2.0, 0.0).sum(), end)
    h = 1e-6
    fd = [
        (
            convLine(x, [0, 0, 0], end.detach() + h * e, 2.0, 0.0)
            - convLine(x, [0, 0, 0], end.detach() - h * e, 2.0, 0.0)
        )
        .sum()
        .item()
        / (2 * h)
        for e in torch.eye(3, dtype=F64)
    ]
    np.testing.assert_allclose(de.numpy(), fd, atol=1e-7)


def test_batched_parameters_give_one_row_per_set():
    x = randn(9, 3, seed=8)
    s_batch = torch.tensor([[1.0], [2.5], [4.0]], dtype=F64)
    tri = [0, 0, 0, 1, 0, 0, 0, 1, 0]
    calls = [
        lambda s: convPoint(x, [0, 0, 0, 1, 1, 1], s, 0.1),
        lambda s: convLine(x, [0, 0, 0], [1, 0, 0], s, 0.1),
        lambda s: convCurve(x, [0, 0, 0, 1, 0, 0, 1, 1, 0], s, 0.1),
        lambda s: convLineR(x, [0, 0, 0], [1, 0, 0], s, 0.2),
        lambda s: convTriangle(x, tri, s, 0.1),
        lambda s: convMesh(x, tri, [1, 2, 3], s, 0.1),
        lambda s: convArc(x, [0, 0, 0], 1.0, 270.0, [0, 0, 1], 0.0, s, 0.1),
    ]
    for call in calls:
        batch = call(s_batch)
        assert batch.shape == (3, 9)
        singles = torch.stack([call(float(v)) for v in s_batch[:, 0]])
        torch.testing.assert_close(batch, singles, rtol=0, atol=1e-14)

    # through @model, which maps (B,) parameters with torch.func.vmap (the model sees 0-d S and R)
    @model(S=Param(2.0, 0.5, 5.0), R=Param(0.2, 0.05, 0.5))
    def rod(p, S, R):
        return convLineR(p, [0, 0, 0], [1, 0, 0], S, R)

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # vmap runs it: no fallback to a loop over the sets
        out = rod(x, S=torch.tensor([1.0, 3.0], dtype=F64), R=torch.tensor([0.1, 0.3], dtype=F64))
    assert out.shape == (2, 9)
    torch.testing.assert_close(out[1], convLineR(x, [0, 0, 0], [1, 0, 0], 3.0, 0.3), rtol=0, atol=1e-14)


def test_numpy_float32_and_shapes():
    x = np.random.default_rng(0).uniform(-1, 1, (4, 5, 3))
    out = convTriangle(x, [0, 0, 0, 1, 0, 0, 0, 1, 0], 2.0, 0.1)
    assert isinstance(out, np.ndarray) and out.shape == (4, 5) and out.dtype == np.float64
    out32 = convArc(torch.from_numpy(x).float(), [0, 0, 0], 1.0, 360.0, [0, 0, 1], 0.0, 2.0, 0.1)
    assert out32.dtype == torch.float32 and out32.shape == (4, 5)
    np.testing.assert_allclose(out32.numpy(), convArc(x, [0, 0, 0], 1.0, 360.0, [0, 0, 1], 0.0, 2.0, 0.1), atol=1e-5)


def test_bad_input_raises():
    x = torch.zeros(3, 3, dtype=F64)
    with pytest.raises(ValueError, match="positive length"):
        convLine(x, [0, 0, 0], [0, 0, 0], 1.0, 0.1)
    with pytest.raises(ValueError, match="positive area"):
        convTriangle(x, [0, 0, 0, 1, 0, 0, 2, 0, 0], 1.0, 0.1)
    with pytest.raises(ValueError, match="vect must hold"):
        convPoint(x, [0, 0], 1.0, 0.1)
    with pytest.raises(ValueError, match="S must be positive"):
        convPoint(x, [0, 0, 0], -1.0, 0.1)
    with pytest.raises(ValueError, match="S must have"):
        convPoint(x, [0, 0, 0, 1, 1, 1], [1.0, 2.0, 3.0], 0.1)
    with pytest.raises(ValueError, match="same number"):
        convLine(x, [0, 0, 0, 1, 1, 1], [1, 0, 0], 1.0, 0.1)
    with pytest.raises(ValueError, match="theta"):
        convArc(x, [0, 0, 0], 1.0, 400.0, [0, 0, 1], 0.0, 1.0, 0.1)
    with pytest.raises(ValueError, match="axis"):
        convArc(x, [0, 0, 0], 1.0, 90.0, [0, 0, 0], 0.0, 1.0, 0.1)
    with pytest.raises(ValueError, match=r"convPoint: vect must be finite, got \[0, nan, 0\]"):
        convPoint(x, [0, float("nan"), 0], 1.0, 0.1)
    with pytest.raises(ValueError, match="x must have shape"):
        convPoint(torch.zeros(3, 2), [0, 0, 0], 1.0, 0.1)
