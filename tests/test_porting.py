"""Porting the paper's reference code (fayolle/PyFRep) is an import change; docs/porting.md holds to the code.

Four of the reference's programs are written below as a user writes them after porting: the
same body (``p[:, i]`` indexing, ``param[k]``, the reference's argument order), with
``from pyfrep_core import *`` instead of ``from FRep.primitives import *``.  Their values are
checked against closed forms written here in numpy (and against the reference itself when
``PYFREP_SRC`` names a checkout of it: the folder holding ``FRep/``); then they are meshed,
differentiated (grad, param_grad against finite differences) and one is fitted.  The claims
of docs/porting.md (sawtooth and triangle-wave ranges, rep, union_m's default, scale with a
tuple, superQuadric's Euler order, convTriangle's S^3, twist) are tested against the
reference's formulas, and the new twist, mapBlob and sdf.superQuadric against theirs, under
vmap, grad and torch.compile too.
"""

import contextlib
import importlib
import inspect
import math
import os
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

import pyfrep_core
from pyfrep_core import *
from pyfrep_core import sdf

# ----------------------------------------------------------------------------- the ported programs


def sphere_grid(p, param):
    """examples/fit_microstructure_*.py's model (the paper's Figs. 7-8), body unchanged."""
    x0 = p[:, 0]
    x1 = p[:, 1]
    x2 = p[:, 2]
    sp = 1.0 - (x0 / 10.0) ** 2 - (x1 / 10.0) ** 2 - (x2 / 10.0) ** 2
    norsp = sp
    offset = 0.15
    offsp = norsp - offset
    sp_shell = difference(sp, offsp)
    t1 = norsp
    scale1 = param[0]
    scale2 = param[1]
    scale = scale1 * (1.0 - t1) + scale2 * t1
    xt = x0 * scale
    yt = x1 * scale
    zt = x2 * scale
    freq1 = param[2]
    freq2 = param[3]
    tsin = freq1 * (1.0 - t1) + freq2 * t1
    xslabs = torch.sin(xt) - tsin
    yslabs = torch.sin(yt) - tsin
    zslabs = torch.sin(zt) - tsin
    xrods = intersection(yslabs, zslabs)
    yrods = intersection(xslabs, zslabs)
    zrods = intersection(xslabs, yslabs)
    grid = union(blendUnion(xrods, zrods, 1.0, 3.0, 3.0), yrods)
    sphere_grid = intersection(union(sp_shell, intersection(sp, grid)), x1)
    return sphere_grid


TRUTH = {"scale1": 9.0, "scale2": 3.0, "freq1": 0.75, "freq2": 0.85}


@pyfrep_core.model(
    bounds=((-10.5, -0.5, -10.5), (10.5, 10.5, 10.5)),
    scale1=Param(9.0, 1.0, 10.0),
    scale2=Param(3.0, 1.0, 10.0),
    freq1=Param(0.75, 0.1, 2.0),
    freq2=Param(0.85, 0.1, 2.0),
)
def microstructure_port(p, scale1, scale2, freq1, freq2):
    """The reference's ``param`` list, declared with names and bounds for fit and param_grad."""
    return sphere_grid(p, (scale1, scale2, freq1, freq2))


def replicant(p):
    """examples/sawtooth_render.py; the one change docs/porting.md asks for: sawtooth's range (* 2 / T)."""
    q = sawtooth(p, 5.0) * 2 / 5.0
    torus1 = torusZ(q, (-1.0, 1.0, 0.0), 1.0, 0.25)
    torus2 = torusX(q, (0.0, -1.0, -1.0), 1.0, 0.25)
    torus3 = torusY(q, (1.0, 0.0, 1.0), 1.0, 0.25)
    sp4 = sphere(q, (0.0, 0.0, 0.0), 0.8)
    res5 = boundBlendUnion(torus1, torus2, sp4, 0.08, 1.0, 1.0, 1.0)
    res6 = boundBlendUnion(res5, torus3, sp4, 0.08, 1.0, 1.0, 1.0)
    return res6


def star(p):
    """test/test_convline_render.py: four convolution segments from the origin."""
    res = convLine(
        p,
        begin=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        end=(1.0, 1.0, 0.0, -1.0, -1.0, 0.0, -1.0, 1.0, 0.0, 1.0, -1.0, 0.0),
        S=(3.0, 3.0, 3.0, 3.0),
        T=0.5,
    )
    return res


# examples/example_CAD.py (thirteen capped cylinders of a machine part, SDF operations), a file of its own:
# the SDF module's union/difference are min/max, so it is star-imported alone, as the reference does
CAD_IMPORTS = "from pyfrep_core.sdf import *\nfrom pyfrep_core import rotate3DX\n"
CAD_REFERENCE_IMPORTS = (
    "from FRep.sdf_primitives import *\nfrom FRep.sdf_ops import *\nfrom FRep.ops import rotate3DX\n"
)
CAD_BODY = """
def model(p):
    piover2 = 1.5707963267948966192
    p = rotate3DX(p, -piover2)
    cyl1 = cappedCylinder(p, [1.078, 3.327, -3.0], [1.078, 3.327, 3.0], 0.5)
    cyl2 = cappedCylinder(p, [0.0, 0.0, -3.0], [0.0, 0.0, 0.0], 5.0)
    cyl3 = cappedCylinder(p, [3.5, 0.0, 0.0], [3.5, 0.0, 3.0], 0.5)
    cyl4 = cappedCylinder(p, [-1.075, -3.329, -19.0], [-1.075, -3.329, 19.0], 1.0)
    cyl5 = cappedCylinder(p, [-1.081, 3.325, -19.0], [-1.081, 3.325, 19.0], 1.0)
    cyl6 = cappedCylinder(p, [1.081, -3.326, 0.0], [1.081, -3.326, 3.0], 0.5)
    cyl7 = cappedCylinder(p, [0.03, 0.015, 0.0], [0.03, 0.015, 2.5], 2.0)
    cyl8 = cappedCylinder(p, [0.0, 0.0, -3.0], [0.0, 0.0, 2.5], 1.5)
    cyl9 = cappedCylinder(p, [2.837, -2.072, -3.0], [2.837, -2.072, 19.0], 1.0)
    cyl10 = cappedCylinder(p, [-3.496, -0.013, -3.0], [-3.496, -0.013, 19.0], 1.0)
    cyl11 = cappedCylinder(p, [2.83, 2.059, -3.0], [2.83, 2.059, 0.0], 1.0)
    cyl12 = cappedCylinder(p, [-2.835, -2.058, 0.0], [-2.835, -2.058, 3.0], 0.5)
    cyl13 = cappedCylinder(p, [-2.834, 2.051, 0.0], [-2.834, 2.051, 3.0], 0.5)
    tmp1 = union(cyl2, cyl3)
    tmp2 = union(cyl4, cyl5)
    tmp3 = difference(tmp1, tmp2)
    tmp4 = union(cyl1, tmp3)
    tmp5 = union(tmp4, cyl6)
    tmp6 = union(tmp5, cyl7)
    tmp7 = union(cyl8, cyl9)
    tmp8 = union(tmp7, cyl10)
    tmp9 = union(tmp8, cyl11)
    tmp10 = difference(tmp6, tmp9)
    tmp11 = union(tmp10, cyl12)
    tmp12 = union(tmp11, cyl13)
    return tmp12
"""
CAD_BOUNDS = ((-6.0, -3.6, -6.0), (6.0, 3.6, 6.0))


def _program(imports, body, name="model"):
    """The function ``name`` of a program file made of ``imports`` and ``body``."""
    namespace = {}
    exec(compile(imports + body, "<ported program>", "exec"), namespace)
    return namespace[name]


cad_part = _program(CAD_IMPORTS, CAD_BODY)

# ----------------------------------------------------------------------------- the reference, when given


def _reference_root():
    """The folder holding the reference's ``FRep/`` (from ``PYFREP_SRC``), or skip with the reason."""
    src = os.environ.get("PYFREP_SRC")
    if not src:
        pytest.skip("PYFREP_SRC is not set (a checkout of fayolle/PyFRep: the folder holding FRep/)")
    root = Path(src)
    root = root.parent if root.name == "FRep" else root
    if not (root / "FRep" / "primitives.py").is_file():
        pytest.skip(f"PYFREP_SRC={src} holds no FRep/primitives.py")
    return root


@contextlib.contextmanager
def _reference_importable():
    root = str(_reference_root())
    sys.path.insert(0, root)
    try:
        yield
    finally:
        sys.path.remove(root)


def _reference_modules():
    with _reference_importable():
        return [importlib.import_module(f"FRep.{name}") for name in ("primitives", "ops", "sdf_primitives")]


def _in_reference(fn, edit=("", "")):
    """``fn``'s own source run under the reference's imports (the same body; ``edit`` undoes a porting change)."""
    source = textwrap.dedent(inspect.getsource(fn)).replace(*edit)
    with _reference_importable():
        return _program("import torch\nfrom FRep.primitives import *\nfrom FRep.ops import *\n", source, fn.__name__)


def _points(bounds, n, seed):
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    return torch.from_numpy(np.random.default_rng(seed).uniform(lo, hi, (n, 3)))


# ----------------------------------------------------------------------------- closed forms (numpy)


def _r_union(a, b):
    return a + b + np.sqrt(a * a + b * b)


def _r_intersection(a, b):
    return a + b - np.sqrt(a * a + b * b)


def sphere_grid_formula(p, s1, s2, c1, c2):
    t = 1.0 - (p * p).sum(-1) / 100.0
    shell = _r_intersection(t, -(t - 0.15))
    scale, level = s1 * (1 - t) + s2 * t, c1 * (1 - t) + c2 * t
    slab = [np.sin(p[:, k] * scale) - level for k in range(3)]
    xrods, yrods, zrods = (_r_intersection(slab[i], slab[j]) for i, j in ((1, 2), (0, 2), (0, 1)))
    blend = _r_union(xrods, zrods) + 1.0 / (1.0 + (xrods / 3.0) ** 2 + (zrods / 3.0) ** 2)
    return _r_intersection(_r_union(shell, _r_intersection(t, _r_union(blend, yrods))), p[:, 1])


def reference_sawtooth(p, period):
    """The reference's sawtooth, as its source writes it: 2 (1/2 - atan(1 / tan(pi (p/T - 1/2))) / pi) - 1."""
    return 2.0 * (0.5 - np.arctan(1.0 / np.tan(np.pi * (p / period - 0.5))) / np.pi) - 1.0


def reference_triangle_wave(p, period):
    return 2.0 / np.pi * np.arcsin(np.sin(np.pi * (2.0 * p / period - 0.5)))


def replicant_formula(p):
    q = reference_sawtooth(p, 5.0)

    def torus(center, axis):
        d = q - np.asarray(center)
        rho = np.sqrt((d * d).sum(-1) - d[:, axis] ** 2)
        return 0.25**2 - (d * d).sum(-1) - 1.0 + 2.0 * rho

    def bounded_blend(f1, f2, f3):  # a0 = 0.08, a1 = a2 = a3 = 1
        r1, r2 = f1 * f1 + f2 * f2, np.maximum(f3, 0.0) ** 2
        r = np.where(r1 > 0, r1 / np.where(r1 + r2 > 0, r1 + r2, 1.0), 0.0)
        return _r_union(f1, f2) + 0.08 * (1.0 - r) ** 3 / (1.0 + r)

    ball = 0.64 - (q * q).sum(-1)
    blended = bounded_blend(torus((-1.0, 1.0, 0.0), 2), torus((0.0, -1.0, -1.0), 0), ball)
    return bounded_blend(blended, torus((1.0, 0.0, 1.0), 1), ball)


def segment_integral(p, end, s, n=400):
    """Gauss-Legendre rule (n nodes) of the Cauchy kernel 1 / (1 + S^2 r^2)^2 along the segment 0 -> end."""
    nodes, weights = np.polynomial.legendre.leggauss(n)
    u = (nodes + 1) / 2
    points = u[:, None] * np.asarray(end)[None]
    r2 = ((p[:, None, :] - points[None]) ** 2).sum(-1)
    return (weights / 2 / (1.0 + s * s * r2) ** 2).sum(-1) * np.linalg.norm(end)


def capped_cylinder_distance(p, a, b, radius):
    """Exact signed distance (positive inside) to the capped cylinder a-b: a 2-D box in (rho, h)."""
    a, b = np.asarray(a), np.asarray(b)
    length = np.linalg.norm(b - a)
    axis = (b - a) / length
    h = (p - a) @ axis
    rho = np.linalg.norm(p - a - h[:, None] * axis, axis=-1)
    q = np.stack([rho - radius, np.abs(h - length / 2) - length / 2], -1)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    return -np.where(q.max(-1) > 0, outside, q.max(-1))


def cad_formula(p):
    p = np.stack([p[:, 0], -p[:, 2], p[:, 1]], -1)  # rotate3DX(p, -pi/2): (x, y cos + z sin, -y sin + z cos)
    rows = [
        l.split("cappedCylinder(p, ")[1].rstrip(")").replace("], ", "];")
        for l in CAD_BODY.splitlines()
        if "capped" in l
    ]
    cyl = [None] + [capped_cylinder_distance(p, *(eval(v) for v in row.split(";"))) for row in rows]  # noqa: S307
    union_, diff = np.maximum, lambda d1, d2: np.minimum(d1, -d2)
    tmp6 = union_(union_(union_(cyl[1], diff(union_(cyl[2], cyl[3]), union_(cyl[4], cyl[5]))), cyl[6]), cyl[7])
    tmp9 = union_(union_(union_(cyl[8], cyl[9]), cyl[10]), cyl[11])
    return union_(union_(diff(tmp6, tmp9), cyl[12]), cyl[13])


# ----------------------------------------------------------------------------- values: closed forms and the reference


MICRO_BOUNDS = ((-10.5, -0.5, -10.5), (10.5, 10.5, 10.5))


def test_ported_microstructure_equals_its_formula_and_the_kernels_model():
    p = _points(MICRO_BOUNDS, 2000, 0)
    values = sphere_grid(p, (9.0, 3.0, 0.75, 0.85))
    np.testing.assert_allclose(
        values.numpy(), sphere_grid_formula(p.numpy(), 9.0, 3.0, 0.75, 0.85), rtol=1e-12, atol=1e-12
    )
    # the same shape as pyfrep_core.models.microstructure (written with x[..., k] instead of p[:, k])
    from pyfrep_core.models import microstructure

    np.testing.assert_allclose(values.numpy(), microstructure(p).numpy(), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(microstructure_port(p).numpy(), values.numpy(), rtol=0, atol=0)
    assert (values > 0).any() and (values < 0).any()


def test_ported_sawtooth_cell_equals_its_formula():
    p = _points(((-10.0,) * 3, (10.0,) * 3), 4000, 1)
    values = replicant(p).numpy()
    expected = replicant_formula(p.numpy())
    np.testing.assert_allclose(values, expected, rtol=1e-10, atol=1e-10)
    assert (values > 0).any() and (values < 0).any()


def test_ported_convolution_star_equals_the_integral_of_the_kernel():
    p = _points(((-2.0,) * 3, (2.0,) * 3), 40, 2)
    ends = [(1.0, 1.0, 0.0), (-1.0, -1.0, 0.0), (-1.0, 1.0, 0.0), (1.0, -1.0, 0.0)]
    expected = sum(segment_integral(p.numpy(), e, 3.0) for e in ends) - 0.5
    # a smooth integrand of width >= 1/S = 1/3 over a length sqrt(2): 400 Gauss nodes give it to rounding
    np.testing.assert_allclose(star(p).numpy(), expected, rtol=0, atol=1e-12)


def test_ported_cad_part_equals_its_distance_formula():
    p = _points(CAD_BOUNDS, 3000, 3)
    values = cad_part(p).numpy()
    np.testing.assert_allclose(values, cad_formula(p.numpy()), rtol=0, atol=1e-12)
    assert (values > 0).any() and (values < 0).any()


def test_ported_programs_equal_the_reference_programs():
    """The same source under the reference's imports gives the same values (skipped without PYFREP_SRC)."""
    p = _points(MICRO_BOUNDS, 2000, 4)
    params = (9.0, 3.0, 0.75, 0.85)
    np.testing.assert_allclose(sphere_grid(p, params), _in_reference(sphere_grid)(p, params), rtol=1e-12, atol=1e-12)
    # the sawtooth program as the reference wrote it: without the * 2 / T that porting adds
    reference_replicant = _in_reference(replicant, edit=("sawtooth(p, 5.0) * 2 / 5.0", "sawtooth(p, 5.0)"))
    p = _points(((-10.0,) * 3, (10.0,) * 3), 4000, 5)
    np.testing.assert_allclose(replicant(p), reference_replicant(p), rtol=1e-10, atol=1e-10)
    p = _points(((-2.0,) * 3, (2.0,) * 3), 400, 6)
    np.testing.assert_allclose(star(p), _in_reference(star)(p), rtol=1e-12, atol=1e-14)
    with _reference_importable():
        reference_cad = _program(CAD_REFERENCE_IMPORTS, CAD_BODY)
    p = _points(CAD_BOUNDS, 3000, 7)
    np.testing.assert_allclose(cad_part(p), reference_cad(p).reshape(-1), rtol=0, atol=1e-12)  # reference: (N, 1)


def test_the_porting_table_against_the_reference():
    """docs/porting.md's value claims, against the reference's own functions (skipped without PYFREP_SRC)."""
    ref, ops, ref_sdf = _reference_modules()
    x = _points(((-3.0,) * 3, (3.0,) * 3), 500, 16)
    for period in (2.0, 5.0):
        np.testing.assert_allclose(sawtooth(x, period) * 2 / period, ops.sawtooth(x, period), atol=1e-9)
        np.testing.assert_allclose(triangleWave(x, period) * 4 / period - 1, ops.triangleWave(x, period), atol=1e-12)
    np.testing.assert_allclose(union_m(x[:, 0], x[:, 1], m=2), ops.union_m(x[:, 0], x[:, 1]), rtol=1e-14)
    np.testing.assert_allclose(scale(x, (1.0, 2.0, 3.0)), ops.scale(x, (1.0, 2.0, 3.0)), rtol=1e-15)
    np.testing.assert_allclose(twist(x, 0.7), ops.twist(x, 0.7), atol=1e-15)
    np.testing.assert_allclose(twistZ(x, -1.0, 1.0, 0.0, 1.0), ops.twistZ(x, -1.0, 1.0, 0.0, 1.0), atol=1e-15)
    np.testing.assert_allclose(
        rotate(x, 0.4, axis=(1.0, 2.0, 3.0)), ops.rotate(x, torch.tensor(0.4), vector=(1.0, 2.0, 3.0)), atol=1e-6
    )  # the reference builds its rotation matrix in float32: 6e-8 relative, |x| <= 3 sqrt(3)
    above = x >= -0.5  # rep: the same coordinates from -c/2 up; below, fmod leaves the cell
    np.testing.assert_allclose(rep(x, 1.0)[above], ops.rep(x, 1.0)[above], atol=1e-14)
    assert float(ops.rep(x, 1.0).min()) < -0.5 - 1e-3 <= float(rep(x, 1.0).min())
    tri = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    np.testing.assert_allclose(8.0 * convTriangle(x, tri, 2.0, 0.0), ref.convTriangle(x, tri, [2.0], 0.0), rtol=1e-12)
    mesh = ([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 1.0, 1.0, 0.5], [1, 2, 3, 2, 4, 3])
    np.testing.assert_allclose(8.0 * convMesh(x, *mesh, 2.0, 0.0), ref.convMesh(x, *mesh, [2.0, 2.0], 0.0), rtol=1e-12)
    # sdf.superQuadric: the reference scales by the norm of the whole batch; per point, the values agree
    e, a, r, t = (1.0, 1.0), (1.0, 0.6, 0.8), (0.3, -0.5, 0.9), (0.1, 0.2, -0.3)  # even powers: no NaN there
    reference = ref_sdf.superQuadric(x, e, a, torch.tensor(r, dtype=x.dtype), t)
    offset = x - torch.tensor(t, dtype=x.dtype)
    per_point = reference / torch.linalg.norm(offset, 2) * offset.norm(dim=-1)
    np.testing.assert_allclose(sdf.superQuadric(x, e, a, r, t), per_point, rtol=1e-12, atol=1e-12)
    # sdf.block: the reference's box is sdf.box with the edge lengths as half-extents
    np.testing.assert_allclose(
        sdf.box(x, (1.0, 2.0, 0.5), center=(0.6, 1.2, 0.05)),
        ref_sdf.block(x, (0.1, 0.2, -0.2), 1.0, 2.0, 0.5),
        atol=1e-14,
    )


# ----------------------------------------------------------------------------- mesh, derivatives, fit


def _truth_grid(p):
    return sphere_grid(p, tuple(TRUTH.values()))


PROGRAMS = {  # program, bounds, meshing resolution
    "microstructure": (_truth_grid, MICRO_BOUNDS, 48),
    "sawtooth cell": (replicant, ((-10.0,) * 3, (10.0,) * 3), 48),
    "convolution star": (star, ((-2.0,) * 3, (2.0,) * 3), 32),
    "CAD part": (cad_part, CAD_BOUNDS, 48),
}


@pytest.mark.parametrize("name", PROGRAMS)
@pytest.mark.filterwarnings("ignore:polygonize.*could not be moved onto f = 0:RuntimeWarning")
def test_ported_programs_mesh(name):
    program, bounds, resolution = PROGRAMS[name]
    mesh = polygonize(program, bounds, resolution)
    assert mesh.n_faces > 100
    # the vertices are projected onto f = 0: first-order distance |f| / |grad f| at rounding level, but for
    # the few polygonize leaves where its root finding does not converge (on creases of the R-functions)
    v = torch.from_numpy(mesh.vertices)
    distance = program(v).abs() / grad(program, v).norm(dim=-1)
    extent = float(np.max(np.abs(np.asarray(bounds))))
    assert float((distance < 1e-10 * extent).double().mean()) > 0.99
    if name == "microstructure":  # the same marching-cubes mesh as the kernel's own model of it
        from pyfrep_core.models import microstructure

        own = polygonize(microstructure, bounds, resolution)
        assert own.n_faces == mesh.n_faces  # the same grid signs (vertices may differ where projection stalls)


@pytest.mark.parametrize("name", PROGRAMS)
def test_ported_programs_spatial_gradient_is_the_central_difference(name):
    program, bounds, _ = PROGRAMS[name]
    p = _points(bounds, 50, 9)
    h = 1e-6  # float64 central differences: truncation ~ h^2 f''', rounding ~ 1e-16 |f| / h
    step = h * torch.eye(3, dtype=p.dtype)
    fd = torch.stack([(program(p + step[k]) - program(p - step[k])) / (2 * h) for k in range(3)], -1)
    torch.testing.assert_close(grad(program, p), fd, rtol=1e-6, atol=1e-7 * max(1.0, float(fd.abs().max())))


def test_ported_microstructure_param_grad_is_the_central_difference():
    p = _points(MICRO_BOUNDS, 200, 10)
    dfdp = param_grad(microstructure_port, p, TRUTH)
    assert list(dfdp) == list(TRUTH)
    for name, value in TRUTH.items():
        h = 1e-6 * value
        up = microstructure_port(p, **{**TRUTH, name: value + h})
        down = microstructure_port(p, **{**TRUTH, name: value - h})
        torch.testing.assert_close(dfdp[name], (up - down) / (2 * h), rtol=1e-6, atol=1e-7)


def test_fit_recovers_a_parameter_of_the_ported_microstructure():
    truth = {**TRUTH, "freq1": 0.7}
    points = sample_surface(microstructure_port, 4000, params=truth, seed=0)
    fixed = {k: v for k, v in truth.items() if k != "freq1"}
    result = fit(
        microstructure_port, points, fixed=fixed, cycles=300, population_size=20, epochs=3, seed=0, progress=False
    )
    # points on the exact surface (projected to ~1e-13): the least-squares polish recovers it to rounding
    assert result.params["freq1"] == pytest.approx(0.7, rel=1e-6)


# ----------------------------------------------------------------------------- docs/porting.md's claims


def test_sawtooth_and_triangle_wave_ranges_as_the_table_says():
    x = torch.linspace(-7.3, 7.3, 1001, dtype=torch.float64)
    for period in (1.0, 2.0, 5.0):
        saw, tri = sawtooth(x, period), triangleWave(x, period)
        assert float(saw.min()) >= -period / 2 and float(saw.max()) < period / 2
        assert float(tri.min()) >= 0.0 and float(tri.max()) <= period / 2
        # the reference's values: sawtooth * 2 / T in [-1, 1], triangleWave * 4 / T - 1
        keep = np.abs(np.remainder(x.numpy() / period + 0.5, 1.0)) > 1e-9  # away from the jumps
        np.testing.assert_allclose(
            (saw * 2 / period).numpy()[keep], reference_sawtooth(x.numpy(), period)[keep], atol=1e-12
        )
        np.testing.assert_allclose(
            (tri * 4 / period - 1).numpy(), reference_triangle_wave(x.numpy(), period), atol=1e-12
        )


def test_rep_differs_from_fmod_below_minus_half_a_period_only():
    x = torch.tensor([[-0.8, 0.3, 1.7]], dtype=torch.float64)
    np.testing.assert_allclose(rep(x, 1.0).numpy(), [[0.2, 0.3, -0.3]], atol=1e-15)
    fmod = torch.fmod(x + 0.5, 1.0) - 0.5  # the reference's
    np.testing.assert_allclose(fmod.numpy(), [[-0.8, 0.3, -0.3]], atol=1e-15)


def test_union_m_default_and_m2_as_the_table_says():
    f1, f2 = torch.tensor([3.0, -1.0], dtype=torch.float64), torch.tensor([4.0, 0.5], dtype=torch.float64)
    rho = torch.sqrt(f1 * f1 + f2 * f2)
    torch.testing.assert_close(union_m(f1, f2), (f1 + f2 + rho) * rho)  # default m = 1
    torch.testing.assert_close(union_m(f1, f2, m=2), (f1 + f2 + rho) * rho**2)  # the reference's default
    torch.testing.assert_close(intersection_m(f1, f2, 2), (f1 + f2 - rho) * rho**2)
    torch.testing.assert_close(difference_m(f1, f2, 2), (f1 - f2 - rho) * rho**2)


def test_scale_with_a_tuple_scales_each_axis():
    x = torch.tensor([[2.0, 4.0, 6.0], [1.0, -1.0, 3.0]], dtype=torch.float64)
    torch.testing.assert_close(scale(x, (2.0, 4.0, 3.0)), x / torch.tensor([2.0, 4.0, 3.0], dtype=torch.float64))
    torch.testing.assert_close(scale(x, (2.0, 4.0, 3.0)), scale3D(x, 2.0, 4.0, 3.0))
    torch.testing.assert_close(scale(x, 2.0), x / 2)
    # B per-axis factors give (B, N, 3); tensor components keep their graph
    batch = torch.tensor([[1.0, 2.0, 4.0], [2.0, 2.0, 2.0]], dtype=torch.float64)
    assert scale(x, batch).shape == (2, 2, 3)
    s = torch.tensor(2.0, dtype=torch.float64, requires_grad=True)
    (d,) = torch.autograd.grad(sphere(scale(x[:1], (s, 1.0, 1.0)), r=1.0).sum(), s)
    assert float(d) == pytest.approx(2 * 2.0**2 / 2.0**3)  # d/ds (1 - (x/s)^2 - ...) = 2 x^2 / s^3
    with pytest.raises(ValueError, match=r"^scale: factor must have no zero component, got \(1\.0, 0\.0, 2\.0\)"):
        scale(x, (1.0, 0.0, 2.0))


def _eul2rotm(r1, r2, r3):
    """The reference's eul2rotm (Z-Y-X), entry by entry."""
    c, s = np.cos([r1, r2, r3]), np.sin([r1, r2, r3])
    return np.array(
        [
            [c[0] * c[1], c[0] * s[1] * s[2] - s[0] * c[2], c[0] * s[1] * c[2] + s[0] * s[2]],
            [s[0] * c[1], s[0] * s[1] * s[2] + c[0] * c[2], s[0] * s[1] * c[2] - c[0] * s[2]],
            [-s[1], c[1] * s[2], c[1] * c[2]],
        ]
    )


def test_superquadric_takes_the_reference_euler_order():
    rng = np.random.default_rng(11)
    x = rng.uniform(-2, 2, (500, 3))
    e, a, r, t = (0.7, 1.3), (1.0, 0.6, 0.8), (0.3, -0.5, 0.9), (0.1, 0.2, -0.3)
    local = (x - np.asarray(t)) @ _eul2rotm(*r)  # R^T (x - t), row by row
    u, v, w = (np.abs(local[:, k]) / a[k] for k in range(3))
    inside_outside = (u ** (2 / e[1]) + v ** (2 / e[1])) ** (e[1] / e[0]) + w ** (2 / e[0])
    np.testing.assert_allclose(superQuadric(x, e, a, r, t), 1.0 - inside_outside, rtol=1e-12, atol=1e-12)
    radius = np.linalg.norm(x - np.asarray(t), axis=-1)
    np.testing.assert_allclose(
        sdf.superQuadric(x, e, a, r, t), radius * (inside_outside ** (-e[0] / 2) - 1.0), rtol=1e-12, atol=1e-12
    )


def test_conv_triangle_is_the_area_integral_of_the_kernel():
    """Ours is the integral itself (the reference's is S^3 times it: checked against it with PYFREP_SRC)."""
    p = np.array([[0.3, 0.2, 0.25], [0.1, 0.1, -0.4], [1.0, 1.0, 0.2], [-0.5, 2.0, 0.0]])
    s = 2.0
    # Gauss-Legendre on the unit square mapped onto the triangle (u, v) = (a, (1 - a) b), dA = (1 - a) da db
    nodes, weights = np.polynomial.legendre.leggauss(200)
    a, b = np.meshgrid((nodes + 1) / 2, (nodes + 1) / 2, indexing="ij")
    w = np.outer(weights, weights) / 4 * (1 - a)
    u, v = a, (1 - a) * b
    r2 = (p[:, 0, None, None] - u) ** 2 + (p[:, 1, None, None] - v) ** 2 + p[:, 2, None, None] ** 2
    integral = (w / (1.0 + s * s * r2) ** 2).sum((1, 2))
    got = convTriangle(p, [0, 0, 0, 1, 0, 0, 0, 1, 0], s, 0.0)
    np.testing.assert_allclose(got, integral, rtol=1e-9)


# ----------------------------------------------------------------------------- the new twist, mapBlob, sdf.superQuadric


def test_twist_is_the_reference_formula():
    x = _points(((-2.0,) * 3, (2.0,) * 3), 200, 12)
    k = 0.7
    c, s = torch.cos(k * x[:, 2]), torch.sin(k * x[:, 2])
    expected = torch.stack([c * x[:, 0] - s * x[:, 1], s * x[:, 0] + c * x[:, 1], x[:, 2]], -1)
    torch.testing.assert_close(twist(x, k), expected, rtol=0, atol=1e-15)
    torch.testing.assert_close(twist(x, k), twistZ(x, 0.0, 1.0, 0.0, -k), rtol=0, atol=1e-14)


def test_map_blob_is_the_reference_formula():
    x = _points(((-2.0,) * 3, (2.0,) * 3), 200, 13)
    f = sphere(x, r=1.2)
    centers = np.array([[0.5, 0.0, 0.0], [-0.3, 0.4, 0.2]])
    depth, width = np.array([0.4, -0.2]), np.array([0.3, 0.6])
    d2 = ((x.numpy()[:, None, :] - centers[None]) ** 2).sum(-1)
    expected = f.numpy() - (depth / (1.0 + d2 / width**2)).sum(-1)
    got = mapBlob(x, f, centers[:, 0], centers[:, 1], centers[:, 2], depth, width)
    np.testing.assert_allclose(got.numpy(), expected, rtol=1e-14, atol=1e-14)
    # at a center the field drops by fobj0 (plus the other blob's tail)
    with pytest.raises(ValueError, match=r"^mapBlob: sigma must be positive"):
        mapBlob(x, f, [0.0], [0.0], [0.0], [1.0], [0.0])


def test_sdf_superquadric_is_exact_for_a_sphere_and_finite_at_its_center():
    x = _points(((-2.0,) * 3, (2.0,) * 3), 300, 14)
    x[0] = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)  # the center
    t = (0.1, 0.2, 0.3)
    d = sdf.superQuadric(x, (1.0, 1.0), (0.8, 0.8, 0.8), (0.4, 0.1, -0.2), t)
    torch.testing.assert_close(d, sdf.sphere(x, t, 0.8), rtol=0, atol=1e-14)
    g = grad(lambda p: sdf.superQuadric(p, (0.5, 1.5), (1.0, 0.5, 0.7), (0.4, 0.1, -0.2), t), x)
    assert torch.isfinite(g).all()


def _new_functions(x, k, s):
    """The three new functions with parameters k and s, in one model."""
    body = mapBlob(x, sphere(twist(x, k), r=1.0), [0.3], [0.0], [0.0], [s], [0.4])
    return union(body, sdf.superQuadric(x, (s, 1.0), (0.5, 0.4, 0.3), (k, 0.0, 0.2), (1.0, 0.0, 0.0)))


def test_new_functions_work_under_vmap_grad_and_compile():
    x = _points(((-1.5,) * 3, (1.5,) * 3), 60, 15)
    ks = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    batched = torch.func.vmap(lambda k: _new_functions(x, k, 0.6))(ks)
    eager = torch.stack([_new_functions(x, float(k), 0.6) for k in ks])
    torch.testing.assert_close(batched, eager, rtol=0, atol=1e-14)
    # per-point d f / d s by vmap(grad) against central differences
    dfds = torch.func.vmap(torch.func.grad(lambda s, p: _new_functions(p[None], 0.5, s)[0]), in_dims=(None, 0))(
        torch.tensor(0.6, dtype=torch.float64), x
    )
    h = 1e-6
    fd = (_new_functions(x, 0.5, 0.6 + h) - _new_functions(x, 0.5, 0.6 - h)) / (2 * h)
    torch.testing.assert_close(dfds, fd, rtol=1e-6, atol=1e-7)
    torch._dynamo.reset()
    compiled = torch.compile(_new_functions, backend="eager", fullgraph=True, dynamic=False)  # no graph break
    k, s = torch.tensor(0.5, dtype=torch.float64), torch.tensor(0.6, dtype=torch.float64)
    torch.testing.assert_close(compiled(x, k, s), _new_functions(x, k, s), rtol=0, atol=1e-14)


def test_porting_document_is_linked_and_names_every_listed_difference():
    root = Path(__file__).resolve().parents[1]
    assert "docs/porting.md" in (root / "README.md").read_text()
    text = (root / "docs" / "porting.md").read_text()
    for name in (
        "sawtooth",
        "triangleWave",
        "superQuadric",
        "union_m",
        "scale",
        "convTriangle",
        "convMesh",
        "convArc",
        "bend",
        "convLineR",
        "twistZ",
        "twist",
        "mapBlob",
        "sdf.superQuadric",
    ):
        assert f"`{name}" in text, name
    assert math.isfinite(float(sdf.superQuadric(np.zeros((1, 3)))[0]))
