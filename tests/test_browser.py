"""The workbench in a real browser: Voila serves notebooks/workbench.ipynb, Playwright drives Chromium.

One Voila server for the module (it is heavy); screenshots go to test-artifacts/.
Needs Debian's chromium at /usr/bin/chromium (``make browser`` installs it).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from browser_support import (
    ARTIFACTS,
    CHROMIUM,
    CHROMIUM_ARGS,
    ROOT,
    free_port,
    needs_chromium,
    pixels,
    record_external,
    wait_for_port,
)

pytestmark = needs_chromium
playwright_api = pytest.importorskip("playwright.sync_api")


@pytest.fixture(scope="module")
def voila_url():
    port = free_port()
    ARTIFACTS.mkdir(exist_ok=True)
    log = open(ARTIFACTS / "voila.log", "w")  # noqa: SIM115 (closed in the teardown)
    voila = Path(sys.executable).with_name("voila")
    proc = subprocess.Popen(
        [
            str(voila),
            "notebooks/workbench.ipynb",
            "--no-browser",
            f"--port={port}",
            "--template=pyfrep",  # workbench/jupyter: the lab page without CDN stylesheets
            "--MappingKernelManager.cull_idle_timeout=120",
            "--MappingKernelManager.cull_interval=30",
        ],
        cwd=ROOT,
        env={**os.environ, "JUPYTER_PATH": str(ROOT / "workbench" / "jupyter")},
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        wait_for_port(proc, port, "voila", ARTIFACTS / "voila.log")
        yield f"http://127.0.0.1:{port}/"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)  # voila and the kernels it started
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
        log.close()


@pytest.fixture(scope="module")
def external():
    """URLs the page requested from anywhere but this machine."""
    return []


@pytest.fixture(scope="module")
def console():
    """Console errors and HTTP error responses of the page, from its first request on."""
    return []


@pytest.fixture(scope="module")
def page(voila_url, external, console):
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            pg = browser.new_page(viewport={"width": 1500, "height": 1000}, accept_downloads=True)
            record_external(pg, external)
            pg.on("console", lambda m: console.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            pg.on("response", lambda r: console.append(f"HTTP {r.status} {r.url}") if r.status >= 400 else None)
            pg.goto(voila_url, wait_until="domcontentloaded", timeout=120_000)  # "load" may never fire
            pg.wait_for_selector(".widget-slider", timeout=240_000)
            yield pg
        finally:
            (ARTIFACTS / "external_requests.txt").write_text("\n".join(external) + "\n")
            browser.close()


def status_text(pg) -> str:
    return pg.locator(".widget-html-content", has_text="remeshed in").last.inner_text()


def view_locator(pg):
    frame = pg.locator("iframe.pyvista")
    if frame.count():
        return frame.first
    return pg.locator(".widget-image").first  # off-screen image fallback


def test_slider_remeshes_and_the_view_changes(page):
    page.wait_for_function("document.body.innerText.includes('remeshed in')", timeout=240_000)
    # let the full-resolution mesh replace the preview before the reference picture
    page.wait_for_function("document.body.innerText.includes('128³')", timeout=240_000)
    view = view_locator(page)
    view.scroll_into_view_if_needed()
    time.sleep(2.0)
    before_text = status_text(page)
    before = view.screenshot(path=str(ARTIFACTS / "shape_before.png"))
    assert "r = 0.5;" in before_text or "r = 0.5)" in before_text

    handle = page.locator(".widget-slider .noUi-handle").first
    handle.focus()
    for _ in range(25):  # 25 steps of 0.002 (range/200 rounded down to 1, 2, 5 x 10^k): r 0.5 -> 0.55
        page.keyboard.press("ArrowRight")
    page.wait_for_function(
        "document.body.innerText.includes('r = 0.55') && document.body.innerText.includes('128³')", timeout=240_000
    )
    after_text = status_text(page)
    assert re.search(r"remeshed in \d+ ms \((compiled|eager)\), \d+ triangles", after_text)
    n_before = int(re.search(r"(\d+) triangles", before_text).group(1))
    n_after = int(re.search(r"(\d+) triangles", after_text).group(1))
    assert n_after != n_before

    deadline = time.monotonic() + 30  # the picture follows the render
    while True:
        after = view.screenshot(path=str(ARTIFACTS / "shape_after.png"))
        changed = (np.abs(pixels(after) - pixels(before)).sum(-1) > 30).mean()
        if changed > 0.005 or time.monotonic() > deadline:
            break
        time.sleep(1.0)
    page.screenshot(path=str(ARTIFACTS / "shape_page.png"))
    assert changed > 0.005, f"only {changed:.2%} of the view's pixels changed"

    # the model's kernels compile in the kernel's background after the first mesh; then moves run compiled
    # (marching cubes at full resolution says so, and dual contouring's mesh that replaces it)
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    deadline = time.monotonic() + 240
    key = "ArrowLeft"
    compiled_mesh = (  # the status line's text at the moment it says "(compiled)"
        "() => { const s = [...document.querySelectorAll('.widget-html-content')]"
        ".filter(e => e.innerText.includes('remeshed in')).pop();"
        " return s && s.innerText.includes('(compiled)') ? s.innerText : false; }"
    )
    compiled_text = ""
    while time.monotonic() < deadline:
        handle.focus()
        page.keyboard.press(key)
        key = "ArrowRight" if key == "ArrowLeft" else "ArrowLeft"
        try:
            compiled_text = page.wait_for_function(compiled_mesh, timeout=3_000, polling=50).json_value()
            break
        except PlaywrightTimeout:
            continue
    page.screenshot(path=str(ARTIFACTS / "shape_compiled.png"))
    assert "(compiled)" in compiled_text, compiled_text
    assert int(re.search(r"(\d+) triangles", compiled_text).group(1)) > 0


RAN: set[str] = set()  # what ran in this page, for the last test (a later model change clears the fit's status)


def test_fit_runs_chart_grows_and_loss_goes_down(page):
    page.get_by_role("tab", name="Fitting").click()
    run = page.get_by_role("button", name="Run")
    run.wait_for(timeout=240_000)
    page.wait_for_function("document.body.innerText.includes('points sampled')", timeout=240_000)
    charts = page.locator(".jupyter-widgets.widget-image")
    before = [charts.nth(i).get_attribute("src") for i in range(charts.count())]
    run.click()
    page.wait_for_selector(".fit-progress", timeout=120_000)
    page.screenshot(path=str(ARTIFACTS / "fit_running.png"))
    page.wait_for_selector(".fit-done", timeout=400_000)
    page.screenshot(path=str(ARTIFACTS / "fit_done.png"))
    after = [charts.nth(i).get_attribute("src") for i in range(charts.count())]
    assert len(after) >= 2 and sum(a != b for a, b in zip(before, after)) >= 2  # loss and parameter charts redrawn

    progress = page.locator(".fit-progress").inner_text()
    charted = int(re.search(r"(\d+) points charted", progress).group(1))
    assert charted >= 3
    first = float(re.search(r"first ([0-9.e+-]+)", progress).group(1))
    final = float(re.search(r"loss ([0-9.e+-]+), stages", page.locator(".fit-done").inner_text()).group(1))
    assert final < first
    RAN.add("fit")


STUDENT_MODEL = """\
import torch
from pyfrep_core import *


@model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(0.9, 0.3, 1.0, label="ball radius"), h=Param(0.3, 0.05, 0.5))
def student_ball(x, r, h):
    return difference(sphere(x, r=r), cylZ(x, r=h))
"""


def test_model_typed_in_the_editor_opens_in_the_shape_view(page):
    page.get_by_role("tab", name="Shape").click()
    page.wait_for_function("document.body.innerText.includes('128³')", timeout=240_000)
    view = view_locator(page)
    view.scroll_into_view_if_needed()
    time.sleep(2.0)
    before = view.screenshot(path=str(ARTIFACTS / "model_shape_before.png"))

    page.get_by_role("tab", name="Model").click()
    panel = page.locator(".pyfrep-model-panel")
    editor = panel.locator(".pyfrep-code textarea")
    editor.wait_for(timeout=240_000)
    editor.fill(STUDENT_MODEL.rsplit("\n", 2)[0] + "\n")  # all but the last line, then type it
    editor.press("Control+End")
    editor.press("Tab")  # indents by 4 spaces: the focus stays in the editor
    editor.press_sequentially("return difference(sphere(x, r=r), cylZ(x, r=h))\n")
    assert editor.evaluate("t => t === document.activeElement")
    assert editor.input_value() == STUDENT_MODEL
    editor.press("Shift+Tab")  # on an empty line: nothing to dedent
    editor.press("Control+a")
    editor.press("Tab")  # the selection's lines indented, then dedented back
    assert editor.input_value().splitlines()[5] == "    def student_ball(x, r, h):"
    editor.press("Shift+Tab")
    assert editor.input_value() == STUDENT_MODEL
    gutter, lines = panel.locator(".pyfrep-gutter pre"), str(STUDENT_MODEL.count("\n") + 1)
    deadline = time.monotonic() + 60  # the kernel renumbers the gutter as the text arrives
    while gutter.inner_text().split()[-1] != lines and time.monotonic() < deadline:
        time.sleep(0.2)
    page.screenshot(path=str(ARTIFACTS / "model_typed.png"))
    assert gutter.inner_text().split()[-1] == lines
    panel.get_by_role("button", name="Run").click()
    page.wait_for_function("document.body.innerText.includes('student_ball built in')", timeout=240_000)
    page.screenshot(path=str(ARTIFACTS / "model_tab.png"))
    status = panel.locator(".widget-html-content", has_text="student_ball built").inner_text()
    assert "opened in Shape" in status, status
    assert panel.get_by_text("ball radius").first.is_visible()  # the preview's slider for r

    page.get_by_role("tab", name="Shape").click()
    page.wait_for_function(
        "document.body.innerText.includes('r = 0.9, h = 0.3') && document.body.innerText.includes('128³')",
        timeout=240_000,
    )
    assert page.get_by_text("ball radius").first.is_visible()
    deadline = time.monotonic() + 30  # the picture follows the render
    while True:
        after = view.screenshot(path=str(ARTIFACTS / "model_shape_after.png"))
        changed = (np.abs(pixels(after) - pixels(before)).sum(-1) > 30).mean()
        if changed > 0.05 or time.monotonic() > deadline:
            break
        time.sleep(1.0)
    assert changed > 0.05, f"only {changed:.2%} of the shape view's pixels changed"

    # a syntax error: the line is marked in the gutter and named in the status
    page.get_by_role("tab", name="Model").click()
    editor.fill(STUDENT_MODEL.replace("cylZ(x, r=h))", "cylZ(x, r=h)"))
    panel.get_by_role("button", name="Run").click()
    bad = panel.locator(".pyfrep-gutter .bad")
    bad.wait_for(timeout=60_000)
    assert bad.inner_text() == "7"  # the return line, whose parenthesis is never closed
    page.screenshot(path=str(ARTIFACTS / "model_error.png"))
    assert "line 7" in panel.inner_text()


def select_model(pg, name: str) -> None:
    """Choose ``name`` in the visible tab's model menu."""
    menu = pg.locator("select:visible").filter(has=pg.locator(f"option[value='{name}']")).first
    menu.select_option(name)


def test_the_page_opens_with_a_short_intro_help_and_no_console_errors(page, console):
    page.get_by_role("tab", name="Shape").click()
    tabs = page.locator(".lm-TabBar-tab, .p-TabBar-tab").first.bounding_box()
    assert tabs["y"] < 200, f"the tabs start {tabs['y']:.0f} px down the page"  # was 280 px of intro
    assert "8866" not in page.locator("body").inner_text()  # the port is the browser's business
    help_text = page.locator(".pyfrep-help:visible").first.inner_text()
    assert help_text.startswith("What am I looking at?") and "Fig. 1" in help_text
    # no broken-image icons: every image shown has a picture
    empty = page.evaluate(
        "[...document.querySelectorAll('img')].filter(i => i.offsetParent !== null && i.naturalWidth === 0).length"
    )
    assert empty == 0
    # no shared-module error from jupyter-server-proxy's lab extension, no 405 from trame's /paraview/
    (ARTIFACTS / "console_errors.txt").write_text("\n".join(console) + "\n")
    assert console == []


def test_export_is_a_browser_download_and_the_page_stays_connected(page):
    page.get_by_role("tab", name="Shape").click()
    select_model(page, "fig1_part")
    page.wait_for_function("document.body.innerText.includes('r = 0.5')", timeout=240_000)
    page.locator("select:visible").filter(has=page.locator("option[value='ply']")).first.select_option("ply")
    page.get_by_role("button", name="Export").click()
    link = page.locator("a.pyfrep-download:visible")
    link.wait_for(timeout=120_000)
    assert "data:" not in (link.get_attribute("href") or "")
    with page.expect_download(timeout=120_000) as info:
        link.click()
    saved = ARTIFACTS / info.value.suggested_filename
    info.value.save_as(str(saved))
    from pyfrep_core import load_mesh

    mesh = load_mesh(str(saved))
    assert saved.name == "fig1_part.ply" and mesh.n_faces > 1000
    np.testing.assert_allclose(np.abs(mesh.vertices).max(), 0.75, atol=1e-6)  # the cube's faces at +-0.75
    git = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT, capture_output=True, text=True
    )
    assert "fig1_part.ply" not in git.stdout  # nothing written into the repository (Voila runs in notebooks/)
    # the page is still the app, connected to its kernel: a slider move still remeshes
    handle = page.locator(".widget-slider:visible .noUi-handle").first
    handle.focus()
    page.keyboard.press("ArrowRight")
    page.wait_for_function("document.body.innerText.includes('r = 0.502')", timeout=240_000)
    assert page.locator("text=Connection closed").count() == 0


def test_redistancing_stop_stops_and_says_where(page):
    page.get_by_role("tab", name="Redistancing").click()
    train = page.get_by_role("button", name="Train")
    train.wait_for(timeout=240_000)
    train.click()
    page.wait_for_selector(".train-progress", timeout=240_000)
    page.get_by_role("button", name="Stop").click()
    page.wait_for_selector(".train-done", timeout=300_000)
    time.sleep(3.0)  # a late answer to the click would land now
    done = page.locator(".train-done").inner_text()
    progress = page.locator(".train-progress").inner_text()
    page.screenshot(path=str(ARTIFACTS / "redistancing_stopped.png"))
    step, total = (int(v) for v in re.search(r"(\d+)/(\d+)", progress).groups())
    assert "stopping" not in page.locator("body").inner_text()
    if step < total:
        assert f"stopped early at step {step}" in done, (done, progress)
    else:  # training ended before the click arrived: then it must not claim to have stopped
        assert "stopped" not in done, (done, progress)


def test_the_microstructure_opens_cut_with_whole_slider_labels(page):
    page.get_by_role("tab", name="Shape").click()
    select_model(page, "microstructure")
    page.wait_for_function("document.body.innerText.includes('slab threshold at the centre')", timeout=120_000)
    labels = page.locator(".widget-slider:visible .widget-label")
    texts = [labels.nth(i).inner_text() for i in range(labels.count())]
    assert "slab threshold near the shell" in texts and "slab threshold at the centre" in texts
    cut = page.evaluate(
        "[...document.querySelectorAll('.widget-slider .widget-label')].filter(l => l.offsetParent !== null"
        " && l.scrollWidth > l.clientWidth + 1).map(l => l.textContent)"
    )
    assert cut == [], f"labels cut: {cut}"
    section = page.get_by_role("checkbox", name="section")
    assert section.first.is_checked()  # a lattice opens with its section on
    page.screenshot(path=str(ARTIFACTS / "microstructure.png"))


def test_dragging_the_surface_in_the_view_moves_the_sliders(page):
    """The trame view sends press, moves and release to the kernel's interactor: a drag pulls the surface."""
    page.get_by_role("tab", name="Shape").click()
    select_model(page, "pawn")
    page.wait_for_function("document.body.innerText.includes('head_radius = ')", timeout=240_000)
    page.wait_for_function("document.body.innerText.includes('128³')", timeout=240_000)
    sliders = page.locator(".widget-slider:visible .widget-readout")
    before = [sliders.nth(i).inner_text() for i in range(sliders.count())]
    page.get_by_role("button", name="drag the surface").click()
    # the kernel has the mode when its status says so (a drag it sees before would turn the view)
    page.wait_for_function("document.body.innerText.includes('drag the surface is on')", timeout=60_000)
    box = view_locator(page).bounding_box()
    x, y = box["x"] + 0.5 * box["width"], box["y"] + 0.5 * box["height"]  # the pawn's body
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, 9):
        page.mouse.move(x + k, y + 3 * k)  # down the screen: the normal there points down and out
        time.sleep(0.1)
    page.mouse.up()
    status = page.locator(".widget-html-content:visible", has_text=re.compile(r"^push-pull: ")).first
    deadline = time.monotonic() + 120
    while any(waiting in status.inner_text() for waiting in ("picked", "click the surface", "is on")):
        assert time.monotonic() < deadline, status.inner_text()
        time.sleep(0.5)
    page.screenshot(path=str(ARTIFACTS / "push_pull_drag.png"))
    text = status.inner_text()
    assert re.search(r"[+-]\d", text) and ("passes through the target" in text or "short of the target" in text), text
    after = [sliders.nth(i).inner_text() for i in range(sliders.count())]
    assert after != before  # the pull and the parameters it solved for moved
    page.get_by_role("button", name="drag the surface").click()


def test_nothing_is_fetched_from_the_internet(page, external):
    """Last test: every request of the page (shape tab, fit, trame views) went to this machine."""
    assert "fit" in RAN  # the fit's requests are among those checked
    assert external == []
