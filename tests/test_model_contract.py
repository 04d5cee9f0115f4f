"""The model calling contract: every entry hands a model (N, d) points and 0-d parameters.

A recording model notes the shape of every point tensor and the kind of every parameter it is
called with; each entry of the kernel (meshing, grids, parameter sets, derivatives, sampling,
fitting, the slice panel) is run through it and every recorded call is checked.  Then: the
paper's ``p[:, i]`` style meshes to its closed-form volume, parameter sets built into tuples,
``torch.stack`` and ``torch.where`` run through vmap with gradients, a model vmap cannot run
falls back to a loop with one warning, a wrong output shape is a ValueError naming the model,
and a 256^3 grid of a user model stays within the call budget.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
import torch

from pyfrep_core import (
    Param,
    _array,
    block,
    curvatures,
    ellipsoid,
    fit,
    grad,
    hessian,
    model,
    param_grad,
    polygonize,
    sample_surface,
    sphere,
    union,
)
from pyfrep_core import evaluate as ev
from pyfrep_core.meshing import evaluate_grid

F64 = torch.float64
BOX = ((-1.2,) * 3, (1.2,) * 3)
CALLS: list[tuple[tuple[int, ...], list[str]]] = []


def _kind(v) -> str:
    if isinstance(v, bool) or not isinstance(v, int | float | torch.Tensor):
        return f"bad {type(v).__name__}"
    if isinstance(v, torch.Tensor):
        return "0-d tensor" if v.ndim == 0 else f"tensor of shape {tuple(v.shape)}"
    return "number"


@model(bounds=BOX, r=Param(1.0, 0.5, 1.1), cx=Param(0.0, -0.2, 0.2))
def recorder(p, r, cx):
    """A ball of radius r centred at (cx, 0, 0), the centre a tuple built from a parameter."""
    CALLS.append((tuple(p.shape), [_kind(r), _kind(cx)]))
    return sphere(p, center=(cx, 0.0, 0.0), r=r)


def _assert_contract(calls, d=3):
    assert calls, "the model was not called"
    for shape, kinds in calls:
        assert len(shape) == 2 and shape[1] == d, f"called with points of shape {shape}"
        assert all(k == "0-d tensor" for k in kinds), f"called with parameters {kinds}"


@pytest.fixture
def calls():
    CALLS.clear()
    yield CALLS
    _assert_contract(CALLS)


def test_polygonize_dense_and_sparse(calls):
    for sparse in (False, True):
        m = polygonize(recorder, resolution=24, sparse=sparse)
        assert m.volume() == pytest.approx(4 / 3 * math.pi, rel=(2.4 / 23) ** 2)


def test_evaluate_grid(calls):
    v = evaluate_grid(recorder, BOX, (5, 6, 7))
    axes = [np.linspace(-1.2, 1.2, n) for n in (5, 6, 7)]
    xx, yy, zz = np.meshgrid(*axes, indexing="ij")
    np.testing.assert_allclose(v, 1.0 - (xx**2 + yy**2 + zz**2), rtol=0, atol=1e-6)


def test_parameter_sets_give_b_by_n_through_vmap_with_gradients(calls):
    x = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.1, -0.2], [1.0, 0.0, 0.0]], dtype=F64)
    r = torch.tensor([0.6, 0.8, 1.0, 1.1], dtype=F64, requires_grad=True)
    cx = torch.tensor([0.0, 0.1, -0.1, 0.2], dtype=F64, requires_grad=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # vmap runs it: no fallback
        out = recorder(x, r=r, cx=cx)
    assert out.shape == (4, 3)
    expected = r[:, None] ** 2 - ((x[:, 0] - cx[:, None]) ** 2 + x[:, 1] ** 2 + x[:, 2] ** 2)
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-15)
    # d/dr sum_i f = 2 r N, d/dcx sum_i f = sum_i 2 (x_i - cx)
    gr, gcx = torch.autograd.grad(out.sum(), (r, cx))
    torch.testing.assert_close(gr, 2 * r.detach() * 3, rtol=0, atol=1e-14)
    torch.testing.assert_close(gcx, 2 * (x[:, 0].sum() - 3 * cx.detach()), rtol=0, atol=1e-14)
    # a grid of points (4, 5, 3) with 2 sets: (2, 4, 5), each set its own scalar call
    grid = torch.rand(4, 5, 3, dtype=F64, generator=torch.Generator().manual_seed(0))
    two = recorder(grid, r=torch.tensor([0.7, 0.9], dtype=F64))
    assert two.shape == (2, 4, 5)
    torch.testing.assert_close(two[1], recorder(grid, r=0.9), rtol=0, atol=0)


def test_derivatives(calls):
    x = torch.tensor([[0.3, 0.4, 0.0], [0.0, 0.6, 0.8]], dtype=F64)
    f = lambda p: recorder(p, r=1.0, cx=0.1)  # noqa: E731
    torch.testing.assert_close(grad(f, x), -2 * (x - torch.tensor([0.1, 0.0, 0.0], dtype=F64)), rtol=0, atol=1e-14)
    torch.testing.assert_close(hessian(f, x), (-2 * torch.eye(3, dtype=F64)).expand(2, 3, 3), rtol=0, atol=1e-14)
    on = torch.tensor([[1.1, 0.0, 0.0], [0.1, 0.6, 0.8]], dtype=F64)  # on the unit sphere about (0.1, 0, 0)
    c = curvatures(f, on)
    torch.testing.assert_close(c.H, torch.ones(2, dtype=F64), rtol=0, atol=1e-12)
    torch.testing.assert_close(c.K, torch.ones(2, dtype=F64), rtol=0, atol=1e-12)


def test_sample_surface(calls):
    pts = sample_surface(recorder, 200, params={"r": 0.9, "cx": 0.1}, seed=0, resolution=24)
    radius = np.linalg.norm(pts - np.array([0.1, 0.0, 0.0]), axis=1)
    assert np.abs(radius - 0.9).max() < 1e-12


def test_fit_short(calls):
    truth = {"r": 0.9, "cx": 0.1}
    pts = sample_surface(recorder, 400, params=truth, seed=1, resolution=24)
    res = fit(recorder, pts, seed=0, progress=False, cycles=200, epochs=2)
    # exact points: the polish's least squares recovers the parameters to rounding
    assert res.params["r"] == pytest.approx(0.9, abs=1e-8)
    assert res.params["cx"] == pytest.approx(0.1, abs=1e-8)


def test_slice_panel(calls):
    from workbench.slice_panel import SlicePanel

    panel = SlicePanel({"recorder": recorder}, resolution=32, distance_resolution=24, threaded=False)
    values = panel.values if panel.values else None
    assert values is not None and values["f"].shape == (32, 32)
    # the slice z = offset of f = 1 - |x - c|^2 at the panel's own points
    offset = float(panel.offset.value)
    u = np.linspace(-1.2, 1.2, 32)
    uu, vv = np.meshgrid(u, u, indexing="xy")
    np.testing.assert_allclose(values["f"], 1.0 - (uu**2 + vv**2 + offset**2), rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- user models


@model(bounds=BOX, r=Param(1.0, 0.5, 1.1))
def paper_ball(p, r):
    x0, x1, x2 = p[:, 0], p[:, 1], p[:, 2]
    return r**2 - x0**2 - x1**2 - x2**2


def test_paper_style_model_meshes_to_the_closed_form_volume():
    for r, n in ((1.0, 32), (0.7, 48)):
        m = polygonize(lambda x, r=r: paper_ball(x, r=r), BOX, n)
        h = 2.4 / (n - 1)
        # marching cubes' chords cut the sphere by O((h / r)^2) of its volume
        assert m.volume() == pytest.approx(4 / 3 * math.pi * r**3, rel=(h / r) ** 2)
    m = polygonize(paper_ball, resolution=32)  # the Model itself, its own bounds
    assert m.volume() == pytest.approx(4 / 3 * math.pi, rel=(2.4 / 31) ** 2)


@model(bounds=BOX, r=Param(0.8, 0.5, 1.0), t=Param(0.1, -0.2, 0.2))
def stacked(p, r, t):
    t = torch.as_tensor(t, dtype=p.dtype)  # a float or a 0-d tensor: as a tensor for torch.stack
    c = torch.stack([t, t * 0.0, -t])  # a centre stacked from parameters
    ball = sphere(p, center=c, r=r)
    slab = block(p, vertex=(-r, -r, -r), dx=2 * r, dy=r, dz=2 * r)  # a tuple of parameters
    return torch.where(p[:, 1] > 0, ball, union(ball, slab))


def test_tuples_stack_and_where_models_run_per_set():
    x = torch.rand(50, 3, dtype=F64, generator=torch.Generator().manual_seed(3)) * 2.4 - 1.2
    r = torch.tensor([0.6, 0.75, 0.9], dtype=F64)
    t = torch.tensor([-0.1, 0.0, 0.15], dtype=F64)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = stacked(x, r=r, t=t)
    singles = torch.stack([stacked(x, r=float(a), t=float(b)) for a, b in zip(r, t)])
    torch.testing.assert_close(out, singles, rtol=0, atol=1e-15)
    m = polygonize(stacked, resolution=24, project=False)  # (the creases of the union need no projection here)
    assert not m.is_empty()


def test_vmap_fallback_loops_with_one_warning_naming_the_model():
    @model(bounds=BOX, r=Param(1.0, 0.5, 1.1))
    def itemized(p, r):
        radius = r.item() if isinstance(r, torch.Tensor) else r  # vmap cannot batch .item()
        return radius**2 - (p * p).sum(1)

    x = torch.rand(7, 3, dtype=F64, generator=torch.Generator().manual_seed(2))
    r = torch.tensor([0.6, 0.8, 1.0], dtype=F64)
    expected = torch.stack([paper_ball(x, r=float(v)) for v in r])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        first = itemized(x, r=r)
        second = itemized(x, r=r)
    torch.testing.assert_close(first, expected, rtol=0, atol=1e-15)
    torch.testing.assert_close(second, expected, rtol=0, atol=1e-15)
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(messages) == 1, messages
    assert messages[0].startswith("itemized: torch.func.vmap cannot") and ".item()" in messages[0]


def test_a_model_vmap_cannot_run_still_fits_with_one_warning():
    @model(bounds=BOX, r=Param(1.0, 0.5, 1.1))
    def branching(p, r):
        if r > 0:  # a Python `if` on a parameter's value: vmap refuses, autograd does not mind
            return r**2 - (p * p).sum(1)
        return -(p * p).sum(1)

    pts = sample_surface(branching, 300, params={"r": 0.8}, seed=0, resolution=24)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = fit(branching, pts, seed=0, progress=False, cycles=100, epochs=1)
    # one warning for the model, although both the evolution's parameter sets and the polish's
    # per-point derivatives found that vmap cannot run it
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(messages) == 1 and messages[0].startswith("branching: torch.func.vmap cannot run"), messages
    assert res.params["r"] == pytest.approx(0.8, abs=1e-8)  # exact points: the polish recovers r


def test_wrong_output_shape_names_the_model_and_both_shapes():
    @model(bounds=BOX)
    def points_back(p):
        return p  # (N, 3), not (N,)

    message = r"points_back: a model must map points \(N, d\) to values \(N,\).*shape \(6, 3\).*shape \(6, 3\)"
    with pytest.raises(ValueError, match=message):
        points_back(torch.zeros(2, 3, 3))
    with pytest.raises(ValueError, match=r"^points_back: .*it returned shape \(8, 3\)"):
        polygonize(points_back, BOX, 2)
    with pytest.raises(ValueError, match=r"^<lambda>: .*it returned shape \(\)"):
        evaluate_grid(lambda p: p.sum(), BOX, 4)

    @model(bounds=BOX, r=Param(1.0, 0.5, 1.1))
    def summed(p, r):
        return (r - p).sum()

    with pytest.raises(ValueError, match=r"^summed: .*per parameter set \(of 2\).*shape \(5, 3\).*shape \(\)"):
        summed(torch.zeros(5, 3), r=torch.tensor([0.6, 0.7]))


def test_a_degenerate_parameter_in_a_set_is_named_not_a_silent_nan():
    @model(bounds=BOX, a=Param(1.0, 0.5, 1.1))
    def egg(p, a):
        return ellipsoid(p, a=a, b=1.0, c=0.8)

    x = torch.rand(6, 3, dtype=F64, generator=torch.Generator().manual_seed(4))
    good = egg(x, a=torch.tensor([0.6, 1.0], dtype=F64))
    torch.testing.assert_close(good[1], ellipsoid(x, a=1.0, b=1.0, c=0.8), rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match=r"^egg: ellipsoid: a must be positive, got 0\.0"):
        egg(x, a=torch.tensor([0.6, 0.0], dtype=F64))  # a = 0 divides by zero: the set is re-run alone


def test_calls_are_chunked_within_the_budget(monkeypatch):
    """With 8 MiB available the budget is 1 MiB: 1000 float64 points a call, 100 for 10 sets."""
    monkeypatch.setattr(_array, "available_memory", lambda: 8 << 20)
    assert ev.call_budget() == 1 << 20
    x = torch.rand(4321, 3, dtype=F64, generator=torch.Generator().manual_seed(0))
    CALLS.clear()
    out = recorder(x)
    assert [s[0] for s, _ in CALLS] == [1000] * 4 + [321]
    torch.testing.assert_close(out, sphere(x, r=1.0), rtol=0, atol=0)
    CALLS.clear()
    r = torch.linspace(0.6, 1.0, 10, dtype=F64)
    sets = recorder(x, r=r)
    assert {s[0] for s, _ in CALLS} <= {100, 21} and sets.shape == (10, 4321)
    torch.testing.assert_close(sets[3], sphere(x, r=float(r[3])), rtol=0, atol=1e-15)
    _assert_contract(CALLS)


_MEMORY_SCRIPT = r"""
import json, sys, torch
from pyfrep_core import Param, model
from pyfrep_core.evaluate import budget_points
from pyfrep_core.meshing.grid import evaluate_grid, CHUNK_POINTS

@model(bounds=((-1.2,) * 3, (1.2,) * 3), r=Param(1.0, 0.5, 1.1), cx=Param(0.0, -0.2, 0.2))
def user(p, r, cx):
    x0, x1, x2 = p[:, 0], p[:, 1], p[:, 2]
    return r**2 - (x0 - cx) ** 2 - x1**2 - x2**2

evaluate_grid(user, user.bounds, 32)  # warm: torch's first allocations
def peak():  # VmHWM: this process's own peak (ru_maxrss would include the forking parent's size)
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmHWM")) * 1024

before = peak()
values = evaluate_grid(user, user.bounds, 256)
after = peak()
chunk = min(CHUNK_POINTS, budget_points(torch.float32, 3))
inside = bool(values[128, 128, 128] > 0)
print(json.dumps({"growth": after - before, "grid": values.nbytes, "chunk": chunk, "ok": inside}))
"""


def test_a_256_cubed_grid_of_a_user_model_stays_within_the_budget():
    out = subprocess.run(
        [sys.executable, "-c", _MEMORY_SCRIPT],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert out.returncode == 0, out.stderr
    m = json.loads(out.stdout.strip().splitlines()[-1])
    assert m["ok"] and m["grid"] == 256**3 * 4
    # the grid itself, plus one chunk's working set ((3 + WORK_VALUES) float32 values a point),
    # plus 64 MiB for the allocator's slack; the whole grid's points at once would be 192 MiB more
    bound = m["grid"] + m["chunk"] * (3 + ev.WORK_VALUES) * 4 + (64 << 20)
    assert m["growth"] < bound, (m, bound)


@model(bounds=BOX, cx=Param(0.1, -0.2, 0.2), cy=Param(0.0, -0.2, 0.2), r=Param(1.0, 0.5, 1.1))
def bare_stack(p, cx, cy, r):
    """A ball whose centre is torch.stack of bare parameters (works because they arrive as 0-d tensors)."""
    return r**2 - ((p - torch.stack([cx, cy, torch.zeros_like(cx)])) ** 2).sum(1)


def test_bare_torch_stack_of_parameters_meshes_differentiates_and_fits():
    truth = {"cx": 0.15, "cy": -0.1, "r": 0.9}
    mesh = polygonize(lambda x: bare_stack(x, **truth), BOX, resolution=48)
    assert mesh.volume() == pytest.approx(4 / 3 * math.pi * 0.9**3, rel=3 * (2.4 / 47 / 0.9) ** 2)
    dfdp = param_grad(bare_stack, np.array([[0.0, 0.0, 0.0]]), truth)  # 2 (x - c) . e_i and 2 r
    np.testing.assert_allclose([dfdp["cx"][0], dfdp["cy"][0], dfdp["r"][0]], [-0.3, 0.2, 1.8], rtol=1e-14)
    points = sample_surface(bare_stack, 1000, params=truth, seed=0)
    result = fit(bare_stack, points, seed=0, progress=False, cycles=200, epochs=2)
    for name, value in truth.items():
        assert result.params[name] == pytest.approx(value, abs=1e-8)
