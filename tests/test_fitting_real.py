"""fit() on measured parts: pose, geometric residual, robust losses, multi-start, honest reports.

Four machined parts (pyfrep_core.models.cad_parts, 4-6 dimensions each, millimetres) are scanned
synthetically: N points on the true surface, Gaussian noise of 0.1 % of the part's size, a random
rigid pose, and 5 % of uniform outliers in the cloud's bounding box.  They are fitted with the pose
from the automatic starts, the geometric residual and a robust loss, and every recovered number is
checked against the truth with tolerances taken from the noise: dimensions and translation within
4 reported standard errors, the standard errors themselves against refits of fresh noise (a chi^2
interval), the fitted surface against the true one (the parameters' share of the noise), the
outliers found.  The plain algebraic l2 fit of the same data is recorded to show what the robust
loss buys.  N is 2,000 here (seconds per part); benchmarks/fit_real.py runs the full 5,000.
"""

import math
import warnings

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from pyfrep_core import Param, fit, model, polygonize, sample_surface, save_mesh, sdf, sphere
from pyfrep_core.diff import _param_jacobian
from pyfrep_core.fitting import IdentifiabilityWarning, fit_error
from pyfrep_core.models import cad_parts
from pyfrep_core.models.cad_parts import PARTS, TRUTH
from pyfrep_core.pose import initial_pose, posed, rotation_matrix

N_POINTS = 2000
NOISE = 1e-3  # of the part's size
OUTLIERS = 0.05  # of the cloud
POSE_NAMES = ("tx", "ty", "tz", "rx", "ry", "rz")
AXISYMMETRIC = {"flanged_bushing", "bearing_ring"}  # a turn about z changes nothing: rx, ry, rz not identifiable
SEED = {"flanged_bushing": 11, "hex_nut": 12, "l_bracket": 13, "bearing_ring": 14}


def clean_surface(name: str) -> np.ndarray:
    """N points on the part's true surface, in its own frame."""
    return cad_parts._surface(name, N_POINTS, SEED[name])


def scan(name: str, noise_seed: int | None = None) -> dict:
    """The synthetic scan: posed noisy surface points, then the outliers (their mask kept)."""
    return cad_parts.scan(name, n=N_POINTS, noise=NOISE, outliers=OUTLIERS, seed=SEED[name], noise_seed=noise_seed)


_fits: dict[str, tuple] = {}


def robust_fit(name: str) -> tuple:
    """The scan of ``name`` fitted with pose, geometric residual and the Cauchy loss (cached)."""
    if name not in _fits:
        data = scan(name)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = fit(PARTS[name], data["points"], pose=True, loss="cauchy", units="mm", seed=0, progress=False)
        _fits[name] = (data, res, [w for w in caught if issubclass(w.category, IdentifiabilityWarning)])
    return _fits[name]


@pytest.mark.parametrize("name", sorted(PARTS))
def test_part_dimensions_pose_and_outliers_recovered(name):
    data, res, warned = robust_fit(name)
    truth, sigma = TRUTH[name], data["sigma"]
    print(f"\n{name}: {res.timings['total']:.1f} s, rms {res.rms:.4f} mm (noise {sigma:.4f}), {res.termination}")
    assert res.residual == "geometric" and res.loss_function == "cauchy" and res.units == "mm"
    assert len(res.starts) >= 4 and sum(s["best"] for s in res.starts) == 1
    # every dimension, and the translation (the parts' origins lie on their symmetry axes), within 4 standard errors
    for k in [*truth, "tx", "ty", "tz"]:
        value = truth.get(k, data["pose"].get(k))
        z = (res.params[k] - value) / res.std_errors[k]
        print(f"  {k:12s} {res.params[k]:10.4f} +- {res.std_errors[k]:.4f}  truth {value:9.4f}  z {z:+.2f}")
        assert abs(z) < 4.0, (k, res.params[k], value, res.std_errors[k])
    # the fitted surface passes through the true one: the noise's share that the P fitted parameters
    # take up is sqrt(P / N) sigma RMS; 5 times that bounds the clean points' distances
    dist = fit_error(res.model, data["surface"], res.params, residual="geometric")
    allowed = 5.0 * math.sqrt(len(res.free) / N_POINTS) * sigma
    assert np.sqrt(np.mean(dist**2)) < allowed, (np.sqrt(np.mean(dist**2)), allowed)
    if name in AXISYMMETRIC:  # the turn about the axis is free: warned, named, no standard error
        assert warned and set(res.unidentifiable) == {"rx", "ry", "rz"}
        assert (
            "rx" in str(warned[0].message) and "rx" not in res.std_errors and "rank-deficient" in res.std_error_reason
        )
    else:
        assert not warned and res.unidentifiable == [] and res.std_error_reason == ""
    if name == "l_bracket":  # no symmetry at all: the rotation vector is the truth's
        rot = rotation_matrix(*(torch.tensor(res.params[k], dtype=torch.float64) for k in ("rx", "ry", "rz")))
        angle = Rotation.from_matrix(rot.numpy() @ data["rotation"].T).magnitude()
        # the rotation's standard error: about sigma / (extent sqrt(N)); 4 of them (and the extent >= 20 mm)
        assert angle < 4.0 * sigma / (20.0 * math.sqrt(N_POINTS)) * math.sqrt(3), angle
    # the inlier residuals: the noise (cut at 3 scales), the outliers found
    assert 0.8 * sigma < res.rms < 1.2 * sigma and res.max_distance < 3.5 * sigma
    assert res.loss_scale == pytest.approx(sigma, rel=0.2)
    found, true = ~res.inliers, data["outlier"]
    precision, recall = (found & true).sum() / found.sum(), (found & true).sum() / true.sum()
    print(f"  outliers: precision {precision:.3f}, recall {recall:.3f}, fraction {res.outlier_fraction:.3f}")
    assert precision > 0.9 and recall > 0.9

    # the plain algebraic l2 fit of the same points, started at the robust answer: the outliers pull
    # the dimensions away (what the robust loss buys), and its own report shows every point kept
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)
        plain = fit(
            PARTS[name], data["points"], pose=True, residual="algebraic", stages=("polish",), init=res.params,
            progress=False,
        )  # fmt: skip
    z_plain = max(abs(plain.params[k] - v) / res.std_errors[k] for k, v in truth.items())
    plain_dist = fit_error(plain.model, data["surface"], plain.params, residual="geometric")
    print(f"  algebraic l2: worst dimension {z_plain:.1f} robust standard errors off, clean-surface rms "
          f"{np.sqrt(np.mean(plain_dist**2)):.4f} mm (robust {np.sqrt(np.mean(dist**2)):.4f})")  # fmt: skip
    assert plain.residual == "algebraic" and plain.loss_function == "l2" and plain.inliers.all()
    assert z_plain > 10.0 and np.sqrt(np.mean(plain_dist**2)) > 3.0 * np.sqrt(np.mean(dist**2))


def test_standard_errors_match_refits_of_fresh_noise():
    """Refits of the hex nut with new noise (same surface points and pose, new stray points): the z-scores of all
    dimensions against the truth, pooled, must have an RMS inside chi^2's 99.9 % interval."""
    name, refits = "hex_nut", 3
    _, res, _ = robust_fit(name)
    z = []
    for k in range(1, refits + 1):
        data = scan(name, noise_seed=k)
        refit = fit(
            PARTS[name], data["points"], pose=True, loss="cauchy", stages=("polish",), init=res.params, progress=False
        )
        z += [(refit.params[p] - v) / refit.std_errors[p] for p, v in TRUTH[name].items()]
    dof = len(z)
    rms = float(np.sqrt(np.mean(np.square(z))))
    lo, hi = math.sqrt(chi2.ppf(0.0005, dof) / dof), math.sqrt(chi2.ppf(0.9995, dof) / dof)
    print(f"\nrefit z-scores RMS {rms:.2f} over {dof} (99.9 % interval {lo:.2f} .. {hi:.2f})")
    assert lo < rms < hi


@model(bounds=((-2.0,) * 3, (2.0,) * 3), a=Param(0.5, 0.2, 1.0), b=Param(0.5, 0.2, 1.0), cx=Param(0.0, -0.5, 0.5))
def two_radii(x, a, b, cx):
    """A ball whose radius is a + b: only the sum shows in the surface."""
    return sdf.sphere(x, center=(cx, 0.0, 0.0), r=a + b)


def test_unidentifiable_parameters_are_named_and_warned():
    pts = sample_surface(two_radii, 500, params={"a": 0.6, "b": 0.5, "cx": 0.1}, seed=0, resolution=32)
    with pytest.warns(IdentifiabilityWarning, match=r"a, b cannot be determined"):
        res = fit(two_radii, pts, stages=("polish",), init={"a": 0.5, "b": 0.5, "cx": 0.0}, progress=False)
    assert res.unidentifiable == ["a", "b"]
    assert set(res.std_errors) == {"cx"} and "a, b" in res.std_error_reason
    assert res.params["a"] + res.params["b"] == pytest.approx(1.1, abs=1e-9)
    assert res.params["cx"] == pytest.approx(0.1, abs=1e-9)


def test_fit_from_a_mesh_file_with_units(tmp_path):
    """A posed nut as an STL file: read, sampled by area with its vertices kept, fitted geometrically."""
    name = "hex_nut"
    truth = TRUTH[name]
    res_grid = 64
    mesh = polygonize(lambda x: PARTS[name](x, **truth), PARTS[name].bounds, res_grid)
    rot = Rotation.from_rotvec([0.3, -0.5, 0.9])
    mesh.vertices = mesh.vertices @ rot.as_matrix().T + (120.0, -40.0, 15.0)
    path = tmp_path / "nut.stl"
    save_mesh(mesh, path)
    # the vertices lie on the surface (to float32), the facets between them off it: by their sagitta
    # on curved faces, by up to half a cell h where they cut an edge.  The median residual is about
    # 0, so the noise scale is given: the facets' deviation, h / 8
    h = float(np.max(np.subtract(PARTS[name].bounds[1], PARTS[name].bounds[0]))) / (res_grid - 1)
    res = fit(
        PARTS[name], path, pose=True, loss="cauchy", loss_scale=h / 8, units="mm", mesh_samples=1500, progress=False
    )
    assert res.units == "mm" and res.residual == "geometric"  # "auto": a file is measured data
    assert res.points.shape == (mesh.n_vertices + 1500, 3)
    errors = {k: abs(res.params[k] - v) for k, v in truth.items()}
    print(f"\nfrom STL: errors {errors} (h = {h:.3f} mm), rms {res.rms:.4f} mm")
    assert max(errors.values()) < h / 20
    assert abs(res.params["tx"] - 120.0) < h / 20 and abs(res.params["tz"] - 15.0) < h / 20


def test_posed_model_under_torch_func_matches_differences():
    """The pose parameters are ordinary 0-d parameters: per-point df/dp by the kernel's per-sample
    reverse mode equals central differences, and (B,) parameter sets batch through vmap."""
    m = posed(PARTS["l_bracket"], scale=True)
    x = torch.tensor(clean_surface("l_bracket")[:64]) + 0.3
    values = {k: torch.tensor(v, dtype=torch.float64) for k, v in m.defaults().items()}
    values.update(rx=torch.tensor(0.4, dtype=torch.float64), rz=torch.tensor(-1.1, dtype=torch.float64))
    jac = _param_jacobian(m.fn, x, values, m.names)
    eps = 1e-6
    for j, k in enumerate(m.names):
        up = m(x, **{**values, k: values[k] + eps})
        down = m(x, **{**values, k: values[k] - eps})
        np.testing.assert_allclose(jac[:, j], (up - down) / (2 * eps), atol=1e-6, err_msg=k)
    sets = m(x, **{**values, "rz": torch.tensor([-1.1, 0.2], dtype=torch.float64)})
    np.testing.assert_allclose(sets[0], m(x, **values), atol=1e-12)
    # rotation at 0: finite derivatives (the Taylor branch of Rodrigues' coefficients)
    jac0 = _param_jacobian(m.fn, x, {**values, "rx": values["rx"] * 0, "rz": values["rz"] * 0}, ["rx", "ry", "rz"])
    assert torch.isfinite(jac0).all() and jac0.abs().max() > 0


def test_planar_pose_recovers_the_angle():
    @model(bounds=((-2.0, -2.0), (2.0, 2.0)), dim=2, a=Param(1.0, 0.5, 1.5), b=Param(0.5, 0.2, 0.9))
    def ellipse2(x, a, b):
        return 1.0 - (x[:, 0] / a) ** 2 - (x[:, 1] / b) ** 2

    t = np.linspace(0, 2 * np.pi, 400, endpoint=False)
    pts = np.c_[1.2 * np.cos(t), 0.6 * np.sin(t)]
    c, s = math.cos(0.7), math.sin(0.7)
    pts = pts @ np.array([[c, -s], [s, c]]).T + (3.0, -1.0)
    res = fit(ellipse2, pts, pose=True, residual="geometric", stages=("polish",), progress=False)
    assert [k for k in res.params if k not in ("a", "b")] == ["tx", "ty", "angle"]
    assert res.params["a"] == pytest.approx(1.2, abs=1e-8) and res.params["b"] == pytest.approx(0.6, abs=1e-8)
    assert (res.params["angle"] - 0.7) % math.pi == pytest.approx(0.0, abs=1e-8) or (
        res.params["angle"] - 0.7
    ) % math.pi == pytest.approx(math.pi, abs=1e-8)
    assert res.params["tx"] == pytest.approx(3.0, abs=1e-8) and res.params["ty"] == pytest.approx(-1.0, abs=1e-8)


def test_initial_pose_candidates_are_proper_distinct_and_hold_the_truth():
    data = scan("l_bracket")
    poses = initial_pose(data["points"], PARTS["l_bracket"], params=TRUTH["l_bracket"])
    rots = [Rotation.from_rotvec([p["rx"], p["ry"], p["rz"]]).as_matrix() for p in poses]
    # the four proper sign flips of the axes, times the swaps of axes of near-equal spread
    assert len(poses) in (4, 8, 24)
    assert all(np.linalg.det(r) == pytest.approx(1.0) for r in rots)
    assert min(np.abs(a - b).max() for i, a in enumerate(rots) for b in rots[i + 1 :]) > 0.1
    # the nearest candidate is within the outliers' pull on the principal axes of the truth
    angles = [Rotation.from_matrix(r @ data["rotation"].T).magnitude() for r in rots]
    assert min(angles) < 0.2, angles
    # the hexagon's in-plane spreads are equal: its axes are also swapped (8 candidates)
    assert len(initial_pose(scan("hex_nut")["points"], PARTS["hex_nut"])) == 8


def test_bare_arrays_keep_the_papers_protocol_and_report_fully():
    """A bare array: algebraic residual, l2 (the paper's E(p)), one start; every report field set."""
    from pyfrep_core import sphere

    @model(bounds=((-2,) * 3, (2,) * 3), r=Param(1.0, 0.5, 1.5))
    def ball(x, r):
        return sphere(x, r=r)

    pts = sample_surface(ball, 300, params={"r": 1.2}, seed=0, resolution=32)
    res = fit(ball, pts, cycles=200, epochs=2, seed=0, progress=False)
    assert res.residual == "algebraic" and res.loss_function == "l2" and res.loss_scale is None
    assert len(res.starts) == 1 and res.starts[0]["best"] and res.starts[0]["params"] == res.params
    assert res.inliers.all() and res.outlier_fraction == 0.0 and res.units is None
    assert res.loss == pytest.approx(np.mean(res.residuals**2))
    assert res.rms < 1e-9 and res.std_error_reason == "" and set(res.std_errors) == {"r"}
    assert "tolerance" in res.termination or "termination" in res.termination
    no_polish = fit(ball, pts, stages=("sgd",), epochs=1, seed=0, progress=False)
    assert no_polish.std_errors == {} and "polish" in no_polish.std_error_reason


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"loss": "l1"}, ValueError, "fit: loss must be one of"),
        ({"residual": "normal"}, ValueError, "fit: residual must be one of"),
        ({"pose": "yes"}, ValueError, "fit: pose must be one of"),
        ({"starts": 0}, ValueError, "fit: starts must be positive"),
        ({"loss_scale": -1.0}, ValueError, "fit: loss_scale must be positive"),
        ({"units": 1}, TypeError, "fit: units must be a string"),
    ],
)
def test_bad_options_are_named(kwargs, error, match):
    with pytest.raises(error, match=match):
        fit(PARTS["hex_nut"], clean_surface("hex_nut"), progress=False, **kwargs)


def test_pose_names_may_not_clash():
    @model(bounds=((-1,) * 3, (1,) * 3), tx=Param(0.5, 0.1, 0.9))
    def slab(x, tx):
        return tx - x[:, 0].abs()

    with pytest.raises(ValueError, match="posed: slab already declares 'tx'"):
        posed(slab)
    with pytest.raises(ValueError, match="fit: cannot tell the format"):
        fit(slab, "part.step")


def _exact_pawn() -> tuple:
    from pyfrep_core.models import pawn

    return pawn, sample_surface(pawn, 2100, seed=0)  # no noise: residuals of rounding size


def test_exact_data_with_a_robust_loss_is_finite_and_has_no_outliers():
    # the MAD of exact data is ~0: the scale's floor (SCALE_FLOOR x the data's size) keeps r / s
    # finite, so no point is an outlier, the loss is finite and the standard errors exist
    from pyfrep_core.fitting import SCALE_FLOOR

    pawn, pts = _exact_pawn()
    res = fit(pawn, pts, loss="cauchy", cycles=200, epochs=2, seed=0, progress=False)
    size = float(np.linalg.norm(np.subtract(*pawn.bounds[::-1])))
    assert math.isfinite(res.loss)
    assert res.loss_scale >= SCALE_FLOOR * size * 0.5  # the floor (algebraic: x median |grad f|, ~1 for the pawn)
    assert res.outlier_fraction == 0.0
    assert set(res.std_errors) == set(res.free) and res.std_error_reason == ""
    assert all(math.isfinite(v) for v in res.std_errors.values())
    for k, v in pawn.defaults().items():  # the data's truth, recovered far below the floor
        assert abs(res.params[k] - v) < SCALE_FLOOR * size, k


def _ball_points(n: int = 600, noise: float = 0.0) -> np.ndarray:
    rng = np.random.default_rng(3)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (1.2 + noise * rng.normal(size=(n, 1))) + (0.1, 0.0, 0.0)


@model(bounds=((-2,) * 3, (2,) * 3), r=Param(1.0, 0.5, 1.5), cx=Param(0.0, -0.5, 0.5))
def _ball(x, r, cx):
    return sphere(x, center=(cx, 0.0, 0.0), r=r)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"loss": "l2"},
        {"loss": "cauchy", "residual": "geometric"},
        {"loss": "huber", "noise": 0.0},
        {"loss": "l2", "stages": ("evolution",)},
        {"loss": "trimmed", "pose": True, "fixed": {"cx": 0.0}, "stages": ("polish",)},
        {"loss": "l2", "pose": True, "fixed": {"cx": 0.0}, "stages": ("polish",), "noise": 0.0},
    ],
)
def test_std_errors_always_present_or_explained_and_starts_listed(kwargs):
    kwargs = dict(kwargs)
    pts = _ball_points(noise=kwargs.pop("noise", 1e-3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IdentifiabilityWarning)  # a posed ball's turns are unidentifiable
        res = fit(_ball, pts, cycles=100, epochs=2, seed=0, progress=False, **kwargs)
    assert math.isfinite(res.loss)
    assert all(math.isfinite(v) for v in res.std_errors.values())
    assert set(res.std_errors) == set(res.free) or res.std_error_reason
    assert len(res.starts) >= 1 and sum(s["best"] for s in res.starts) == 1
    best = next(s for s in res.starts if s["best"])
    assert best["params"] == res.params


def test_polish_steps_continue_across_re_polishes():
    from pyfrep_core.fitting import _LazyProgress, _polish, _Problem

    events = []
    prob = _Problem(_ball, {}, {k: (p.lower, p.upper) for k, p in _ball.params.items()}, "geometric", "cauchy")
    x = torch.as_tensor(_ball_points(noise=1e-3))
    prob.set_scale_floor(x)
    cfg = {"polish_iters": 40, "xtol": 1e-10}

    def report(total, stage, every=1):
        return _LazyProgress(total, stage, events.append, every, None, False)

    first = _polish(prob, x, torch.tensor([0.2, 0.6]), cfg, report)
    _polish(prob, x, torch.tensor([0.8, 0.4]), cfg, report, len(first["losses"]))
    steps = [e.step for e in events]
    assert steps == list(range(len(steps))) and len(steps) > len(first["losses"])
    assert all(e.step < e.total for e in events)
