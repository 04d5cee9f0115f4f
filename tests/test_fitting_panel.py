"""The fitting tab without a browser: options, outliers drawn apart, the table, stale state, files, the camera."""

from __future__ import annotations

from datetime import UTC, datetime

import numpy as np
import pytest
import torch

from pyfrep_core import Mesh, Param, model, polygonize, save_mesh
from workbench.fitting_panel import OUTLIER_COLOUR, FittingPanel

# the panel's logic, not the fit's search, is under test here: the polish alone, from near the truth
POLISH = {"stages": ("polish",), "polish_iters": 30}


def near(truth: dict[str, float], factor: float = 1.03) -> dict[str, float]:
    return {k: v * factor for k, v in truth.items()}


@model(bounds=((-1.5,) * 3, (1.5,) * 3), a=Param(1.0, 0.6, 1.4), b=Param(0.6, 0.3, 0.9))
def plate(x, a, b):
    """A rectangular plate of half-sizes a, b, 0.3 (its faces' exact distance inside)."""
    return torch.minimum(torch.minimum(a - x[:, 0].abs(), b - x[:, 1].abs()), 0.3 - x[:, 2].abs())


@model(bounds=((-15.0,) * 3, (15.0,) * 3), a=Param(10.0, 6.0, 14.0), b=Param(6.0, 3.0, 9.0))
def big_plate(x, a, b):
    """The plate ten times larger (millimetres instead of centimetres, say)."""
    return torch.minimum(torch.minimum(a - x[:, 0].abs(), b - x[:, 1].abs()), 3.0 - x[:, 2].abs())


@pytest.fixture
def panel():
    p = FittingPanel({"plate": plate, "big_plate": big_plate}, n_points=400, noise=0.01, seed=4, backend="image")
    yield p
    p.view.close()


def framed_points(p: FittingPanel) -> tuple[np.ndarray, float]:
    """The camera's focal point and its distance to it."""
    cam = p.view.plotter.camera
    focal = np.asarray(cam.focal_point)
    return focal, float(np.linalg.norm(np.asarray(cam.position) - focal))


def camera(p: FittingPanel) -> np.ndarray:
    """(9,) the camera's position, focal point and up direction."""
    cp = p.view.plotter.camera_position
    return np.array([*cp.position, *cp.focal_point, *cp.viewup])


def test_the_options_become_fit_settings():
    p = FittingPanel({"plate": plate}, n_points=50, backend="image")
    try:
        p.pose.value, p.residual.value, p.loss.value, p.starts.value = "rigid + scale", "geometric", "huber", 4
        cfg = p.settings()
        assert (cfg["pose"], cfg["residual"], cfg["loss"], cfg["starts"]) == ("scale", "geometric", "huber", 4)
        assert cfg["polish_iters"] >= 100  # a robust polish reweights in rounds
        p.pose.value, p.starts.value, p.loss.value = "off", "auto", "l2"
        assert (p.settings()["pose"], p.settings()["starts"], p.settings()["polish_iters"]) == (False, None, 20)
        # a generated cloud in a random pose: the true pose is known and tabulated with the fit
        p.moved.value = True
        p.make_cloud()
        assert set(p.true_pose) == {"tx", "ty", "tz", "rx", "ry", "rz"}
        assert abs(plate(p.points, **p.truth)).max() > 0.1  # moved: off the model at the origin
    finally:
        p.view.close()


def test_a_robust_fit_draws_outliers_apart_and_tabulates_standard_errors(panel):
    p = panel
    p.outliers.value = 0.1
    p.make_cloud()
    assert p.planted.sum() == 40 and len(p.points) == 440
    p.loss.value, p.residual.value = "cauchy", "geometric"
    p.start(**POLISH, init=near(p.truth))
    result = p.wait()
    assert result.loss_function == "cauchy"
    # the planted outliers are the ones found, and they are drawn as a red cloud of their own
    found = ~result.inliers
    assert (found & p.planted).sum() >= 0.9 * p.planted.sum() and (found & ~p.planted).sum() <= 0.1 * found.sum()
    poly, actor = p.view.overlays["outliers"]
    assert actor.visibility and poly.n_points == found.sum()
    assert actor.prop.color.hex_rgb == OUTLIER_COLOUR
    assert p.view.overlay_poly.n_points == (~found).sum()  # the inliers, coloured by their distance
    # the colour bar tells the cloud's colours: the geometric distance with its range
    assert p.view.bar.GetVisibility() and "distance" in p.view.bar.GetTitle()
    lo, hi = p.view.overlay_actor.mapper.scalar_range
    assert lo == 0.0 and 0.0 < hi < 0.1
    # the fitted dimensions are the hidden ones, within their standard errors, in the table
    for k in ("a", "b"):
        assert abs(result.params[k] - p.truth[k]) < 4 * result.std_errors[k]
        assert f"<td>{k}</td><td>{result.params[k]:.6g}</td><td>{result.std_errors[k]:.2g}</td>" in p.table.value
    assert p.table.value.count("<tr>") == 1 + len(result.params) and "error / s.e." in p.table.value
    assert f"{found.sum()} outliers" in p.status.value and "planted" in p.status.value
    # the progress bar ends full and says so (it stopped at 'polish 3/20' before)
    assert p.bar.value == p.bar.max and p.bar.description == "done" and "polish" in p.progress_text.value
    assert "done: polish" in p.progress_text.value


def test_a_new_model_clears_the_previous_fit_and_the_camera_follows(panel):
    p = panel
    p.start(**POLISH, init=near(p.truth))
    p.wait()
    assert p.loss_chart.n_points > 0 and p.table.value and p.view.actor.visibility
    _, small = framed_points(p)
    p.model_choice.value = "big_plate"  # ten times larger
    p.main.drain()
    assert p.result is None and p.loss_chart.n_points == 0 and p.param_chart.n_points == 0
    assert p.bar.value == 0 and p.bar.description == "" and p.progress_text.value == "" and p.table.value == ""
    assert not p.view.actor.visibility  # the old fitted surface is gone until the next fit
    focal, large = framed_points(p)
    assert 5 < large / small < 20  # the camera backs off with the data's size
    centre = (p.points.min(0) + p.points.max(0)) / 2
    assert np.linalg.norm(focal - centre) < 1.0
    p.start(**POLISH, init=near(p.truth))
    result = p.wait()
    assert result.params["a"] == pytest.approx(p.truth["a"], abs=0.05) and p.view.actor.visibility


def test_the_users_camera_stays_over_new_clouds_and_fits_until_the_model_changes(panel):
    p = panel
    cam = p.view.plotter.camera
    cam.azimuth += 50.0  # the user turns the view and zooms in
    cam.zoom(1.5)
    turned = camera(p)
    p.seed.value = 5
    p.make_cloud()  # "New cloud": the same model, the same place
    assert np.allclose(camera(p), turned)
    p.start(**POLISH, init=near(p.truth))
    p.wait()
    assert p.view.actor.visibility and np.allclose(camera(p), turned)
    p.moved.value = True  # a random pose takes the cloud out of the framed box: framed again
    p.make_cloud()
    assert not np.allclose(camera(p), turned)
    focal, _ = framed_points(p)
    assert np.linalg.norm(focal - (p.points.min(0) + p.points.max(0)) / 2) < 0.5
    p.moved.value = False
    p.model_choice.value = "big_plate"  # a new model: framed, whatever the user did
    p.main.drain()
    focal, _ = framed_points(p)
    assert np.linalg.norm(focal - (p.points.min(0) + p.points.max(0)) / 2) < 1.0


def test_an_uploaded_mesh_is_named_in_the_status_and_fitted(panel, tmp_path):
    p = panel
    truth = {"a": 1.2, "b": 0.5}
    mesh = polygonize(lambda x: plate(x, **truth), plate.bounds, 48, progress=False)
    save_mesh(mesh, tmp_path / "part.stl")
    content = (tmp_path / "part.stl").read_bytes()
    p.upload.value = ({"name": "my part.stl", "type": "", "size": len(content), "content": memoryview(content),
                       "last_modified": datetime.now(UTC)},)  # fmt: skip
    p.main.drain()
    assert "my part.stl" in p.status.value and "upload" not in p.status.value
    assert isinstance(p.data, Mesh) and p.source.value == "file" and p.truth is None
    assert len(p.points) == mesh.n_vertices + p.n_points.value  # vertices and area samples shown
    p.start(**POLISH, init=near(truth))
    result = p.wait()
    assert p.param_chart.title == "parameters" and not p.param_chart.references  # no true values to draw
    assert result.residual == "geometric"  # measured data: the geometric residual under "auto"
    # marching cubes' facets cut the plate's edges: within a few % of a cell (0.064)
    assert result.params["a"] == pytest.approx(1.2, abs=0.01) and result.params["b"] == pytest.approx(0.5, abs=0.01)
    assert "my part.stl" in p.status.value
    assert "true" not in p.table.value  # no truth for a file


def test_a_fit_of_old_data_is_not_drawn(panel):
    p = panel
    run = p.start(cycles=100_000, population_size=20, children=1, epochs=1)
    p.make_cloud()  # new data while it runs: the run is stopped and its result ignored
    run.wait(60)
    p.main.drain()
    assert p.result is None and p.table.value == "" and (p.view.actor is None or not p.view.actor.visibility)
    assert p.run_button.disabled is False
