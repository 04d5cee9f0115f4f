"""Neural redistancing (paper section 5.3) against exact distances: sphere and box."""

from __future__ import annotations

import math
import os
import threading

import numpy as np
import pytest
import torch

from pyfrep_core import block, sphere, torusZ
from pyfrep_core.distance import distance_error
from pyfrep_core.meshing import grid_axes
from pyfrep_core.normalization import omega_1
from pyfrep_core.redistancing import RedistancedSDF, load_redistanced, redistance

QUICK = os.environ.get("PYFREP_QUICK", "0") not in ("", "0")
STEPS = 1500 if QUICK else 4000
BOX_STEPS = 4000 if QUICK else 8000  # ~10 s / ~20 s on one thread
BOUNDS = ((-1.5,) * 3, (1.5,) * 3)
RES = 40  # error grid: 64,000 points


def ball(x):
    return sphere(x, r=1.0)


def ball_distance(x):
    return 1.0 - np.linalg.norm(x, axis=-1)


BOX_LO, BOX_HI = np.array([-0.6, -0.5, -0.4]), np.array([0.6, 0.5, 0.4])


def box(x):
    return block(x, vertex=tuple(BOX_LO), dx=1.2, dy=1.0, dz=0.8)


def box_distance(x):
    """Exact signed distance to the box, positive inside."""
    q = np.abs(x - (BOX_LO + BOX_HI) / 2) - (BOX_HI - BOX_LO) / 2
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return -(outside + inside)


def exact_grid(fn):
    axes = grid_axes(BOUNDS, RES)
    return fn(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1))


@pytest.fixture(scope="module")
def trained_ball():
    events = []
    model = redistance(ball, BOUNDS, steps=STEPS, callback=events.append, every=25, progress=False)
    return model, events


@pytest.mark.parametrize("name", ["ball", "box"])
def test_mean_error_and_sign(name, trained_ball):
    if name == "ball":
        f, exact, model = ball, ball_distance, trained_ball[0]
    else:
        f, exact = box, box_distance
        model = redistance(box, BOUNDS, steps=BOX_STEPS, progress=False)
    err = distance_error(model, f, BOUNDS, resolution=RES, reference=exact_grid(exact), band=0.1)
    # the target, quick mode included (measured: sphere 1.4e-3 after 1500 steps, box
    # 2.3e-3 to 2.6e-3 after 4000 steps over seeds 0-2, 2.1e-3 after 8000)
    limit = 5e-3
    assert err.mean < limit, (name, err.mean)
    assert err.band_mean < 2 * limit, (name, err.band_mean)
    # sign(d) == sign(f) everywhere on a fine grid: the ansatz keeps the zero set of f
    axes = grid_axes(BOUNDS, 57)
    x = torch.as_tensor(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3))
    with torch.no_grad():
        fx, dx = f(x), model(x)
    assert torch.equal(torch.sign(dx), torch.sign(fx))


def test_ansatz_is_sign_f_times_h(trained_ball):
    model = trained_ball[0]
    x = torch.rand(100, 3, dtype=torch.float64) * 3 - 1.5
    with torch.no_grad():
        expected = torch.sign(ball(x)) * model.h(x).double()
        assert torch.allclose(model(x), expected)
    assert model(x).dtype == torch.float64
    assert isinstance(model(x.numpy()), np.ndarray)


def test_callback_fires_with_decreasing_loss(trained_ball):
    model, events = trained_ball
    assert [e.step for e in events][:3] == [0, 25, 50]
    assert events[-1].step == STEPS - 1
    assert all(e.stage == "redistance" and e.total == STEPS for e in events)
    assert events[-1].loss < 0.05 * events[0].loss
    assert len(model.history) == STEPS and math.isclose(model.history[0], events[0].loss)


def test_callback_and_stop_flag_end_training_early():
    model = redistance(ball, BOUNDS, steps=500, callback=lambda e: e.step >= 5, every=1, progress=False)
    assert len(model.history) == 6
    flag = threading.Event()
    flag.set()
    model = redistance(ball, BOUNDS, steps=500, stop=flag, progress=False)
    assert len(model.history) == 0  # set before the training pool is built: nothing runs


def test_save_load_round_trip(tmp_path, trained_ball):
    model = trained_ball[0]
    path = tmp_path / "ball.pt"
    model.save(path)
    loaded = load_redistanced(path, ball)
    x = torch.rand(1000, 3) * 3 - 1.5
    with torch.no_grad():
        assert torch.equal(model(x), loaded(x))
    assert loaded.config == model.config and loaded.history == model.history
    (tmp_path / "bad.pt").write_bytes(b"not a network")
    with pytest.raises(ValueError, match="not a saved redistanced network"):
        load_redistanced(tmp_path / "bad.pt", ball)
    with pytest.raises(TypeError, match="callable"):
        load_redistanced(path, "ball")


def test_paper_mode_eikonal_and_p_poisson_reduce_their_loss():
    for loss in ("eikonal", "p-poisson"):
        model = redistance(ball, BOUNDS, mode="paper", steps=60, loss=loss, batch=64, progress=False)
        assert np.mean(model.history[-10:]) < np.mean(model.history[:10]), loss


TORUS_R, TORUS_r = 0.8, 0.35
TORUS_BOUNDS = ((-1.4, -1.4, -0.7), (1.4, 1.4, 0.7))


def torus(x):
    return torusZ(x, R=TORUS_R, r=TORUS_r)


def torus_distance(x):
    """Exact signed distance to the torus, positive inside; its medial axis: the tube's centre
    circle inside, the z axis outside."""
    return TORUS_r - np.hypot(np.hypot(x[..., 0], x[..., 1]) - TORUS_R, x[..., 2])


def test_paper_mode_beats_omega_1_without_distance_labels():
    """The paper's training (eikonal loss, every target from f) on a torus: f = r^2 - (rho - R)^2
    - z^2 is no distance (omega_1 is off by 0.1 on average); the network must be a distance."""
    res = 24
    model = redistance(torus, TORUS_BOUNDS, mode="paper", steps=400, batch=64, surface_resolution=res, progress=False)
    x = np.stack(np.meshgrid(*grid_axes(TORUS_BOUNDS, res), indexing="ij"), axis=-1).reshape(-1, 3)
    exact = torus_distance(x)
    t = torch.tensor(x, dtype=torch.float32, requires_grad=True)
    d = model(t)
    (grad,) = torch.autograd.grad(d.sum(), t)
    err = np.abs(d.detach().numpy() - exact)
    omega_err = np.abs(omega_1(torus, x) - exact)
    # measured: 8.7e-3 against omega_1's 1.0e-1; the samples' grid spacing h = 0.12
    h = 2.8 / (res - 1)
    assert err.mean() < omega_err.mean() / 5, (err.mean(), omega_err.mean())
    assert err.mean() < h / 8, err.mean()
    # |grad d| = 1 off the medial axis (more than h from the centre circle and from the z axis)
    rho = np.hypot(x[:, 0], x[:, 1])
    off_axis = (np.hypot(rho - TORUS_R, x[:, 2]) > h) & (rho > h)
    slope_error = np.abs(grad.norm(dim=-1).numpy() - 1.0)[off_axis]
    assert slope_error.mean() < 0.05, slope_error.mean()
    # the network g itself learned inside from outside (sign(f) |g| would hide a wrong sign)
    with torch.no_grad():
        g = model.signed_network(torch.as_tensor(x, dtype=torch.float32)).numpy()
    away = np.abs(exact) > h / 2
    assert np.mean(np.sign(g[away]) == np.sign(exact[away])) > 0.99


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"bounds": ((float("nan"), -1, -1), (1, 1, 1))}, ValueError, "finite"),
        ({"bounds": ((1, -1, -1), (-1, 1, 1))}, ValueError, "inverted"),
        ({"bounds": ((2, 2, 2), (3, 3, 3))}, ValueError, "zero set"),
        ({"steps": 0}, ValueError, "steps"),
        ({"loss": "l1"}, ValueError, "loss"),
        ({"activation": "relu6"}, ValueError, "activation"),
        ({"last_activation": "max"}, ValueError, "last_activation"),
        ({"threads": 0}, ValueError, "threads"),
        ({"clip_grad": -1.0}, ValueError, "clip_grad"),
    ],
)
def test_bad_input(kwargs, error, match):
    args = {"bounds": BOUNDS, "steps": 2, "progress": False, **kwargs}
    with pytest.raises(error, match=match):
        redistance(ball, **args)


def test_threads_restored_after_training():
    before = torch.get_num_threads()
    redistance(ball, BOUNDS, steps=3, threads=1, progress=False)
    assert torch.get_num_threads() == before
    # the last hidden layer's piecewise-linear units are part of the saved architecture
    model = redistance(ball, BOUNDS, steps=2, last_activation="relu", progress=False)
    assert isinstance(model.net[-2], torch.nn.ReLU) and isinstance(model.net[-4], torch.nn.SiLU)


def test_non_callable_f():
    with pytest.raises(TypeError, match="callable"):
        redistance("sphere", BOUNDS)
    with pytest.raises(TypeError, match="callable"):
        RedistancedSDF(None, BOUNDS)
