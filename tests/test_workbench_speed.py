"""The slider's round trip without a browser: a quick preview first, then the full-resolution mesh,
which a newer move stops (never shown stale)."""

from __future__ import annotations

import functools
import threading

import numpy as np
import pytest

from pyfrep_core.models import fig1_part
from workbench._threads import LatestWorker, MainThread
from workbench.shape_panel import shape_panel


def test_a_newer_move_stops_the_full_resolution_mesh_and_it_is_never_shown():
    delivered: list[str] = []
    started = threading.Event()

    def compute(job: str) -> str:
        if job == "full 1":  # a long build: it ends when told that a newer move waits
            started.set()
            assert worker.superseded.wait(10.0)
        return job

    worker = LatestWorker(compute, lambda job, result, error: delivered.append(result), MainThread(), settle=0.0)
    worker.submit("preview 1", followup="full 1")
    assert started.wait(10.0)
    worker.submit("preview 2", followup="full 2")
    worker.wait(10.0)
    assert delivered == ["preview 1", "preview 2", "full 2"]
    assert worker.dropped == 1 and not worker.superseded.is_set()


def test_preview_keeps_marching_cubes_vertices_then_the_full_mesh_at_once():
    p = shape_panel(fig1_part, resolution=40, preview_resolution=24, backend="image", threaded=True)
    try:
        p.wait()
        shown: list[tuple[int, float]] = []
        deliver = p.worker.deliver

        def record(job, result, error):
            x = result["mesh"].vertices
            f = functools.partial(fig1_part, **job["params"])
            eps = 1e-6  # |grad f| by central differences: |f| / |grad f| is the distance to f = 0
            grad = [f(x + eps * e) - f(x - eps * e) for e in np.eye(3)]
            distance = np.abs(f(x)) / (np.linalg.norm(grad, axis=0) / (2 * eps))
            shown.append((job["resolution"], float(distance.max()), bool(result["dc"])))
            deliver(job, result, error)

        p.worker.deliver = record
        p.sliders["r"].value = 0.4
        p.wait()
        # the preview, then at once the full marching-cubes mesh, then dual contouring's (interval bounds)
        assert [(res, dc) for res, _, dc in shown] == [(24, False), (40, False), (40, True)]
        cell = 2.2 / 23  # the preview's grid step (fig1_part's box is 2.2 wide)
        assert 1e-6 < shown[0][1] < cell  # linear interpolation along the edges: off f = 0, within a cell
        assert shown[1][1] < 1e-9  # the full marching-cubes mesh: projected onto f = 0
        assert shown[2][1] < 2.2 / 39  # dual contouring: within one of its own cells of f = 0
        assert p.last_job["params"]["r"] == pytest.approx(0.4)
    finally:
        p.view.close()
