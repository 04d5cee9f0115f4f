"""Interval bounds (pyfrep_core.interval): guaranteed, tight where it is cheap, and honest when it cannot.

Soundness is checked the only way that can fail: random boxes of several sizes, 10^5 points
sampled inside them (their corners included), every value the model computes at a point, in
float64 and in float32, inside the bounds of its box.  This over the whole catalogue (every
primitive, operation, transform, lattice, periodic and sdf function, the convolution surfaces),
the paper's models and random compositions drawn by hypothesis.  Tightness: the width of the
bounds shrinks at first order with the box (a fitted log-log slope), the R-functions are exact
by monotonicity, and on the Fig. 1 part most cells of a 32^3 grid are proved empty.
"""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest
import strategies as S
import torch
from hypothesis import given, settings
from test_validation import ARGS, CATALOGUE, _operands

import pyfrep_core as P
from pyfrep_core import models, sdf
from pyfrep_core.interval import Interval, IntervalUnsupported, bounds, supports

SAMPLES = 50_000  # points sampled per check and dtype (10^5 in all), spread over all its boxes
SIZES = (0.02, 0.1, 0.4)  # box edges, as fractions of the domain's half-width
BOXES = 16  # boxes per size

# ----------------------------------------------------------------------------- the checker


def _boxes(center, half, d, dtype, seed):
    """BOXES random boxes of each size in SIZES, inside center +- half: (lo, hi) of shape (B, d)."""
    g = torch.Generator().manual_seed(seed)
    center = torch.as_tensor(center, dtype=torch.float64)
    los, his = [], []
    for s in SIZES:
        c = center + (torch.rand(BOXES, d, generator=g, dtype=torch.float64) * 2 - 1) * half
        h = torch.rand(BOXES, d, generator=g, dtype=torch.float64) * (s * half) + 1e-3 * s * half
        los.append(c - h / 2)
        his.append(c + h / 2)
    return torch.cat(los).to(dtype), torch.cat(his).to(dtype)


def _samples(lo, hi, n, seed):
    """n points spread over the boxes (B, per, d): the 2^d corners of each box, then uniform points."""
    b, d = lo.shape
    per = max(2**d, n // b)
    g = torch.Generator().manual_seed(seed)
    t = torch.rand(b, per, d, generator=g, dtype=torch.float64)
    corners = torch.tensor([[(k >> i) & 1 for i in range(d)] for k in range(2**d)], dtype=torch.float64)
    t[:, : 2**d] = corners
    x = lo[:, None].double() + t * (hi - lo)[:, None].double()
    x = x.to(lo.dtype)
    return torch.minimum(torch.maximum(x, lo[:, None]), hi[:, None])  # the rounding kept inside


def check_sound(f, center=0.0, half=1.2, d=3, dtypes=(torch.float64, torch.float32), seed=0, n=SAMPLES, **params):
    """Every value of f at n points sampled in random boxes lies in the box's bounds; returns widths/ranges."""
    ratios = []
    for dtype in dtypes:
        lo, hi = _boxes(center, half, d, dtype, seed)
        flo, fhi = bounds(f, lo, hi, **params)
        assert flo.dtype == dtype and flo.shape == (lo.shape[0],)
        assert not (torch.isnan(flo).any() or torch.isnan(fhi).any())
        x = _samples(lo, hi, n, seed + 1)
        with torch.no_grad():
            v = f(x.reshape(-1, d), **params).reshape(x.shape[:2])
        inside = torch.isnan(v) | ((v >= flo[:, None]) & (v <= fhi[:, None]))
        if not bool(inside.all()):
            i, j = (int(k) for k in torch.nonzero(~inside)[0])
            pytest.fail(
                f"{dtype}: box {i} [{lo[i].tolist()}, {hi[i].tolist()}] has bounds [{flo[i].item()!r}, "
                f"{fhi[i].item()!r}] but f({x[i, j].tolist()}) = {v[i, j].item()!r}"
            )
        ratios.append(((fhi - flo) / (v.amax(1) - v.amin(1)).clamp_min(1e-12)).double())
    return torch.cat(ratios)


# ----------------------------------------------------------------------------- the catalogue


def _field1(x):
    return P.sphere(x, center=(0.1, -0.2, 0.05), r=0.8)


def _field2(x):
    return P.cylZ(x, center=(0.3, 0.0, 0.0), r=0.5)


def _field3(x):
    return P.sphere(x, center=(-0.2, 0.3, 0.1), r=0.6)


def _sdf1(x):
    return sdf.sphere(x, center=(0.1, -0.2, 0.05), r=0.8)


def _sdf2(x):
    return sdf.box(x, b=(0.5, 0.4, 0.6))


def catalogue_model(name):
    """A model of points exercising catalogue entry ``name``: the function itself, a transform or
    periodic map under a sphere, an operation on two or three fields."""
    fn, kw = CATALOGUE[name], ARGS.get(name, {})
    ops = _operands(fn)
    if ops[0] == "x":
        if fn.__module__.endswith((".transforms", ".periodic")):  # a point map
            return lambda x: P.sphere(fn(x, **kw), center=(0.1, 0.0, 0.0), r=0.7)
        return lambda x: fn(x, **kw)
    fields = (_sdf1, _sdf2, _field3) if name.startswith("sdf.") else (_field1, _field2, _field3)
    return lambda x: fn(*[g(x) for g in fields[: len(ops)]], **kw)


def test_every_catalogue_entry_is_checked():
    # every exported function of the seven modules is in the sweep below, but the one that
    # computes no field (spinodoid_directions: the wave vectors of a spinodoid)
    for module in ("primitives", "operations", "transforms", "lattices", "periodic", "sdf", "convolution"):
        names = importlib.import_module(f"pyfrep_core.{module}").__all__
        prefix = "sdf." if module == "sdf" else ""
        missing = {n for n in names if prefix + n not in CATALOGUE} - {"spinodoid_directions"}
        assert not missing, (module, missing)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_catalogue_bounds_hold_every_sampled_value(name):
    ratio = check_sound(catalogue_model(name))
    # not vacuous: on the smallest boxes the bounds are finite and within a modest factor of the
    # sampled range.  Larger boxes may get infinite bounds (a quotient whose divisor's bounds hold
    # 0), and so may small ones of the bound-blends near f1 = f2 = 0, f3 <= 0: their displacement
    # divides r1 by r1 + r2, both near 0 there (in [0, 1] in truth; the interval quotient cannot tell)
    n = len(SIZES) * BOXES
    small = torch.cat([ratio[:BOXES], ratio[n : n + BOXES]])
    if "bound" in name.lower():
        small = small[torch.isfinite(small)]
        assert small.numel() >= BOXES
    assert torch.isfinite(small).all()
    assert float(small.median()) < 40.0


# the paper's models, over their own boxes, at their default parameters and at others
PAPER = [
    ("fig1_part", {}),
    ("fig1_part", {"r": 0.65}),
    ("microstructure", {}),
    ("pawn", {}),
    ("pawn", {"head_radius": 0.35}),
    ("schwarz_d", {"c": 0.3}),
    ("ellipse", {}),
]


@pytest.mark.parametrize(("name", "params"), PAPER)
def test_paper_models_bounds_hold_every_sampled_value(name, params):
    m = getattr(models, name)
    lo, hi = (np.array(b) for b in m.bounds)
    ratio = check_sound(m, center=(lo + hi) / 2, half=float((hi - lo).max() / 2), d=m.dim, **params)
    assert float(ratio[:BOXES].median()) < 10.0


def test_naturally_written_model_with_parameter_tuples_and_stack():
    # p[:, i], a centre built from parameters, torch.stack, torch.where, Python arithmetic
    def f(p, cx, r):
        c = torch.stack([cx, cx * 0.5, torch.zeros_like(cx)])
        d = p - c
        ball = r**2 - (d * d).sum(1)
        slab = torch.where(p[:, 2] > 0.0, 0.4 - p[:, 2], 0.4 + p[:, 2])
        return P.intersection(ball, slab) + 0.1 * torch.tanh(p[:, 0]) - torch.exp(-(p[:, 1] ** 2))

    check_sound(f, cx=torch.tensor(0.2), r=0.9)


def test_user_torch_code_over_the_rules():
    # the operations a user writes that the catalogue does not: every rule at least once
    def f(x):
        a, b, c = x.unbind(-1)
        u = torch.linalg.vector_norm(x, dim=-1) + torch.linalg.norm(x[:, :2], dim=1) + x.norm(p=1, dim=-1)
        v = torch.clamp(a, -0.5, 0.5) + b.clamp_min(0.0) + torch.abs(c) ** 1.5 + torch.sqrt(a * a + 1.0)
        w = torch.atan2(b + 2.0, a) + torch.log(1.0 + c * c) + torch.cos(3.0 * a) * torch.sin(2.0 * b)
        z = (x @ torch.tensor([[1.0, -2.0], [0.5, 0.0], [0.0, 3.0]], dtype=x.dtype)).amax(-1) + 1.0 / (2.0 + a)
        q = torch.maximum(a, b).min(torch.minimum(b, c)) + torch.cat([a[:, None], b[:, None]], 1).sum(-1)
        r = torch.remainder(a * 3.0, 1.0) + torch.floor(2.0 * b) + torch.round(c) + (a - b) ** 3 + torch.tan(0.3 * c)
        k = torch.tensor([0.3, -1.0, 2.0]).type_as(x).expand_as(x)  # a constant vector per point
        s = torch.linalg.cross(x, k)[:, 0] + torch.einsum("ij,j->i", x, k[0]) + torch.exp(-(a**2)) * torch.cosh(b)
        return u + v + w + z + q + r + s + x.mean(-1) + torch.hypot(a, c) - 2.0**b + torch.sigmoid(c) + torch.atan(a)

    check_sound(f)


# ----------------------------------------------------------------------------- random compositions


@settings(max_examples=25, deadline=None, derandomize=True, database=None)
@given(S.trees())
def test_random_compositions_are_sound(tree):
    check_sound(tree, half=S.POINT_BOX, n=8_000, seed=3)


# ----------------------------------------------------------------------------- tightness


def _widths(f, center, sizes, d=3):
    c = torch.as_tensor(center, dtype=torch.float64)
    out = []
    for h in sizes:
        flo, fhi = bounds(f, (c - h / 2)[None], (c + h / 2)[None])
        out.append(float(fhi[0] - flo[0]))
    return np.array(out)


@pytest.mark.parametrize(
    ("name", "f", "center", "factor"),
    [
        ("sphere", lambda x: P.sphere(x, r=1.0), (0.3, 0.4, 0.5), 1.01),
        # -|d|^2 and 2 R rho depend on each other: their widths add up
        ("torus", lambda x: P.torusZ(x, R=1.0, r=0.3), (0.8, 0.5, 0.1), 20.0),
        ("gyroid", lambda x: P.gyroid(x, alpha=1.0, beta=1.0, gamma=1.0, c=0.0), (0.1, 0.2, 0.3), 2.0),
        ("fig1 part", models.fig1_part, (0.55, 0.6, 0.15), 2.0),
        ("blend", lambda x: P.blendUnion(_field1(x), _field2(x), 0.3, 0.5, 0.5), (0.2, 0.3, 0.1), 2.0),
        (
            "twisted ellipsoid",
            lambda x: P.ellipsoid(P.twistZ(x, -1.0, 1.0, 0.0, 1.0), a=1.0, b=0.5, c=0.7),
            (0.3, 0.2, 0.1),
            2.0,
        ),
    ],
)
def test_width_shrinks_at_first_order(name, f, center, factor):
    # width ~ C h on cubes of side h: the fitted slope of log width against log h is 1, and C is
    # at least the exact range's |grad f|_1 (a linear function's range over the cube) and at
    # most ``factor`` times it (the natural extension's constant: 1 for a sum of squares)
    sizes = 2.0 ** -np.arange(4, 12)
    w = _widths(f, center, sizes)
    slope = np.polyfit(np.log(sizes), np.log(w), 1)[0]
    assert 0.95 < slope < 1.05, (name, slope, w)
    x = torch.tensor([center], dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(f(x).sum(), x)
    l1 = float(g.abs().sum())
    c = w[-1] / sizes[-1]
    assert l1 * (1 - 1e-3) <= c < factor * l1, (name, c, l1)


def test_r_functions_are_exact_by_monotonicity():
    # intersection / union of the coordinate fields x and y: the exact range over a box is
    # [R(lo_x, lo_y), R(hi_x, hi_y)]; the natural extension would be wider by 2 sqrt(...)
    lo = torch.tensor([[-0.3, -0.2, 0.0], [0.1, -0.9, 0.0], [-1.0, -1.0, 0.0]], dtype=torch.float64)
    hi = lo + torch.tensor([0.5, 0.4, 1.0], dtype=torch.float64)
    for fn, sign in ((P.intersection, -1.0), (P.union, 1.0), (sdf.union, None)):
        flo, fhi = bounds(lambda x, fn=fn: fn(x[:, 0], x[:, 1]), lo, hi)
        if sign is None:  # sdf.union = max: exact too
            exact_lo, exact_hi = torch.maximum(lo[:, 0], lo[:, 1]), torch.maximum(hi[:, 0], hi[:, 1])
        else:
            exact_lo = lo[:, 0] + lo[:, 1] + sign * torch.hypot(lo[:, 0], lo[:, 1])
            exact_hi = hi[:, 0] + hi[:, 1] + sign * torch.hypot(hi[:, 0], hi[:, 1])
        assert (flo <= exact_lo).all() and (fhi >= exact_hi).all()
        # to rounding: 24 eps (|x| + |y|) (|x|, |y| <= 1 here) and an ulp
        atol = 64 * torch.finfo(torch.float64).eps
        torch.testing.assert_close(flo, exact_lo, rtol=0, atol=atol)
        torch.testing.assert_close(fhi, exact_hi, rtol=0, atol=atol)


def test_squares_are_exact():
    x = Interval.of(torch.tensor([-1.0, 2.0, -3.0]), torch.tensor([2.0, 3.0, -1.0]))
    y = x * x
    assert y.lo.tolist() == pytest.approx([0.0, 4.0, 1.0], abs=1e-6) and (y.lo <= torch.tensor([0.0, 4.0, 1.0])).all()
    assert y.hi.tolist() == pytest.approx([4.0, 9.0, 9.0], rel=1e-6) and (y.hi >= torch.tensor([4.0, 9.0, 9.0])).all()
    z = x**3
    assert (z.lo <= torch.tensor([-1.0, 8.0, -27.0])).all() and (z.hi >= torch.tensor([8.0, 27.0, -1.0])).all()


def test_fig1_part_grid_cells_proved_empty():
    # 32^3 cells over [-1.1, 1.1]^3: cells that cannot meet the surface (bounds of one sign).  A
    # cell meeting the surface is never proved empty: a sign change at its sampled corners means
    # the surface passes through it
    n = 32
    g = torch.linspace(-1.1, 1.1, n + 1, dtype=torch.float64)
    lo = torch.stack(torch.meshgrid(g[:-1], g[:-1], g[:-1], indexing="ij"), -1).reshape(-1, 3)
    hi = lo + 2.2 / n
    flo, fhi = bounds(models.fig1_part, lo, hi)
    empty = (flo > 0) | (fhi < 0)
    corners = _samples(lo, hi, 8 * lo.shape[0], 0)[:, :8]
    v = models.fig1_part(corners.reshape(-1, 3)).reshape(-1, 8)
    crossing = (v.amax(1) > 0) & (v.amin(1) < 0)
    assert not (empty & crossing).any()
    # the surface meets about n^2 cells (area 8.4 of the part / cell face 0.0047: ~1800-3000);
    # all but a thin layer around it are proved empty
    assert int(crossing.sum()) > 1500
    assert float(empty.float().mean()) > 0.88


# ----------------------------------------------------------------------------- interface


def test_numpy_in_numpy_out_and_dtype_kept():
    lo = np.array([[0.1, 0.2, 0.3]], np.float32)
    flo, fhi = bounds(lambda x: P.sphere(x, r=1.0), lo, lo + np.float32(0.1))
    assert isinstance(flo, np.ndarray) and flo.dtype == np.float32 and flo.shape == (1,)
    exact = 1.0 - np.array([0.1, 0.2, 0.3]) ** 2 @ np.ones(3), 1.0 - np.array([0.2, 0.3, 0.4]) ** 2 @ np.ones(3)
    assert flo[0] <= exact[1] <= fhi[0] and flo[0] <= exact[0] <= fhi[0]
    t = torch.tensor([[0.1, 0.2, 0.3]], dtype=torch.float64)
    flo, fhi = bounds(lambda x: P.sphere(x, r=1.0), t, t + 0.1)
    assert isinstance(flo, torch.Tensor) and flo.dtype == torch.float64
    # nested lists are numbers without a dtype: float64 numpy out (as_tensor's rule), not a crash
    flo, fhi = bounds(lambda x: P.sphere(x, r=1.0), [[0.1, 0.2, 0.3]], [[0.2, 0.3, 0.4]])
    assert isinstance(flo, np.ndarray) and flo.dtype == np.float64
    assert flo[0] <= exact[1] and exact[0] <= fhi[0]


def test_model_parameters_and_defaults():
    lo = torch.tensor([[0.3, 0.3, 0.6]], dtype=torch.float64)
    hi = lo + 0.05
    # a box 0.42 to 0.5 from the z axis, 0.67 from the others, inside the sphere and the cube:
    # drilled by the default cylinders (r = 0.5: f < 0), solid with r = 0.2 (f > 0)
    lo_default, hi_default = bounds(models.fig1_part, lo, hi)
    lo_thin, hi_thin = bounds(models.fig1_part, lo, hi, r=torch.tensor(0.2, dtype=torch.float64))
    assert float(hi_default[0]) < 0 < float(lo_thin[0])
    lo_f, hi_f = bounds(models.fig1_part, lo, hi, r=0.2)
    assert torch.equal(lo_f, lo_thin) and torch.equal(hi_f, hi_thin)
    with pytest.raises(TypeError, match="no parameter 'radius'"):
        bounds(models.fig1_part, lo, hi, radius=0.2)
    with pytest.raises(ValueError, match="must be a scalar"):
        bounds(models.fig1_part, lo, hi, r=torch.tensor([0.2, 0.3]))


def test_point_boxes_contain_the_value_and_chunks_agree():
    g = torch.Generator().manual_seed(5)
    x = torch.rand(1000, 3, generator=g, dtype=torch.float64) * 2 - 1
    flo, fhi = bounds(models.fig1_part, x, x)
    v = models.fig1_part(x)
    assert ((flo <= v) & (v <= fhi)).all()
    # a point box: the value, to the roundings of the operations (each widened by a few ulps of
    # its operands, whose magnitudes grow with |f| here: up to 50 at the corners of the cube)
    assert ((fhi - flo) < 1e-12 * (1.0 + v.abs())).all()
    lo2, hi2 = bounds(models.fig1_part, x, x + 0.05, chunk=97)
    lo1, hi1 = bounds(models.fig1_part, x, x + 0.05)
    assert torch.equal(lo1, lo2) and torch.equal(hi1, hi2)


def test_bad_boxes_are_refused():
    lo = torch.zeros(2, 3)
    with pytest.raises(ValueError, match=r"box 1 has lo > hi"):
        bounds(P.sphere, lo, torch.tensor([[1.0, 1.0, 1.0], [1.0, -1.0, 1.0]]))
    with pytest.raises(ValueError, match=r"one shape \(B, d\)"):
        bounds(P.sphere, lo, torch.ones(3, 3))
    with pytest.raises(ValueError, match="finite"):
        bounds(P.sphere, lo, torch.full((2, 3), math.inf))
    with pytest.raises(ValueError, match="takes points of 2 coordinates"):
        bounds(models.ellipse, lo, lo + 1.0)
    with pytest.raises(TypeError, match="float32 or float64"):
        bounds(P.sphere, np.zeros((2, 3), np.int64), np.ones((2, 3), np.int64))


@pytest.mark.parametrize(
    ("f", "op"),
    [
        (lambda x: torch.sort(x, dim=1).values[:, 0], "sort"),
        (lambda x: torch.fft.fft(x).real[:, 0], "fft"),
        (lambda x: torch.cumsum(x, 1)[:, -1], "cumsum"),
        (lambda x: x[:, 0] - x[:, 1].median(), "median"),
        (lambda x: x[:, 0] if bool((x[:, 0] > 0.3).all()) else -x[:, 0], r"bool\(\) of a comparison"),
        (lambda x: x[:, 0] * float(x[0, 1]), r"reading values \(\.item\(\), float\(\)"),
    ],
)
def test_unsupported_operation_is_named(f, op):
    lo = torch.tensor([[0.2, 0.2, 0.2]], dtype=torch.float64)
    with pytest.raises(IntervalUnsupported, match=op):
        bounds(f, lo, lo + 0.5)
    assert not supports(f)
    assert issubclass(IntervalUnsupported, TypeError)


def test_a_decided_python_if_is_fine():
    def f(x):
        return x[:, 0] if bool((x[:, 0] > 0.0).all()) else -x[:, 0]

    lo = torch.tensor([[0.2, 0.2, 0.2]], dtype=torch.float64)
    flo, fhi = bounds(f, lo, lo + 0.5)
    assert float(flo[0]) <= 0.2 and float(fhi[0]) >= 0.7 and float(fhi[0] - flo[0]) < 0.5 + 1e-12
    assert supports(models.fig1_part) and supports(models.microstructure)


def test_threads_give_the_serial_bounds():
    from concurrent.futures import ThreadPoolExecutor

    g = torch.Generator().manual_seed(2)
    boxes = [torch.rand(500, 3, generator=g, dtype=torch.float64) * 2 - 1 for _ in range(8)]
    models_ = [models.fig1_part, models.pawn, lambda x: P.gyroid(x, alpha=1.0, beta=1.0, gamma=1.0, c=0.1)]
    jobs = [(f, b) for f in models_ for b in boxes]
    serial = [bounds(f, b, b + 0.1) for f, b in jobs]
    with ThreadPoolExecutor(4) as pool:
        threaded = list(pool.map(lambda job: bounds(job[0], job[1], job[1] + 0.1), jobs))
    for (a, b), (c, d) in zip(serial, threaded, strict=True):
        assert torch.equal(a, c) and torch.equal(b, d)


def test_ordinary_use_is_untouched():
    # after interval evaluation, the same catalogue functions run under torch.func as before
    lo = torch.zeros(4, 3, dtype=torch.float64)
    bounds(models.fig1_part, lo, lo + 0.1)
    x = torch.tensor([[0.55, 0.55, 0.55]], dtype=torch.float64)
    g = torch.func.vmap(torch.func.grad(lambda p: models.fig1_part.fn(p[None], r=torch.tensor(0.5))[0]))(x)
    x.requires_grad_(True)
    (g_ref,) = torch.autograd.grad(models.fig1_part(x).sum(), x)
    torch.testing.assert_close(g, g_ref)
    assert not isinstance(models.fig1_part(x.detach()), Interval)
