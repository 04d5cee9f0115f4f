"""The Model tab: code written in the editor, Run, the model in every panel with its sliders; errors with
their line; templates equal to the paper's models."""

import numpy as np
import pytest
import torch

import workbench
from pyfrep_core.models import fig1_part, pawn
from workbench import user_models
from workbench.model_panel import ModelPanel, check_model
from workbench.model_templates import TEMPLATES

BALL = """\
import torch
from pyfrep_core import *


@model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(0.7, 0.3, 1.0, label="ball radius"), h=Param(0.2, 0.05, 0.4))
def student_ball(x, r, h):
    return difference(sphere(x, r=r), cylZ(x, r=h))
"""

DISC = """\
from pyfrep_core import *


@model(bounds=((-1, -1), (1, 1)), dim=2, a=Param(0.5, 0.2, 0.9))
def student_disc(p, a):
    return a**2 - p[:, 0] ** 2 - p[:, 1] ** 2
"""


@pytest.fixture(autouse=True)
def _forget_user_models():
    user_models.clear()
    yield
    user_models.clear()


def _panel(**kwargs):
    return ModelPanel(namespace={}, backend="image", preview={"resolution": 24, "threaded": False}, **kwargs)


def _close(*panels):
    for p in panels:
        view = getattr(p, "view", None) or getattr(getattr(p, "shape", None), "view", None)
        if view is not None:
            view.close()


@pytest.mark.parametrize(("name", "truth"), [("Fig. 1 part", fig1_part), ("pawn (Figs. 5-6)", pawn)])
def test_templates_give_the_paper_models_values(name, truth):
    namespace = {}
    panel = ModelPanel(namespace=namespace, backend="image", preview={"resolution": 24, "threaded": False})
    try:
        panel.template.value = name
        built = panel.run()
        assert built is not None, panel.error.value
        assert list(built.params) == list(truth.params)
        assert built.params == truth.params and built.bounds == truth.bounds
        x = torch.rand(2000, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 2.4 - 1.2
        values = {k: (p.lower + p.upper) / 2 for k, p in truth.params.items()}
        torch.testing.assert_close(built(x, **values), truth(x, **values), rtol=0, atol=1e-12)
    finally:
        _close(panel)


def test_every_template_builds_and_shows_a_surface():
    for name, code in TEMPLATES.items():
        panel = _panel(template=name)
        try:
            model = panel.run()
            assert model is not None, f"{name}: {panel.error.value}"
            assert check_model(model) == []
            assert panel.shape.mesh.n_faces > 100, name
            assert list(panel.shape.sliders) == list(model.params)
            assert panel.editor.value == code
        finally:
            _close(panel)


def test_run_opens_the_model_in_every_panel_with_its_sliders():
    w = workbench.app(
        backend="image",
        Shape={"resolution": 24, "threaded": False},
        Model={"namespace": {}, "preview": {"resolution": 24, "threaded": False}},
        Curvature={"resolution": 24, "threaded": False},
        Slices={"resolution": 32, "distance_resolution": 16, "threaded": False},
        Fitting={"n_points": 100, "resolution": 24},
    )
    try:
        for title in ("Model", "Curvature", "Redistancing", "Fitting"):  # built before the run; Slices after
            w.panel(title)
        editor = w.panels["Model"]
        editor.editor.value = BALL  # as typed
        editor.run_button.click()
        assert "student_ball" in editor.status.value and not editor.error.value
        assert "opened in Shape, Curvature, Redistancing, Fitting" in editor.status.value
        shape = w.panels["Shape"]
        assert shape.model.__name__ == "student_ball" and shape.choice.value == "student_ball"
        slices = w.panel("Slices")  # a tab opened after the run opens the model too
        slices.fields.value = ("f",)  # (one plot per draw from here: quicker)
        for title in ("Curvature", "Slices", "Redistancing", "Fitting"):
            panel = w.panels[title]
            assert panel.model_choice.value == "student_ball", title
            assert panel.model.__name__ == "student_ball", title
            assert "fig1_part" in panel.model_choice.options, title  # the paper's shapes stay offered
        # one slider per Param, with its range, default and label
        for sliders in (shape.sliders, editor.shape.sliders):
            assert list(sliders) == ["r", "h"]
            assert (sliders["r"].min, sliders["r"].max, sliders["r"].value) == (0.3, 1.0, 0.7)
            assert sliders["r"].description == "ball radius" and sliders["h"].description == "h"
            for s in sliders.values():  # the default on the step grid: the browser would round it
                assert ((s.value - s.min) / s.step) == pytest.approx(round((s.value - s.min) / s.step), abs=1e-9)
        # the shape shown is the ball with a hole: a vertex on the hole's wall is at radius h
        verts = shape.mesh.vertices
        wall = np.abs(verts[:, 2]) < 0.3
        assert np.hypot(verts[wall, 0], verts[wall, 1]).min() == pytest.approx(0.2, abs=0.02)
        # the same name run again with a new range: the sliders follow
        editor.run(BALL.replace("Param(0.7, 0.3, 1.0", "Param(0.9, 0.3, 1.1"))
        assert shape.sliders["r"].max == 1.1 and shape.sliders["r"].value == 0.9
        assert w.panels["Curvature"].model.params["r"].upper == 1.1
        # a 2-D model: only the slices take it
        editor.run(DISC)
        assert w.panels["Slices"].model_choice.value == "student_disc"
        assert "student_disc" not in shape.choices and "student_disc" not in w.panels["Fitting"].models
        assert "opened in Slices" in editor.status.value
    finally:
        for panel in w.panels.values():
            _close(panel)


def test_syntax_error_shows_its_line():
    panel = _panel()
    try:
        code = BALL.replace("return difference(", "return difference((")  # line 7: unclosed parenthesis
        assert panel.run(code) is None
        assert panel.editor.marked == 7
        assert "error in the code at line 7" in panel.status.value
        assert "SyntaxError" in panel.error.value
        assert "class='bad'>7<" in panel.editor.gutter.value
        panel.editor.value = BALL  # an edit clears the mark
        assert panel.editor.marked is None
    finally:
        _close(panel)


def test_runtime_errors_show_the_users_line_only():
    panel = _panel()
    try:
        bad_call = BALL.replace("cylZ(x, r=h)", "cylZ(x, r=h - 1.0)")  # cylZ refuses a negative radius
        assert panel.run(bad_call) is None
        assert panel.editor.marked == 7
        assert "r must be positive" in panel.error.value
        assert "line 7, in student_ball" in panel.error.value
        assert "pyfrep_core" not in panel.error.value  # the kernel's own frames are cut
        assert panel.run("x = 1\ny = undefined_name + 1\n") is None
        assert panel.editor.marked == 2 and "NameError" in panel.error.value
        assert panel.run("x = 1\n") is None
        assert "no model defined" in panel.error.value
        no_box = BALL.replace("bounds=((-1.2,) * 3, (1.2,) * 3), ", "")
        assert panel.run(no_box) is None
        assert "declare the box" in panel.error.value
        nan = BALL.replace("return difference(", "return torch.sqrt(x[:, 0]) * difference(")
        assert panel.run(nan) is None
        assert "non-finite values" in panel.error.value
        assert panel.run(BALL) is not None and not panel.error.value  # and it recovers
    finally:
        _close(panel)


def test_code_runs_in_the_given_namespace_like_a_cell():
    namespace = {"ratio": 0.5}
    panel = ModelPanel(namespace=namespace, backend="image", preview={"resolution": 24, "threaded": False})
    try:
        model = panel.run(BALL.replace("r=r)", "r=r * ratio / 0.5)"))
        assert namespace["student_ball"] is model
        assert "sphere" in namespace  # the import stays, as in a notebook cell
        assert user_models.user_models()["student_ball"] is model
    finally:
        _close(panel)
