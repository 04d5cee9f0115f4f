"""Options of the long-running and meshing entries: every bad setting is a clear error, edge values still work.

Issue 10, items 2, 10, 13, 15 and 16: ``redistance``/``fit`` settings that are NaN, infinite, of
the wrong sign or not integers; non-float grids and integer-valued functions in ``polygonize``;
a normalized function meshed; the stop flag while redistance builds its training pool; the memory
estimate of a thin grid.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest
import torch

from pyfrep_core import Param, fit, model, offset, polygonize, project_to_surface, sample_surface, shell, sphere
from pyfrep_core.distance import TrueDistance, distance_error, fmm_distance, surface_samples, true_distance
from pyfrep_core.fitting import fit_error
from pyfrep_core.meshing import Mesh, evaluate_grid, grid_axes, grid_memory
from pyfrep_core.normalization import normalized
from pyfrep_core.redistancing import RedistancedSDF, redistance
from pyfrep_core.sampling import sample_mesh
from pyfrep_core.sensitivity import normal_velocity, param_derivative

BOUNDS = ((-1.5,) * 3, (1.5,) * 3)
BOX = ((-1.2,) * 3, (1.2,) * 3)
NAN, INF = float("nan"), float("inf")


def ball(x):
    return sphere(x, r=1.0)


@model(bounds=BOX, r=Param(1.0, 0.5, 1.1))
def ball_model(x, r):
    return sphere(x, r=r)


def unit_points(n: int, radius: float = 1.0, seed: int = 0) -> np.ndarray:
    """n points on the sphere of ``radius`` (normalized Gaussian directions)."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True)


PTS = unit_points(50)
TRIANGLE = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))


@pytest.fixture(scope="module")
def reference():
    return true_distance(ball, BOUNDS, resolution=16)


def call_redistance(**kw):
    return redistance(ball, BOUNDS, **{"steps": 2, "pool_size": 256, "surface_resolution": 16, "progress": False, **kw})


def call_fit(**kw):
    return fit(ball_model, PTS, **{"progress": False, **kw})


# (label, call with the bad value, option named in the message, the bad value as shown, error)
BAD = [
    # redistance (item 2): every numeric setting finite, of the right sign, integer where counted
    *[("redistance", lambda v=v: call_redistance(eikonal=v), "eikonal", v, ValueError) for v in (NAN, INF, -1.0)],
    *[("redistance", lambda v=v: call_redistance(supervised=v), "supervised", v, ValueError) for v in (NAN, INF, -0.5)],
    ("redistance", lambda: call_redistance(supervised=0.0, eikonal=0.0), "supervised", 0.0, ValueError),
    *[("redistance", lambda v=v: call_redistance(steps=v), "steps", v, ValueError) for v in (0, -3, 2.5, NAN)],
    ("redistance", lambda: call_redistance(steps="10"), "steps", "10", TypeError),
    ("redistance", lambda: call_redistance(steps=True), "steps", True, TypeError),
    *[("redistance", lambda v=v: call_redistance(batch=v), "batch", v, ValueError) for v in (0, 1.5)],
    *[("redistance", lambda v=v: call_redistance(pool_size=v), "pool_size", v, ValueError) for v in (0, INF)],
    *[("redistance", lambda v=v: call_redistance(lr=v), "lr", v, ValueError) for v in (0.0, -1e-3, NAN, INF)],
    *[("redistance", lambda v=v: call_redistance(clip_grad=v), "clip_grad", v, ValueError) for v in (0.0, NAN)],
    ("redistance", lambda: call_redistance(p=NAN), "p", NAN, ValueError),
    ("redistance", lambda: call_redistance(loss="p-poisson", p=1.0), "p", 1.0, ValueError),
    ("redistance", lambda: call_redistance(loss="l2"), "loss", "l2", ValueError),
    *[
        ("redistance", lambda v=v: call_redistance(fourier_features=v), "fourier_features", v, ValueError)
        for v in (2.5, -1)
    ],
    *[("redistance", lambda v=v: call_redistance(width=v), "width", v, ValueError) for v in (0, 2.5)],
    ("redistance", lambda: call_redistance(depth=0), "depth", 0, ValueError),
    ("redistance", lambda: call_redistance(mode="fast"), "mode", "fast", ValueError),
    *[
        ("redistance", lambda v=v: call_redistance(mode="paper", boundary=v), "boundary", v, ValueError)
        for v in (-1.0, NAN)
    ],
    ("redistance", lambda: call_redistance(mode="paper", supervised=1.0), "supervised", 1.0, ValueError),
    ("redistance", lambda: call_redistance(normal=1.0), "normal", 1.0, ValueError),  # a paper-mode weight
    ("redistance", lambda: call_redistance(activation="relu6"), "activation", "relu6", ValueError),
    *[
        ("redistance", lambda v=v: call_redistance(surface_resolution=v), "surface_resolution", v, ValueError)
        for v in (1, 1000, 16.5)
    ],
    *[("redistance", lambda v=v: call_redistance(threads=v), "threads", v, ValueError) for v in (0, 1.5)],
    *[("redistance", lambda v=v: call_redistance(seed=v), "seed", v, ValueError) for v in (1.5, -1)],
    ("redistance", lambda: call_redistance(every=0), "every", 0, ValueError),
    ("redistance", lambda: call_redistance(refit="yes"), "refit", "yes", TypeError),
    ("redistance", lambda: call_redistance(progress=1), "progress", 1, TypeError),
    *[
        ("redistance", lambda v=v: call_redistance(dtype=v), "dtype", v, ValueError)
        for v in (torch.int32, torch.float16)
    ],
    ("redistance", lambda: call_redistance(callback="print"), "callback", "print", TypeError),
    ("redistance", lambda: call_redistance(stop=True), "stop", True, TypeError),
    ("RedistancedSDF", lambda: RedistancedSDF(ball, BOUNDS, beta=0.0), "beta", 0.0, ValueError),
    ("RedistancedSDF", lambda: RedistancedSDF(ball, BOUNDS, fourier_scale=INF), "fourier_scale", INF, ValueError),
    ("RedistancedSDF", lambda: RedistancedSDF(ball, BOUNDS, dtype=torch.int64), "dtype", torch.int64, ValueError),
    # fit (item 13)
    *[("fit", lambda v=v: call_fit(lr=v), "lr", v, ValueError) for v in (INF, NAN, 0.0, -0.1)],
    *[("fit", lambda v=v: call_fit(xtol=v), "xtol", v, ValueError) for v in (NAN, 0.0, -1e-8)],
    *[("fit", lambda v=v: call_fit(seed=v), "seed", v, ValueError) for v in (1.5, -1)],
    ("fit", lambda: call_fit(seed="0"), "seed", "0", TypeError),
    *[("fit", lambda v=v: call_fit(cycles=v), "cycles", v, ValueError) for v in (1.5, -1, INF)],
    ("fit", lambda: call_fit(epochs=-1), "epochs", -1, ValueError),
    ("fit", lambda: call_fit(batch_size=0), "batch_size", 0, ValueError),
    ("fit", lambda: call_fit(polish_iters=0), "polish_iters", 0, ValueError),
    *[
        ("fit", lambda v=v: call_fit(mutation=v), "mutation", v, ValueError)
        for v in ((0.0, 1.0), (1.0, 0.1), (NAN, 1.0), (1e-3, INF))
    ],
    ("fit", lambda: call_fit(mutation=0.5), "mutation", 0.5, TypeError),
    ("fit", lambda: call_fit(num_threads=0), "num_threads", 0, ValueError),
    ("fit", lambda: call_fit(dtype=torch.int64), "dtype", torch.int64, ValueError),
    ("fit", lambda: call_fit(every=0), "every", 0, ValueError),
    ("fit", lambda: call_fit(progress="no"), "progress", "no", TypeError),
    ("fit", lambda: call_fit(callback=3), "callback", 3, TypeError),
    ("fit", lambda: call_fit(stop="flag"), "stop", "flag", TypeError),
    ("fit_error", lambda: fit_error(ball_model, np.array([[NAN, 0.0, 0.0]])), "points", NAN, ValueError),
    ("fit_error", lambda: fit_error(ball, PTS), "model", "ball", TypeError),
    # model (item 13)
    *[("model", lambda v=v: model(dim=v), "dim", v, ValueError) for v in (0, -2, 2.5)],
    *[("model", lambda v=v: model(dim=v), "dim", v, TypeError) for v in ("3", True, None)],
    # sensitivity (item 13)
    *[
        ("normal_velocity", lambda v=v: normal_velocity(ball_model, PTS, "r", chunk=v), "chunk", v, ValueError)
        for v in (0, 2.5, NAN)
    ],
    ("param_derivative", lambda: param_derivative(ball_model, PTS, "r", chunk=0), "chunk", 0, ValueError),
    # sample_surface (item 13)
    *[
        (
            "sample_surface",
            lambda v=v: sample_surface(ball_model, 10, resolution=16, max_rounds=v),
            "max_rounds",
            v,
            ValueError,
        )
        for v in (0, 2.5)
    ],
    ("sample_surface", lambda: sample_surface(ball_model, 10, resolution=16, seed=1.5), "seed", 1.5, ValueError),
    ("sample_surface", lambda: sample_surface(ball_model, 10, resolution=16, noise=INF), "noise", INF, ValueError),
    # distance (item 13)
    *[
        ("true_distance", lambda v=v: true_distance(ball, BOUNDS, 16, refine_steps=v), "refine_steps", v, ValueError)
        for v in (-1, 1.5)
    ],
    *[("true_distance", lambda v=v: true_distance(ball, BOUNDS, v), "resolution", v, ValueError) for v in (1, 600)],
    ("true_distance", lambda: true_distance(ball, BOUNDS, "16"), "resolution", "16", TypeError),
    ("surface_samples", lambda: surface_samples(ball, BOUNDS, 16, n_points=-1), "n_points", -1, ValueError),
    ("surface_samples", lambda: surface_samples(ball, BOUNDS, 16, n_points=2.5), "n_points", 2.5, ValueError),
    ("surface_samples", lambda: surface_samples(ball, BOUNDS, 16, seed=-1), "seed", -1, ValueError),
    *[
        ("distance_error", lambda v=v: distance_error(ball, ball, BOUNDS, 8, band=v), "band", v, ValueError)
        for v in (0.0, NAN)
    ],
    (
        "distance_error",
        lambda: distance_error(ball, ball, BOUNDS, 8, dtype=torch.int32),
        "dtype",
        torch.int32,
        ValueError,
    ),
    ("fmm_distance", lambda: fmm_distance(ball, BOUNDS, 1), "resolution", 1, ValueError),
    # polygonize and the grid (item 10)
    *[
        ("polygonize", lambda v=v: polygonize(ball, BOX, 8, dtype=v), "dtype", v, ValueError)
        for v in (torch.int32, torch.int64, torch.float16, torch.bool, "float32")
    ],
    *[("polygonize", lambda v=v: polygonize(ball, BOX, 8, tol=v), "tol", v, ValueError) for v in (0.0, -1e-3, NAN)],
    ("polygonize", lambda: polygonize(ball, BOX, 8, project="yes"), "project", "yes", TypeError),
    ("polygonize", lambda: polygonize(ball, BOX, 8, sparse=1), "sparse", 1, TypeError),
    ("polygonize", lambda: polygonize(ball, BOX, 8, device="gpu0"), "device", "gpu0", ValueError),
    ("polygonize", lambda: polygonize("ball", BOX, 8), "f", "str", TypeError),
    ("evaluate_grid", lambda: evaluate_grid(ball, BOX, 8, dtype=torch.int32), "dtype", torch.int32, ValueError),
    *[
        ("evaluate_grid", lambda v=v: evaluate_grid(ball, BOX, 8, max_points=v), "max_points", v, ValueError)
        for v in (0, 2.5)
    ],
    ("evaluate_grid", lambda: evaluate_grid(ball, BOX, 8, device="tpu:x"), "device", "tpu:x", ValueError),
    ("grid_memory", lambda: grid_memory(8, dtype=torch.int8), "dtype", torch.int8, ValueError),
    *[("grid_axes", lambda v=v: grid_axes(BOX, 8, dim=v), "dim", v, ValueError) for v in (0, 1.5)],
    # Newton projection: a step or distance limit <= 0 left every point in place, reported unconverged
    *[
        ("project_to_surface", lambda v=v: project_to_surface(ball, PTS, max_step=v), "max_step", v, ValueError)
        for v in (0.0, -0.1, NAN)
    ],
    *[
        ("project_to_surface", lambda v=v: project_to_surface(ball, PTS, max_distance=v), "max_distance", v, ValueError)
        for v in (0.0, -1.0, INF)
    ],
    *[
        ("project_to_surface", lambda v=v: project_to_surface(ball, PTS, tol=v), "tol", v, ValueError)
        for v in (0.0, NAN)
    ],
    *[
        ("sample_mesh", lambda v=v: sample_mesh(TRIANGLE, v, np.random.default_rng(0)), "n", v, ValueError)
        for v in (0, -5, 2.5)
    ],
]


@pytest.mark.parametrize(
    "call, option, value, error",
    [pytest.param(c, o, v, e, id=f"{fn}-{o}={v!r}") for fn, c, o, v, e in BAD],
)
def test_bad_option_is_refused_naming_it_and_its_value(call, option, value, error):
    with pytest.raises(error) as info:
        call()
    message = str(info.value)
    assert option in message
    assert repr(value) in message or str(value) in message, message


def test_true_distance_far_point(reference):
    # 1e100 is far but its distance is representable: -(1e100 - 1) to float64 precision
    far = reference(np.array([[1e100, 0.0, 0.0], [0.0, -1e100, 0.0]]))
    np.testing.assert_allclose(far, [-1e100, -1e100], rtol=1e-15)
    # beyond 1e150 the squared distances overflow: a clear error, not "index 3600 is out of bounds"
    with pytest.raises(ValueError, match=r"points has a coordinate 1e\+200 at index \(0, 0\)"):
        reference(np.array([[1e200, 0.0, 0.0]]))


# ----------------------------------------------------------------------------- valid edge values


def test_redistance_edge_values_train():
    # lr tiny, seed 0, no clipping, no eikonal term, integral floats for counts, threads left alone
    lr = 1e-9
    net = call_redistance(
        lr=lr, seed=0, clip_grad=None, eikonal=0.0, batch=64.0, threads=None, refit=False, dtype=torch.float64
    )
    assert len(net.history) == 2 and all(math.isfinite(v) for v in net.history)
    # Adam moves a weight by at most lr (1 - beta1) / sqrt(1 - beta2) = 3.2 lr a step (the warm-up
    # scales lr down): 2 steps from the seeded initial weights stay within 6.4 lr (float64: no rounding)
    start = RedistancedSDF(ball, BOUNDS, last_activation="leaky_relu", seed=0, dtype=torch.float64)
    moved = max(float((a - b).abs().max()) for a, b in zip(net.state_dict().values(), start.state_dict().values()))
    assert 0 < moved <= 2 * 0.1 / math.sqrt(0.001) * lr
    # the p-Poisson energy with p just above 1; fourier features; the paper mode (no distance labels)
    model = call_redistance(loss="p-poisson", p=1.5, fourier_features=2, mode="paper")
    assert len(model.history) == 2 and all(math.isfinite(v) for v in model.history)


def test_fit_edge_values_work():
    # lr 1e-12: two SGD epochs cannot move the start (in the unit box, by ~lr a step)
    res = call_fit(stages=("sgd",), init={"r": 0.8}, epochs=2, lr=1e-12, seed=0)
    assert res.params["r"] == pytest.approx(0.8, abs=1e-9)
    # seed 0, integral floats for counts, the polish alone finds r = 1 exactly (points on the unit sphere)
    res = call_fit(stages=("polish",), init={"r": 0.7}, seed=0, polish_iters=20.0, xtol=1e-14, mutation=(0.5, 0.5))
    assert res.params["r"] == pytest.approx(1.0, abs=1e-12)


def test_model_dim_edge_values():
    assert model(dim=2)(lambda x: x[..., 0]).dim == 2
    m = model(dim=3.0)(lambda x: x[..., 0])
    assert m.dim == 3 and isinstance(m.dim, int)


def test_chunk_one_and_one_round_give_exact_results():
    # v = -(df/dr) / |grad f| = -(2r) / (2r) = -1 on the sphere, whatever the chunking
    np.testing.assert_allclose(normal_velocity(ball_model, PTS, "r", chunk=1), -1.0, rtol=1e-12)
    np.testing.assert_allclose(param_derivative(ball_model, PTS, "r", chunk=7), 2.0, rtol=1e-12)
    pts = sample_surface(ball_model, 50, seed=0, resolution=24, max_rounds=1)
    assert np.abs(np.linalg.norm(pts, axis=1) - 1.0).max() < 1e-12


def test_true_distance_without_refinement_never_underestimates(reference):
    plain = true_distance(ball, BOUNDS, resolution=16, refine_steps=0)
    x = unit_points(200, 0.5, seed=1) * np.random.default_rng(2).uniform(0.2, 2.5, (200, 1))
    exact = 1.0 - np.linalg.norm(x, axis=1)
    # every candidate is a surface point: |d| >= the true distance (up to the projection tolerance);
    # refinement (same samples) only accepts closer ones
    plain_d, refined = np.abs(plain(x)), np.abs(reference(x))
    assert (plain_d >= np.abs(exact) - 1e-12).all() and (refined >= np.abs(exact) - 1e-12).all()
    assert (refined <= plain_d).all() and (refined < plain_d).any()


# ----------------------------------------------------------------------------- polygonize (item 10)


def inscribed_volume_bounds(resolution: int, radius: float = 1.0) -> tuple[float, float]:
    """Bounds on the volume of a mesh of the ball whose vertices lie on the sphere (box BOX).

    The mesh is inscribed: its volume is at most the ball's, and each triangle (edges at most a
    cell diagonal h sqrt 3, so circumradius at most that) is within the sagitta
    r - sqrt(r^2 - 3 h^2) of the sphere, so the deficit is at most the sphere's area times it.
    """
    h = (BOX[1][0] - BOX[0][0]) / (resolution - 1)
    ball_volume = 4 / 3 * math.pi * radius**3
    sagitta = radius - math.sqrt(radius**2 - 3 * h * h)
    return ball_volume - 4 * math.pi * radius**2 * sagitta, ball_volume * (1 + 1e-12)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_polygonize_float_grids_give_the_inscribed_ball(dtype):
    lo, hi = inscribed_volume_bounds(32)
    assert lo < polygonize(ball, BOX, 32, dtype=dtype).volume() <= hi


def test_integer_or_boolean_f_is_refused_naming_f_and_its_dtype():
    def rounded_ball(x):
        return (10 * sphere(x, r=1.0)).to(torch.int64)

    with pytest.raises(TypeError, match=r"f \(rounded_ball\) returned int64 values for float32 points"):
        polygonize(rounded_ball, BOX, 16)
    with pytest.raises(TypeError, match=r"f \(<lambda>\) returned bool values"):
        polygonize(lambda x: sphere(x, r=1.0) > 0, BOX, 16, sparse=True)
    with pytest.raises(TypeError, match="rounded_ball"):
        evaluate_grid(rounded_ball, BOX, 8)


def test_normalized_function_is_meshed():
    # a plain function's normalization declares no dim: it meshes in the bounds given
    lo, hi = inscribed_volume_bounds(32)
    for kind in ("omega1", "delta1"):
        assert lo < polygonize(normalized(ball, kind), BOX, 32).volume() <= hi
    # a model's normalization carries its bounds (and dim)
    assert lo < polygonize(normalized(ball_model), resolution=32).volume() <= hi


# ----------------------------------------------------------------------------- stop flag (item 15)


class CountingBall:
    """The unit ball, counting its calls; sets ``flag`` at call ``stop_at`` and counts the calls after."""

    def __init__(self, flag: threading.Event | None = None, stop_at: int | None = None):
        self.calls, self.after, self.flag, self.stop_at = 0, 0, flag, stop_at

    def __call__(self, x):
        if self.flag is not None and self.flag.is_set():
            self.after += 1
        self.calls += 1
        if self.calls == self.stop_at:
            self.flag.set()
        return sphere(x, r=1.0)


POOL = dict(pool_size=4096, surface_resolution=24, seed=0)


@pytest.mark.parametrize("mode", ["supervised", "paper"])
def test_stop_set_before_training_evaluates_nothing(mode):
    flag = threading.Event()
    flag.set()
    f = CountingBall()
    net = redistance(f, BOUNDS, steps=50, mode=mode, eikonal=1.0, stop=flag, progress=False, **POOL)
    assert f.calls == 0 and net.history == []


def test_stop_during_the_pool_ends_it_within_one_refinement_step():
    # the pool: surface samples (true_distance's construction), then closest-point steps for the
    # distances of its points (the long part, ~1 s at the defaults); count f's calls in each
    built = CountingBall()
    reference = true_distance(built, BOUNDS, resolution=POOL["surface_resolution"], seed=POOL["seed"])
    samples_calls = built.calls
    full = CountingBall()
    redistance(full, BOUNDS, steps=1, progress=False, **POOL)
    pool_calls = full.calls - samples_calls  # the reference distance of the pool (no f call in training)
    # one refinement step's calls on as many points, measured (the first step is the largest: it
    # also takes the gradient at the starting samples)
    x = np.random.default_rng(0).uniform(-1.5, 1.5, (POOL["pool_size"] - POOL["pool_size"] // 8, 3))
    one_step = CountingBall()
    TrueDistance(one_step, reference.samples, reference.tree, refine_steps=1).unsigned(x)
    assert pool_calls >= 3 * one_step.calls  # so the bound below is a real one
    for stop_at in (samples_calls + 1, samples_calls + 3):  # at the start of the first step, inside it
        flag = threading.Event()
        f = CountingBall(flag, stop_at)
        net = redistance(f, BOUNDS, steps=50, stop=flag, progress=False, **POOL)
        assert flag.is_set() and net.history == []
        assert f.after <= one_step.calls, (stop_at, f.after, one_step.calls)


# ----------------------------------------------------------------------------- memory estimate (item 16)


def old_grid_memory(n: int, dtype: torch.dtype) -> int:
    """The estimate before the fix, for a cube of n^3 samples (4 n^2 vertices)."""
    per_sample = 4 if dtype == torch.float32 else 12
    return int(n**3 * per_sample * 1.25) + (256 << 20) + 400 * 4 * n * n


@pytest.mark.parametrize("n", [3, 16, 128, 512, 1024])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_cube_estimate_unchanged(n, dtype):
    assert grid_memory(n, dtype) == old_grid_memory(n, dtype)


MEASURE = textwrap.dedent(
    """
    import json, sys, torch
    from pyfrep_core import polygonize
    from pyfrep_core.meshing import grid_memory
    torch.set_num_threads(1)
    res = tuple(json.loads(sys.argv[1]))
    plane = lambda x: 0.01 - x[..., 2]  # parallel to the slab, between its two layers: one vertex per z-line
    bounds = ((-1.0, -1.0, -0.5), (1.0, 1.0, 0.5))
    polygonize(plane, bounds, 16)  # imports, warm-up
    def status(key):
        with open("/proc/self/status") as fh:
            return next(int(line.split()[1]) * 1024 for line in fh if line.startswith(key))
    base = status("VmRSS:")
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")  # the peak (VmHWM) restarts from the current size
    mesh = polygonize(plane, bounds, res)
    print(json.dumps([status("VmHWM:") - base, mesh.n_vertices, grid_memory(res)]))
    """
)


@pytest.mark.skipif(not os.path.exists("/proc/self/clear_refs"), reason="needs Linux's peak-RSS reset")
def test_thin_slab_estimate_within_a_factor_of_the_measured_peak():
    # a (4096, 4096, 2) grid was estimated at 25.4 GiB for its 168 MB of samples (4 vertices per
    # z-line counted, where a line of one edge holds at most one)
    res = (1024, 1024, 2)
    out = subprocess.run([sys.executable, "-c", MEASURE, str(list(res))], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    measured, vertices, estimate = (int(v) for v in out.stdout.split("[")[-1].strip(" ]\n").split(","))
    assert vertices == 1024 * 1024  # every z-line crossed once: the most such a slab holds
    assert measured / 2 <= estimate <= 2 * measured, (measured, estimate)
    assert grid_memory((4096, 4096, 2)) < 5 * 2**30


def test_projection_with_limits_still_converges():
    """Positive limits are kept: a point 0.1 outside the unit ball lands on it in steps of at most 0.06."""
    p = project_to_surface(ball, 1.1 * PTS, max_step=0.06, max_distance=0.2)
    assert p.converged.all()
    np.testing.assert_allclose(np.linalg.norm(p.points, axis=1), 1.0, atol=1e-12)


def test_shell_and_offset_refuse_degenerate_values():
    """shell with t <= 0 is empty (negative everywhere); a non-finite offset moves the surface to infinity."""
    f = torch.tensor([0.0, 0.5, -0.5], dtype=torch.float64)
    for t in (0.0, -0.1):
        with pytest.raises(ValueError, match=r"shell: thickness must be positive, got -?0\.\d"):
            shell(f, t)
    with pytest.raises(ValueError, match="offset: d must be finite"):
        offset(f, INF)
    # the nearest valid values: a thin shell is positive only inside |f| < t
    assert (shell(f, 1e-3) > 0).tolist() == [True, False, False]
    np.testing.assert_allclose(offset(f, -0.5).numpy(), [-0.5, 0.0, -1.0])
