"""Workbench panels without a browser: widgets driven from Python, off-screen image views."""

from __future__ import annotations

import functools
import importlib
import io
import time

import numpy as np
import pytest
import torch
from PIL import Image

import workbench
from pyfrep_core import Param, model, polygonize, sphere
from pyfrep_core.models import fig1_part
from pyfrep_core.sensitivity import normal_velocity
from workbench.app import App
from workbench.shape_panel import shape_panel, symmetric_range
from workbench.view import MeshView, resolve_backend

# small, fast fit settings for the tests (the panel's "quick" effort is a bit larger)
TINY_FIT = {"cycles": 60, "population_size": 20, "children": 10, "epochs": 2, "batch_size": 256, "polish_iters": 8}


@pytest.fixture
def panel():
    p = shape_panel(fig1_part, resolution=40, backend="image", threaded=False)
    yield p
    p.view.close()


def test_slider_remeshes_in_place_and_updates_status(panel):
    poly = panel.view.poly
    before_vertices = panel.mesh.vertices.copy()
    before_png = panel.view.widget.value
    count = panel.remesh_count
    assert panel.status.value.startswith("remeshed in")
    assert f"{panel.mesh.n_faces} triangles" in panel.status.value

    panel.sliders["r"].value = 0.35  # Fig. 2, left
    assert panel.remesh_count == count + 1
    assert panel.view.poly is poly  # the one PolyData of the view, replaced in place
    assert panel.view.poly.n_points == panel.mesh.n_vertices
    assert panel.mesh.n_vertices != before_vertices.shape[0] or not np.allclose(panel.mesh.vertices, before_vertices)
    assert "r = 0.35" in panel.status.value and f"{panel.mesh.n_faces} triangles" in panel.status.value
    assert panel.view.widget.value != before_png  # the picture changed...
    fresh = MeshView(backend="image")  # ... to the picture of the new mesh, not a stale frame
    try:
        fresh.update(panel.mesh, scalars=panel.scalars, title="v (r)", clim=symmetric_range(panel.scalars))
        shown, expected = (
            np.asarray(Image.open(io.BytesIO(bytes(w.value)))) for w in (panel.view.widget, fresh.widget)
        )
        assert np.abs(shown.astype(int) - expected).mean() < 0.5
    finally:
        fresh.close()
    # the new mesh is the surface at the new radius
    assert np.abs(fig1_part(panel.mesh.vertices, r=0.35)).max() < 1e-9
    # slider range, step and label come from the declaration
    s, p = panel.sliders["r"], fig1_part.params["r"]
    assert (s.min, s.max, s.description) == (p.lower, p.upper, p.label)
    assert s.step <= (p.upper - p.lower) / 200  # and the default on its grid (the browser rounds to it)
    assert (p.default - p.lower) / s.step == pytest.approx(round((p.default - p.lower) / s.step), abs=1e-9)


def test_compiled_evaluation_gives_the_eager_mesh_and_colours(panel):
    """After warm_up the panel meshes with the compiled model: same triangles, vertices and sensitivity."""
    panel.sliders["r"].value = 0.42
    eager_mesh, eager_v = panel.mesh, panel.scalars
    assert "(eager)" in panel.status.value and panel.evaluator() is fig1_part
    seconds = panel.warm_up()
    assert seconds > 0 and panel.warm_up() == 0.0  # compiled once
    assert panel.evaluator() is not fig1_part and panel.evaluator().eager is fig1_part
    panel.sliders["r"].value = 0.43
    panel.sliders["r"].value = 0.42
    assert "(compiled)" in panel.status.value
    np.testing.assert_array_equal(panel.mesh.faces, eager_mesh.faces)
    # Same mesh, judged geometrically: both vertex sets on f = 0, and each vertex as close to its twin
    # as the method that placed it guarantees.  Vertices on grid edges come from the edge root finder,
    # which stops at a step of 1e-11 cells: twins within two such steps.  The few others (next to the
    # part's creases) come from Newton steps along grad f, which may move a vertex up to one cell and
    # whose landing point along a crease follows the rounding: twins within one cell, both on f = 0.
    n = panel.resolution.value
    lo, hi = (np.asarray(b) for b in fig1_part.bounds)
    cell = (hi - lo) / (n - 1)
    for mesh in (eager_mesh, panel.mesh):
        assert np.abs(fig1_part(mesh.vertices, r=0.42)).max() < 1e-9
    k = (eager_mesh.vertices - lo) / cell
    on_edge = (np.abs(k - np.round(k)) * cell < 1e-9 * cell).sum(axis=1) >= 2
    assert on_edge.mean() > 0.9  # marching cubes places most vertices on edges
    gap = np.linalg.norm(panel.mesh.vertices - eager_mesh.vertices, axis=1)
    assert gap[on_edge].max() <= 2 * 1e-11 * cell.min() * np.sqrt(3)
    assert gap[~on_edge].max() <= np.linalg.norm(cell)
    # The colouring -(df/dp)/|grad f| agrees wherever it is continuous.  On a crease df/dp jumps (a
    # sub-gradient, chosen by the sign of a difference that rounding decides): find those vertices as
    # the ones where the eager colouring changes under a 1e-7 move, and leave them out.
    near = [eager_mesh.vertices + d * np.eye(3)[i] for i in range(3) for d in (-1e-7, 1e-7)]
    around = np.stack([normal_velocity(fig1_part, x, "r", {"r": 0.42}) for x in near])
    smooth = np.ptp(around, axis=0) < 1e-5
    assert smooth.mean() > 0.9
    np.testing.assert_allclose(panel.scalars[smooth], eager_v[smooth], rtol=1e-9, atol=1e-9)


def test_a_live_panel_compiles_in_the_background_then_remeshes_compiled():
    p = shape_panel(fig1_part, resolution=32, preview_resolution=None, backend="image", threaded=True)
    try:
        p.wait()
        p.main.drain()  # no kernel loop here: the main-thread work is queued
        assert "(eager)" in p.status.value or "(compiled)" in p.status.value  # compiled already in this process?
        assert p._warm_thread is not None or p.evaluator() is not fig1_part  # the background compilation started
        if p._warm_thread is not None:
            p._warm_thread.join(timeout=300)
        assert p.evaluator() is not fig1_part and not p.warm_up_errors
        shown = []
        p.status.observe(lambda change: shown.append(change["new"]), names="value")
        p.sliders["r"].value = 0.45
        p.wait()
        p.main.drain()
        # marching cubes through the compiled kernels first, then dual contouring through them too
        # (its interval bounds over boxes go through the eager model)
        assert len(shown) == 2, shown
        assert "(compiled)" in shown[0] and "dual contouring" not in shown[0] and "r = 0.45" in shown[0]
        assert "(compiled)" in shown[1] and "dual contouring" in shown[1] and "compiling" not in shown[1]
        fast = functools.partial(p.evaluator(), r=0.45)
        dc = polygonize(fast, p.last_job["bounds"], 32, method="dc", progress=False)
        np.testing.assert_array_equal(p.mesh.faces, dc.faces)
        np.testing.assert_array_equal(p.mesh.vertices, dc.vertices)
        eager = polygonize(functools.partial(fig1_part, r=0.45), p.last_job["bounds"], 32, method="dc", progress=False)
        np.testing.assert_array_equal(p.mesh.faces, eager.faces)  # the same signs at every node
        # fused kernels reorder float operations (a few ulp): the roots agree to their tolerance (1e-7
        # cells), the QEF's pseudo-inverse scales that by at most 1 / SINGULAR_CUTOFF
        from pyfrep_core.meshing.dual_contouring import SINGULAR_CUTOFF

        np.testing.assert_allclose(p.mesh.vertices, eager.vertices, atol=1e-7 * 2.2 / 31 / SINGULAR_CUTOFF)
    finally:
        p.view.close()


@torch.library.custom_op("pyfrep_test_workbench::opaque_copy", mutates_args=())
def _opaque_copy(x: torch.Tensor) -> torch.Tensor:
    """A copy that torch.compile cannot trace (no fake implementation)."""
    return x.clone()


_opaque_copy.register_autograd(lambda ctx, cotangent: cotangent)


@model(bounds=((-1.0,) * 3, (1.0,) * 3), r=Param(0.6, 0.3, 0.9))
def opaque_ball(x, r):
    return sphere(_opaque_copy(x), r=r)


def test_a_model_that_does_not_compile_stays_eager_and_says_so():
    p = shape_panel(opaque_ball, resolution=24, backend="image", threaded=False)
    try:
        with pytest.warns(RuntimeWarning, match="torch.compile failed"):
            p.warm_up()
        assert p.evaluator() is opaque_ball and "opaque_ball" in p.warm_up_errors
        assert p.warm_up() == 0.0  # not tried again
        p.sliders["r"].value = 0.7
        assert "(eager)" in p.status.value and "not compiled" in p.status.value
        np.testing.assert_allclose(np.linalg.norm(p.mesh.vertices, axis=1), 0.7, atol=1e-9)
    finally:
        p.view.close()


def test_a_panel_without_compilation_stays_eager():
    p = shape_panel(fig1_part, resolution=24, backend="image", threaded=False, compiled=False)
    try:
        assert p.warm_up() == 0.0 and p.evaluator() is fig1_part
        p.sliders["r"].value = 0.3
        assert "(eager)" in p.status.value
    finally:
        p.view.close()


def test_sensitivity_to_cylinder_radius_lives_on_the_cylinder_walls(panel):
    r = 0.6
    panel.sliders["r"].value = r
    v, x = panel.scalars, panel.mesh.vertices
    assert panel.last_moved == "r" and v.shape == (panel.mesh.n_vertices,)
    radial = np.stack([np.hypot(x[:, 1], x[:, 2]), np.hypot(x[:, 0], x[:, 2]), np.hypot(x[:, 0], x[:, 1])])
    gaps = np.sort(np.abs(radial - r), axis=0)
    wall_distance, second_wall = gaps[0], gaps[1]
    moving = np.abs(v) > 1e-6
    assert moving.sum() > 100  # the walls are there and they move
    assert wall_distance[moving].max() < 1e-6  # ... and nothing else moves
    # away from the edges (sphere, cube faces, where two walls cross) a wall moves into the
    # solid at unit speed: v = -(-2r)/(2r) = 1
    sphere_gap = 1 - np.linalg.norm(x, axis=1)
    slab_gap = 0.75 - np.abs(x).max(axis=1)
    clear = (wall_distance < 1e-9) & (second_wall > 0.05) & (sphere_gap > 0.05) & (slab_gap > 0.05)
    assert clear.sum() > 50
    np.testing.assert_allclose(v[clear], 1.0, atol=1e-9)
    # the view is coloured by it on a map centred on zero
    lo, hi = panel.view.actor.mapper.scalar_range
    assert lo == pytest.approx(-hi) and hi == pytest.approx(np.percentile(np.abs(v), 99))
    assert hi >= 1.0 - 1e-9  # the walls' unit speed is inside the colour range


def test_normal_velocity_of_a_growing_sphere_is_minus_one_and_checks_names():
    @model(r=Param(1.0, 0.5, 2.0))
    def ball(x, r):
        return sphere(x, r=r)

    rng = np.random.default_rng(0)
    d = rng.normal(size=(50, 3))
    x = 1.3 * d / np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(normal_velocity(ball, x, "r", {"r": 1.3}), -1.0, atol=1e-12)
    with pytest.raises(ValueError, match="no parameter 'R'"):
        normal_velocity(ball, x, "R")
    with pytest.raises(ValueError, match="outside its range"):
        normal_velocity(ball, x, "r", {"r": 5.0})


def test_moves_during_a_build_are_coalesced_latest_wins():
    p = shape_panel(fig1_part, resolution=32, preview_resolution=None, backend="image", threaded=True)
    try:
        p.wait()
        start = p.remesh_count
        values = np.linspace(0.3, 0.7, 12)
        for v in values:
            p.sliders["r"].value = float(v)
        p.wait()
        built = p.remesh_count - start
        assert 1 <= built < len(values)  # no backlog: superseded moves were dropped
        assert p.worker.dropped >= len(values) - built
        assert p.last_job["params"]["r"] == pytest.approx(values[-1])  # the latest value won
        last = functools.partial(fig1_part, r=float(values[-1]))  # and its settled mesh is shown
        np.testing.assert_array_equal(p.mesh.faces, polygonize(last, p.last_job["bounds"], 32, method="dc").faces)
    finally:
        p.view.close()


def test_preview_while_dragging_then_full_resolution():
    p = shape_panel(fig1_part, resolution=48, preview_resolution=24, settle=0.05, backend="image", threaded=True)
    try:
        p.wait()
        assert p.last_job["resolution"] == 48
        p.sliders["r"].value = 0.4
        p.wait()
        assert p.last_job["resolution"] == 48 and p.last_job["params"]["r"] == pytest.approx(0.4)
        assert p.remesh_count >= 6  # preview, marching cubes and dual contouring at full resolution, twice
        # the settled full-resolution mesh is dual contouring's (the part has interval bounds)
        dc = polygonize(functools.partial(fig1_part, r=0.4), p.last_job["bounds"], 48, method="dc", progress=False)
        np.testing.assert_array_equal(p.mesh.faces, dc.faces)
    finally:
        p.view.close()


def test_reset_bounds_and_export(panel, tmp_path):
    panel.sliders["r"].value = 0.7
    panel.reset()
    assert panel.sliders["r"].value == fig1_part.params["r"].default
    assert panel.last_job["params"]["r"] == fig1_part.params["r"].default

    panel.bounds.value = "(0, 0, 0), (1.1, 1.1, 1.1)"  # one octant
    assert panel.mesh.vertices.min() >= -1e-12
    panel.bounds.value = "(1, 0, 0), (0, 1, 1)"
    assert "bounds not accepted" in panel.status.value and "inverted" in panel.status.value

    import pyvista as pv

    for fmt in ("stl", "obj", "ply"):
        panel.export_format.value = fmt
        path = panel.export(str(tmp_path / f"part.{fmt}"))
        back = pv.read(path)
        assert back.n_cells == panel.exported.n_faces, fmt
        assert "saved to" in panel.download.value and str(tmp_path) in panel.download.value
    # the file is dual contouring's mesh (the part has interval bounds): sharp edges kept
    job = panel.last_job
    dc = polygonize(functools.partial(fig1_part, **job["params"]), job["bounds"], 40, method="dc", progress=False)
    np.testing.assert_array_equal(panel.exported.faces, dc.faces)


def test_any_user_model_and_errors():
    @model(bounds=((-1.5,) * 3, (1.5,) * 3), r=Param(1.0, 0.5, 1.4, label="radius"), cx=Param(0.0, -0.1, 0.1))
    def ball(x, r, cx):
        return sphere(x, center=(cx, 0.0, 0.0), r=r)

    p = shape_panel(ball, resolution=32, backend="image", threaded=False)
    try:
        assert list(p.sliders) == ["r", "cx"] and p.sliders["r"].description == "radius"
        p.sliders["cx"].value = 0.05
        # moving the center along x: df/dcx = 2 (x - cx), |grad f| = 2 |x - c|, so v = -n_x with n the
        # outward normal: the +x pole moves outward (v = -1), the -x pole inward (v = +1)
        v, x = p.scalars, p.mesh.vertices
        n = (x - [0.05, 0, 0]) / np.linalg.norm(x - [0.05, 0, 0], axis=1, keepdims=True)
        np.testing.assert_allclose(v, -n[:, 0], atol=1e-9)
    finally:
        p.view.close()
    with pytest.raises(TypeError, match="Model"):
        shape_panel(lambda x: x[..., 0], backend="image")


def test_view_backend_choice(monkeypatch):
    monkeypatch.setenv("PYFREP_VIEW", "image")
    assert resolve_backend("auto") == "image"
    monkeypatch.delenv("PYFREP_VIEW")
    assert resolve_backend("auto") == "image"  # no kernel here
    with pytest.raises(ValueError, match="backend"):
        resolve_backend("webgl")


def test_fit_charts_grow_during_the_run_and_loss_goes_down():
    from workbench.fitting_panel import fitting_panel

    p = fitting_panel(backend="image", n_points=400, seed=3)
    try:
        truth = p.truth["r"]
        seen = []  # chart size at every redraw: recorded by the chart itself, not by polling a clock
        redraw = p.loss_chart.refresh

        def recording_refresh(*args, **kwargs):
            seen.append(p.loss_chart.n_points)
            return redraw(*args, **kwargs)

        p.loss_chart.refresh = recording_refresh
        p.start(**TINY_FIT)
        result = p.wait()
        final = p.loss_chart.n_points
        assert len(seen) >= 3 and seen == sorted(seen)  # redrawn again and again while it ran, growing
        assert any(0 < s < final for s in seen)  # points arrived before the end
        assert p.param_chart.n_points == p.loss_chart.n_points
        assert set(p.loss_chart.series) == {"evolution", "sgd", "polish"}
        first = p.loss_chart.series["evolution"][1][0]
        assert p.loss_chart.last("polish") < first
        assert result.params["r"] == pytest.approx(truth, abs=1e-6)
        assert "fit done" in p.status.value and "stopped" not in p.status.value
        assert p.view.overlay_poly.n_points == 400 and p.view.poly.n_points > 0  # cloud + fitted surface
        assert p.loss_chart.draws >= 2 and p.run_button.disabled is False
    finally:
        p.view.close()


def test_stop_ends_a_fit_early():
    from workbench.fitting_panel import fitting_panel

    p = fitting_panel(backend="image", n_points=300, seed=2)
    try:
        planned = 200_000  # generations enough for minutes
        run = p.start(**{**TINY_FIT, "cycles": planned, "population_size": 20, "children": 1})
        t0 = time.monotonic()
        while run.running and len(p.events) < 3 and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        assert run.running
        p.stop_button.click()
        result = p.wait(timeout=60)
        assert result.stopped and "stopped early" in p.status.value
        assert result.stages == ("evolution",)
        assert len(result.history["evolution"]) < planned / 10
    finally:
        p.view.close()


def test_app_has_every_tab_and_survives_a_missing_module(monkeypatch):
    app_module = importlib.import_module("workbench.app")  # (workbench.app is also the function)

    w = workbench.app(backend="image", Shape={"resolution": 32, "threaded": False})
    try:
        assert [w.get_title(i) for i in range(len(w.children))] == [
            "Shape",
            "Model",
            "Curvature",
            "Slices",
            "Redistancing",
            "Fitting",
        ]
        assert isinstance(w.panels["Shape"], workbench.ShapePanel)
        assert "fig1_part" in w.panels["Shape"].choices
    finally:
        w.panels["Shape"].view.close()
    monkeypatch.setattr(app_module, "TABS", (("Shape", "workbench.no_such_panel:build"),))
    broken = App(backend="image")
    assert "not available yet" in broken.panels["Shape"].value


@model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(0.8, 0.5, 1.0, label="radius"))
def ball_model(x, r):
    return sphere(x, r=r)


def test_slice_panel_shows_f_and_the_true_distance_with_errors():
    from workbench.slice_panel import slice_panel

    p = slice_panel(models={"ball": ball_model}, resolution=41, distance_resolution=24, threaded=False)
    assert bytes(p.image.value).startswith(b"\x89PNG")
    lo, hi = ball_model.bounds
    u = np.linspace(lo[0], hi[0], 41)
    uu, vv = np.meshgrid(u, u, indexing="xy")
    rho = np.hypot(uu, vv)
    exact = 0.8 - rho  # signed distance to the sphere in the plane z = 0 (positive inside)
    np.testing.assert_allclose(p.values["true distance"], exact, atol=2e-3)
    np.testing.assert_allclose(p.values["f"], 0.8**2 - rho**2, atol=1e-12)
    mean_err = np.abs((0.8**2 - rho**2) - exact).mean()
    assert p.errors["f"][0] == pytest.approx(mean_err, rel=1e-2)
    assert p.errors["omega_1"][0] < p.errors["f"][0]  # normalized functions are closer to the distance than f
    # moving the plane to z = 0.6 shrinks the circle to radius sqrt(0.8^2 - 0.6^2)
    p.offset.value = 0.6
    inside = p.values["f"] > 0
    assert rho[inside].max() <= np.sqrt(0.8**2 - 0.6**2) + 1e-12


def test_redistance_panel_trains_charts_and_hands_the_network_to_the_slices():
    from workbench.redistance_panel import redistance_panel
    from workbench.slice_panel import slice_panel

    tiny = {"steps": 30, "width": 16, "depth": 2, "surface_resolution": 24, "pool_size": 2048, "batch": 256}
    p = redistance_panel(models={"ball": ball_model}, settings=tiny, slice_resolution=32, distance_resolution=24)
    s = slice_panel(models={"ball": ball_model}, resolution=24, distance_resolution=24, threaded=False)
    p.on_trained.append(s.set_network)
    seen = []  # chart size at every redraw, recorded by the chart itself (no polling of a clock)
    redraw = p.loss_chart.refresh

    def recording_refresh(*args, **kwargs):
        seen.append(p.loss_chart.n_points)
        return redraw(*args, **kwargs)

    p.loss_chart.refresh = recording_refresh
    p.start(every=1)
    network = p.wait()
    assert len(seen) >= 3 and seen == sorted(seen)  # redrawn again and again while training, growing
    assert any(0 < n < p.loss_chart.n_points for n in seen)  # the chart grew while training
    assert p.loss_chart.n_points >= 10 and "trained in" in p.status.value and "stopped" not in p.status.value
    assert bytes(p.slices.value).startswith(b"\x89PNG")
    # the network keeps the zero set (sign of f) and is a distance-like field
    x = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.1]])
    d = np.asarray(network(x)).ravel()
    assert d[0] > 0 > d[1]
    assert "redistanced" in s.values and "redistanced" in s.errors  # handed over to the slice panel

    run = p.start(steps=100_000, every=1)
    while run.running and len(p.events) < 3:
        time.sleep(0.01)
    p.stop_button.click()
    p.wait(timeout=120)
    assert "stopped early" in p.status.value and len(p.events) < 1000


def test_curvature_panel_on_a_sphere():
    from workbench.curvature_panel import curvature_panel

    p = curvature_panel(models={"ball": ball_model}, resolution=32, backend="image", threaded=False)
    try:
        t = p.table
        np.testing.assert_allclose(np.abs(t["H"]), 1 / 0.8, rtol=1e-6)
        np.testing.assert_allclose(t["K"], 1 / 0.8**2, rtol=1e-6)
        np.testing.assert_allclose(t["kmin"], t["kmax"], atol=1e-6)
        assert bytes(p.histogram.value).startswith(b"\x89PNG") and "median" in p.status.value
        before = p.view.widget.value
        p.quantity.value = "Gaussian K"
        assert p.view.widget.value != before  # recoloured and retitled (K is constant on a sphere, so its title)
        assert "median" in p.status.value and "K in [" in p.status.value
    finally:
        p.view.close()


def test_fitting_panel_loads_a_cloud_from_xyz(tmp_path):
    from pyfrep_core.io import save_points
    from workbench.fitting_panel import fitting_panel

    p = fitting_panel(backend="image", n_points=200, seed=5)
    try:
        pts = p.points[:150]
        save_points(pts, tmp_path / "cloud.xyz")
        p.load_cloud(str(tmp_path / "cloud.xyz"))
        np.testing.assert_allclose(p.points, pts)
        assert p.truth is None and p.source.value == "file" and "150 points loaded" in p.status.value
        p.load_cloud(str(tmp_path / "missing.xyz"))
        assert "FileNotFoundError" in p.status.value and len(p.points) == 150
    finally:
        p.view.close()


def test_param_derivative_agrees_with_diff_param_grad():
    from pyfrep_core.diff import param_grad
    from pyfrep_core.sensitivity import param_derivative

    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, size=(200, 3))
    ours = param_derivative(fig1_part, x, "r", {"r": 0.42})
    np.testing.assert_allclose(ours, param_grad(fig1_part, x, {"r": 0.42})["r"], rtol=1e-12, atol=1e-12)


def test_slice_panel_shows_the_2d_ellipse_directly_with_its_exact_distance():
    from pyfrep_core.models import ellipse, ellipse_distance
    from pyfrep_core.sampling import plane_points
    from workbench.slice_panel import slice_panel

    p = slice_panel(models={"ellipse": ellipse}, resolution=40, threaded=False)
    assert p.axis.layout.display == "none"  # a planar model has no slicing plane to choose
    pts, _ = plane_points(ellipse.bounds, 2, 0.0, 40, dim=2)
    np.testing.assert_allclose(p.values["true distance"], ellipse_distance(pts.reshape(-1, 2)).reshape(40, 40))
    np.testing.assert_allclose(p.values["f"], ellipse(pts.reshape(-1, 2)).reshape(40, 40))
    assert set(p.errors) >= {"f", "omega_1", "omega_2", "delta_1"}


def test_shape_panel_switches_models_in_the_same_view():
    p = shape_panel(fig1_part, resolution=32, backend="image", threaded=False, choices={"ball": ball_model})
    try:
        poly, plotter = p.view.poly, p.view.plotter
        p.choice.value = "ball"
        assert list(p.sliders) == ["r"] and p.sliders["r"].description == "radius"
        assert p.slider_box.children == (p.sliders["r"],)
        assert p.view.poly is poly and p.view.plotter is plotter
        np.testing.assert_allclose(np.linalg.norm(p.mesh.vertices, axis=1), 0.8, atol=1e-9)
        assert "(-1.2, -1.2, -1.2)" in p.bounds.value
    finally:
        p.view.close()
