"""The input-validation layer (pyfrep_core._array): one path for every entry that takes points.

The catalogue (every primitive, transform, operation and sdf function exported) is swept
systematically: a NaN torch point and an inf numpy point are refused naming the function,
the argument and the value; float32 comes back float32, numpy and torch; complex and integer
input raise TypeError; no points give no values.  Model calls and Param follow the same rules,
checks are skipped under vmap / torch.compile, and a model of 20 primitives reads its points
once, not 20 times.
"""

import inspect
import math
import re

import numpy as np
import pytest
import torch

import pyfrep_core
from pyfrep_core import Param, RedistancedSDF, model, sdf, sphere, superEll, superQuadric
from pyfrep_core import _array as array
from pyfrep_core._array import validated_inputs

# ----------------------------------------------------------------------------- the catalogue

# valid arguments besides the points (or values) for the functions that need some
ARGS = {
    "blobby": dict(x0=[0.0], y0=[0.0], z0=[0.0], a=[1.0], b=[1.0]),
    "metaBall": dict(x0=[0.0], y0=[0.0], z0=[0.0], b=[1.0], d=[1.0]),
    "soft": dict(x0=[0.0], y0=[0.0], z0=[0.0], d=[1.0]),
    "translate": dict(offset=(0.1, 0.2, 0.3)),
    "scale": dict(factor=2.0),
    "rotate3DX": dict(theta=0.3),
    "rotate3DY": dict(theta=0.3),
    "rotate3DZ": dict(theta=0.3),
    "rotate": dict(angle=0.3),
    "orient": dict(direction=(1.0, 1.0, 0.0)),
    "twistX": dict(x1=-1.0, x2=1.0, theta1=0.0, theta2=1.0),
    "twistY": dict(y1=-1.0, y2=1.0, theta1=0.0, theta2=1.0),
    "twistZ": dict(z1=-1.0, z2=1.0, theta1=0.0, theta2=1.0),
    "taperX": dict(x1=-1.0, x2=1.0, s1=1.0, s2=0.5),
    "taperY": dict(y1=-1.0, y2=1.0, s1=1.0, s2=0.5),
    "taperZ": dict(z1=-1.0, z2=1.0, s1=1.0, s2=0.5),
    "bend": dict(k=0.5),
    "twist": dict(k=0.5),
    "mapBlob": dict(fobj=0.5, x0=[0.0], y0=[0.0], z0=[0.0], fobj0=[0.2], sigma=[0.5]),
    "spinodoid": dict(numwaves=50),
    "convPoint": dict(vect=[0.0, 0.0, 0.0], S=1.0, T=0.1),
    "convLine": dict(begin=[0.0, 0.0, 0.0], end=[1.0, 0.0, 0.0], S=1.0, T=0.1),
    "convLineR": dict(begin=[0.0, 0.0, 0.0], end=[1.0, 0.0, 0.0], S=1.0, R=0.5),
    "convCurve": dict(vect=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0], S=1.0, T=0.1),
    "convTriangle": dict(vect=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], S=1.0, T=0.1),
    "convMesh": dict(vect=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0], tri=[1, 2, 3], S=1.0, T=0.1),
    "convArc": dict(center=[0.0, 0.0, 0.0], radius=1.0, theta=90.0, axis=[0.0, 0.0, 1.0], angle=0.0, S=1.0, T=0.1),
    "offset": dict(d=0.1),
    "shell": dict(thickness=0.1),
    "sdf.dilate": dict(r=0.1),
    "sdf.erode": dict(r=0.1),
    "sdf.shell": dict(e=0.1),
}


CATALOGUE_MODULES = {
    f"pyfrep_core.{m}" for m in ("primitives", "operations", "transforms", "sdf", "periodic", "lattices", "convolution")
}


def _catalogue():
    """name -> function for every checked catalogue entry: pyfrep_core.__all__ and pyfrep_core.sdf.__all__."""
    out = {}
    for prefix, module in (("", pyfrep_core), ("sdf.", sdf)):
        for name in module.__all__:
            fn = getattr(module, name)
            # the catalogue is what frep wraps: a function of points (x) or of field values (f, d, f1, d1)
            if inspect.isfunction(fn) and hasattr(fn, "__wrapped__") and fn.__module__ in CATALOGUE_MODULES:
                out[prefix + name] = fn
    return out


CATALOGUE = _catalogue()


def _operands(fn):
    """The names of the arguments holding points or values: x, or f / f1, f2, f3 / d, d1, d2."""
    names = list(inspect.signature(fn).parameters)
    return [names[0], *(n for n in names[1:] if re.fullmatch(r"[fd][2-9]", n))]


def _label(name):
    """How messages name a catalogue entry: its function's name (sdf.cylX is sdf.cylinderX), sdf. for sdf."""
    return ("sdf." if name.startswith("sdf.") else "") + CATALOGUE[name].__name__


def _call(name, array):
    """``name`` on ``array`` as its points (a function of points) or as every operand (an operation)."""
    fn = CATALOGUE[name]
    ops = _operands(fn)
    if ops[0] == "x":
        return fn(array, **ARGS.get(name, {}))
    values = array[..., 0]  # field values (N,) of the same dtype and kind
    return fn(*[values] * len(ops), **ARGS.get(name, {}))


def _points(dtype=np.float64, n=6):
    rng = np.random.default_rng(7)
    return rng.uniform(-0.8, 0.8, (n, 3)).astype(dtype)


def test_the_catalogue_is_complete():
    # every primitive, transform, operation, periodic, lattice, convolution and sdf function is swept
    assert len(CATALOGUE) >= 100
    for name in ("sphere", "superEll", "union", "blendUnion", "twistZ", "rep", "gyroid", "convMesh", "sdf.capsule"):
        assert name in CATALOGUE
    assert all(_operands(fn)[0] in ("x", "f", "f1", "d", "d1") for fn in CATALOGUE.values())


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_nan_torch_point_is_refused_naming_function_argument_and_index(name):
    arg = _operands(CATALOGUE[name])[0]
    x = torch.from_numpy(_points())
    x[3, 1 if arg == "x" else 0] = math.nan  # an operation sees column 0 as its values
    index = r"\(3, 1\)" if arg == "x" else r"\(3,\)"
    with pytest.raises(
        ValueError, match=rf"^{re.escape(_label(name))}: {arg} contains a non-finite value \(nan\) at index {index}"
    ):
        _call(name, x)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_inf_numpy_point_is_refused(name):
    x = _points()
    x[2, 0] = -math.inf
    with pytest.raises(ValueError, match=rf"^{re.escape(_label(name))}: .* contains a non-finite value \(-inf\)"):
        _call(name, x)


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_float32_in_float32_out_numpy_and_torch_alike(name):
    x32 = _points(np.float32)
    out_np = _call(name, x32)
    out_t = _call(name, torch.from_numpy(x32))
    assert isinstance(out_np, np.ndarray) and out_np.dtype == np.float32
    assert isinstance(out_t, torch.Tensor) and out_t.dtype == torch.float32
    # the same computation either way: numpy in is torch inside
    np.testing.assert_array_equal(out_np, out_t.numpy())
    assert np.isfinite(out_np).all()
    # and float64 stays float64
    assert _call(name, _points()).dtype == np.float64


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_complex_and_integer_points_raise_type_error(name):
    x = _points()
    arg = _operands(CATALOGUE[name])[0]
    with pytest.raises(TypeError, match=rf"^{re.escape(_label(name))}: {arg} must be real .*got complex128"):
        _call(name, x.astype(np.complex128))
    with pytest.raises(TypeError, match=rf"^{re.escape(_label(name))}: {arg} must be float32 or float64, got int64"):
        _call(name, torch.zeros(6, 3, dtype=torch.int64))
    with pytest.raises(TypeError, match=rf"^{re.escape(_label(name))}: {arg} must be real .*got complex64"):
        _call(name, torch.zeros(6, 3, dtype=torch.complex64))


@pytest.mark.parametrize("name", sorted(CATALOGUE))
def test_no_points_give_no_values(name):
    """Documented choice (pyfrep_core._array): pointwise evaluation of no points is an empty result."""
    for empty in (np.zeros((0, 3), np.float32), torch.zeros(0, 3, dtype=torch.float64)):
        out = _call(name, empty)
        transform = out.ndim == 2
        assert tuple(out.shape) == ((0, 3) if transform else (0,))
        assert str(out.dtype).removeprefix("torch.") == str(empty.dtype).removeprefix("torch.")


def test_nan_parameters_of_the_catalogue_are_refused_naming_them():
    x = torch.from_numpy(_points())
    with pytest.raises(ValueError, match=r"^sphere: r must be finite, got nan"):
        sphere(x, r=math.nan)
    with pytest.raises(ValueError, match=r"^sphere: center must be finite, got \(0\.0, inf, 0\.0\)"):
        sphere(x, center=(0.0, math.inf, 0.0))
    with pytest.raises(ValueError, match=r"^translate: offset contains a non-finite value \(nan\) at index \(2,\)"):
        pyfrep_core.translate(x, torch.tensor([0.0, 0.0, math.nan]))
    with pytest.raises(TypeError, match=r"^sphere: r must be a real number, got 1j"):
        sphere(x, r=1j)
    with pytest.raises(ValueError, match=r"^union: f2 must be finite, got nan"):
        pyfrep_core.union(x[:, 0], math.nan)
    # inside a checked call (a model, grad) the points are not read again, but numbers still are
    with validated_inputs(), pytest.raises(ValueError, match=r"^sphere: center must be finite, got \(nan, 0, 0\)"):
        sphere(x, center=(math.nan, 0, 0))
    with pytest.raises(ValueError, match=r"^grad: translate: offset must be finite, got \(0, inf, 0\)"):
        pyfrep_core.grad(lambda p: sphere(pyfrep_core.translate(p, (0, math.inf, 0))), x)


def test_wrong_point_shapes_and_types_name_the_function():
    with pytest.raises(ValueError, match=r"^sphere: points x must have shape \(N, 3\), got \(4, 2\)"):
        sphere(torch.zeros(4, 2))
    with pytest.raises(TypeError, match=r"^sphere: x must be a torch tensor or a numpy array of points, got list"):
        sphere([[0.0, 0.0, 0.0]])
    with pytest.raises(TypeError, match=r"^sphere: x must be float32 or float64, got float16"):
        sphere(torch.zeros(4, 3, dtype=torch.float16))
    with pytest.raises(TypeError, match=r"^sphere: x must be float32 or float64, got bool"):
        sphere(np.zeros((4, 3), bool))


def test_results_have_the_points_dtype_whatever_the_parameters():
    x32 = torch.from_numpy(_points(np.float32))
    r = torch.tensor(0.5, dtype=torch.float64, requires_grad=True)
    out = sphere(x32, r=r)
    assert out.dtype == torch.float32
    out.sum().backward()  # the graph to the float64 parameter is kept: d/dr sum(r^2 - |x|^2) = 2 r N
    assert r.grad.item() == pytest.approx(2 * 0.5 * 6, rel=1e-12)
    centres = np.array([0.1, 0.0, 0.0])  # a float64 numpy parameter beside float32 points
    assert sphere(x32.numpy(), center=centres).dtype == np.float32


# ----------------------------------------------------------------------------- NaN never reads inside


def test_superellipsoids_never_report_a_nan_point_as_inside():
    # where values are not read (an outer checked call, vmap, compile), NaN must stay NaN, not 1.0 (inside)
    p = torch.tensor([[math.nan, 0.0, 0.0], [0.0, math.nan, 0.0], [0.0, 0.0, math.nan], [0.5, 0.0, 0.0]])
    with validated_inputs():
        for out in (superEll(p, s1=0.5, s2=0.5), superQuadric(p, e=(0.5, 0.5))):
            assert torch.isnan(out[:3]).all()
            assert out[3].item() == pytest.approx(1 - 0.5**4, rel=1e-6)  # |u|^(2/s) = 0.5^4 on the x axis
    vmapped = torch.func.vmap(lambda q: superEll(q, s1=0.5, s2=0.5))(p)
    assert torch.isnan(vmapped[:3]).all()
    # the gradient stays finite at the center, where the power's argument is 0
    g = pyfrep_core.grad(lambda q: superEll(q, s1=0.5, s2=0.5), torch.zeros(1, 3, dtype=torch.float64))
    assert torch.isfinite(g).all()


def test_redistanced_sdf_refuses_nan_points():
    net = RedistancedSDF(lambda x: sphere(x, r=1.0), ((-1.5,) * 3, (1.5,) * 3), width=8, depth=1)
    with pytest.raises(ValueError, match=r"^RedistancedSDF: x contains a non-finite value \(nan\) at index \(1, 2\)"):
        net(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, math.nan]]))
    with pytest.raises(ValueError, match=r"RedistancedSDF: x contains a non-finite value \(inf\)"):
        net(np.array([[math.inf, 0.0, 0.0]]))
    assert net(np.zeros((0, 3))).shape == (0,)
    assert net(np.zeros((2, 3), np.float32)).dtype == np.float32


# ----------------------------------------------------------------------------- models and Param


@model(bounds=((-1, -1, -1), (1, 1, 1)), r=Param(0.5, 0.1, 0.9))
def ball(x, r):
    return sphere(x, r=r)


def test_model_call_checks_points_like_the_catalogue():
    with pytest.raises(ValueError, match=r"^ball: x contains a non-finite value \(nan\) at index \(1, 0\)"):
        ball(torch.tensor([[0.0, 0.0, 0.0], [math.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"^ball: x contains a non-finite value \(inf\)"):
        ball(np.array([[0.0, math.inf, 0.0]]))
    with pytest.raises(TypeError, match=r"^ball: x must be real"):
        ball(np.zeros((2, 3), np.complex128))
    with pytest.raises(TypeError, match=r"^ball: x must be float32 or float64, got int64"):
        ball(np.zeros((2, 3), np.int64))
    with pytest.raises(TypeError, match=r"^ball: x must be float32 or float64, got int64"):
        ball(torch.zeros(2, 3, dtype=torch.int64))
    with pytest.raises(ValueError, match=r"^ball: x must have shape \(N, 3\), got \(2, 2\)"):
        ball(np.zeros((2, 2)))


def test_model_call_keeps_the_dtype_and_gives_no_values_for_no_points():
    x = _points(np.float32)
    out = ball(x)
    assert out.dtype == np.float32
    # float32 arithmetic on exact float32 points: 3 squares and 3 sums of magnitude <= 2, half an ulp each
    bound = 3 * np.finfo(np.float32).eps
    np.testing.assert_allclose(out, 0.25 - (x.astype(np.float64) ** 2).sum(1), rtol=0, atol=bound)
    assert ball(torch.from_numpy(x)).dtype == torch.float32
    assert ball([[0, 0, 0]]).dtype == np.float64  # a list: Python numbers become float64
    assert ball([[0, 0, 0]])[0] == 0.25
    assert ball(np.zeros((0, 3), np.float32)).shape == (0,)
    assert ball(np.zeros((0, 3), np.float32)).dtype == np.float32
    assert ball(torch.zeros(0, 3), r=torch.tensor([0.2, 0.3])).shape == (2, 0)


@pytest.mark.parametrize(
    "value",
    [math.nan, math.inf, -math.inf, np.float32("nan"), torch.tensor(math.inf), torch.tensor([0.3, math.nan])],
    ids=["nan", "inf", "-inf", "np.float32-nan", "0-d-tensor-inf", "batch-with-nan"],
)
def test_model_parameters_must_be_finite(value):
    with pytest.raises(ValueError, match=r"^ball: r must be finite"):
        ball(np.zeros((2, 3)), r=value)


def test_model_errors_from_inside_name_the_model():
    @model(a=Param(1.0, 0.0, 2.0))
    def egg(x, a):
        return pyfrep_core.ellipsoid(x, a=a)

    # the primitive's own message, prefixed with the model's name: which call failed, and where inside
    with pytest.raises(ValueError, match=r"^egg: ellipsoid: a must be positive, got 0\.0$"):
        egg(np.zeros((2, 3)), a=0.0)


@pytest.mark.parametrize(
    "value",
    [np.float32(0.5), np.float64(0.5), np.int64(1), torch.tensor(0.5), np.array(0.5), 0.5, 1],
    ids=["np.float32", "np.float64", "np.int64", "0-d tensor", "0-d array", "float", "int"],
)
def test_param_accepts_any_real_number(value):
    p = Param(value, 0, 2)
    assert p.default == pytest.approx(float(value))
    assert type(p.default) in (int, float)


@pytest.mark.parametrize(
    "value, error",
    [
        (True, TypeError),
        (np.bool_(False), TypeError),
        ("0.5", TypeError),
        (1j, TypeError),
        (torch.tensor([0.5, 0.6]), TypeError),
        (math.nan, ValueError),
        (np.float32("inf"), ValueError),
        (torch.tensor(math.nan), ValueError),
    ],
    ids=["True", "np.bool_", "str", "complex", "1-d tensor", "nan", "np.float32-inf", "0-d-tensor-nan"],
)
def test_param_refuses_bool_non_numbers_and_non_finite(value, error):
    with pytest.raises(error, match=r"Param default must be a (real|finite) number"):
        Param(value, 0, 2)


# ----------------------------------------------------------------------------- tracing and cost


@model(r=Param(0.5, 0.1, 0.9))
def twenty(x, r):
    """A union of 20 spheres along x (20 primitives, 19 operations)."""
    f = sphere(x, center=(-0.95, 0.0, 0.0), r=r)
    for i in range(1, 20):
        f = pyfrep_core.union(f, sphere(x, center=(-0.95 + 0.1 * i, 0.0, 0.0), r=r))
    return f


def _count_point_passes(monkeypatch, n):
    """Count the finiteness passes (torch.aminmax, torch.isfinite, np.isfinite) over arrays of ``n`` entries."""
    calls = []

    def counting(module, name, size):
        original = getattr(module, name)

        def wrapper(a, *args, **kwargs):
            if size(a) == n:
                calls.append(name)
            return original(a, *args, **kwargs)

        monkeypatch.setattr(module, name, wrapper)

    counting(torch, "aminmax", torch.numel)
    counting(torch, "isfinite", torch.numel)
    counting(np, "isfinite", np.size)
    return calls


def test_a_model_of_twenty_primitives_reads_its_points_once(monkeypatch):
    n = 10**6
    x = torch.rand(n, 3) * 2 - 1
    calls = _count_point_passes(monkeypatch, 3 * n)
    out = twenty(x)
    assert calls == ["aminmax"]  # one reduction over the points, not 20
    assert out.shape == (n,) and out.dtype == torch.float32
    # the values are right: the R-union is positive exactly where one of the 20 spheres is
    x64 = x.double()
    best = torch.full((n,), -math.inf, dtype=torch.float64)
    for i in range(20):
        best = torch.maximum(best, 0.25 - ((x64 - torch.tensor([-0.95 + 0.1 * i, 0.0, 0.0])) ** 2).sum(-1))
    clear = best.abs() > 1e-5  # away from the surface, where float32 rounding cannot flip the sign
    assert torch.equal((out > 0)[clear], (best > 0)[clear]) and clear.sum() > 0.99 * n
    calls.clear()
    twenty(x.numpy())
    assert calls == ["aminmax"]
    calls.clear()
    # a plain function of the same primitives: each public call checks (what a Model call avoids) ...
    plain = twenty.fn
    plain(x, r=0.5)
    assert calls == ["aminmax"] * 20
    calls.clear()
    # ... unless an outer entry has checked: inside it, nothing is read again
    with validated_inputs():
        plain(x, r=0.5)
    assert calls == []


def test_grad_and_polygonize_do_not_read_points_per_primitive(monkeypatch):

    checks = []
    check_finite = array.check_finite

    def counting(x, name="x", fn=None):
        checks.append(fn)
        return check_finite(x, name, fn)

    monkeypatch.setattr(array, "check_finite", counting)  # what a catalogue function calls when it checks
    plain = lambda p: twenty.fn(p, r=0.5)  # noqa: E731  (20 primitives, no Model around them)
    x = torch.rand(5000, 3, dtype=torch.float64) - 0.5
    plain(x)
    assert len(checks) == 20 + 19 * 2  # alone, each public call checks: 20 spheres, 19 unions of 2 operands
    checks.clear()
    # grad checks x once (diff's entry) and evaluates in chunks, in worker threads: none checks again
    g = pyfrep_core.grad(plain, x, chunk=1000)
    assert checks == []
    torch.testing.assert_close(g, pyfrep_core.grad(plain, x), rtol=0, atol=0)
    # polygonize builds its grid from checked bounds and projects vertices onto f = 0: none re-read
    mesh = pyfrep_core.polygonize(plain, ((-1.5, -1, -1), (1.5, 1, 1)), resolution=17)
    assert checks == [] and len(mesh.faces) > 0
    # so does dual contouring: roots, vertices and their gradients are found inside their cells
    mesh = pyfrep_core.polygonize(plain, ((-1.5, -1, -1), (1.5, 1, 1)), resolution=17, method="dc")
    assert checks == [] and len(mesh.faces) > 0


def test_check_finite_reads_a_transposed_tensor_in_memory_order():
    x = torch.rand(3, 1000, dtype=torch.float64).t()  # (1000, 3), x[:, 0] contiguous (compiled kernels' layout)
    array.check_finite(x)
    x[617, 2] = float("inf")
    with pytest.raises(ValueError, match=r"non-finite value \(inf\) at index \(617, 2\)"):
        array.check_finite(x)


def test_vmap_and_grad_transforms_of_a_model_still_work():
    x = torch.tensor([[0.1, 0.2, 0.3], [0.5, 0.0, 0.0]], dtype=torch.float64)
    rs = torch.tensor([0.3, 0.4, 0.6], dtype=torch.float64)
    per_r = torch.func.vmap(lambda r: ball(x, r=r))(rs)
    expected = rs[:, None] ** 2 - (x**2).sum(1)[None]
    torch.testing.assert_close(per_r, expected, rtol=0, atol=1e-15)
    per_point = torch.func.vmap(lambda p: ball(p[None])[0])(x)
    torch.testing.assert_close(per_point, 0.25 - (x**2).sum(1), rtol=0, atol=1e-15)
    g = torch.func.vmap(torch.func.grad(lambda p: ball(p[None])[0]))(x)
    torch.testing.assert_close(g, -2 * x, rtol=0, atol=1e-15)


def test_torch_compile_of_a_model_has_no_graph_break_from_the_checks():
    torch._dynamo.reset()
    fn = torch.compile(lambda p: twenty.fn(p, r=0.5), fullgraph=True, dynamic=False)
    x = torch.rand(64, 3, dtype=torch.float64) - 0.5
    eager = twenty(x)
    # fused code rounds differently: 20 spheres and 19 unions f1 + f2 + sqrt(f1^2 + f2^2), whose
    # intermediates are at most 4 max(|f1|, |f2|); each operation adds a few roundings (4 ulp) of its
    # largest intermediate, so the gap is bounded by 39 * 4 ulp of the largest one at the point
    with validated_inputs():
        spheres = [sphere(x, center=(-0.95 + 0.1 * i, 0.0, 0.0), r=0.5) for i in range(20)]
        partial, largest = spheres[0], spheres[0].abs()
        for s in spheres[1:]:
            largest = torch.maximum(largest, 4 * torch.maximum(partial.abs(), s.abs()))
            partial = pyfrep_core.union(partial, s)
    bound = 39 * 4 * torch.finfo(torch.float64).eps * largest
    assert (fn(x) - eager).abs().le(bound).all()
    # the Model object itself (its __call__ with the checks) compiles whole too, a parameter as a tensor
    whole = torch.compile(twenty, fullgraph=True, dynamic=False)
    assert (whole(x, r=torch.tensor(0.5, dtype=torch.float64)) - eager).abs().le(bound).all()
    # a compiled function does not read its input: a NaN point gives NaN, never a wrong finite value
    assert torch.isnan(fn(torch.full((64, 3), math.nan, dtype=torch.float64))).all()


@model(a=Param(1.0, 0.5, 1.5), cx=Param(0.0, -0.3, 0.3))
def shifted_egg(x, a, cx):
    return pyfrep_core.ellipsoid(x, center=(cx, 0.0, 0.0), a=a)


def test_batched_parameters_inside_a_centre_tuple_are_checked_and_evaluated():
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    out = shifted_egg(x, a=torch.tensor([1.0, 1.0]), cx=torch.tensor([0.0, 0.5]))
    # 1 - ((x - cx) / a)^2 on the x axis, one row per parameter set
    np.testing.assert_allclose(out, [[1.0, 0.0], [0.75, 0.75]], rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match=r"^shifted_egg: cx must be finite, got \[0\.0, nan\]"):
        shifted_egg(x, cx=torch.tensor([0.0, math.nan]))


# ----------------------------------------------------------------------------- analysis entries

from pyfrep_core import curvature, diff, normalization, sensitivity  # noqa: E402
from pyfrep_core.models import fig1_part  # noqa: E402

# every public entry that differentiates or analyses f at user points: name -> call on points
ANALYSES = {
    "value_and_grad": lambda p: diff.value_and_grad(fig1_part, p),
    "grad": lambda p: diff.grad(fig1_part, p),
    "value_grad_hessian": lambda p: diff.value_grad_hessian(fig1_part, p),
    "hessian": lambda p: diff.hessian(fig1_part, p),
    "laplacian": lambda p: diff.laplacian(fig1_part, p),
    "p_laplacian": lambda p: diff.p_laplacian(fig1_part, p, 3.0),
    "tangent_hessian": lambda p: diff.tangent_hessian(fig1_part, p),
    "div": lambda p: diff.div(lambda q: q * q, p),
    "param_grad": lambda p: diff.param_grad(fig1_part, p),
    "project_to_surface": lambda p: diff.project_to_surface(fig1_part, p).points,
    "curvatures": lambda p: curvature.curvatures(fig1_part, p),
    "mean_curvature": lambda p: curvature.mean_curvature(fig1_part, p),
    "gaussian_curvature": lambda p: curvature.gaussian_curvature(fig1_part, p),
    "principal_curvatures": lambda p: curvature.principal_curvatures(fig1_part, p),
    "principal_directions": lambda p: curvature.principal_directions(fig1_part, p),
    "omega_1": lambda p: normalization.omega_1(fig1_part, p),
    "omega_k": lambda p: normalization.omega_k(fig1_part, p, k=2),
    "delta_1": lambda p: normalization.delta_1(fig1_part, p),
    "normal_derivative": lambda p: normalization.normal_derivative(fig1_part, p),
    "param_derivative": lambda p: sensitivity.param_derivative(fig1_part, p, "r"),
    "normal_velocity": lambda p: sensitivity.normal_velocity(fig1_part, p, "r"),
}
ARGUMENT = {"project_to_surface": "points"}


def _arrays(out):
    """The floating arrays of a result (a tensor or array, a tuple/NamedTuple or dict of them)."""
    if isinstance(out, dict):
        return [a for v in out.values() for a in _arrays(v)]
    if isinstance(out, tuple | list):
        return [a for v in out for a in _arrays(v)]
    kind = out.dtype.kind if isinstance(out, np.ndarray) else ("f" if out.is_floating_point() else "b")
    return [out] if kind == "f" else []


@pytest.mark.parametrize("name", sorted(ANALYSES))
def test_analysis_entries_refuse_bad_points_naming_themselves(name):
    call, arg = ANALYSES[name], ARGUMENT.get(name, "x")
    with pytest.raises(ValueError, match=rf"^{name}: {arg} contains a non-finite value \(nan\) at index \(1, 1\)"):
        call(torch.tensor([[0.1, 0.2, 0.3], [0.1, math.nan, 0.3]]))
    with pytest.raises(ValueError, match=rf"^{name}: {arg} contains a non-finite value \(inf\) at index \(0, 2\)"):
        call(np.array([[0.1, 0.2, math.inf]]))
    with pytest.raises(TypeError, match=rf"^{name}: {arg} must be real .*got complex128"):
        call(np.zeros((2, 3), np.complex128))
    with pytest.raises(TypeError, match=rf"^{name}: {arg} must be float32 or float64, got int64"):
        call(np.zeros((2, 3), np.int64))
    # documented choice: an analysis needs points to work on (pyfrep_core._array)
    with pytest.raises(ValueError, match=rf"^{name}: {arg} is empty \(shape \(0, 3\)\)"):
        call(np.zeros((0, 3)))


@pytest.mark.parametrize("name", sorted(ANALYSES))
def test_analysis_entries_give_back_the_points_dtype(name):
    x32 = np.array([[0.3, -0.2, 0.45], [0.7, 0.1, -0.2], [0.1, 0.6, 0.2]], np.float32)
    out_np, out_t = ANALYSES[name](x32), ANALYSES[name](torch.from_numpy(x32))
    arrays_np, arrays_t = _arrays(out_np), _arrays(out_t)
    assert arrays_np and len(arrays_np) == len(arrays_t)
    for a, t in zip(arrays_np, arrays_t, strict=True):
        assert isinstance(a, np.ndarray) and a.dtype == np.float32
        assert isinstance(t, torch.Tensor) and t.dtype == torch.float32
        np.testing.assert_array_equal(a, t.numpy())  # numpy in is the same torch computation
    for a in _arrays(ANALYSES[name](x32.astype(np.float64))):
        assert a.dtype == np.float64


def test_an_error_inside_f_names_the_outermost_entry_and_the_primitive():
    with pytest.raises(ValueError, match=r"^grad: sphere: r must be positive, got -1\.0$"):
        diff.grad(lambda p: sphere(p, r=-1.0), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"^curvatures: fig1_part: r must be finite, got nan$"):
        curvature.curvatures(lambda p: fig1_part(p, r=math.nan), np.zeros((2, 3)))
