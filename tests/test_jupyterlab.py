"""The panels in JupyterLab, driven by Playwright/Chromium, with widget callbacks on a kernel subshell thread.

JupyterLab 4.6 sends widget messages over a kernel *subshell* (``commsOverSubshells``, on by
default and left on here), so widget callbacks run on a thread other than the kernel's main one,
where VTK renders black frames (or crashes the kernel).  The panels hand their renders back to the
main thread (``workbench._threads.MainThread``); this module checks that path end to end in a
notebook that does what the README says, ``workbench.shape_panel(fig1_part)``:

- a shape-panel slider move (subshell -> meshing thread -> main thread) remeshes, the status line
  follows, and the 3-D view shows a new, coloured, non-black picture;
- a curvature-panel colour toggle (subshell -> ``MainThread.call``, no worker) redraws the same way;
- a probe cell records which thread ran the last callback, so the tests fail if the callbacks stop
  coming from a subshell (the path would then go unchecked).  JupyterLab sends each comm's first
  message on the main shell and the following ones on the subshell: the actions under test are
  never a widget's first message.

In JupyterLab the 3-D views are pyvista's trame viewers (``iframe.pyvista``: frames rendered
off-screen in the kernel and streamed), not the image fallback.  Needs Debian's chromium at
/usr/bin/chromium (``make browser`` installs it) and jupyterlab.  Screenshots and the server's log
go to test-artifacts/.
"""

from __future__ import annotations

import json
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
    free_port,
    needs_chromium,
    pixels,
    record_external,
    wait_for_port,
)

JUPYTER_LAB = Path(sys.executable).with_name("jupyter-lab")

pytestmark = [
    needs_chromium,
    pytest.mark.skipif(not JUPYTER_LAB.exists(), reason=f"jupyterlab not installed ({JUPYTER_LAB} missing)"),
]
playwright_api = pytest.importorskip("playwright.sync_api")
pytest.importorskip("jupyterlab", reason="jupyterlab not installed")

CELLS = [
    # the documented use: a panel for any model, straight in a notebook
    "import workbench\n"
    "from pyfrep_core.models import fig1_part\n"
    "panel = workbench.shape_panel(fig1_part, resolution=48, compiled=False)\n"
    "panel",
    # a callback that renders without a worker thread: the colour toggle redraws through MainThread.call
    "curv = workbench.curvature_panel(models={'fig1_part': fig1_part}, resolution=48)\ncurv",
    # which thread runs the widgets' callbacks (a subshell's under JupyterLab's defaults)
    "import threading\n"
    "import ipywidgets as widgets\n"
    "probe = widgets.HTML('none yet', _dom_classes=['thread-probe'])\n"
    "def record(change):\n"
    "    probe.value = f'{change[\"owner\"].description} callback thread: {threading.current_thread().name}'\n"
    "panel.sliders['r'].observe(record, names='value')\n"
    "curv.quantity.observe(record, names='value')\n"
    "probe",
]


def processes_naming(path: Path) -> list[int]:
    """Ids of the processes whose command line contains ``path`` (this run's own directory)."""
    found = []
    for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
        try:
            if str(path).encode() in cmdline.read_bytes() and int(cmdline.parent.name) != os.getpid():
                found.append(int(cmdline.parent.name))
        except OSError:  # ended meanwhile
            pass
    return found


def notebook() -> dict:
    return {
        "cells": [
            {
                "cell_type": "code",
                "execution_count": None,
                "id": f"cell{i}",
                "metadata": {},
                "outputs": [],
                "source": src,
            }
            for i, src in enumerate(CELLS)
        ],
        "metadata": {
            "kernelspec": {"display_name": "Python 3 (ipykernel)", "language": "python", "name": "python3"},
            "language_info": {"name": "python"},
        },
        "nbformat": 4,
        "nbformat_minor": 5,
    }


@pytest.fixture(scope="module")
def lab_log() -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    return ARTIFACTS / "jupyterlab.log"  # the server's and the kernel's output


@pytest.fixture(scope="module")
def lab_url(tmp_path_factory, lab_log):
    root = tmp_path_factory.mktemp("lab")
    (root / "panel.ipynb").write_text(json.dumps(notebook(), indent=1))
    # no "notified about official Jupyter news?" toast (the news feed is off server-side too)
    settings = root / ".settings" / "@jupyterlab" / "apputils-extension"
    settings.mkdir(parents=True)
    (settings / "notification.jupyterlab-settings").write_text(json.dumps({"fetchNews": "false"}))
    runtime = root / ".runtime"
    port = free_port()
    log = open(lab_log, "w")  # noqa: SIM115 (closed in the teardown)
    env = {
        **{k: v for k, v in os.environ.items() if k != "PYFREP_VIEW"},  # the view as a user gets it ("auto")
        # user settings and workspaces of this run only: JupyterLab's defaults (subshells on), no saved layout
        "JUPYTERLAB_SETTINGS_DIR": str(root / ".settings"),
        "JUPYTERLAB_WORKSPACES_DIR": str(root / ".workspaces"),
        "JUPYTER_CONFIG_DIR": str(root / ".config"),
        "JUPYTER_RUNTIME_DIR": str(runtime),  # the kernel's connection file: its command line names it
    }
    proc = subprocess.Popen(
        [
            str(JUPYTER_LAB),
            "--no-browser",
            "--allow-root",
            f"--port={port}",
            "--ip=127.0.0.1",
            "--IdentityProvider.token=",  # ServerApp.token, without its deprecation warning
            "--ServerApp.password=",
            f"--ServerApp.root_dir={root}",
            # offline and quiet: no news feed, no update check, no PyPI extension manager
            "--LabApp.news_url=None",
            "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate",
            "--LabApp.extension_manager=readonly",
            "--ServerApp.log_level=WARN",
        ],
        cwd=root,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
    )
    try:
        wait_for_port(proc, port, "jupyter lab", lab_log)
        yield f"http://127.0.0.1:{port}/lab/tree/panel.ipynb"
    finally:
        proc.terminate()  # the server shuts its kernel down, then exits
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5)
        for pid in processes_naming(runtime):  # a kernel left behind (it runs in a session of its own)
            os.kill(pid, signal.SIGKILL)
        log.close()


@pytest.fixture(scope="module")
def external():
    """URLs the page requested from anywhere but this machine."""
    return []


def run_all_cells(pg, attempts: int = 3) -> None:
    """Run > Run All Cells once the kernel is idle; again if no cell got queued (a click made while
    the kernel's session was still connecting is dropped: seen once in about ten runs)."""
    pg.wait_for_function("document.body.innerText.includes('| Idle')", timeout=60_000)  # the status bar
    for attempt in range(attempts):
        pg.locator(".lm-MenuBar-itemLabel", has_text=re.compile(r"^Run$")).click()
        pg.locator(".lm-Menu-itemLabel", has_text=re.compile(r"^Run All Cells$")).click()
        try:  # a prompt turns from "[ ]:" into "[*]:" (queued or running) or "[1]:" (done)
            pg.wait_for_function(
                "[...document.querySelectorAll('.jp-InputPrompt')].some(p => /\\[(\\*|\\d+)\\]/.test(p.innerText))",
                timeout=15_000,
            )
            return
        except playwright_api.TimeoutError:
            if attempt == attempts - 1:
                raise


@pytest.fixture(scope="module")
def page(lab_url, external):
    """The notebook open in JupyterLab, all its cells run (Run > Run All Cells), both panels shown."""
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        pg = browser.new_page(viewport={"width": 1500, "height": 1000})
        try:
            record_external(pg, external)
            pg.goto(lab_url, wait_until="domcontentloaded", timeout=60_000)
            pg.wait_for_selector(".jp-Notebook .jp-Cell", timeout=60_000)
            run_all_cells(pg)
            pg.wait_for_selector(".thread-probe", timeout=60_000)  # the last cell ran
            pg.wait_for_function(
                "document.body.innerText.includes('remeshed in') && document.body.innerText.includes('curvatures in')",
                timeout=60_000,
            )
            yield pg
        finally:
            pg.screenshot(path=str(ARTIFACTS / "lab_page.png"), full_page=True)
            (ARTIFACTS / "jupyterlab_external_requests.txt").write_text("\n".join(external) + "\n")
            browser.close()


def picture_stats(png: bytes) -> dict[str, float]:
    """Fractions of a view's pixels: drawn (neither white background nor black), black, red, blue."""
    rgb = pixels(png)
    lo, hi = rgb.min(-1), rgb.max(-1)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    # black: dark AND neutral (a black frame); the diverging map's dark ends, shaded, are dark but coloured
    return {
        "drawn": float(((lo < 225) & (hi > 50)).mean()),
        "black": float(((hi <= 50) & (hi - lo < 12)).mean()),
        "red": float(((r > 90) & (r - g > 60) & (r - b > 50)).mean()),
        "blue": float(((b > 60) & (b - r > 40) & (b - g > 15)).mean()),
        "coloured": float((hi - lo > 60).mean()),  # any colour map's saturated colours, not grey shading
    }


def changed(png: bytes, reference: bytes) -> float:
    return float((np.abs(pixels(png) - pixels(reference)).sum(-1) > 30).mean())


def view_picture(view, path: Path, ok, timeout: float = 20.0) -> tuple[bytes, dict[str, float]]:
    """Screenshot the view until ``ok(png, stats)``: the frame streams in after the kernel renders."""
    deadline = time.monotonic() + timeout
    while True:
        png = view.screenshot(path=str(path))
        stats = picture_stats(png)
        if ok(png, stats) or time.monotonic() > deadline:
            return png, stats
        time.sleep(0.5)


def rendered(stats: dict[str, float]) -> bool:
    """A shaded, coloured part, not a black or blank frame: the Fig. 1 part fills ~30% of the view,
    under 5% is neutral black (axes labels, colour bar text), a colour map shows (diverging for signed
    quantities, one-sided for one-signed ones such as K on this part)."""
    return stats["drawn"] > 0.15 and stats["black"] < 0.05 and stats["coloured"] > 0.05


def trame_view(page, index: int):
    """The index-th 3-D view: pyvista's trame viewer (frames rendered in the kernel, streamed to an iframe)."""
    view = page.locator("iframe.pyvista").nth(index)
    view.wait_for(timeout=30_000)
    page.frame_locator("iframe.pyvista").nth(index).locator("canvas").first.wait_for(timeout=30_000)
    return view


def callback_thread(page, widget: str) -> str:
    """The thread the kernel ran ``widget``'s last value callback on (the probe cell)."""
    page.wait_for_function(
        f"document.querySelector('.thread-probe').innerText.startsWith('{widget} callback thread: ')", timeout=10_000
    )
    return page.locator(".thread-probe").inner_text().split("callback thread: ")[1].strip()


def test_shape_slider_remeshes_and_renders(page):
    """Slider (subshell) -> worker thread meshes -> main thread renders -> trame frame and status line."""
    assert page.locator("iframe.pyvista").count() == 2  # JupyterLab gets the trame views, not the image fallback
    view = trame_view(page, 0)
    status = page.locator(".widget-html-content", has_text="remeshed in").first
    before_text = status.inner_text()
    # marching cubes, then dual contouring (the part has interval bounds): either may be shown, and
    # dual contouring runs compiled once the kernels compiled in the background are there
    line = r"remeshed in \d+ ms \((eager|compiled)\), \d+ triangles \(48³(, dual contouring)?; r = {}\)"
    assert re.search(line.format("0.5"), before_text), before_text
    before, stats = view_picture(view, ARTIFACTS / "lab_shape_before.png", lambda png, st: rendered(st))
    assert rendered(stats) and stats["red"] > 0.005, f"first frame is not the coloured part: {stats}"

    handle = page.locator(".widget-slider .noUi-handle").first
    handle.focus()
    for _ in range(25):  # 25 steps of 0.002 (range/200 rounded down to 1, 2, 5 x 10^k): r 0.5 -> 0.55
        page.keyboard.press("ArrowRight")
    page.wait_for_function("document.body.innerText.includes('r = 0.55')", timeout=30_000)
    after_text = status.inner_text()
    assert re.search(line.format("0.55"), after_text), after_text
    n_before = int(re.search(r"(\d+) triangles", before_text).group(1))
    n_after = int(re.search(r"(\d+) triangles", after_text).group(1))
    assert n_after != n_before
    # the last moves' callbacks came on a subshell thread (JupyterLab sends a comm's first message on
    # the main shell, the rest on the subshell): the path under test, not the main-thread one
    thread = callback_thread(page, "cylinder radius")
    assert thread != "MainThread", "slider callbacks ran on the main thread: are JupyterLab's kernel subshells off?"

    after, stats = view_picture(
        view, ARTIFACTS / "lab_shape_after.png", lambda png, st: changed(png, before) > 0.005 and rendered(st)
    )
    assert changed(after, before) > 0.005, f"only {changed(after, before):.2%} of the view's pixels changed"
    assert rendered(stats) and stats["red"] > 0.005, f"the view after the move is no coloured part: {stats}"


def test_curvature_toggle_redraws(page):
    """Toggle (subshell) -> MainThread.call hops to the main thread -> new colours in the trame frame."""
    view = trame_view(page, 1)
    status = page.locator(".widget-html-content", has_text="curvatures in").first
    assert "H: median" in status.inner_text()
    first, stats = view_picture(view, ARTIFACTS / "lab_curvature_first.png", lambda png, st: rendered(st))
    assert rendered(stats), f"first curvature frame is not the coloured part: {stats}"
    # JupyterLab sends a comm's first message on the main shell, the following ones on the subshell:
    # one click first, so that the click under test arrives on the subshell
    page.get_by_role("button", name="kmin").click()
    page.wait_for_function("document.body.innerText.includes('kmin: median')", timeout=30_000)
    before, stats = view_picture(
        view, ARTIFACTS / "lab_curvature_before.png", lambda png, st: changed(png, first) > 0.005 and rendered(st)
    )
    assert rendered(stats), f"kmin frame is not the coloured part: {stats}"

    page.get_by_role("button", name="Gaussian K").click()
    page.wait_for_function("document.body.innerText.includes(' K: median')", timeout=30_000)
    assert callback_thread(page, "colour") != "MainThread", "the toggle's callback ran on the main thread"
    after, stats = view_picture(
        view, ARTIFACTS / "lab_curvature_after.png", lambda png, st: changed(png, before) > 0.005 and rendered(st)
    )
    assert changed(after, before) > 0.005, f"only {changed(after, before):.2%} of the view's pixels changed"
    assert rendered(stats), f"the view after the toggle is no coloured part: {stats}"


def test_kernel_and_page_stayed_clean(page, lab_log, external):
    """Last: no traceback in the cells, no VTK error or kernel restart in the log, nothing fetched from outside."""
    assert page.locator(".jp-OutputArea-output", has_text="Traceback").count() == 0
    assert page.locator(".widget-html-content span[style*='#b00']").count() == 0  # the panels' error lines
    log = lab_log.read_text()
    for bad in ("Traceback", "Exception in callback", "ERR|", "restarted", "died"):
        assert bad not in log, f"{bad!r} in {lab_log}:\n{log[-3000:]}"
    assert external == [], external
