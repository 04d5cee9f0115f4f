"""polygonize and Mesh: the Fig. 1 part against its exact volume, spheres against closed forms, bad input."""

import math
import os
import re
import tracemalloc
import warnings

import numpy as np
import pytest
import torch

from pyfrep_core import Mesh, Param, grad, model, polygonize, sphere
from pyfrep_core.diff import value_and_grad
from pyfrep_core.meshing import GridTooLargeError, evaluate_grid, grid_axes, grid_memory
from pyfrep_core.meshing.grid import _MALLOC_VARIABLES, _glibc
from pyfrep_core.models import fig1_part

BOX = ((-1.1,) * 3, (1.1,) * 3)
# Exact volume of the Fig. 1 part (sphere r = 1 cut by the cube [-0.75, 0.75]^3, three r = 0.5
# cylinders removed): the z-extent over (x, y) is 2 max(0, min(0.75, sqrt(1 - x^2 - y^2))
# - sqrt(max(0, 0.25 - min(x^2, y^2)))), integrated with scipy.integrate.dblquad.
FIG1_VOLUME = 0.9887887


def edge_counts(faces):
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(edges, axis=0, return_counts=True)[1]


def face_normals(mesh):
    a, b, c = (mesh.vertices[mesh.faces[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def fig1_128():
    return polygonize(fig1_part, BOX, 128)


def test_fig1_part_at_128_is_watertight_on_the_surface_and_has_the_exact_volume(fig1_128):
    m = fig1_128
    assert m.vertices.dtype == np.float64 and m.faces.dtype == np.int64
    assert m.n_faces > 50_000
    assert (edge_counts(m.faces) == 2).all()  # closed 2-manifold: every edge in exactly two faces
    assert np.array_equal(np.unique(m.faces), np.arange(m.n_vertices))  # no stray vertices
    assert (m.vertices >= -1.1).all() and (m.vertices <= 1.1).all()
    f = fig1_part(torch.as_tensor(m.vertices, dtype=torch.float64))
    assert float(f.abs().max()) < 1e-9
    assert abs(m.volume() - FIG1_VOLUME) < 3e-3


def test_fig1_part_normals_point_outward(fig1_128):
    m = fig1_128
    assert m.volume() > 0  # counter-clockwise seen from outside
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-12)
    vertex_normal = m.normals[m.faces].mean(axis=1)
    agree = np.einsum("ij,ij->i", face_normals(m), vertex_normal / np.linalg.norm(vertex_normal, axis=1)[:, None])
    assert (agree > 0).all()
    assert (agree > 0.9).mean() > 0.99  # only triangles across the part's sharp edges differ more
    # outward: a small step along the normal leaves the solid, one against it enters
    x = torch.as_tensor(m.vertices)
    n = torch.as_tensor(m.normals)
    assert float((fig1_part(x + 1e-4 * n) < 0).double().mean()) > 0.99
    assert float((fig1_part(x - 1e-4 * n) > 0).double().mean()) > 0.99


def test_fig1_part_at_256_volume_within_5e4():
    m = polygonize(fig1_part, BOX, 256)
    assert (edge_counts(m.faces) == 2).all()
    assert abs(m.volume() - FIG1_VOLUME) < 5e-4
    assert float(fig1_part(torch.as_tensor(m.vertices)).abs().max()) < 1e-9


def test_model_uses_its_default_bounds_and_parameters():
    m = polygonize(fig1_part, resolution=48)
    explicit = polygonize(lambda x: fig1_part(x), BOX, 48)
    np.testing.assert_array_equal(m.faces, explicit.faces)
    np.testing.assert_allclose(m.vertices, explicit.vertices, atol=1e-12)
    thin = polygonize(lambda x: fig1_part(x, r=0.35), BOX, 48)
    assert thin.volume() > m.volume() + 0.1  # narrower holes, more material


@pytest.mark.parametrize("n", [24, 48, 96])
def test_sphere_volume_and_area_converge_at_second_order(n):
    r = 0.9
    m = polygonize(lambda x: sphere(x, center=(0.05, -0.02, 0.01), r=r), ((-1.0,) * 3, (1.0,) * 3), n)
    h = 2.0 / (n - 1)
    volume_err = m.volume() / (4 / 3 * math.pi * r**3) - 1
    area_err = m.area() / (4 * math.pi * r**2) - 1
    # chords of a sphere of radius r: relative deficits of about h^2 / (2 r^2) and h^2 / (4 r^2)
    assert -0.8 * h**2 / r**2 < volume_err < 0
    assert -0.4 * h**2 / r**2 < area_err < 0
    radius = np.linalg.norm(m.vertices - np.array([0.05, -0.02, 0.01]), axis=1)
    np.testing.assert_allclose(radius, r, atol=1e-12)
    np.testing.assert_allclose(m.normals, (m.vertices - [0.05, -0.02, 0.01]) / r, atol=1e-9)


def test_anisotropic_grid_and_box():
    f = lambda x: sphere(x, center=(0.3, 0.0, 0.0), r=0.5)  # noqa: E731
    m = polygonize(f, ((-0.3, -0.6, -0.7), (0.9, 0.6, 0.7)), (40, 30, 50))
    assert (edge_counts(m.faces) == 2).all()
    assert abs(m.volume() / (4 / 3 * math.pi * 0.125) - 1) < 0.01
    np.testing.assert_allclose(np.linalg.norm(m.vertices - [0.3, 0, 0], axis=1), 0.5, atol=1e-12)


def test_surface_touching_the_bounds_gives_an_open_mesh_inside_them():
    m = polygonize(lambda x: sphere(x, r=1.0), ((0.0, -1.2, -1.2), (1.2, 1.2, 1.2)), 40)
    assert (m.vertices[:, 0] >= 0).all()
    assert (edge_counts(m.faces) <= 2).all() and (edge_counts(m.faces) == 1).any()


def test_project_false_keeps_marching_cubes_vertices():
    f = lambda x: sphere(x, r=1.0)  # noqa: E731
    raw = polygonize(f, ((-1.2,) * 3, (1.2,) * 3), 32, project=False)
    projected = polygonize(f, ((-1.2,) * 3, (1.2,) * 3), 32)
    np.testing.assert_array_equal(raw.faces, projected.faces)
    off = np.abs(np.linalg.norm(raw.vertices, axis=1) - 1)
    assert 1e-6 < off.max() < 0.01  # linear interpolation of r^2 - |x|^2 on the grid
    np.testing.assert_allclose(np.linalg.norm(raw.normals, axis=1), 1.0)


def test_float64_grid_gives_the_same_mesh():
    f32 = polygonize(fig1_part, BOX, 40)
    f64 = polygonize(fig1_part, BOX, 40, dtype=torch.float64)
    np.testing.assert_array_equal(f32.faces, f64.faces)
    np.testing.assert_allclose(f32.vertices, f64.vertices, atol=1e-10)


def test_evaluate_grid_order_end_points_and_chunks():
    f = lambda x: x[..., 0] + 10 * x[..., 1] + 100 * x[..., 2]  # noqa: E731
    bounds = ((-1.0, 0.0, 2.0), (1.0, 3.0, 4.0))
    axes = grid_axes(bounds, (5, 4, 3))
    assert [a[0] for a in axes] == [-1.0, 0.0, 2.0] and [a[-1] for a in axes] == [1.0, 3.0, 4.0]
    expected = axes[0][:, None, None] + 10 * axes[1][None, :, None] + 100 * axes[2][None, None, :]
    for max_points in (1, 5, 7, 12, 1000):  # both chunkings: rows of z, and whole x-slices
        v = evaluate_grid(f, bounds, (5, 4, 3), dtype=torch.float64, max_points=max_points)
        assert v.shape == (5, 4, 3) and v.dtype == np.float64
        np.testing.assert_allclose(v, expected, rtol=0, atol=1e-12)


def test_f_sees_bounded_chunks_only():
    sizes = []

    def f(x):
        sizes.append(x.shape[:-1].numel())
        return sphere(x, r=0.8)

    m = polygonize(f, ((-1.0,) * 3, (1.0,) * 3), 96)
    assert sum(sizes) > 96**3 + m.n_vertices  # the grid, then the vertices
    assert max(sizes) <= 1 << 16  # memory stays bounded however fine the grid


def test_no_surface_gives_an_empty_mesh_and_a_warning():
    with pytest.warns(RuntimeWarning, match="does not change sign"):
        m = polygonize(lambda x: sphere(x, center=(5.0, 0.0, 0.0), r=1.0), BOX, 16)
    assert m.is_empty() and m.vertices.shape == (0, 3) and m.volume() == 0.0 and m.area() == 0.0
    with pytest.warns(RuntimeWarning, match="does not change sign"):
        assert polygonize(lambda x: sphere(x, r=5.0), BOX, 16).is_empty()  # all inside


def test_unconverged_vertices_stay_at_marching_cubes_and_are_counted():
    # a triple root: grad f = 0 on the surface, so Newton and the edge search cannot certify it
    f = lambda x: sphere(x, r=1.0) ** 3  # noqa: E731
    bounds = ((-1.2,) * 3, (1.2,) * 3)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = polygonize(f, bounds, 20)
    messages = [str(w.message) for w in caught if "could not be moved" in str(w.message)]
    assert len(messages) == 1
    failed, total = (int(g) for g in re.search(r"(\d+) of (\d+) vertices", messages[0]).groups())
    assert 0 < failed <= total and m.n_vertices <= total  # coincident vertices may have been merged
    raw = polygonize(f, bounds, 20, project=False)
    at_raw = (m.vertices[:, None, :] == raw.vertices[None, :, :]).all(axis=2).any(axis=1)
    assert int(at_raw.sum()) >= failed - (total - m.n_vertices)
    assert (edge_counts(m.faces) == 2).all()
    assert np.isfinite(m.normals).all()


@pytest.mark.parametrize("resolution", [1, 0, -5, 2.5, "64", True, None, (32, 32), float("nan")])
def test_bad_resolution(resolution):
    with pytest.raises(ValueError, match="resolution"):
        polygonize(fig1_part, BOX, resolution)


@pytest.mark.parametrize(
    "bounds, match",
    [
        (((1.0, -1, -1), (-1.0, 1, 1)), "inverted"),
        (((0.0, 0, 0), (0.0, 1, 1)), "inverted"),
        (((-1, -1), (1, 1)), "3 lower"),
        ((-1, 1), "bounds"),
        (((-1, -1, float("nan")), (1, 1, 1)), "finite"),
    ],
)
def test_bad_bounds(bounds, match):
    with pytest.raises(ValueError, match=match):
        polygonize(lambda x: sphere(x, r=0.5), bounds, 16)


def test_nan_from_f_names_the_point():
    f = lambda x: torch.sqrt(x[..., 0] + 0.5) - 0.5  # NaN for x < -0.5  # noqa: E731
    with pytest.raises(ValueError, match=r"not finite at x = \(-1\.0"):
        polygonize(f, ((-1.0,) * 3, (1.0,) * 3), 9)
    with pytest.raises(ValueError, match="not finite"):
        evaluate_grid(lambda x: 1.0 / x[..., 0], ((-1.0,) * 3, (1.0,) * 3), 3)  # inf at x = 0


def test_f_with_wrong_output_shape():
    with pytest.raises(ValueError, match="must map points"):
        polygonize(lambda x: x, BOX, 8)
    with pytest.raises(ValueError, match="must map points"):
        grad(lambda x: x, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="must map points"):
        polygonize(lambda x: fig1_part(x, r=torch.tensor([0.3, 0.4])), BOX, 8)  # a batch of 2 parameter sets


def test_two_d_model_and_missing_bounds_are_refused():
    @model(bounds=((-1, -1), (1, 1)), dim=2, r=Param(0.5, 0.1, 0.9))
    def disc(x, r):
        return r * r - (x * x).sum(-1)

    with pytest.raises(ValueError, match="dim=2"):
        polygonize(disc)
    with pytest.raises(ValueError, match="bounds must be given"):
        polygonize(lambda x: sphere(x, r=0.5))


def test_resolution_too_large_says_how_much_memory_before_allocating():
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"resolution 100000 needs about [\d.e+]+ GiB") as info:
            polygonize(fig1_part, BOX, 100_000)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert isinstance(info.value, MemoryError) and isinstance(info.value, GridTooLargeError)
    assert peak < 50 << 20  # nothing grid-sized was allocated
    need = float(re.search(r"about ([\d.e+]+) GiB", str(info.value)).group(1))
    assert need == pytest.approx(4 * 100_000**3 * 1.25 / 2**30, rel=1e-2)
    with pytest.raises(MemoryError, match="GiB"):
        evaluate_grid(fig1_part, BOX, (100_000, 100_000, 10))
    assert grid_memory(512) < 1.5 * 2**30  # 512^3 (0.5 GiB of float32 grid) meshes in under 1.5 GiB


def test_mesh_validates_its_arrays():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    with pytest.raises(ValueError, match="vertices must have shape"):
        Mesh(v[:, :2], np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="faces must have shape"):
        Mesh(v, np.array([0, 1, 2]))
    with pytest.raises(ValueError, match="faces index vertices"):
        Mesh(v, np.array([[0, 1, 3]]))
    with pytest.raises(ValueError, match="integer"):
        Mesh(v, np.array([[0, 1, 1.5]]))
    with pytest.raises(ValueError, match="normals must have shape"):
        Mesh(v, np.array([[0, 1, 2]]), normals=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="point_data"):
        Mesh(v, np.array([[0, 1, 2]]), point_data={"k": np.zeros(4)})
    with pytest.raises(ValueError, match="NaN"):
        Mesh(v * np.nan, np.array([[0, 1, 2]]))
    tri = Mesh(v.tolist(), [[0, 1, 2]])
    assert tri.faces.dtype == np.int64 and tri.area() == pytest.approx(0.5)


def test_to_pyvista_carries_normals_and_point_data(fig1_128):
    m = Mesh(fig1_128.vertices, fig1_128.faces, fig1_128.normals, {"height": fig1_128.vertices[:, 2]})
    poly = m.to_pyvista()
    assert poly.n_points == m.n_vertices and poly.n_cells == m.n_faces
    np.testing.assert_array_equal(poly.point_data["height"], m.vertices[:, 2])
    np.testing.assert_array_equal(poly.point_data["Normals"], m.normals)
    assert poly.volume == pytest.approx(m.volume(), rel=1e-9)


def test_demo_writes_the_stl_and_an_off_screen_png(tmp_path, capsys):
    from pyfrep_core.demo import main
    from pyfrep_core.io import load_mesh

    assert main(["--out", str(tmp_path / "out"), "--resolution", "40"]) == 0
    printed = capsys.readouterr().out
    stl, png = tmp_path / "out" / "fig1.stl", tmp_path / "out" / "fig1.png"
    assert str(stl) in printed and str(png) in printed and "triangles" in printed
    assert abs(load_mesh(stl).volume() - FIG1_VOLUME) < 0.03
    import pyvista as pv

    image = pv.read(str(png)).point_data.active_scalars  # (pixels, 3 or 4) uint8
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and len(image) == 800 * 600
    background = (image[:, :3] == 255).all(axis=1)
    assert 0.1 < 1 - background.mean() < 0.9  # the part fills a good share of the picture, not all
    with pytest.raises(ValueError, match="outside its range"):
        main(["--out", str(tmp_path), "-r", "2.0"])


# --------------------------------------------------------------------------- sparse (coarse-to-fine) evaluation

H128 = 2.2 / 127  # fine cell at 128^3 over BOX
_AXES128 = grid_axes(BOX, 128)[0]
BLOCK_CENTRE = tuple(float(_AXES128[4 * k + 2]) for k in (13, 17, 22))  # farthest from the coarse corners


def _sparse_cases():
    from pyfrep_core import blobby, gyroidSheet, metaBall, sdf, torusZ, union
    from pyfrep_core.models import microstructure, pawn, schwarz_d

    quick = os.environ.get("PYFREP_QUICK", "") not in ("", "0")
    return [
        ("fig1 64", fig1_part, BOX, 64),
        ("fig1 128", fig1_part, BOX, 128),
        ("fig1 256", fig1_part, BOX, 160 if quick else 256),
        ("sphere", lambda x: sphere(x, r=0.8), BOX, 96),
        ("torus", lambda x: torusZ(x, R=0.6, r=0.2), BOX, 96),
        # features smaller than a coarse block (4^3 cells) that change no coarse corner's sign
        ("ball of one cell", lambda x: sphere(x, center=(0.113, -0.271, 0.3377), r=H128), BOX, 128),
        ("ball at a block centre", lambda x: sphere(x, center=BLOCK_CENTRE, r=1.2 * H128), BOX, 128),
        ("sdf ball at a block centre", lambda x: sdf.sphere(x, center=BLOCK_CENTRE, r=1.2 * H128), BOX, 128),
        ("thin gyroidSheet", lambda x: gyroidSheet(x, 1.0, 1.0, 1.0, 0.05, -0.05), BOX, 96 if quick else 128),
        ("SchwarzD", schwarz_d, schwarz_d.bounds, 96 if quick else 128),
        ("microstructure", microstructure, microstructure.bounds, 64 if quick else 128),
        ("pawn", pawn, pawn.bounds, 128),
        ("blobby", lambda x: blobby(x, [-0.3, 0.35, 0.0], [0.0, 0.1, 0.4], [0.0, -0.2, 0.3], 8.0, 1.0, 0.5), BOX, 96),
        (
            "metaBall",
            lambda x: metaBall(x, [-0.3, 0.35, 0.0], [0.0, 0.1, 0.4], [0.0, -0.2, 0.3], 1.0, 0.9, 0.3),
            BOX,
            96,
        ),
        (
            "two nearly touching balls",
            lambda x: union(sphere(x, center=(-0.4, 0, 0), r=0.395), sphere(x, center=(0.4, 0, 0), r=0.395)),
            BOX,
            128,
        ),
    ]


@pytest.mark.parametrize("case", _sparse_cases(), ids=lambda c: c[0])
def test_sparse_evaluation_gives_the_dense_mesh(case, monkeypatch):
    import pyfrep_core.meshing.sparse as sparse_module

    _, f, bounds, n = case
    # never fall back to the dense grid, so that lattices exercise the sparse path too
    monkeypatch.setattr(sparse_module, "SPARSE_MAX_FRACTION", 1.0)
    dense = polygonize(f, bounds, n)
    sparse = polygonize(f, bounds, n, sparse=True)
    assert dense.n_faces > 0
    np.testing.assert_array_equal(sparse.faces, dense.faces)
    np.testing.assert_allclose(sparse.vertices, dense.vertices, rtol=0, atol=1e-12)
    np.testing.assert_allclose(sparse.normals, dense.normals, rtol=0, atol=1e-12)


def test_sparse_evaluation_skips_most_of_the_grid_and_falls_back_on_lattices():
    from pyfrep_core.meshing.sparse import SPARSE_STEP, _sparse_grid

    calls = []

    def f(x):
        calls.append(x.shape[:-1].numel())
        return fig1_part(x)

    values, vmin, vmax, mask, evaluated = _sparse_grid(f, grid_axes(BOX, 128), torch.float32, "cpu", SPARSE_STEP, 0.5)
    assert values.shape == mask.shape == (128,) * 3 and vmin < 0 < vmax
    assert sum(calls) < 0.5 * 128**3 and evaluated.mean() < 0.5  # fine values only near the surface
    assert mask.mean() < 0.2  # marching cubes visits the blocks the surface crosses
    from pyfrep_core import gyroidSheet

    lattice = _sparse_grid(lambda x: gyroidSheet(x), grid_axes(BOX, 64), torch.float32, "cpu", SPARSE_STEP, 0.5)
    assert lattice is None  # surface everywhere: polygonize evaluates densely


def test_sparse_mesh_of_no_surface_is_empty_with_a_warning():
    with pytest.warns(RuntimeWarning, match="does not change sign"):
        assert polygonize(lambda x: sphere(x, center=(5.0, 0.0, 0.0), r=1.0), BOX, 32, sparse=True).is_empty()


def test_polygonize_keeps_grad_f_at_the_vertices(fig1_128):
    m = fig1_128
    exact = value_and_grad(fig1_part, torch.as_tensor(m.vertices))[1].numpy()
    np.testing.assert_allclose(m.gradient, exact, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(m.normals, -exact / np.linalg.norm(exact, axis=1, keepdims=True), atol=1e-12)


def test_coincident_vertices_are_merged_and_the_mesh_stays_closed(tmp_path):
    # a printable gyroid-sheet block: Newton steps at its sharp rims used to put two vertices of
    # a few triangles on one point (zero-area triangles, dropped by VTK's STL reader)
    from pyfrep_core import block, gyroidSheet, intersection

    def printable(x):
        return intersection(block(x, (0.0, 0.0, 0.0), 20.0, 20.0, 10.0), gyroidSheet(x, 0.2, 0.2, 0.2, 0.4, -0.4))

    m = polygonize(printable, ((-0.3,) * 3, (20.3, 20.3, 10.3)), 64)
    a, b, c = (m.vertices[m.faces[:, i]] for i in range(3))
    assert (np.linalg.norm(np.cross(b - a, c - a), axis=1) > 0).all()
    assert (edge_counts(m.faces) == 2).all()
    assert np.array_equal(np.unique(m.faces), np.arange(m.n_vertices))
    assert m.gradient.shape == m.normals.shape == m.vertices.shape
    import pyvista as pv

    m.save(tmp_path / "sheet.stl")
    assert pv.read(str(tmp_path / "sheet.stl")).n_cells == m.n_faces


@pytest.mark.parametrize("resolution, dtype", [((41, 50, 63), torch.float32), (57, torch.float64)])
def test_sparse_evaluation_on_uneven_blocks_and_in_float64(resolution, dtype, monkeypatch):
    import pyfrep_core.meshing.sparse as sparse_module

    monkeypatch.setattr(sparse_module, "SPARSE_MAX_FRACTION", 1.0)
    bounds = ((-1.1, -1.0, -1.2), (1.1, 1.05, 1.0))  # the Fig. 1 part cut by the box: an open mesh
    dense = polygonize(fig1_part, bounds, resolution, dtype=dtype)
    sparse = polygonize(fig1_part, bounds, resolution, dtype=dtype, sparse=True)
    assert dense.n_faces > 10_000
    np.testing.assert_array_equal(sparse.faces, dense.faces)
    np.testing.assert_allclose(sparse.vertices, dense.vertices, rtol=0, atol=1e-12)


def test_polygonize_tol_trades_projection_accuracy_for_speed():
    from pyfrep_core.models import fig1_part

    bounds = ((-1.1,) * 3, (1.1,) * 3)
    cell = 2.2 / 63 * np.sqrt(3)
    strict = polygonize(fig1_part, bounds, 64)
    loose = polygonize(fig1_part, bounds, 64, tol=1e-3 * cell)
    assert np.array_equal(strict.faces, loose.faces)
    residual = np.abs(fig1_part(loose.vertices) / np.linalg.norm(loose.gradient, axis=1))
    assert residual.max() <= 1e-3 * cell  # accepted at the display-grade distance asked for
    assert np.abs(fig1_part(strict.vertices)).max() < 1e-12
    assert abs(loose.volume() - strict.volume()) < 1e-4
    with pytest.raises(ValueError, match="tol"):
        polygonize(fig1_part, bounds, 16, tol=-1.0)


# a mesher's pass after a 1 MiB block was freed: glibc's own thresholds are then 1 MiB (mmap) and 2 MiB
# (trim), so the 9 MB of ten 900 kB arrays freed together went back to the system and were faulted in
# again on every pass (about 9,700 of 11,000 pages on the 2-core machine)
_HEAP_SCRIPT = """
import resource
import numpy as np
from pyfrep_core import polygonize, sphere
from pyfrep_core.meshing.grid import _steady_heap
polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 12, progress=False)
np.ones((1 << 20) // 8)
def passes(n):
    for _ in range(n):
        arrays = [np.ones(900_000 // 8) for _ in range(10)]  # every page written
        del arrays
passes(1)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
passes(5)
print(_steady_heap(), resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(_glibc() is None, reason="glibc's malloc settings")
@pytest.mark.parametrize(
    "environment", [{}, {"MALLOC_TRIM_THRESHOLD_": "131072"}, {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=131072"}]
)
def test_after_polygonize_freed_arrays_are_reused_not_faulted_in_again(environment):
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in (*_MALLOC_VARIABLES, "GLIBC_TUNABLES")}
    out = subprocess.run(
        [sys.executable, "-c", _HEAP_SCRIPT], env={**env, **environment}, capture_output=True, text=True, check=True
    )
    pinned, faults = out.stdout.split()
    pages = 5 * 10 * 900_000 // os.sysconf("SC_PAGE_SIZE")
    if environment:  # the user's own malloc settings are left as they are (and this one trims at 128 kB)
        assert pinned == "False" and int(faults) > pages // 2
    else:
        assert pinned == "True" and int(faults) < pages // 100
