"""fit(): the paper's microstructure recovered to 0.1 %, SGD alone worse (Fig. 7), noise-derived tolerances,
progress events and early stop, fixed parameters, bounds, clear errors."""

import math
import os
import threading

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from pyfrep_core import Param, ellipsoid, fit, model, sample_surface
from pyfrep_core.fitting import _jacobian, _Problem, fit_error
from pyfrep_core.models import microstructure

QUICK = os.environ.get("PYFREP_QUICK", "0") == "1"
# the paper's protocol: 10,000 cycles (population 100, tournaments of 10), 100 SGD epochs; quick mode: fewer
PROTOCOL = dict(cycles=5000, epochs=20) if QUICK else dict(cycles=10_000, epochs=100)
TRUTH = dict(scale1=8.2, scale2=3.6, freq1=0.7, freq2=0.9)  # inside the bounds, not the defaults


@pytest.fixture(scope="module")
def cloud():
    return sample_surface(microstructure, 40_000, params=TRUTH, seed=0, resolution=128)


def rel_errors(params, truth=TRUTH):
    return {k: abs(params[k] / truth[k] - 1) for k in truth}


def test_full_pipeline_recovers_every_parameter(cloud):
    res = fit(microstructure, cloud, seed=1, progress=False, **PROTOCOL)
    errors = rel_errors(res.params)
    assert max(errors.values()) < 1e-3, errors
    assert res.stages == ("evolution", "sgd", "polish") and not res.stopped
    assert res.residuals.shape == (40_000,) and res.residuals.dtype == np.float64
    np.testing.assert_allclose(res.residuals, fit_error(microstructure, cloud, res.params))
    assert res.loss == pytest.approx(np.mean(res.residuals**2)) and res.loss < 1e-12
    # one loss per step: generations of the batched evolution, Adam steps, polish evaluations
    n_gen = math.ceil((PROTOCOL["cycles"] - 100) / 50)
    assert len(res.history["evolution"]) == n_gen
    assert len(res.history["sgd"]) == PROTOCOL["epochs"] * math.ceil(40_000 / 16384)
    assert res.history["polish"][-1] == pytest.approx(res.loss, rel=1e-6, abs=1e-20)
    assert all(res.timings[s] > 0 for s in ("evolution", "sgd", "polish", "total"))
    assert set(res.standard_errors) == set(TRUTH)


def test_sgd_alone_from_a_random_start_is_worse(cloud):
    """Fig. 7: gradient descent alone stalls in one of the many local minima of E in the rod scales."""
    full = fit(microstructure, cloud, seed=2, progress=False, **PROTOCOL)
    sgd = fit(microstructure, cloud, stages=("sgd",), seed=2, progress=False, epochs=PROTOCOL["epochs"])
    print(f"\nSGD alone: {sgd.params}, E = {sgd.loss:.3e}; full pipeline: E = {full.loss:.3e}")
    assert sgd.stages == ("sgd",)
    assert sgd.loss > 1e6 * full.loss
    assert max(rel_errors(sgd.params).values()) > 1e-2
    assert np.median(sgd.residuals) > 100 * np.median(full.residuals)


@model(
    bounds=((-1.5,) * 3, (1.5,) * 3),
    a=Param(1.0, 0.5, 1.3),
    b=Param(0.8, 0.4, 1.2),
    c=Param(0.6, 0.3, 1.0),
    cx=Param(0.0, -0.3, 0.3),
)
def egg(x, a, b, c, cx):
    return ellipsoid(x, center=(cx, 0.0, 0.0), a=a, b=b, c=c)


def test_noisy_fit_within_tolerance_derived_from_the_noise():
    """sigma = 1 % of the box.  The tolerance comes from the noise, two ways:
    - spread: the polish's sandwich covariance (J^T J)^-1 J^T diag(r^2) J (J^T J)^-1, checked
      against the spread of refits of fresh noise (chi-square bounds on the ratio);
    - bias: an algebraic fit of noisy points is biased (E f(x + e) = f(x) + sigma^2/2 Lap f);
      a parametric bootstrap at the fitted parameters estimates it.
    Each parameter, bias-corrected, must lie within 4 standard errors of the truth."""
    truth = dict(a=1.1, b=0.75, c=0.55, cx=0.12)
    sigma = 0.01 * 3.0  # the box is 3 wide
    n, k_boot = 20_000, 16
    noisy = sample_surface(egg, n, params=truth, noise=sigma, seed=0, resolution=48)
    res = fit(egg, noisy, seed=0, progress=False, cycles=2000, epochs=10)
    se = res.standard_errors
    clean_hat = sample_surface(egg, n, params=res.params, seed=1, resolution=48)
    rng = np.random.default_rng(2)
    boot = []
    for _ in range(k_boot):
        refit = fit(
            egg, clean_hat + rng.normal(0, sigma, clean_hat.shape), stages=("polish",), init=res.params, progress=False
        )
        boot.append([refit.params[k] for k in truth])
    boot = np.array(boot)
    lo, hi = (math.sqrt(chi2.ppf(q, k_boot - 1) / (k_boot - 1)) for q in (1e-4, 1 - 1e-4))
    for j, name in enumerate(truth):
        bias = boot[:, j].mean() - res.params[name]
        spread = boot[:, j].std(ddof=1)
        assert lo < spread / se[name] < hi, (name, spread, se[name])
        corrected = res.params[name] - bias
        assert abs(corrected - truth[name]) < 4 * se[name] * math.sqrt(1 + 1 / k_boot), (name, corrected, se[name])


def test_noisy_microstructure_bias_corrected_within_bootstrap_spread(cloud):
    """The microstructure with noise of 0.1 % of its box (sigma = 0.021; at the issue's 1 % the noise,
    0.21, is wider than the outer rods, ~0.18, and no parameter is identifiable: measured, see the
    report).  The algebraic fit is biased (freq1 by ~10 %); a parametric bootstrap at the fitted
    parameters estimates the bias and the estimator's spread, which set the tolerance."""
    sigma, k_boot = 0.001 * 21.0, 16  # the box is 21 wide
    noisy = cloud + np.random.default_rng(5).normal(0, sigma, cloud.shape)
    res = fit(microstructure, noisy, seed=0, progress=False, **PROTOCOL)
    clean_hat = sample_surface(microstructure, len(cloud), params=res.params, seed=1, resolution=128)
    rng = np.random.default_rng(2)
    boot = []
    for _ in range(k_boot):
        noisy_hat = clean_hat + rng.normal(0, sigma, clean_hat.shape)
        refit = fit(microstructure, noisy_hat, stages=("polish",), init=res.params, progress=False)
        boot.append([refit.params[k] for k in TRUTH])
    boot = np.array(boot)
    for j, name in enumerate(TRUTH):
        bias = boot[:, j].mean() - res.params[name]
        spread = max(boot[:, j].std(ddof=1), res.standard_errors[name])
        corrected = res.params[name] - bias
        assert abs(corrected - TRUTH[name]) < 4 * spread * math.sqrt(1 + 1 / k_boot), (name, corrected, spread)


def test_fixed_parameters_stay_fixed(cloud):
    res = fit(microstructure, cloud[:8000], fixed={"freq1": 0.7, "freq2": 0.9}, seed=3, progress=False, **PROTOCOL)
    assert res.params["freq1"] == 0.7 and res.params["freq2"] == 0.9
    assert res.free == ("scale1", "scale2")
    assert max(rel_errors(res.params).values()) < 1e-3


def test_param_bounds_narrow_the_search(cloud):
    res = fit(microstructure, cloud[:4000], param_bounds={"scale1": (5.0, 6.0)}, seed=0, progress=False, cycles=500)
    assert 5.0 <= res.params["scale1"] <= 6.0  # the truth (8.2) is outside: the fit stays in the box


def test_callbacks_fire_per_stage_every_k_steps(cloud):
    events = []
    res = fit(
        microstructure, cloud[:2000], seed=0, progress=False, cycles=600, epochs=6, every=2, callback=events.append
    )
    stages = [e.stage for e in events]
    assert stages == sorted(stages, key=["evolution", "sgd", "polish"].index)
    assert set(stages) == {"evolution", "sgd", "polish"}
    for e in events:
        assert np.isfinite(e.loss) and set(e.params) == set(TRUTH)
        assert all(microstructure.params[k].lower <= v <= microstructure.params[k].upper for k, v in e.params.items())
    evo = [e.step for e in events if e.stage == "evolution"]
    assert evo == [0, 2, 4, 6, 8, 9]  # (600 - 100) / 50 = 10 generations: every 2nd and the last
    assert [e.step for e in events if e.stage == "sgd"] == [0, 2, 4, 5]
    assert events[-1].stage == "polish" and not res.stopped


def test_early_stop_from_callback_and_stop_flag(cloud):
    pts = cloud[:2000]

    def stop_in_sgd(e):
        return e.stage == "sgd" and e.step >= 2

    res = fit(microstructure, pts, seed=0, progress=False, cycles=600, epochs=50, every=1, callback=stop_in_sgd)
    assert res.stopped and res.stages == ("evolution", "sgd") and "polish" not in res.timings
    assert len(res.history["sgd"]) == 3 * math.ceil(2000 / 16384)  # epochs 0, 1, 2
    assert set(res.params) == set(TRUTH) and res.residuals.shape == (2000,)

    flag = threading.Event()

    def set_flag(e):
        if e.step == 3:
            flag.set()

    res = fit(microstructure, pts, seed=0, progress=False, cycles=5000, every=1, callback=set_flag, stop=flag)
    assert res.stopped and res.stages == ("evolution",) and len(res.history["evolution"]) == 4

    res = fit(microstructure, pts, init=TRUTH, stages=("polish",), callback=lambda e: True, progress=False)
    assert res.stopped and res.stages == ("polish",)


def test_jacobian_equals_central_differences_with_and_without_parameter_vectors():
    """The polish's Jacobian (per-sample reverse mode) for the microstructure (parameters used
    element-wise) and the egg (a parameter inside a centre vector: no per-point broadcasting)."""
    rng = np.random.default_rng(0)
    x = torch.tensor(rng.uniform(-9, 9, (300, 3)))
    for m, q, points in (
        (microstructure, torch.tensor(list(TRUTH.values()), dtype=torch.float64), x),
        (egg, torch.tensor([1.1, 0.75, 0.55, 0.12], dtype=torch.float64), x / 8),
    ):
        prob = _Problem(m, {}, {k: (p.lower, p.upper) for k, p in m.params.items()})
        jac = _jacobian(prob, points, q)
        assert jac.shape == (300, len(m.params)) and jac.dtype == torch.float64
        for j in range(q.shape[0]):
            # central differences at the step eps^(1/3) that balances truncation (h^2 f'''/6) and
            # rounding (eps |f| / h): both ~1e-10 of the column's scale, well inside 1e-6 of it
            h = torch.finfo(torch.float64).eps ** (1 / 3)
            dq = torch.zeros_like(q)
            dq[j] = h
            fd = (prob.f(points, q + dq) - prob.f(points, q - dq)) / (2 * h)
            torch.testing.assert_close(jac[:, j], fd, rtol=1e-6, atol=1e-6 * float(fd.abs().max()))


@pytest.mark.parametrize(
    "points, kwargs, err, match",
    [
        ("nan", {}, ValueError, "non-finite"),
        ("empty", {}, ValueError, "empty"),
        ("2d", {}, ValueError, "shape"),
        ("ok", {"fixed": {"radius": 1.0}}, TypeError, "radius"),
        ("ok", {"init": {"scale3": 1.0}}, TypeError, "scale3"),
        ("ok", {"param_bounds": {"scale1": (6.0, 5.0)}}, ValueError, "below"),
        ("ok", {"param_bounds": {"scale1": (0.5, 5.0)}}, ValueError, "declared range"),
        ("ok", {"fixed": {"scale1": 20.0}}, ValueError, "outside"),
        ("ok", {"init": {"freq1": 3.0}}, ValueError, "outside"),
        ("ok", {"fixed": dict(TRUTH)}, ValueError, "nothing to fit"),
        ("ok", {"stages": ("sgd", "newton")}, ValueError, "stages"),
        ("ok", {"cycles": -1}, ValueError, "cycles"),
    ],
)
def test_bad_input_is_a_clear_error(points, kwargs, err, match):
    pts = {
        "nan": np.array([[0.0, 1.0, 2.0], [np.nan, 0.0, 0.0]]),
        "empty": np.zeros((0, 3)),
        "2d": np.zeros((5, 2)),
        "ok": np.ones((5, 3)),
    }[points]
    with pytest.raises(err, match=match):
        fit(microstructure, pts, progress=False, **kwargs)


def test_model_must_declare_parameters():
    with pytest.raises(TypeError, match="Model"):
        fit(lambda x: x[:, 0], np.ones((5, 3)))


def test_a_fit_in_a_background_thread_leaves_other_threads_alone():
    import threading

    from pyfrep_core._threads import intra_op_threads

    before = torch.get_num_threads()
    inside, release = threading.Event(), threading.Event()
    seen = {}

    def long_run():  # what the workbench does: fit on a background thread
        seen["worker before"] = torch.get_num_threads()
        with intra_op_threads(1):
            seen["worker"] = torch.get_num_threads()
            inside.set()
            release.wait(10)
        seen["worker after"] = torch.get_num_threads()

    worker = threading.Thread(target=long_run)
    worker.start()
    inside.wait(10)
    assert torch.get_num_threads() == before  # the main thread keeps its threads meanwhile
    with intra_op_threads(1):  # a second run on the main thread, overlapping the first
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == before
    release.set()
    worker.join(10)
    assert seen["worker"] == 1
    assert seen["worker after"] == seen["worker before"]
