"""Octree dual contouring (polygonize(method="dc")): sharp edges kept, certified pruning, manifold output.

Truths: the Fig. 1 part's closed-form volume and its crease circles, exact distances to a sphere and
a torus, Newton feet on the gyroid; an independent library (pymeshlab, then VTK's collision filter)
for self-intersections.
"""

import threading

import numpy as np
import pytest
import torch
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from pyfrep_core import (
    SchwarzD,
    block,
    gyroid,
    intersection,
    polygonize,
    project_to_surface,
    sphere,
    torusZ,
    value_and_grad,
)
from pyfrep_core.meshing import dual_contouring, folds
from pyfrep_core.meshing.grid import grid_axes
from pyfrep_core.meshing.octree import prune, sample_blocks
from pyfrep_core.meshing.roots import SECTION_POINTS
from pyfrep_core.models import fig1_part

BOX = ((-1.1,) * 3, (1.1,) * 3)
# sphere r = 1 cut by the cube [-0.75, 0.75]^3 minus three r = 0.5 cylinders (see tests/test_mesh.py)
FIG1_VOLUME = 0.9887887
N = 128  # the voxel size: 2.2 / 127


@pytest.fixture(scope="module")
def fig1_dc():
    return polygonize(fig1_part, BOX, N, method="dc")


def test_fig1_volume_error_below_libfive_level(fig1_dc):
    # marching cubes misses by 2.0e-3 here (its chamfered creases); libfive's DC by 7.6e-5
    assert abs(fig1_dc.volume() - FIG1_VOLUME) < 1e-4
    mc_error = abs(polygonize(fig1_part, BOX, 64).volume() - FIG1_VOLUME)
    assert abs(polygonize(fig1_part, BOX, 64, method="dc").volume() - FIG1_VOLUME) < mc_error / 10


def edge_table(faces):
    """Undirected edges (E, 2) and, per edge, how many faces hold it and the sum of its directions."""
    directed = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    undirected = np.sort(directed, axis=1)
    sign = np.where(directed[:, 0] < directed[:, 1], 1, -1)
    edges, inverse, counts = np.unique(undirected, axis=0, return_inverse=True, return_counts=True)
    orientation = np.bincount(inverse.ravel(), weights=sign, minlength=len(edges))
    return edges, counts, orientation


def vertex_link_components(faces, n_vertices):
    """Per vertex, the number of fans its faces form (1 for a manifold vertex): corners (vertex, face)
    are joined when their faces share an edge at that vertex."""
    f = len(faces)
    corner_vertex = faces.ravel()  # corner 3 t + k is vertex faces[t, k] in face t
    corners = np.arange(3 * f)
    rows, cols = [], []
    for k in range(3):
        for other in ((k + 1) % 3, (k + 2) % 3):
            # the half-edge (v, w) at corner (t, k): key shared by the other face holding edge {v, w} at v
            key = faces[:, k].astype(np.int64) * n_vertices + faces[:, other]
            rows.append(key)
            cols.append(corners[k::3])
    key = np.concatenate(rows)
    corner = np.concatenate(cols)
    order = np.argsort(key, kind="stable")
    key, corner = key[order], corner[order]
    same = np.flatnonzero(key[1:] == key[:-1])
    graph = coo_matrix((np.ones(len(same)), (corner[same], corner[same + 1])), shape=(3 * f, 3 * f))
    _, label = connected_components(graph, directed=False)
    pairs = np.unique(np.stack([corner_vertex, label], axis=1), axis=0)
    return np.bincount(pairs[:, 0], minlength=n_vertices)


def test_fig1_watertight_manifold_and_consistently_oriented(fig1_dc):
    m = fig1_dc
    _, counts, orientation = edge_table(m.faces)
    assert (counts == 2).all()  # watertight, and no edge in more than two faces
    assert (orientation == 0).all()  # the two faces of an edge run it in opposite directions
    fans = vertex_link_components(m.faces, m.n_vertices)
    assert (fans == 1).all()  # every vertex's faces form one fan (no pinched vertex)
    assert np.isfinite(m.vertices).all() and m.gradient.shape == m.vertices.shape


def self_intersecting_pairs(mesh):
    """Pairs of faces sharing no vertex that intersect: pymeshlab selects candidate faces, VTK's
    collision filter (an independent triangle-triangle test) decides among them."""
    pymeshlab = pytest.importorskip("pymeshlab")
    import vtk
    from vtk.util.numpy_support import vtk_to_numpy

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(mesh.vertices, mesh.faces))
    ms.compute_selection_by_self_intersections_per_face()
    flagged = np.flatnonzero(ms.current_mesh().face_selection_array())
    if len(flagged) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    # each flagged face against every face that could reach it, by VTK, in batches (bounded memory)
    import pyvista as pv

    corners = mesh.vertices[mesh.faces]
    centroid = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroid[:, None], axis=2).max(axis=1)  # faces lie within these balls
    tree = cKDTree(centroid)
    found = []
    for start in range(0, len(flagged), 512):
        batch = flagged[start : start + 512]
        near = np.unique(np.concatenate(tree.query_ball_point(centroid[batch], radius[batch] + radius.max())))
        polys = [
            pv.PolyData(mesh.vertices, np.hstack([np.full((len(part), 1), 3), mesh.faces[part]]).ravel())
            for part in (batch, near)
        ]
        collide = vtk.vtkCollisionDetectionFilter()
        for i in (0, 1):
            collide.SetInputData(i, polys[i])
            collide.SetMatrix(i, vtk.vtkMatrix4x4())
        collide.SetCollisionModeToAllContacts()
        collide.Update()
        a, b = (vtk_to_numpy(collide.GetContactCells(i)).astype(np.int64) for i in (0, 1))
        a, b = batch[a], near[b]
        apart = ~(mesh.faces[a][:, :, None] == mesh.faces[b][:, None, :]).any(axis=(1, 2))
        found.append(np.sort(np.stack([a[apart], b[apart]], axis=1), axis=1))
    return np.unique(np.concatenate(found), axis=0)


def test_fig1_has_no_self_intersections(fig1_dc):
    assert len(self_intersecting_pairs(fig1_dc)) == 0


def gyroid_solid(x):
    """The gyroid solid cut to [-1, 1]^3 (benchmarks/mesh.py's block)."""
    return intersection(gyroid(x), block(x, vertex=(-1.0, -1.0, -1.0), dx=2.0, dy=2.0, dz=2.0))


def assert_gradient_at_the_vertices(m, f):
    """The mesh's ``gradient`` is grad f at its vertices (also where folds moved them), to rounding."""
    _, g = value_and_grad(f, m.vertices)
    np.testing.assert_allclose(m.gradient, g, rtol=0, atol=1e-12 * np.abs(g).max())


def assert_closed_manifold(m):
    _, counts, orientation = edge_table(m.faces)
    assert (counts == 2).all() and (orientation == 0).all()
    assert (vertex_link_components(m.faces, m.n_vertices) == 1).all()


@pytest.mark.parametrize("shape", ["gyroid", "microstructure"])
def test_lattices_have_no_self_intersections_and_stay_closed_manifolds(shape, monkeypatch):
    # at 48 samples across the microstructure's 21 units, sheets of its rods pass within a cell of
    # each other, where plain dual contouring's quads pierce each other (the control below)
    from pyfrep_core.models import microstructure

    f, bounds, n = (gyroid_solid, BOX, 64) if shape == "gyroid" else (microstructure, None, 48)
    m = polygonize(f, bounds, n, method="dc", progress=False)
    assert len(self_intersecting_pairs(m)) == 0
    assert_closed_manifold(m)
    assert_gradient_at_the_vertices(m, f)
    if shape == "microstructure":  # control: without the fallback to marching-cubes fans, pairs intersect
        from pyfrep_core.meshing import dual_contouring, folds

        def no_fallback(quads, corner, points, x, *rest):
            crossing = len(x) + np.arange(len(quads))
            faces = folds._hybrid(crossing, np.zeros(len(x), dtype=bool), folds._halves(quads, corner))
            return faces, np.concatenate([x, points]), np.zeros(0, dtype=np.int64)

        monkeypatch.setattr(dual_contouring, "_without_folds", no_fallback)
        plain = polygonize(f, bounds, n, method="dc", progress=False)
        assert len(self_intersecting_pairs(plain)) > 0
        assert (edge_table(plain.faces)[1] > 2).any()  # and edges in four faces


def test_marching_cubes_fans_everywhere_stay_closed_manifold_and_cell_local(monkeypatch):
    # every vertex sent to the fallback: each cell's marching-cubes polygon fanned from its mass point
    from pyfrep_core.meshing import dual_contouring, folds

    real, calls = folds._intersecting_pairs, []

    def everything_first(v, faces, origin, h, changed=None):
        if calls:
            return real(v, faces, origin, h, changed)
        calls.append(len(faces))
        return np.repeat(np.arange(len(faces))[:, None], 2, axis=1)  # "every face intersects"

    monkeypatch.setattr(folds, "_intersecting_pairs", everything_first)
    monkeypatch.setattr(dual_contouring, "_CONFINED", np.zeros(256, dtype=bool))  # every face searched
    n = 32
    m = polygonize(fig1_part, BOX, n, method="dc", progress=False)
    assert calls and m.n_faces == calls[0]  # each quad's four triangles became its two diamonds' four
    assert_closed_manifold(m)
    assert_gradient_at_the_vertices(m, fig1_part)  # every vertex in a cell moved to its mass point
    assert len(self_intersecting_pairs(m)) == 0
    # every triangle lies in one grid cell (closed): a fan of that cell's polygon
    h = 2.2 / (n - 1)
    corners = (m.vertices[m.faces] + 1.1) / h
    assert (np.floor(corners.max(axis=1) - 1e-9) == np.floor(corners.min(axis=1) + 1e-9)).all()


@pytest.mark.parametrize("shape", ["fig1", "gyroid", "microstructure"])
def test_the_fold_search_looks_only_at_cells_not_proved_free_of_folds(shape, monkeypatch):
    # a cell with one surface component and two crossings per face holds a cone over a simple polygon
    # on its boundary (dual_contouring._confined): faces can only meet in the other cells, so only
    # faces with a vertex there are searched, and the independent check still finds nothing
    from pyfrep_core.meshing import folds
    from pyfrep_core.models import microstructure

    real, searched = folds._intersecting_pairs, []

    def counted(v, faces, origin, h, changed=None):
        searched.append((int(changed.sum()), len(faces)))
        return real(v, faces, origin, h, changed)

    monkeypatch.setattr(folds, "_intersecting_pairs", counted)
    f, bounds, n = {"fig1": (fig1_part, BOX, 96), "gyroid": (gyroid_solid, BOX, 64)}.get(
        shape, (microstructure, None, 48)
    )
    m = polygonize(f, bounds, n, method="dc", progress=False)
    assert len(self_intersecting_pairs(m)) == 0
    assert_closed_manifold(m)
    assert_gradient_at_the_vertices(m, f)
    if shape == "microstructure":  # rods thinner than a cell: cells with two components, searched
        assert searched and all(0 < watched < total for watched, total in searched)
    else:  # nothing thinner than a cell: nothing to search
        assert all(watched == 0 for watched, _ in searched)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_fields_full_of_saddles_stay_closed_manifolds_without_self_intersections(seed):
    # sums of random plane waves, cut by a ball: saddles put four crossings on many cell faces,
    # and thin necks give cells of two components (the search's part)
    rng = np.random.default_rng(seed)
    k = torch.as_tensor(rng.normal(size=(12, 3)) * 6.0)
    phase = torch.as_tensor(rng.uniform(0.0, 2 * np.pi, 12))

    def waves(x):
        field = 0.3 * torch.cos(x @ k.T.to(x.dtype) + phase.to(x.dtype)).sum(dim=1) + 0.1
        return intersection(field, sphere(x, r=0.9))

    m = polygonize(waves, BOX, 40, method="dc", progress=False)
    assert m.n_faces > 1000
    assert_closed_manifold(m)
    assert len(self_intersecting_pairs(m)) == 0


def test_the_self_intersection_check_finds_an_intersection():
    # two overlapping balls in one mesh: the check must report pairs
    m = polygonize(lambda x: sphere(x, r=0.8), BOX, 24, method="dc")
    from pyfrep_core import Mesh

    both = Mesh(np.concatenate([m.vertices, m.vertices + 0.3]), np.concatenate([m.faces, m.faces + m.n_vertices]))
    assert len(self_intersecting_pairs(both)) > 0


def crease_points(per_circle=400):
    """Points on the Fig. 1 part's sharp edges: on each cube face x_a = +-0.75 the circle where the
    sphere meets it (radius sqrt(1 - 0.75^2)) and the cylinder hole's rim (radius 0.5)."""
    t = np.linspace(0.0, 2 * np.pi, per_circle, endpoint=False)
    out = []
    for radius in (np.sqrt(1 - 0.75**2), 0.5):
        for a in range(3):
            for side in (-0.75, 0.75):
                p = np.zeros((per_circle, 3))
                p[:, a] = side
                p[:, (a + 1) % 3] = radius * np.cos(t)
                p[:, (a + 2) % 3] = radius * np.sin(t)
                out.append(p)
    return np.concatenate(out)


def test_fig1_every_sharp_edge_lies_within_1e3_of_a_mesh_edge(fig1_dc):
    m = fig1_dc
    edges, _, _ = edge_table(m.faces)
    a, b = m.vertices[edges[:, 0]], m.vertices[edges[:, 1]]
    pts = crease_points()
    _, idx = cKDTree((a + b) / 2).query(pts, k=32)  # edges are < 2 cells long: the nearest lie among these
    pa, d = a[idx], b[idx] - a[idx]
    t = np.clip(np.einsum("nkj,nkj->nk", pts[:, None] - pa, d) / np.einsum("nkj,nkj->nk", d, d), 0.0, 1.0)
    distance = np.linalg.norm(pts[:, None] - (pa + t[..., None] * d), axis=2).min(axis=1)
    assert distance.max() < 1e-3
    # marching cubes cuts the creases: its edges stay farther away (control: the check can fail)
    mc = polygonize(fig1_part, BOX, N)
    edges, _, _ = edge_table(mc.faces)
    a, b = mc.vertices[edges[:, 0]], mc.vertices[edges[:, 1]]
    _, idx = cKDTree((a + b) / 2).query(pts, k=32)
    pa, d = a[idx], b[idx] - a[idx]
    t = np.clip(np.einsum("nkj,nkj->nk", pts[:, None] - pa, d) / np.einsum("nkj,nkj->nk", d, d), 0.0, 1.0)
    assert np.linalg.norm(pts[:, None] - (pa + t[..., None] * d), axis=2).min(axis=1).max() > 1e-3


H = 1 / 32  # the cell of a grid of 65 over [-1, 1]
X0, THICKNESS = 2.45 * H, 1.2 * H  # in the 4-cell block [0, 4 H] along x, holding the nodes 2 H and 3 H


def thin_plate(x):
    """A plate 1.2 cells thick around x = X0, bounded by |y|, |z| <= 0.5: where the Gaussian ridge
    exp(-((x - X0) / w)^2) exceeds 1/2.  At the 4-cell blocks' corners (x = 0 and 4 H, 2.45 and 1.55
    cells away) f is below -0.49 and |f| / |grad f| > 0.26 > half a block's diagonal (0.11): the sparse
    grid's heuristic sees nothing there."""
    w = THICKNESS / 2 / np.sqrt(np.log(2.0))
    ridge = torch.exp(-(((x[:, 0] - X0) / w) ** 2)) - 0.5
    return intersection(ridge, block(x, vertex=(-1.0, -0.5, -0.5), dx=2.0, dy=1.0, dz=1.0))


def test_fig1_every_crossing_is_on_the_surface_to_a_thousandth_of_a_cell():
    # the edges' roots (dual contouring's Hermite points): where f bends sharply in an edge's bracket
    # (R-functions' corners), 12 secant steps left 48 of 52,544 crossings more than 1e-3 cells off f = 0
    # (5.3e-3 at most); multisection bounds each within 1/33^2 of its bracket after the secant steps
    lo = np.full(3, -1.1)
    axes = grid_axes(BOX, N)
    spacing = np.array([a[1] - a[0] for a in axes])
    tree = prune(fig1_part, lo, spacing, (N - 1,) * 3, dual_contouring.LEAF_BLOCK)
    samples = sample_blocks(fig1_part, axes, tree.blocks, tree.block, torch.float32, "cpu")
    points, _, _ = dual_contouring._hermite(fig1_part, samples, lo, spacing, "cpu", None)
    assert len(points) > 50000
    value, gradient = value_and_grad(fig1_part, torch.as_tensor(points))
    distance = (value.abs() / gradient.norm(dim=1)).numpy() / spacing[0]  # first order, in cells
    assert distance.max() <= 1 / (SECTION_POINTS + 1) ** dual_contouring.SECTIONS


def test_a_thin_plate_missed_by_the_sparse_grid_is_found_by_the_octree():
    bounds = ((-1.0,) * 3, (1.0,) * 3)
    dense = polygonize(thin_plate, bounds, 65)
    assert dense.n_faces > 0  # the dense grid sees it
    with pytest.warns(RuntimeWarning, match="does not change sign"):
        assert polygonize(thin_plate, bounds, 65, sparse=True).is_empty()  # the heuristic does not
    dc = polygonize(thin_plate, bounds, 65, method="dc")
    # a box of THICKNESS x 1 x 1: the flat faces come out exact; the rims (4 x 1 long, THICKNESS wide)
    # can be off by at most a cell across
    assert abs(dc.volume() - THICKNESS) < 4 * THICKNESS * H
    _, counts, _ = edge_table(dc.faces)
    assert (counts == 2).all()


def test_pruning_is_certified_and_samples_a_fraction_of_the_grid():
    n = 96
    axes = grid_axes(BOX, n)
    h = np.array([a[1] - a[0] for a in axes])
    tree = prune(fig1_part, np.array(BOX[0]), h, (n - 1,) * 3, 4)
    assert tree.certified
    b = tree.block  # 4, or 8 where the surface crowds the blocks
    kept_cells = len(tree.blocks) * b**3
    assert kept_cells < 0.25 * (n - 1) ** 3
    # every cell that dense marching cubes sees the surface in lies in a kept block
    from pyfrep_core.meshing import evaluate_grid

    inside = evaluate_grid(fig1_part, BOX, n) > 0
    mixed = np.zeros((n - 1,) * 3, dtype=bool)
    for c in range(1, 8):
        dx, dy, dz = c & 1, c >> 1 & 1, c >> 2 & 1
        mixed |= inside[dx : dx + n - 1, dy : dy + n - 1, dz : dz + n - 1] != inside[:-1, :-1, :-1]
    kept = np.zeros((-(-(n - 1) // b),) * 3, dtype=bool)
    kept[tuple(tree.blocks.T)] = True
    cells = np.argwhere(mixed)
    assert kept[tuple((cells // b).T)].all()


def distance_to_mesh(points, mesh):
    import pyvista as pv

    return np.abs(pv.PolyData(points).compute_implicit_distance(mesh.to_pyvista())["implicit_distance"])


def hausdorff(mesh, distance_to_surface, surface_points):
    """max(mesh -> surface at the vertices, edge midpoints and centroids; surface samples -> mesh)."""
    v = mesh.vertices
    f = mesh.faces
    samples = np.concatenate([v, (v[f[:, 0]] + v[f[:, 1]]) / 2, (v[f[:, 1]] + v[f[:, 2]]) / 2, v[f].mean(axis=1)])
    return max(distance_to_surface(samples).max(), distance_to_mesh(surface_points, mesh).max())


def sphere_case():
    rng = np.random.default_rng(0)
    u = rng.normal(size=(4000, 3))
    return (
        (lambda x: sphere(x, r=0.8)),
        (lambda p: np.abs(np.linalg.norm(p, axis=1) - 0.8)),
        0.8 * u / np.linalg.norm(u, axis=1, keepdims=True),
    )


def torus_case():
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, 2 * np.pi, (2, 4000))
    pts = np.stack([(0.6 + 0.25 * np.cos(b)) * np.cos(a), (0.6 + 0.25 * np.cos(b)) * np.sin(a), 0.25 * np.sin(b)], 1)

    def dist(p):
        return np.abs(np.hypot(np.hypot(p[:, 0], p[:, 1]) - 0.6, p[:, 2]) - 0.25)

    return (lambda x: torusZ(x, R=0.6, r=0.25)), dist, pts


def gyroid_case(f=lambda x: gyroid(x), seed=2):
    rng = np.random.default_rng(seed)
    start = torch.as_tensor(rng.uniform(-0.8, 0.8, (4000, 3)))
    feet = project_to_surface(f, start, warn=False)
    inner = feet.points.numpy()[feet.converged.numpy() & (np.abs(feet.points.numpy()) < 0.85).all(axis=1)]

    def dist(p):
        # interior samples only (the open mesh ends at the box), distance to their Newton foot
        p = p[(np.abs(p) < 0.85).all(axis=1)]
        proj = project_to_surface(f, torch.as_tensor(p), warn=False)
        return np.linalg.norm(proj.points.numpy() - p, axis=1)

    return f, dist, inner


def schwarz_d_case():
    return gyroid_case(lambda x: SchwarzD(x), seed=3)  # the same Newton-foot distances


@pytest.mark.parametrize(
    "case", [sphere_case, torus_case, gyroid_case, schwarz_d_case], ids=["sphere", "torus", "gyroid", "SchwarzD"]
)
def test_smooth_shapes_are_as_close_to_the_surface_as_marching_cubes(case):
    f, dist, surface = case()
    n = 64  # 36 cells per period of the gyroid (at 18, n = 40, its worst edge midpoint is 1% farther than MC's)
    mc = polygonize(f, BOX, n)
    dc = polygonize(f, BOX, n, method="dc")
    h_mc, h_dc = hausdorff(mc, dist, surface), hausdorff(dc, dist, surface)
    assert h_dc <= h_mc
    assert h_dc < 0.25 * 2.2 / (n - 1)  # and well below a cell


def test_method_auto_falls_back_to_marching_cubes_without_interval_extension():
    def sorted_ball(x):  # torch.sort has no interval rule
        return 0.64 - torch.sort(x * x, dim=1).values.sum(dim=1)

    auto = polygonize(sorted_ball, BOX, 32, method="auto")
    mc = polygonize(sorted_ball, BOX, 32)
    np.testing.assert_array_equal(auto.faces, mc.faces)
    ball = lambda x: sphere(x, r=0.8)  # noqa: E731
    np.testing.assert_array_equal(
        polygonize(ball, BOX, 32, method="auto").faces, polygonize(ball, BOX, 32, method="dc").faces
    )
    with pytest.raises(ValueError, match="polygonize: method must be one of"):
        polygonize(ball, BOX, 32, method="octree")


@pytest.mark.parametrize("method", ["mc", "dc"])
def test_polygonize_reports_progress_and_stops(method):
    events = []
    m = polygonize(fig1_part, BOX, 64, method=method, callback=events.append, progress=False)
    assert m.n_faces > 0 and events and all(e.stage == "polygonize" for e in events)
    assert events[-1].step == events[-1].total - 1
    stop = threading.Event()
    stop.set()
    assert polygonize(fig1_part, BOX, 64, method=method, stop=stop, progress=False).is_empty()
    assert polygonize(fig1_part, BOX, 64, method=method, callback=lambda e: True, progress=False).is_empty()


def test_dual_contouring_stops_promptly_and_raises_a_slabs_error_across_its_slabs(monkeypatch):
    monkeypatch.setattr(dual_contouring, "SLAB_POINTS", 20000)  # a dozen blocks a slab: many slabs, one chunk each
    whole = []
    assert polygonize(fig1_part, BOX, 64, method="dc", callback=whole.append, progress=False).n_faces > 0
    assert whole[-1].total == 6  # six slabs of whole block layers, one chunk each
    events = []
    stopped = polygonize(fig1_part, BOX, 64, method="dc", callback=lambda e: events.append(e) or len(events) >= 2)
    assert stopped.is_empty()
    assert len(events) <= 2 + dual_contouring.WORKERS  # only the slabs begun when asked sample on
    calls = []

    def failing(x):
        if type(x) is torch.Tensor and x.dtype == torch.float32:  # the samples (roots: float64; bounds: a subclass)
            calls.append(len(x))
            if len(calls) == 3:  # the third slab's: the fourth waits for its carry
                raise RuntimeError("the model failed on the third slab")
        return fig1_part(x)

    result = []

    def mesh():
        try:
            polygonize(failing, BOX, 64, method="dc", progress=False)
        except RuntimeError as error:
            result.append(error)

    thread = threading.Thread(target=mesh)
    thread.start()
    thread.join(timeout=300)
    assert not thread.is_alive(), "a slab waited forever for the slab that failed"
    assert len(result) == 1 and "third slab" in str(result[0])


@pytest.mark.parametrize("pad", [0, 1, 3])
def test_within_marks_exactly_the_cells_near_the_keys(monkeypatch, pad):
    rng = np.random.default_rng(pad)
    dims = np.array([9, 7, 11])
    keys = rng.choice(int(np.prod(dims)), 12, replace=False)
    query = np.arange(int(np.prod(dims)))
    ijk = np.stack(np.unravel_index(query, tuple(dims)), axis=1)
    exact = (np.abs(ijk[:, None, :] - ijk[keys][None]).max(axis=2) <= pad).any(axis=1)
    grid = folds._within(keys, dims, pad, query)  # the dilation on the grid of cells
    np.testing.assert_array_equal(grid, exact)
    monkeypatch.setattr(folds, "DENSE_CELLS", 0)
    sparse = folds._within(keys, dims, pad, query[:10])  # 4 per queried cell < the grid: on the keys
    assert (sparse >= exact[:10]).all()  # a key shifted past a row's end: more cells, never fewer
    inner = (ijk >= pad).all(axis=1) & (ijk < dims - pad).all(axis=1)
    sparse = folds._within(keys, dims, pad, query[inner][:10])
    np.testing.assert_array_equal(sparse, exact[inner][:10])


@pytest.mark.parametrize("seed", range(3))
def test_the_fold_search_finds_every_intersecting_pair_of_a_triangle_soup(seed):
    # small triangles (up to 1.5 cells) in a box of 6^3 cells, some sharing vertices; every pair
    # that shares no vertex is tested by brute force
    rng = np.random.default_rng(seed)
    centers = rng.uniform(0.0, 6.0, size=(150, 3))
    v = np.concatenate([centers[:, None, :] + rng.uniform(-0.75, 0.75, size=(150, 3, 3))]).reshape(-1, 3)
    faces = np.arange(len(v)).reshape(-1, 3)
    faces[::7, 0] = faces[1::7, 1][: len(faces[::7])]  # some faces share a vertex with the next
    i, j = np.triu_indices(len(faces), 1)
    apart = ~(faces[i][:, :, None] == faces[j][:, None, :]).any(axis=(1, 2))
    every = np.stack([i[apart], j[apart]], axis=1)
    truth = every[folds._pairs_intersect(v, faces, every)]
    assert len(truth) > 20  # the soup has intersecting pairs to find
    origin, h = np.zeros(3), np.ones(3)
    found = folds._intersecting_pairs(v, faces, origin, h)
    np.testing.assert_array_equal(found, truth)
    changed = rng.random(len(faces)) < 0.3
    found = folds._intersecting_pairs(v, faces, origin, h, changed)
    np.testing.assert_array_equal(found, truth[changed[truth].any(axis=1)])


@pytest.mark.parametrize("seed", range(3))
def test_coplanar_triangles_meet_only_where_they_overlap_in_their_plane(seed):
    # pairs of triangles in one plane, turned and moved at random (their corners off the plane by
    # rounding only, as symmetric parts give): apart (the second beyond a gap of a hundredth of a cell
    # past a line the first stays behind), or meeting (the second has a corner at the first's centroid)
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    k, h = 300, 0.07
    first = rng.uniform([-1.0, -1.0], [-0.01, 1.0], (k, 3, 2))
    apart = rng.uniform([0.0, -1.0], [1.0, 1.0], (k, 3, 2))
    meeting = rng.uniform(-1.0, 1.0, (k, 3, 2))
    meeting[:, 0] = first.mean(axis=1)
    flat = np.concatenate([first, apart, meeting]).reshape(-1, 2) * h
    turn = Rotation.random(random_state=seed).as_matrix()
    v = np.concatenate([flat, np.zeros((len(flat), 1))], axis=1) @ turn.T + rng.uniform(-1.0, 1.0, 3)
    faces = np.arange(len(v)).reshape(-1, 3)
    pairs = np.concatenate(
        [np.stack([np.arange(k), k + np.arange(k)], 1), np.stack([np.arange(k), 2 * k + np.arange(k)], 1)]
    )
    hit = folds._pairs_intersect(v, faces, pairs)
    assert not hit[:k].any()
    assert hit[k:].all()


def test_a_vertex_without_faces_is_dropped_and_the_rest_is_the_mesh_without_it(monkeypatch):
    # a sphere of half a cell at a corner of the bounds crosses only the three edges on the bounds'
    # faces there, which have no quad (fewer than four cells): its cell's vertex is in no face
    box, n = ((-1.0,) * 3, (1.0,) * 3), 21
    corner = torch.tensor([-1.0, -1.0, -1.0])

    def with_corner(x):
        return torch.maximum(sphere(x, r=0.6), sphere(x - corner.to(x.dtype), r=0.5 * 2.0 / (n - 1)))

    kept = []
    compact = dual_contouring._compact
    monkeypatch.setattr(dual_contouring, "_compact", lambda *a: kept.append(compact(*a)) or kept[-1])
    a = polygonize(with_corner, box, n, method="dc", progress=False)
    assert kept[0] is not None and len(kept[0]) == a.n_vertices  # compacted: one vertex fewer
    kept.clear()
    b = polygonize(lambda x: sphere(x, r=0.6), box, n, method="dc", progress=False)
    assert kept == [None]  # every vertex in a face: taken as it is
    assert np.unique(a.faces).tolist() == list(range(a.n_vertices))
    # far from the corner the union is the sphere's f, bit for bit: the same mesh, gradients included
    for name in ("vertices", "faces", "normals", "gradient"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
