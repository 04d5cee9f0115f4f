"""The workbench ready for a class, without a browser: each control does what its label says,
colour scales a student can trust, exports that never land in the repository."""

from __future__ import annotations

import subprocess
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from pyfrep_core import Param, intersection, load_mesh, model, sphere
from pyfrep_core.models import ellipse, fig1_part, microstructure, schwarz_d
from workbench.colours import DIVERGING, SEQUENTIAL, UNDEFINED_COLOUR, colour_range
from workbench.curvature_panel import CurvaturePanel
from workbench.help import HELP, help_box
from workbench.shape_panel import LABEL_PX, ShapePanel, shape_panel
from workbench.slice_panel import SlicePanel, slice_figure

ROOT = Path(__file__).resolve().parents[1]


@model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(0.8, 0.5, 1.0, label="radius"))
def ball(x, r):
    return sphere(x, r=r)


@model(bounds=((-1.0,) * 3, (1.0,) * 3), a=Param(0.5, 0.2, 1.5, label="half edge"))
def cube(x, a):
    """A cube of half edge a: three slabs intersected."""
    slabs = [a * a - x[:, i] * x[:, i] for i in range(3)]
    return intersection(intersection(slabs[0], slabs[1]), slabs[2])


# -- 1. slices: every control stays visible -------------------------------------------------------
def test_slice_controls_stay_visible_with_a_2d_model_first_and_the_plane_moves():
    p = SlicePanel({"ellipse": ellipse, "ball": ball}, resolution=32, distance_resolution=24, threaded=False)
    # the 2-D ellipse hides its plane controls, and only those
    assert p.axis.layout.display == "none" and p.offset.layout.display == "none"
    for w in (p.model_choice, p.resolution, p.fields):
        assert w.layout.display != "none", w.description
    p.model_choice.value = "ball"
    assert p.offset.layout.display != "none" and p.axis.layout.display != "none"
    p.offset.value = 0.6  # the plane z = 0.6 cuts the ball of radius 0.8 in a circle of radius sqrt(0.28)
    assert "z = 0.6" in p.status.value
    pts_inside = p.values["f"] > 0
    assert pts_inside.any() and pts_inside.mean() < 0.2


# -- 2. redistancing: Stop, honest "stopped early", no flood of redraws ---------------------------
class QueuedMain:
    """A main thread that is busy: calls wait in a queue until ``drain`` (like a kernel's loop)."""

    has_loop = True

    def __init__(self) -> None:
        self.queue: list = []
        self.lock = threading.Lock()

    def call(self, fn, *args, vtk: bool = True) -> None:  # noqa: ARG002
        with self.lock:
            self.queue.append((fn, args))

    def drain(self) -> int:
        n = 0
        while True:
            with self.lock:
                if not self.queue:
                    return n
                fn, args = self.queue.pop(0)
            fn(*args)
            n += 1


TINY = {"width": 16, "depth": 2, "surface_resolution": 24, "pool_size": 2048, "batch": 256}


def _redistance_panel(main):
    from workbench.redistance_panel import RedistancePanel

    p = RedistancePanel({"ball": ball}, settings=TINY, slice_resolution=24, distance_resolution=20)
    p.main = main
    p.loss_chart.schedule = lambda fn: main.call(fn, vtk=False)
    return p


def test_a_busy_kernel_gets_at_most_one_chart_and_one_progress_call_queued():
    main = QueuedMain()
    p = _redistance_panel(main)
    most = 0
    run = p.start(steps=60, every=1)
    while run.running:
        most = max(most, len(main.queue))
        time.sleep(0.005)
    assert len(p.events) == 60
    # 60 events: one chart redraw and one progress line may wait, then the end of the run
    assert most <= 3, most
    main.drain()
    assert "trained in" in p.status.value and "stopped" not in p.status.value
    assert "60/60" in p.progress_text.value


def test_a_stop_that_arrives_after_the_last_step_changes_nothing():
    main = QueuedMain()
    p = _redistance_panel(main)
    run = p.start(steps=20, every=1)
    run._thread.join(120)
    p.stop()  # the click was queued behind the busy loop; training is over
    main.drain()
    assert "trained in" in p.status.value
    assert "stopping" not in p.status.value and "stopped early" not in p.status.value


def test_stop_during_training_stops_it_and_says_where():
    main = QueuedMain()
    p = _redistance_panel(main)
    run = p.start(steps=100_000, every=1)
    while len(p.events) < 5:
        time.sleep(0.01)
    p.stop()
    assert p.status.value == "stopping..."
    run._thread.join(60)
    assert not run.running
    main.drain()
    last = p.events[-1]
    assert last.step + 1 < 1000  # it stopped promptly, far from 100 000 steps
    assert f"stopped early at step {last.step + 1}" in p.status.value


def test_the_papers_training_is_offered_says_what_it_trains_on_and_stops(monkeypatch):
    import pyfrep_core.redistancing as redistancing

    main = QueuedMain()
    p = _redistance_panel(main)
    assert p.mode.value == "supervised" and "labels" in p.mode_help.value
    p.mode.value = "paper"
    assert "eq. 9" in p.mode_help.value and "from f alone" in p.mode_help.value
    modes = []
    real = redistancing.redistance
    monkeypatch.setattr(redistancing, "redistance", lambda *a, **k: modes.append(k["mode"]) or real(*a, **k))
    run = p.start(steps=100_000, every=1)
    while len(p.events) < 5:
        time.sleep(0.01)
    p.stop()
    run._thread.join(60)
    assert not run.running and modes == ["paper"]
    main.drain()
    last = p.events[-1]
    assert last.step + 1 < 1000
    assert "paper: eikonal, no labels" in p.status.value and f"stopped early at step {last.step + 1}" in p.status.value


# -- 3. curvature: undefined points grey and counted, robust range, one-sided when one-signed --------
def test_curvature_of_the_fig1_part_counts_its_creases_and_keeps_them_out_of_the_range():
    p = CurvaturePanel({"fig1_part": fig1_part}, resolution=48, backend="image", threaded=False)
    try:
        t, shown = p.table, p.resolved
        # at a crease the level sets bend on the scale of the distance to it (1e10 and more), or
        # there is no curvature at all: grey, counted, out of the range
        bend = np.fmax(np.abs(t["kmin"]), np.abs(t["kmax"]))
        crease = ~t["defined"] | (bend * p.spacing > 2.0)
        assert crease.sum() > 0 and np.array_equal(~shown, crease)
        scalars = np.asarray(p.view.poly.point_data["values"])
        assert np.array_equal(np.isnan(scalars), crease)  # undefined -> NaN -> the grey nan colour
        lut = p.view.actor.mapper.lookup_table
        assert np.allclose(lut.nan_color.float_rgb, _rgb(UNDEFINED_COLOUR), atol=1e-2)
        # the smooth pieces: the unit sphere (H = K = 1), the cube's faces (0, 0) and the cylinders
        # of radius r = 0.5 (|H| = 1/(2r) = 1, K = 0): H's range is exactly [-1, 1] on a diverging
        # map, K's [0, 1] on a one-sided one, whatever the creases give
        span = p.colours
        assert span.undefined == int(crease.sum())
        assert span.diverging and span.clim == pytest.approx((-1.0, 1.0), abs=1e-6)
        assert f"{span.undefined} undefined (grey)" in p.status.value
        assert "% of" in p.status.value and "clipped" in p.status.value
        p.quantity.value = "Gaussian K"
        assert not p.colours.diverging and p.colours.cmap == SEQUENTIAL
        assert p.colours.clim == pytest.approx((0.0, 1.0), abs=1e-6)
        assert p.colours.clipped < 0.05
    finally:
        p.view.close()


def _rgb(hex_colour: str) -> tuple[float, float, float]:
    return tuple(int(hex_colour[i : i + 2], 16) / 255 for i in (1, 3, 5))


def test_gaussian_curvature_of_schwarz_d_is_one_sided_and_mean_curvature_centred_on_zero():
    p = CurvaturePanel({"schwarz_d": schwarz_d}, resolution=24, backend="image", threaded=False)
    try:
        p.quantity.value = "Gaussian K"
        k = p.table["K"][p.table["defined"]]
        assert k.max() < 1e-6  # a minimal surface: K <= 0 everywhere
        assert p.colours.cmap == SEQUENTIAL and p.colours.hi <= 1e-6  # no white that means -0.51
        assert p.view.actor.mapper.scalar_range[1] <= 1e-6
        p.quantity.value = "mean H"
        assert p.colours.cmap == DIVERGING and p.colours.lo == -p.colours.hi  # white is H = 0
    finally:
        p.view.close()


def test_colour_range_ignores_a_huge_value_and_masked_points():
    h = np.r_[np.linspace(-1.0, 1.0, 200), 1.999e153]
    r = colour_range(h, percentiles=(1, 99))
    assert r.hi < 1.1 and r.clipped == pytest.approx(3 / 201)  # the huge one and the two beyond +-0.99
    masked = colour_range(h, defined=np.r_[np.ones(200, bool), False], percentiles=(0, 100))
    assert masked.hi == 1.0 and masked.undefined == 1 and masked.clipped == 0.0


# -- 4. lattices are visible: a section on by default; slider labels whole ----------------------------
def test_the_microstructure_opens_cut_so_its_lattice_shows():
    p = shape_panel(microstructure, resolution=40, preview_resolution=None, backend="image", threaded=False)
    try:
        assert p.view.section.value  # on by default for a lattice
        assert 0.2 < p.view.visible_fraction() < 0.8
        cut = np.asarray(_png(p.view.widget.value))
        p.view.set_section(on=False)
        whole = np.asarray(_png(p.view.widget.value))
        assert np.abs(cut.astype(int) - whole).sum(-1).astype(bool).mean() > 0.02  # the picture opened up
        p.set_model(microstructure)
        assert p.view.section.value
    finally:
        p.view.close()
    q = shape_panel(fig1_part, resolution=24, backend="image", threaded=False)
    try:
        assert not q.view.section.value  # a solid part opens whole
    finally:
        q.view.close()


def _png(data: bytes):
    import io

    from PIL import Image

    return Image.open(io.BytesIO(bytes(data))).convert("RGB")


def test_slider_labels_are_whole_and_told_apart():
    p = shape_panel(microstructure, resolution=24, backend="image", threaded=False)
    try:
        labels = [s.description for s in p.sliders.values()]
        assert len(set(labels)) == len(labels)
        for name, s in p.sliders.items():
            assert s.description == microstructure.params[name].label
            # 13 px sans-serif: at most 7 px a character fits the label column
            assert 7 * len(s.description) <= LABEL_PX, s.description
            assert s.description in s.tooltip and name in s.tooltip
    finally:
        p.view.close()


# -- 5. the camera follows size changes -------------------------------------------------------------
def _corners_in_view(view) -> bool:
    from vtkmodules.vtkRenderingCore import vtkCoordinate

    b = view.poly.bounds
    w, h = view.plotter.window_size
    c = vtkCoordinate()
    c.SetCoordinateSystemToWorld()
    for x in b[0:2]:
        for y in b[2:4]:
            for z in b[4:6]:
                c.SetValue(x, y, z)
                px, py = c.GetComputedDisplayValue(view.plotter.renderer)
                if not (0 <= px <= w and 0 <= py <= h):
                    return False
    return True


def test_the_camera_follows_a_size_change():
    p = shape_panel(cube, resolution=24, backend="image", threaded=False, colouring="plain")
    try:
        assert _corners_in_view(p.view)
        p.bounds.value = "(-3.2, -3.2, -3.2), (3.2, 3.2, 3.2)"
        p.sliders["a"].max = 3.0
        p.sliders["a"].value = 3.0  # a box edge of 6: three times the first
        assert p.mesh.vertices.max() == pytest.approx(3.0, abs=1e-6)
        assert _corners_in_view(p.view)
        p.sliders["a"].value = 0.3  # and back down: refitted, not a speck in the middle
        assert _corners_in_view(p.view)
        assert p.view.framed[1] == pytest.approx(0.3, abs=1e-6)
    finally:
        p.view.close()


# -- 8. the legend says what the colours are, only when they are ----------------------------------
def test_the_velocity_legend_shows_only_with_the_velocity_colouring():
    p = shape_panel(ball, resolution=24, backend="image", threaded=False)
    try:
        assert p.legend.layout.display != "none"
        p.colouring.value = "plain"
        assert p.legend.layout.display == "none"
        p.colouring.value = "sensitivity"
        assert p.legend.layout.display != "none"
    finally:
        p.view.close()


# -- 6. exports: a streamed browser download, never in the repository -----------------------------
def _repo_status(path: str) -> str:
    return subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all", "--", path],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def test_export_is_a_download_served_from_outside_the_repository(monkeypatch):
    monkeypatch.chdir(ROOT / "notebooks")  # where Voila runs the notebook
    p = shape_panel(fig1_part, resolution=24, backend="image", threaded=False)
    try:
        for fmt in ("stl", "ply"):
            p.export_format.value = fmt
            path = p.export()
            assert not Path(path).resolve().is_relative_to(ROOT)
            html_link = p.download.value
            assert "data:" not in html_link and f"download fig1_part.{fmt}" in html_link
            url = html_link.split("href='")[1].split("'")[0].replace("localhost", "127.0.0.1")
            with urllib.request.urlopen(url) as r:
                assert r.headers["Content-Disposition"] == f'attachment; filename="fig1_part.{fmt}"'
                data = r.read()
            saved = Path(path).with_name(f"back.{fmt}")
            saved.write_bytes(data)
            back = load_mesh(str(saved))
            assert back.n_faces == p.exported.n_faces
            np.testing.assert_allclose(np.sort(back.vertices, axis=0), np.sort(p.exported.vertices, axis=0), atol=1e-6)
    finally:
        p.view.close()
    assert "fig1_part." not in _repo_status(str(ROOT))  # no export anywhere in the working tree


# -- 8. slice plots: readable fonts, delta_1's scale not blown out by one value --------------------
def test_slice_plots_use_readable_fonts_and_robust_colour_ranges():
    p = SlicePanel({"ellipse": ellipse}, resolution=60, threaded=False)
    delta = p.values["delta_1"]
    assert np.nanmax(np.abs(delta)) > 3 * np.nanpercentile(np.abs(delta), 99)  # near grad f = 0 it blows up
    u = v = np.linspace(-1.0, 1.0, 60)
    fig = slice_figure([u, v], p.values, p.truth, ("x", "y"))
    for ax in fig.axes:
        texts = [ax.title, ax.xaxis.label, ax.yaxis.label, *ax.get_xticklabels(), *ax.get_yticklabels()]
        for t in texts:
            if t.get_text():
                assert t.get_fontsize() >= 10, (t.get_text(), t.get_fontsize())
                # the PNG is shown at its own size, one pixel per CSS pixel (1/96 in): 10 pt is 13.3 px
                assert t.get_fontsize() * fig.dpi / 72 >= 10 * 96 / 72 - 1e-9, (t.get_text(), fig.dpi)
    top = [ax for ax in fig.axes if ax.get_title().startswith("delta_1")][0]
    levels = top.collections[0].levels if hasattr(top.collections[0], "levels") else top.collections[0].get_array()
    span = colour_range(delta, percentiles=(1, 99), diverging=True)
    assert max(abs(levels[0]), abs(levels[-1])) == pytest.approx(span.hi)
    assert span.hi < 0.5 * np.nanmax(np.abs(delta))
    assert "clipped" in top.get_title()


# -- help and intro ---------------------------------------------------------------------------------
def test_every_tab_says_what_it_shows_with_the_papers_equation_or_figure():
    from workbench.app import TABS

    for title, _ in TABS:
        if title in ("Model",):  # the user's own code: no paper figure
            continue
        text = help_box(title).value
        assert "What am I looking at?" in text, title
        assert "eq. " in HELP[title] or "Fig. " in HELP[title], title


def test_the_intro_is_short_and_names_no_port():
    import nbformat

    nb = nbformat.read(ROOT / "notebooks" / "workbench.ipynb", as_version=4)
    intro = nb.cells[0].source
    assert "8866" not in intro and "localhost" not in intro
    assert len(intro.splitlines()) <= 6


def test_image_views_never_show_an_empty_image():
    from workbench.view import MeshView

    view = MeshView(backend="image", size=(160, 120))
    try:
        assert bytes(view.widget.value[:4]) == b"\x89PNG" and _png(view.widget.value).size == (160, 120)
    finally:
        view.close()
    p = SlicePanel({"ball": ball}, resolution=24, distance_resolution=20, threaded=True)
    assert p.image.layout.display == "none" or bytes(p.image.value[:4]) == b"\x89PNG"
    p.wait()
    assert bytes(p.image.value[:4]) == b"\x89PNG" and p.image.layout.display != "none"


def test_shape_panel_default_export_dir_is_not_the_working_directory():
    import inspect

    assert inspect.signature(ShapePanel).parameters["export_dir"].default is None
