"""Fig. 1 program, R-functions, @model/Param, grad and projection against closed forms."""

import math

import numpy as np
import pytest
import torch

from pyfrep_core import *
from pyfrep_core.models import fig1_part


def paper_fig1(x):  # the Fig. 1 program exactly as printed in the paper
    sp1 = sphere(x, center=(0, 0, 0), r=1)
    b1 = block(x, vertex=(-0.75, -0.75, -0.75), dx=1.5, dy=1.5, dz=1.5)
    t1 = intersection(sp1, b1)
    c1 = cylX(x, center=(0, 0, 0), r=0.5)
    c2 = cylY(x, center=(0, 0, 0), r=0.5)
    c3 = cylZ(x, center=(0, 0, 0), r=0.5)
    t2 = difference(t1, c1)
    t3 = difference(t2, c2)
    t4 = difference(t3, c3)
    return t4


def formula_fig1(p, r=0.5):
    x, y, z = p[:, 0], p[:, 1], p[:, 2]

    def inter(a, b):
        return a + b - np.sqrt(a * a + b * b)

    sp = 1 - (x * x + y * y + z * z)
    slab = [(c + 0.75) * (0.75 - c) for c in (x, y, z)]
    t = inter(sp, inter(inter(slab[0], slab[1]), slab[2]))
    for cyl in (r * r - y * y - z * z, r * r - x * x - z * z, r * r - x * x - y * y):
        t = inter(t, -cyl)
    return t


def test_fig1_program_matches_formulas_numpy_and_torch():
    rng = np.random.default_rng(0)
    p = rng.uniform(-1.2, 1.2, (1000, 3))
    expected = formula_fig1(p)
    out_np = paper_fig1(p)
    assert isinstance(out_np, np.ndarray) and out_np.shape == (1000,)
    np.testing.assert_allclose(out_np, expected, rtol=0, atol=1e-9)
    out_t = paper_fig1(torch.from_numpy(p))
    assert isinstance(out_t, torch.Tensor) and out_t.dtype == torch.float64
    np.testing.assert_allclose(out_t.numpy(), expected, atol=1e-9)
    np.testing.assert_allclose(fig1_part(p), expected, atol=1e-9)


def test_rfunction_gradient_finite_at_f1_equals_f2_equals_zero():
    for op in (union, intersection, difference):
        a = torch.zeros(4, requires_grad=True)
        b = torch.zeros(4, requires_grad=True)
        op(a, b).sum().backward()
        assert torch.isfinite(a.grad).all() and torch.isfinite(b.grad).all()
        assert a.grad.abs().max() <= 1.0
    # a point exactly on two surfaces of the Fig. 1 part: finite spatial gradient
    x = torch.tensor([[0.75, 0.75, 0.5]], dtype=torch.float64)
    g = grad(paper_fig1, x)
    assert torch.isfinite(g).all()


def test_model_params_batch_and_validation():
    x = torch.rand(50, 3, dtype=torch.float64) * 2 - 1
    assert fig1_part(x).shape == (50,)
    batch = fig1_part(x, r=torch.tensor([0.3, 0.4, 0.5], dtype=torch.float64))
    assert batch.shape == (3, 50)
    torch.testing.assert_close(batch[1], fig1_part(x, r=0.4))
    assert fig1_part.params["r"] == Param(default=0.5, lower=0.2, upper=0.8, label="cylinder radius")
    assert fig1_part(x, r=0.95).shape == (50,)  # out of range is allowed when exploring
    with pytest.raises(ValueError, match="r=0.95"):
        fig1_part.check(r=0.95)
    with pytest.raises(TypeError, match="radius"):
        fig1_part(x, radius=0.3)
    with pytest.raises(ValueError, match="lower"):
        Param(0.5, 0.9, 0.1)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        fig1_part(torch.zeros(5, 2))


def test_param_grad_closed_form_sphere():
    r = torch.tensor(0.7, dtype=torch.float64, requires_grad=True)
    x = torch.rand(20, 3, dtype=torch.float64)
    sphere(x, r=r).sum().backward()
    assert math.isclose(r.grad.item(), 2 * 0.7 * 20, rel_tol=1e-12)


def test_grad_and_projection_on_sphere():
    x = np.array([[0.3, -0.2, 0.5], [1.5, 0.0, 0.0]])
    g = grad(lambda p: sphere(p, r=1.0), x)
    np.testing.assert_allclose(g, -2 * x, atol=1e-12)
    proj = project_to_surface(lambda p: sphere(p, r=1.0), x)
    np.testing.assert_allclose(np.linalg.norm(proj.points, axis=1), 1.0, atol=1e-12)
    assert proj.converged.all()
    with pytest.raises(ValueError, match="non-finite"):
        project_to_surface(lambda p: sphere(p, r=1.0), np.array([[np.nan, 0, 0]]))


def test_projection_reports_points_with_zero_gradient():
    with pytest.warns(RuntimeWarning, match="did not converge"):
        proj = project_to_surface(lambda p: sphere(p, r=1.0), torch.zeros(1, 3, dtype=torch.float64))
    assert not bool(proj.converged[0])
    assert torch.equal(proj.points, torch.zeros(1, 3, dtype=torch.float64))


def test_numpy_points_with_tensor_parameter_keep_the_gradient():
    r = torch.tensor(0.5, dtype=torch.float64, requires_grad=True)
    x = np.array([[0.1, 0.2, 0.3], [1.0, 0.0, 0.0]])
    out = sphere(x, r=r)
    assert isinstance(out, torch.Tensor)
    out.sum().backward()
    assert r.grad.item() == pytest.approx(2.0)  # d/dr (r^2 - |x|^2) = 2r, twice


def test_bad_points_get_clear_errors():
    with pytest.raises(ValueError, match=r"shape \(N, 3\), got \(4, 2\)"):
        sphere(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"shape \(N, 3\), got \(4, 2\)"):
        cylX(torch.zeros(4, 2))
    with pytest.raises(ValueError, match=r"sphere: x contains a non-finite value \(nan\) at index \(0, 0\)"):
        sphere(np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"fig1_part: x contains a non-finite value \(inf\) at index \(0, 1\)"):
        fig1_part(np.array([[0.0, np.inf, 0.0]]))
