"""The meshers' compiled loops (pyfrep_core.meshing.loops) against plain NumPy and closed forms, and
dual contouring's slabs and threads: the same mesh however the grid is cut.
"""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from pyfrep_core import polygonize, sphere
from pyfrep_core.meshing import dual_contouring
from pyfrep_core.meshing.loops import (
    _classify_blocks,
    _edge_points,
    _section_points,
    _section_step,
    _symmetric_eigen3,
    _unbias_requests,
    _unbias_scale,
)
from pyfrep_core.meshing.roots import SECTION_POINTS, _bracketed_roots
from pyfrep_core.models import fig1_part

BOX = ((-1.1,) * 3, (1.1,) * 3)


def eigen(matrix):
    w, u = np.empty(3), np.empty((3, 3))
    _symmetric_eigen3(matrix.copy(), w, u)
    return w, u


@pytest.mark.parametrize("seed", range(5))
def test_jacobi_eigen_gives_the_eigenpairs_of_a_rotated_diagonal(seed):
    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    values = np.sort(rng.uniform(0.0, 5.0, 3))
    values[0] = 0.0 if seed % 2 else values[0]  # a QEF of a crease: one zero eigenvalue
    w, u = eigen(rotation @ np.diag(values) @ rotation.T)
    np.testing.assert_allclose(w, values, atol=1e-13 * values[-1])
    np.testing.assert_allclose(u.T @ u, np.eye(3), atol=1e-14)
    # each eigenvector is the rotation's column, up to sign (the eigenvalues are distinct)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->j", u, rotation)), 1.0, atol=1e-12)


def test_jacobi_eigen_of_a_repeated_eigenvalue_spans_its_plane():
    n = np.array([0.0, 0.6, 0.8])
    w, u = eigen(np.outer(n, n))  # a flat patch: eigenvalues 0, 0, 1
    np.testing.assert_allclose(w, [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(np.abs(u[:, 2]), np.abs(n), atol=1e-15)
    np.testing.assert_allclose(u[:, :2].T @ n, 0.0, atol=1e-15)


def _classify_reference(v, part, s, shape):
    """Plain NumPy: every node, cell and edge of the blocks, one by one."""
    cells, edges = {}, {}
    n = np.prod(shape)
    for b in range(len(part)):
        for i, j, m in np.ndindex(s + 1, s + 1, s + 1):
            g = part[b] * s + (i, j, m)
            if (g > shape - 1).any():
                continue
            if i < s and j < s and m < s and (g < shape - 1).all():
                inside = [v[b, i + (c & 1), j + (c >> 1 & 1), m + (c >> 2 & 1)] > 0 for c in range(8)]
                config = sum(int(x) << c for c, x in enumerate(inside))
                if 0 < config < 255:
                    cells[int(np.ravel_multi_index(g, shape - 1))] = config
            for a in range(3):
                step = np.eye(3, dtype=int)[a]
                local = np.array([i, j, m])
                if local[a] == s or g[a] == shape[a] - 1:
                    continue
                f0, f1 = v[b, i, j, m], v[(b, *(local + step))]
                if (f0 > 0) != (f1 > 0):
                    edges.setdefault(int(np.ravel_multi_index(g, shape)) + a * n, set()).add((f0, f1))
    return cells, edges


@pytest.mark.parametrize("seed", range(3))
def test_block_classification_matches_a_plain_loop(seed):
    rng = np.random.default_rng(seed)
    s, shape = 3, np.array([8, 7, 9])  # blocks past the grid's last node (padding) on every axis
    part = np.array([(x, y, z) for x in range(3) for y in range(3) for z in range(3)], dtype=np.int64)
    v = rng.normal(size=(len(part), s + 1, s + 1, s + 1))
    keys, config, edge_keys, f0, f1 = _classify_blocks(v, part, s, shape)
    cells, edges = _classify_reference(v, part, s, shape)
    assert dict(zip(keys.tolist(), config.tolist())) == cells and len(keys) == len(cells)
    # edges on faces shared by two blocks come once from each block, with that block's end values
    found = {}
    for key, start, end in zip(edge_keys.tolist(), f0, f1):
        found.setdefault(key, set()).add((start, end))
    assert found == edges and len(edge_keys) == sum(len(pairs) for pairs in edges.values())


@pytest.mark.parametrize("workers", [1, 2, 3])
def test_compaction_keeps_the_used_vertices_in_order_and_renumbers_faces(workers):
    rng = np.random.default_rng(workers)
    faces = rng.integers(0, 5000, size=(3000, 3))  # about 1 in 6 vertices never used
    used = np.unique(faces)
    want = np.searchsorted(used, faces)
    with ThreadPoolExecutor(workers) as pool:
        kept = dual_contouring._compact(faces, 5000, pool.submit, workers)
    assert 0 < len(kept) < 5000
    np.testing.assert_array_equal(kept, used)
    np.testing.assert_array_equal(faces, want)


def test_edge_points_are_component_first_and_on_their_edges():
    start = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]])
    points = _edge_points(
        np.array([1, 0]), start, np.array([0, 2]), np.array([0.0, 5.0]), np.full(2, 0.5), np.full(2, 0.25)
    )
    np.testing.assert_array_equal(points, [[3.0, 4.0, 5.125], [0.125, 1.0, 2.0]])
    assert points.strides == (8, 16)  # x[:, 0] contiguous: what compiled kernels read


def test_bracketed_roots_find_the_roots_of_a_sphere_on_its_edges():
    # edges along x from x = 0 to 0.1 at heights where the unit sphere crosses them
    y = np.linspace(0.0, 0.99, 50)
    x_root = np.sqrt(1.0 - y * y) - 0.95
    keep = (x_root > 0.0) & (x_root < 0.1)
    y, x_root = y[keep], x_root[keep]
    start = np.stack([np.full_like(y, 0.95), y, np.zeros_like(y)], axis=1)

    def f(p):
        return sphere(p, r=1.0)

    f0 = 1.0 - (0.95**2 + y * y)
    f1 = 1.0 - (1.05**2 + y * y)
    c = f0 / (f0 - f1)
    root, rest, _ = _bracketed_roots(
        f,
        start,
        start[:, 0].copy(),
        np.full_like(y, 0.1),
        np.zeros(len(y), dtype=np.int64),
        c,
        f1 - f0,
        f0,
        f1,
        1e-13,
        "cpu",
    )
    assert len(rest) == 0
    np.testing.assert_allclose(0.95 + 0.1 * root, x_root + 0.95, atol=1e-12)


def unbias_scale(quads, points, point_gradient, x, gradient):
    total, count = np.zeros((1, len(x))), np.zeros((1, len(x)))
    _unbias_requests(quads, points, point_gradient, x, gradient, total[0], count[0])
    return _unbias_scale(total, count, gradient)


@pytest.mark.parametrize("h", [0.1, 0.05, 0.025])
def test_unbias_steps_ask_for_nine_eighths_of_the_centroid_depth_on_a_sphere(h):
    # one quad on the unit sphere f = 1 - |x|^2 (grad f = -2 x, inward): vertices at (1, +-h, +-h)
    # projected, the crossing at (1, 0, 0); each vertex is in two triangles, so it is asked for the
    # mean of their two centroids' 9/8 depth; the chord formula is exact to O(h^2) relatively
    corners = np.array([[1.0, -h, -h], [1.0, h, -h], [1.0, h, h], [1.0, -h, h]])
    x = corners / np.linalg.norm(corners, axis=1, keepdims=True)
    crossing = np.array([[1.0, 0.0, 0.0]])
    scale = unbias_scale(np.array([[0, 1, 2, 3]]), crossing, -2 * crossing, x, -2 * x)
    exact = [1 - np.linalg.norm((crossing[0] + x[i] + x[(i + 1) % 4]) / 3) for i in range(4)]
    want = [1.125 * (exact[i - 1] + exact[i]) / 2 for i in range(4)]
    asked = scale * np.linalg.norm(-2 * x, axis=1)  # back to length units
    np.testing.assert_allclose(asked, want, rtol=2 * h**2)
    smooth_gradient = -2 * x
    smooth_gradient[0] = np.nan  # a vertex that is not smooth is neither moved nor asked
    scale = unbias_scale(np.array([[0, 1, 2, 3]]), crossing, -2 * crossing, x, smooth_gradient)
    assert scale[0] == 0.0
    np.testing.assert_allclose(scale[2] * 2, want[2], rtol=2 * h**2)  # its two triangles do not touch vertex 0


def test_dual_contouring_gives_the_same_mesh_however_the_slabs_are_cut(monkeypatch):
    monkeypatch.setattr(dual_contouring, "WORKERS", 1)
    monkeypatch.setattr(dual_contouring, "SLAB_POINTS", 1 << 40)
    one = polygonize(fig1_part, BOX, 64, method="dc")  # one slab, one thread
    monkeypatch.setattr(dual_contouring, "WORKERS", 2)
    monkeypatch.setattr(dual_contouring, "SLAB_POINTS", 20000)  # a block layer or two each, two at a time
    many = polygonize(fig1_part, BOX, 64, method="dc")
    assert many.n_faces == one.n_faces and many.n_vertices == one.n_vertices
    np.testing.assert_allclose(np.sort(many.vertices, axis=0), np.sort(one.vertices, axis=0), atol=1e-12)
    assert many.volume() == pytest.approx(one.volume(), abs=1e-12)


def kinked_edges():
    """Edges x in [0, 1] (the root moves with y) along which f = min(plateau, slope (x - root)): nearly
    flat (a face grazing the edge) beyond a kink just past the root.  Their roots, and
    ``_bracketed_roots``' arguments before ``step_tol``."""
    root_x = np.array([0.197, 0.31, 0.52, 0.8])
    slope, plateau = 0.0548, 4.1e-4

    def f(p):
        return torch.clamp(slope * (p[:, 0] - 0.197 - p[:, 1]), max=plateau)

    n = len(root_x)
    start = np.zeros((n, 3))
    start[:, 1] = root_x - 0.197
    f0, f1 = -slope * root_x, np.full(n, plateau)
    c = f0 / (f0 - f1)
    return root_x, (f, start, start[:, 0].copy(), np.ones(n), np.zeros(n, dtype=np.int64), c, f1 - f0, f0, f1)


def test_bracketed_roots_close_in_on_a_kink_from_both_sides():
    # Plain regula falsi keeps the far end and creeps along the plateau (after 20 steps its estimates
    # were still 0.26-0.30 short of the roots; it took 60); halving the kept end's value (Illinois)
    # crosses the kink in a few steps.
    root_x, args = kinked_edges()
    root, rest, _ = _bracketed_roots(*args, 1e-12, "cpu", 20)
    assert len(rest) == 0
    np.testing.assert_allclose(root, root_x, atol=1e-12)


def test_a_multisection_step_keeps_the_first_sign_change_from_a_and_ends_with_regula_falsi():
    # brackets [a, p] of three edges along x from 0, of length 2; f(t) = t - root in edge units, one
    # root on a section point (exact), one with NaN among the values (dropped, no root)
    a, p = np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 1.0])  # the second runs from 1 down to 0
    roots = np.array([0.3, 0.6, 0.3])
    fa, fp = a - roots, p - roots
    rows, m = np.arange(3), 4
    t, points = _section_points(
        rows, np.zeros((3, 3)), np.zeros(3, dtype=np.int64), np.zeros(3), np.full(3, 2.0), a, p, m
    )
    np.testing.assert_allclose(t, [0.2, 0.4, 0.6, 0.8, 0.8, 0.6, 0.4, 0.2, 0.2, 0.4, 0.6, 0.8])
    np.testing.assert_allclose(points[:, 0], 2 * t)
    ft = t - np.repeat(roots, m)
    ft[8] = np.nan
    root = np.full(3, np.nan)
    moving = _section_step(rows, t, ft, m, a, fa, p, fp, False, root)
    assert moving.tolist() == [0]  # the second's root is t = 0.6 exactly; the third has a NaN
    np.testing.assert_allclose([a[0], p[0]], [0.2, 0.4])  # 1/5 of the bracket, around the root
    assert root[1] == t[5] and np.isnan(root[2])
    moving = _section_step(
        moving,
        *_section_points(moving, np.zeros((3, 3)), np.zeros(3, dtype=np.int64), np.zeros(3), np.full(3, 2.0), a, p, m)[
            :1
        ],
        np.array([0.24, 0.28, 0.32, 0.36]) - 0.3,
        m,
        a,
        fa,
        p,
        fp,
        True,
        root,
    )
    assert len(moving) == 0
    assert root[0] == pytest.approx(0.3, abs=1e-15)  # regula falsi on a straight line: exact


def test_bracketed_roots_narrow_the_edges_where_the_secant_creeps_by_multisection():
    # the kinked edges after 3 secant steps only: far from the roots (the plateau), then two
    # multisection steps put each root within 1/33^2 of its bracket, whatever f's shape there
    root_x, args = kinked_edges()
    args = (*args, 1e-12, "cpu", 3)
    _, rest, estimate = _bracketed_roots(*args)
    assert len(rest) == len(root_x) and np.abs(estimate - root_x[rest]).max() > 0.1  # the secant alone: still creeping
    root, rest, _ = _bracketed_roots(*args, sections=2)
    assert len(rest) == 0
    assert np.abs(root - root_x).max() <= 1 / (SECTION_POINTS + 1) ** 2
