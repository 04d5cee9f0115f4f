"""Push-pull: the surface moved through a point by a distance, the parameters solved for.

Truths: R-functions keep the zero sets of their arguments, so where one primitive forms the
surface (a drilled cylinder's wall, the pawn's head) moving that primitive's parameter moves
the surface by exactly the same amount; the solver's own tolerance (1e-9 in length) is all
that separates the result from the closed form.
"""

import math

import numpy as np
import pytest
import torch

from pyfrep_core import Param, model, sphere
from pyfrep_core.models import fig1_part, pawn
from pyfrep_core.push_pull import push_pull

C = 0.5 / math.sqrt(2.0)
WALL = [C, C, 0.6]  # on the z cylinder's wall (radius 0.5), away from the other two holes and the cube


@model(bounds=((-3,) * 3, (3,) * 3), r=Param(1.0, 0.5, 2.0), cx=Param(0.0, -1.0, 1.0))
def shifted_ball(x, r, cx):
    return sphere(x, center=(cx, 0.0, 0.0), r=r)


def test_fig1_cylinder_wall_pulled_out_narrows_the_hole_by_the_displacement():
    # outward from the solid on a hole's wall points to the axis: the hole's radius shrinks by 0.05
    result = push_pull(fig1_part, WALL, 0.05)
    assert result.converged
    assert result.change["r"] == pytest.approx(-0.05, abs=1e-6)
    assert np.hypot(*result.target[:2]) == pytest.approx(0.45, abs=1e-12)
    assert float(fig1_part(result.target[None], **result.params)[0]) == pytest.approx(0.0, abs=1e-8)
    pushed = push_pull(fig1_part, WALL, -0.05)  # into the solid: the hole widens
    assert pushed.change["r"] == pytest.approx(0.05, abs=1e-6)


def test_a_point_beside_the_surface_is_projected_first():
    off = [C * 1.002, C * 1.002, 0.6]  # 1.4e-3 into the solid
    result = push_pull(fig1_part, off, 0.05)
    assert np.hypot(*result.point[:2]) == pytest.approx(0.5, abs=1e-9)
    assert result.change["r"] == pytest.approx(-0.05, abs=1e-6)


def test_bounds_hold_and_the_distance_left_is_reported():
    result = push_pull(fig1_part, WALL, 0.4)  # would need r = 0.1, below the range [0.2, 0.8]
    assert result.params["r"] == 0.2 and result.at_bound == ("r",)
    assert not result.converged
    # wall at radius 0.2, target at 0.1; the walk to the wall follows grad f, which the R-intersection
    # with the cube tilts slightly off the radial direction (3e-5 here): 1e-3 tells 0.1 from 0.132 (f/|grad f|)
    assert result.distance == pytest.approx(0.1, abs=1e-3)


def test_smallest_change_in_units_of_each_range():
    # at (1, 0, 0) both r and cx move the surface outward at unit speed: dr + dcx = d exactly.
    # The smallest change in range units u_j = dp_j / span_j splits d as span_j^2 / sum span^2.
    d = 0.1
    result = push_pull(shifted_ball, [1.0, 0.0, 0.0], d)
    spans = np.array([1.5, 2.0])
    share = spans**2 / np.sum(spans**2)
    assert result.converged
    assert result.change["r"] == pytest.approx(d * share[0], abs=1e-8)
    assert result.change["cx"] == pytest.approx(d * share[1], abs=1e-8)
    only_r = push_pull(shifted_ball, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float32), d, free=["r"])
    assert only_r.change == pytest.approx({"r": d}, abs=1e-7)
    assert only_r.params["cx"] == 0.0


def test_pawn_head_pulled_moves_the_head_radius_only():
    top = [0.0, 0.0, 0.45 + 0.27 + 0.3]
    result = push_pull(pawn, top, 0.03, params=pawn.defaults())
    assert result.converged
    assert result.change["head_radius"] == pytest.approx(0.03, abs=1e-6)
    for name in ("neck_radius", "base_radius", "collar_radius"):
        assert abs(result.change[name]) < 1e-5


def test_refusals_name_the_problem():
    with pytest.raises(ValueError, match="free must name declared parameters"):
        push_pull(fig1_part, WALL, 0.05, free=["radius"])
    with pytest.raises(ValueError, match="grad f vanishes"):
        push_pull(shifted_ball, [0.0, 0.0, 0.0], 0.05)
    with pytest.raises(ValueError, match="no free parameter"):
        push_pull(pawn, [0.0, 0.0, 0.45 + 0.27 + 0.3], 0.03, free=["base_radius"])
    with pytest.raises(ValueError, match="displacement must be a finite number"):
        push_pull(fig1_part, WALL, float("nan"))
    with pytest.raises(ValueError, match="outside its range"):
        push_pull(fig1_part, WALL, 0.05, params={"r": 0.9})
    with pytest.raises(ValueError, match="one point"):
        push_pull(fig1_part, [WALL, WALL], 0.05)


def _pixel(plotter, point):
    """Display coordinates (origin bottom left) of a world point in the plotter's renderer."""
    ren = plotter.renderer
    ren.SetWorldPoint(*point, 1.0)
    ren.WorldToDisplay()
    x, y, _ = ren.GetDisplayPoint()
    return round(x), round(y)


def test_shape_panel_click_then_pull_moves_the_slider():
    from workbench.shape_panel import ShapePanel

    panel = ShapePanel(fig1_part, resolution=48, backend="image", threaded=False, compiled=False)
    try:
        pp = panel.push_pull
        assert pp.pull.disabled  # nothing picked yet
        # a click on the sphere's face seen by the isometric camera picks the point under the pixel
        seen = np.full(3, 1.0 / math.sqrt(3.0))
        pp.click(*_pixel(panel.view.plotter, seen))
        assert pp.point is not None and np.linalg.norm(pp.point - seen) < 0.02
        assert not pp.pull.disabled
        # the browser rounds a slider to min + k step: a typed 0.05 must lie on that grid
        assert (0.05 - pp.pull.min) / pp.pull.step == pytest.approx(round((0.05 - pp.pull.min) / pp.pull.step))
        # pick the cylinder wall, type a pull of +0.05: the slider r goes to 0.45, the view remeshes
        pp.pick(WALL)
        before = panel.remesh_count
        pp.pull.value = 0.05
        assert panel.sliders["r"].value == pytest.approx(0.45, abs=1e-6)
        assert panel.remesh_count == before + 1 and panel.last_job["params"]["r"] == pytest.approx(0.45, abs=1e-6)
        assert "passes through the target" in pp.status.value
        pp.pull.value = -0.05  # dragged back past 0: from the parameters at the pick
        assert panel.sliders["r"].value == pytest.approx(0.55, abs=1e-6)
        pp.pull.value = 0.4
        assert panel.sliders["r"].value == 0.2 and "r at a bound" in pp.status.value
        panel.reset_button.click()  # Reset: the defaults, and no stale pick or pull
        assert panel.sliders["r"].value == 0.5 and pp.point is None
        assert pp.pull.disabled and pp.pull.value == 0.0 and "click the surface" in pp.status.value
        assert not pp.marker_actor.visibility
    finally:
        panel.view.close()


@model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(0.8, 0.5, 1.0))
def ball(x, r):
    return sphere(x, r=r)


def _display(plotter, point):
    """Display coordinates (float, origin bottom left) of a world point."""
    ren = plotter.renderer
    ren.SetWorldPoint(*point, 1.0)
    ren.WorldToDisplay()
    return np.array(ren.GetDisplayPoint()[:2])


def _looking(plotter):
    """The camera's unit viewing direction."""
    d = np.subtract(plotter.camera.focal_point, plotter.camera.position)
    return d / np.linalg.norm(d)


def test_dragging_the_surface_pulls_it_by_the_mouse_travel_along_the_normal():
    from workbench.shape_panel import ShapePanel

    panel = ShapePanel(ball, resolution=48, backend="image", threaded=False, compiled=False)
    try:
        pp, plotter = panel.push_pull, panel.view.plotter
        n = np.array([1.0, 1.0, -0.5]) / 1.5  # 55 degrees off the isometric line of sight: seen, and across
        point = 0.8 * n
        start = _pixel(plotter, point)
        # off: a drag turns the camera and picks nothing
        before = _looking(plotter)
        pp.drag_mouse(start, (start[0] + 40, start[1]))
        assert pp.point is None and not np.allclose(_looking(plotter), before)
        panel.view.render(reset_camera=True)
        # on: a press on the surface picks there; the pull is the travel along the normal's screen direction
        pp.drag.value = True
        start = _pixel(plotter, point)
        h = 1e-4
        along = (_display(plotter, point + h * n) - _display(plotter, point)) / h  # pixels per unit, on screen
        end = np.round(start + 20 * along / np.linalg.norm(along)).astype(int)
        expected = float(np.dot(end - start, along / np.linalg.norm(along))) / np.linalg.norm(along)
        looking, position = _looking(plotter), np.array(plotter.camera.position)
        pp.drag_mouse(start, tuple(end))
        assert np.linalg.norm(pp.point - point) < 0.02  # the pixel's point, a mesh facet off the sphere
        # the camera neither turned nor backed off under the mouse, though the ball grew
        assert np.allclose(_looking(plotter), looking) and np.allclose(plotter.camera.position, position)
        assert not panel.view.hold_camera  # released: a later change of size refits again
        # rounded to the slider's step; the perspective's change of scale along 20 px adds under 2 %
        assert pp.pull.value == pytest.approx(expected, abs=pp.pull.step / 2 + 0.02 * expected)
        assert 0.05 < pp.pull.value < 0.2  # dragged outward: the ball grows
        # the sphere's radius moves by exactly the pull: the surface passes through the dragged-to point
        assert panel.sliders["r"].value == pytest.approx(0.8 + pp.pull.value, abs=1e-6)
        assert panel.last_job["params"]["r"] == pytest.approx(0.8 + pp.pull.value, abs=1e-6)
        # a normal seen end-on (the ball's point facing the camera): the vertical travel, up is outward
        eye = np.asarray(plotter.camera.position)
        pp.pick(panel.sliders["r"].value * eye / np.linalg.norm(eye))
        direction, per_unit = pp.screen_normal()
        assert np.array_equal(direction, [0.0, 1.0]) and per_unit > 0
        # a press beside the shape still turns the camera, and picks nothing new
        picked = pp.point.copy()
        pp.drag_mouse((3, 3), (40, 3))
        assert not np.allclose(_looking(plotter), looking) and np.array_equal(pp.point, picked)
    finally:
        panel.view.close()
