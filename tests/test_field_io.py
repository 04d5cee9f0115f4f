"""save_field: grids of f and derived fields written as VTK image data, read back with pyvista.

Values are compared with closed forms at the grid points rebuilt independently (numpy, VTK's
x-fastest order), and the band mode with the dense grid: every evaluated point bit for bit,
every other point of the proved sign and beyond the band.
"""

from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest
import pyvista as pv
import torch

from pyfrep_core import sdf, sphere
from pyfrep_core.field_io import save_field
from pyfrep_core.models import ellipse, fig1_part


def _grid_points(lo, hi, n):
    """Grid points (N, d) in VTK's order: x fastest, then y, then z."""
    axes = [np.linspace(a, b, k) for a, b, k in zip(lo, hi, n, strict=True)]
    mesh = np.meshgrid(*axes[::-1], indexing="ij")[::-1]  # (z, y, x) arrays, C order = x fastest
    return np.stack([m.ravel() for m in mesh], axis=-1)


def test_dense_round_trip_against_closed_forms(tmp_path):
    lo, hi, n = (-1.2, -1.0, -0.9), (1.0, 1.3, 0.8), (9, 11, 13)  # every axis different: order checked
    path = tmp_path / "ball.vti"
    grid = save_field(
        path,
        lambda x, r: sphere(x, r=r),
        (lo, hi),
        n,
        extra=("grad_norm", "omega1", ("distance", lambda x: sdf.sphere(x, r=1.0))),
        r=1.0,
    )
    back = pv.read(path)
    assert back.dimensions == n and sorted(back.point_data.keys()) == ["distance", "f", "grad_norm", "omega1"]
    np.testing.assert_allclose(back.origin, lo, rtol=0, atol=1e-15)
    np.testing.assert_allclose(back.spacing, [(b - a) / (k - 1) for a, b, k in zip(lo, hi, n)], rtol=1e-15)
    p = _grid_points(lo, hi, n)
    np.testing.assert_allclose(back.points, p, rtol=0, atol=1e-12)
    rho = np.linalg.norm(p, axis=1)
    f = 1.0 - rho**2
    np.testing.assert_allclose(back["f"], f, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back["grad_norm"], 2.0 * rho, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back["omega1"], f / np.sqrt(f**2 + 4.0 * rho**2), rtol=0, atol=1e-14)
    np.testing.assert_allclose(back["distance"], 1.0 - rho, rtol=0, atol=1e-14)
    assert back["f"].dtype == np.float64
    np.testing.assert_array_equal(grid["f"], back["f"])


def test_band_evaluates_only_near_the_surface_and_proves_the_rest(tmp_path):
    n, w = 33, 0.05
    save_field(tmp_path / "dense.vti", fig1_part, fig1_part.bounds, n)
    dense = pv.read(tmp_path / "dense.vti")
    banded = save_field(tmp_path / "band.vti", fig1_part, fig1_part.bounds, n, band=w, extra=("grad_norm",))
    back = pv.read(tmp_path / "band.vti")
    evaluated = back["evaluated"].astype(bool)
    np.testing.assert_array_equal(back["f"][evaluated], dense["f"][evaluated])
    f_out = dense["f"][~evaluated]
    assert (np.abs(f_out) > w).all()  # every unevaluated point is proved beyond the band ...
    np.testing.assert_array_equal(back["f"][~evaluated], np.where(f_out > 0, w, -w))  # ... of its sign
    assert np.isnan(back["grad_norm"][~evaluated]).all() and np.isfinite(back["grad_norm"][evaluated]).all()
    # the band is a thin shell: the surface's cells and their neighbours, not the grid
    assert evaluated.mean() < 0.35
    assert (np.abs(dense["f"]) <= w).sum() <= evaluated.sum()
    np.testing.assert_array_equal(banded["evaluated"], back["evaluated"])


def test_band_falls_back_to_dense_for_models_without_interval_rules(tmp_path):
    def sorted_ball(x):
        return 1.0 - torch.sort(x * x, dim=1).values.sum(1)

    with pytest.warns(RuntimeWarning, match="'sort' has no interval rule"):
        grid = save_field(tmp_path / "s.vti", sorted_ball, ((-1,) * 3, (1,) * 3), 5, band=0.1)
    assert grid["evaluated"].all()
    p = _grid_points((-1,) * 3, (1,) * 3, (5,) * 3)
    np.testing.assert_allclose(grid["f"], 1.0 - (p * p).sum(1), rtol=0, atol=1e-15)


def test_planar_model_and_float32(tmp_path):
    grid = save_field(tmp_path / "e.vti", ellipse, ellipse.bounds, (15, 9), dtype=torch.float32, a=4.0)
    back = pv.read(tmp_path / "e.vti")
    assert back.dimensions == (15, 9, 1) and back["f"].dtype == np.float32
    p = _grid_points(*ellipse.bounds, (15, 9))
    np.testing.assert_allclose(back["f"], 1.0 - (p[:, 0] / 4.0) ** 2 - (p[:, 1] / 2.0) ** 2, rtol=0, atol=2e-6)
    assert grid.n_points == 15 * 9


def test_stop_writes_nothing(tmp_path):
    flag = threading.Event()
    flag.set()
    assert save_field(tmp_path / "x.vti", fig1_part, fig1_part.bounds, 9, stop=flag) is None
    assert not (tmp_path / "x.vti").exists()
    events = []
    save_field(tmp_path / "y.vti", fig1_part, fig1_part.bounds, 9, band=0.1, callback=events.append)
    assert events and events[-1].stage == "save_field"


def test_bad_arguments_are_refused(tmp_path):
    box = ((-1,) * 3, (1,) * 3)
    with pytest.raises(ValueError, match=r"\.vti"):
        save_field(tmp_path / "a.vtk", sphere, box, 5)
    with pytest.raises(ValueError, match="at least 2"):
        save_field(tmp_path / "a.vti", sphere, box, 1)
    with pytest.raises(ValueError, match="'curl'"):
        save_field(tmp_path / "a.vti", sphere, box, 5, extra=("curl",))
    with pytest.raises(ValueError, match="band"):
        save_field(tmp_path / "a.vti", sphere, box, 5, band=-1.0)
    with pytest.raises(ValueError, match="distinct"):
        save_field(tmp_path / "a.vti", sphere, box, 5, extra=(("f", sphere),))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_field(tmp_path / "ok.vti", sphere, box, 3)
