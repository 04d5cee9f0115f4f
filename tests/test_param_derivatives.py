"""Per-point parameter derivatives df/dp: one implementation (per-sample reverse mode) behind
``param_grad``, ``param_derivative``/``normal_velocity``, the shape panel's colouring and the
fitting Jacobian.  Values against central differences and closed forms, for models written
naturally (tuples of parameters as centres, ``p[:, i]``, ``torch.stack``, ``torch.where``, a
rotation angle) and for the paper's models; bit-for-bit results from threads; bounded memory."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import threading
import warnings

import numpy as np
import pytest
import torch

from pyfrep_core import Param, block, cylZ, difference, model, param_grad, rotate, sphere, translate
from pyfrep_core.compiled import compiled
from pyfrep_core.fitting import _jacobian, _Problem
from pyfrep_core.models import ellipse, fig1_part, microstructure, pawn, schwarz_d
from pyfrep_core.sensitivity import normal_velocity, param_derivative

EPS = torch.finfo(torch.float64).eps
# central differences at the step that balances truncation (h^2 |f'''| / 6) and rounding
# (eps |f| / h): both about eps^(2/3) ~ 4e-11 of the derivative's scale, far inside 1e-6
STEP = EPS ** (1 / 3)
RTOL = 1e-6


# ----------------------------------------------------------------------------- models, written naturally


@model(bounds=((-2.0,) * 3, (2.0,) * 3), r=Param(1.0, 0.5, 1.5), cx=Param(0.1, -0.5, 0.5))
def ball_tuple(x, r, cx):
    return sphere(x, center=(cx, 0.0, 0.0), r=r)  # a tuple built from a parameter


@model(bounds=((-2.0,) * 3, (2.0,) * 3), tx=Param(0.2, -0.5, 0.5), r=Param(0.8, 0.5, 1.5))
def moved_ball(x, tx, r):
    return sphere(translate(x, (tx, 0.0, 0.0)), r=r)


@model(bounds=((-1.0,) * 3, (1.0,) * 3), size=Param(1.0, 0.6, 1.4), hole=Param(0.2, 0.05, 0.28))
def box_with_hole(x, size, hole):
    h = size / 2
    return difference(block(x, vertex=(-h, -h, -h), dx=size, dy=size, dz=size), cylZ(x, r=hole))


@model(bounds=((-1.5,) * 3, (1.5,) * 3), a=Param(1.0, 0.5, 1.5), b=Param(0.6, 0.3, 0.9))
def paper_style(p, a, b):
    x0, x1, x2 = p[:, 0], p[:, 1], p[:, 2]
    return 1.0 - (x0 / a) ** 2 - (x1 / b) ** 2 - x2**2


@model(bounds=((-1.5,) * 3, (1.5,) * 3), cx=Param(0.1, -0.5, 0.5), w=Param(1.2, 0.5, 2.0))
def stacked(x, cx, w):
    q = torch.stack([x[:, 0] - cx, w * x[:, 1], x[:, 2]], dim=1)
    return 1.0 - (q * q).sum(dim=1)


@model(bounds=((-1.5,) * 3, (1.5,) * 3), z0=Param(0.1, -0.5, 0.5), r=Param(1.0, 0.5, 1.5))
def capped(x, z0, r):
    ball = sphere(x, r=r)
    return torch.where(x[:, 2] > z0, ball - 4.0 * (x[:, 2] - z0) ** 2, ball)


@model(bounds=((-1.0,) * 3, (1.0,) * 3), angle=Param(0.3, -1.0, 1.0), length=Param(1.0, 0.5, 1.4))
def turned_bar(x, angle, length):
    return block(rotate(x, angle, (0.0, 0.0, 1.0)), vertex=(-length / 2, -0.2, -0.1), dx=length, dy=0.4, dz=0.2)


NATURAL = [ball_tuple, moved_ball, box_with_hole, paper_style, stacked, capped, turned_bar]
PAPER = [fig1_part, microstructure, pawn, schwarz_d, ellipse]


def in_bounds(m, n: int, seed: int) -> np.ndarray:
    lo, hi = (np.asarray(b, dtype=float) for b in m.bounds)
    return np.random.default_rng(seed).uniform(lo, hi, (n, m.dim))


def central_difference(m, x: np.ndarray, values: dict, name: str) -> np.ndarray:
    up, down = dict(values), dict(values)
    up[name] += STEP
    down[name] -= STEP
    return (m(x, **up) - m(x, **down)) / (2 * STEP)


def assert_matches_differences(m, x: np.ndarray, values: dict) -> None:
    got = param_grad(m, x, values)
    assert list(got) == m.names
    for name in m.names:
        fd = central_difference(m, x, values, name)
        scale = np.abs(fd).max()
        assert got[name].shape == (x.shape[0],) and got[name].dtype == np.float64
        np.testing.assert_allclose(got[name], fd, rtol=RTOL, atol=RTOL * scale, err_msg=f"{m.__name__}: {name}")


# ----------------------------------------------------------------------------- values


@pytest.mark.parametrize("m", NATURAL, ids=lambda m: m.__name__)
def test_naturally_written_models_equal_central_differences(m):
    values = m.defaults()
    assert_matches_differences(m, in_bounds(m, 400, seed=1), values)


@pytest.mark.parametrize("m", PAPER, ids=lambda m: m.__name__)
def test_the_papers_models_equal_central_differences(m):
    assert_matches_differences(m, in_bounds(m, 300, seed=2), m.defaults())


def test_closed_forms_of_the_sphere():
    x = in_bounds(ball_tuple, 500, seed=3)
    d = param_grad(ball_tuple, x, {"r": 1.2, "cx": -0.3})
    np.testing.assert_allclose(d["r"], 2.4, rtol=4 * EPS)  # d/dr (r^2 - |x - c|^2) = 2 r
    np.testing.assert_allclose(d["cx"], 2 * (x[:, 0] + 0.3), rtol=8 * EPS, atol=32 * EPS)  # |x0 + 0.3| < 2.3
    # the same values through param_derivative, normal_velocity and the fitting Jacobian
    np.testing.assert_array_equal(param_derivative(ball_tuple, x, "r", {"r": 1.2, "cx": -0.3}), d["r"])
    on_sphere = x / np.linalg.norm(x, axis=1, keepdims=True) * 1.2 + [-0.3, 0.0, 0.0]
    v = normal_velocity(ball_tuple, on_sphere, "r", {"r": 1.2, "cx": -0.3})
    np.testing.assert_allclose(v, -1.0, rtol=1e-13)  # the sphere grows outward at unit speed (a few roundings)
    prob = _Problem(ball_tuple, {}, {k: (p.lower, p.upper) for k, p in ball_tuple.params.items()})
    jac = _jacobian(prob, torch.as_tensor(x), torch.tensor([1.2, -0.3], dtype=torch.float64))
    np.testing.assert_array_equal(jac.numpy(), np.stack([d["r"], d["cx"]], axis=1))


def test_box_with_a_hole_closed_forms_on_its_faces():
    """On the hole's wall (R-difference with a cylinder, away from edges) the surface moves at
    unit speed when the hole widens; on a face x = size / 2 at half the speed of size."""
    values = {"size": 1.0, "hole": 0.2}
    t = np.linspace(0.0, 2 * np.pi, 50, endpoint=False)
    wall = np.stack([0.2 * np.cos(t), 0.2 * np.sin(t), np.linspace(-0.3, 0.3, 50)], axis=1)
    np.testing.assert_allclose(normal_velocity(box_with_hole, wall, "hole", values), 1.0, rtol=1e-12)
    face = np.stack([np.full(50, 0.5), np.linspace(-0.3, 0.3, 50), np.linspace(0.3, -0.3, 50)], axis=1)
    np.testing.assert_allclose(normal_velocity(box_with_hole, face, "size", values), -0.5, rtol=1e-12)
    np.testing.assert_allclose(normal_velocity(box_with_hole, face, "hole", values), 0.0, atol=1e-15)


def test_float32_numpy_and_torch_come_back_as_they_came():
    x = in_bounds(fig1_part, 100, seed=4)
    d64 = param_grad(fig1_part, x)["r"]
    d32 = param_grad(fig1_part, x.astype(np.float32))["r"]
    assert d32.dtype == np.float32
    np.testing.assert_allclose(d32, d64, rtol=1e-4, atol=1e-5 * np.abs(d64).max())
    t = param_grad(fig1_part, torch.as_tensor(x))["r"]
    assert isinstance(t, torch.Tensor) and t.dtype == torch.float64
    np.testing.assert_array_equal(t.numpy(), d64)


def test_chunks_do_not_change_values():
    x = torch.as_tensor(in_bounds(box_with_hole, 3000, seed=5))
    whole = param_grad(box_with_hole, x, chunk=10**6)
    pieces = param_grad(box_with_hole, x, chunk=77)
    for name in box_with_hole.names:
        torch.testing.assert_close(pieces[name], whole[name], rtol=0, atol=0)


def test_create_graph_keeps_the_parameters_and_the_points_in_the_graph():
    # d/dr (df/dr) of the sphere r^2 - |x - c|^2 is 2; d/dx (df/dcx) is 2 e_x
    r = torch.tensor(1.1, dtype=torch.float64, requires_grad=True)
    x = torch.as_tensor(in_bounds(ball_tuple, 20, seed=6)).requires_grad_(True)
    d = param_grad(ball_tuple, x, {"r": r, "cx": 0.2}, create_graph=True)
    (d2r,) = torch.autograd.grad(d["r"].sum(), r)
    assert d2r.item() == pytest.approx(2 * 20, rel=1e-14)
    (dx,) = torch.autograd.grad(d["cx"].sum(), x)
    torch.testing.assert_close(dx, torch.tensor([2.0, 0.0, 0.0], dtype=torch.float64).expand(20, 3))


def test_a_model_with_a_wrong_output_shape_is_named():
    @model(r=Param(0.5, 0.1, 1.0))
    def total(x, r):
        return (r - x).sum()  # one value for all points

    with pytest.raises(ValueError, match=r"total.*\(1, 3\).*\(\)"):
        param_grad(total, np.zeros((4, 3)))


def test_a_model_vmap_cannot_run_falls_back_per_point_with_one_warning():
    @model(r=Param(0.7, 0.5, 1.0))
    def branchy(x, r):
        if bool(x[:, 0].max() > 10.0):  # Python `if` on a point's value: vmap refuses it
            return -(x * x).sum(dim=1)
        return r**2 - (x * x).sum(dim=1)

    x = in_bounds(ball_tuple, 30, seed=7)
    with pytest.warns(RuntimeWarning, match="branchy.*vmap") as caught:
        d = param_grad(branchy, x, {"r": 0.8})
        param_grad(branchy, x, {"r": 0.8})
    assert sum("branchy" in str(w.message) for w in caught) == 1  # once per model
    np.testing.assert_allclose(d["r"], 1.6, rtol=4 * EPS)


# ----------------------------------------------------------------------------- compiled models


@pytest.mark.parametrize("m", [box_with_hole, fig1_part, ball_tuple], ids=lambda m: m.__name__)
def test_a_compiled_model_gives_the_eager_derivatives(m):
    fast = compiled(m)
    x = in_bounds(m, 500, seed=8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no compile failure, no per-point fallback
        got = param_grad(fast, x)
        one = param_derivative(fast, x, m.names[-1])
    want = param_grad(m, x)
    for name in m.names:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)
    np.testing.assert_array_equal(one, want[m.names[-1]])


# ----------------------------------------------------------------------------- threads


def _from_threads(call, n_threads: int = 4, calls: int = 40) -> list:
    """``call()`` from ``n_threads`` threads at once, ``calls`` times in all; the results and errors."""
    results, errors = [], []
    barrier = threading.Barrier(n_threads)

    def work() -> None:
        barrier.wait()
        for _ in range(calls // n_threads):
            try:
                results.append(call())
            except Exception as error:  # noqa: BLE001  (reported below)
                errors.append(error)

    threads = [threading.Thread(target=work) for _ in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not any(t.is_alive() for t in threads), "a thread hung"
    assert not errors, errors[:3]
    assert len(results) == calls
    return results


@pytest.mark.parametrize(
    "name",
    ["param_grad", "normal_velocity", "fitting_jacobian"],
)
def test_threads_give_exactly_the_serial_results(name):
    x = torch.as_tensor(in_bounds(fig1_part, 3000, seed=9))
    xb = torch.as_tensor(in_bounds(box_with_hole, 3000, seed=10))
    prob = _Problem(box_with_hole, {}, {k: (p.lower, p.upper) for k, p in box_with_hole.params.items()})
    q = torch.tensor([0.9, 0.25], dtype=torch.float64)
    calls = {
        # chunks of 512 points: the chunks of every call also run in the kernel's pool
        "param_grad": lambda: param_grad(fig1_part, x, {"r": 0.42}, chunk=512)["r"],
        "normal_velocity": lambda: normal_velocity(box_with_hole, xb, "hole", {"size": 0.9}, chunk=512),
        "fitting_jacobian": lambda: _jacobian(prob, xb, q),
    }
    call = calls[name]
    serial = call()
    assert serial.abs().max() > 0.1
    for got in _from_threads(call):
        assert torch.equal(got, serial)


# ----------------------------------------------------------------------------- memory


MEMORY_SCRIPT = textwrap.dedent(
    """
    import resource, sys
    import numpy as np, torch
    sys.path.insert(0, {tests!r})
    from test_param_derivatives import box_with_hole
    from pyfrep_core import Mesh, value_and_grad
    from pyfrep_core.sensitivity import normal_velocity
    from workbench.shape_panel import surface_velocity

    def rss():
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * resource.getpagesize()

    def reset_peak():
        try:
            with open("/proc/self/clear_refs", "w") as fh:
                fh.write("5")  # resets VmHWM to the current RSS
            return True
        except OSError:
            return False

    def peak():
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024

    # 100k points on the box's faces (size 1) and on the hole's wall (radius 0.2)
    rng = np.random.default_rng(0)
    n = 100_000
    u = rng.uniform(-0.5, 0.5, (n, 3))
    axis = rng.integers(0, 3, n)
    u[np.arange(n), axis] = np.where(rng.random(n) < 0.5, -0.5, 0.5)
    t = rng.uniform(0, 2 * np.pi, n // 4)
    u[: n // 4, 0], u[: n // 4, 1] = 0.2 * np.cos(t), 0.2 * np.sin(t)
    values = {{"size": 1.0, "hole": 0.2}}
    _, g = value_and_grad(lambda p: box_with_hole(p, **values), u)
    mesh = Mesh(u, np.zeros((0, 3), dtype=np.int64), gradient=g)
    surface_velocity(box_with_hole, Mesh(u[:100], np.zeros((0, 3), dtype=np.int64), gradient=g[:100]), "hole", values)
    base = rss()
    exact = reset_peak()
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    a = surface_velocity(box_with_hole, mesh, "hole", values)
    b = normal_velocity(box_with_hole, u, "size", values)
    used = (peak() if exact else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024) - base
    assert np.isfinite(a).all() and np.isfinite(b).all()
    wall = np.arange(n) < n // 4
    wall &= np.abs(u[:, 2]) < 0.45  # away from the hole's rims
    print(used, float(np.median(a[wall])), float(np.abs(b).max()))
    """
)


def test_colouring_100k_vertices_of_the_box_with_a_hole_stays_under_500_mb():
    tests = str(__import__("pathlib").Path(__file__).parent)
    out = subprocess.run(
        [sys.executable, "-c", MEMORY_SCRIPT.format(tests=tests)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    used, wall_speed, vmax_size = (float(v) for v in out.stdout.split()[-3:])
    assert used < 500e6, f"peak memory of the colouring: {used / 1e6:.0f} MB"
    assert wall_speed == pytest.approx(1.0, rel=1e-12)  # the hole's wall moves at unit speed
    assert vmax_size > 0.1
