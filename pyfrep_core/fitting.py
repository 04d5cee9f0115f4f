"""Fitting a model's named, bounded parameters to a point cloud (paper section 5.4).

The error of fit is the paper's ``E(p) = 1/N sum_i f(x_i; p)^2``.  :func:`fit` minimizes it in
up to three stages:

1. ``"evolution"``: regularized evolution (Real et al. 2019) in the normalized parameter box,
   a global search that finds the basin of the minimum (``E`` is very oscillatory in the rod
   scales of the microstructure, so gradient descent alone stalls in a local minimum, Fig. 7);
2. ``"sgd"``: Adam on random batches of the points (the paper's SGD on ``E~``);
3. ``"polish"``: bounded least squares (scipy's trust-region reflective) on the residuals
   ``f(x_i; p)`` with the Jacobian ``df(x_i)/dp`` by per-sample reverse-mode autodiff (the
   kernel's one per-point parameter derivative, :func:`pyfrep_core.diff.param_grad`), since E
   is a sum of squares: it converges quadratically to the minimum instead of jittering around it.

>>> from pyfrep_core import model, Param, sphere, sample_surface
>>> @model(bounds=((-2,) * 3, (2,) * 3), r=Param(1.0, 0.5, 1.5), cx=Param(0.0, -0.5, 0.5))
... def ball(x, r, cx):
...     return sphere(x, center=(cx, 0.0, 0.0), r=r)
>>> pts = sample_surface(ball, 2000, params={"r": 1.2, "cx": 0.1}, seed=0, resolution=48)
>>> res = fit(ball, pts, cycles=300, epochs=5, seed=0, progress=False)
>>> {k: round(v, 6) for k, v in res.params.items()}
{'r': 1.2, 'cx': 0.1}
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ._array import as_tensor, check_finite, check_option, check_points
from ._threads import intra_op_threads
from .diff import _param_jacobian
from .model import Model
from .progress import Event, Progress, StopFlag

__all__ = ["FitResult", "fit", "fit_error"]

STAGES = ("evolution", "sgd", "polish")


@dataclass
class FitResult:
    """What :func:`fit` returns.

    Attributes
    ----------
    params : name -> fitted value (float), every parameter of the model (fixed ones included).
    loss : E(p) = mean f(x_i; p)^2 over all points at ``params``.
    residuals : (N,) float64 numpy, |f(x_i; p)| per point.
    history : stage -> list of losses, one per step (evolution: best score per generation on
        the selection subset; sgd: batch loss per step; polish: E(p) per function evaluation).
    timings : stage -> wall seconds, and ``"total"``.
    stages : the stages run, in order.
    stopped : True when a callback or the stop flag ended the run early.
    standard_errors : name -> standard error of each free parameter from the polish
        (heteroscedasticity-robust sandwich covariance of the least-squares estimate); empty
        without a polish.
    covariance : (P, P) numpy covariance of the free parameters (order of ``free``), or None.
    free : names of the fitted (not fixed) parameters.
    """

    params: dict[str, float]
    loss: float
    residuals: np.ndarray
    history: dict[str, list[float]] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    stages: tuple[str, ...] = ()
    stopped: bool = False
    standard_errors: dict[str, float] = field(default_factory=dict)
    covariance: np.ndarray | None = None
    free: tuple[str, ...] = ()

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={v:.6g}" for k, v in self.params.items())
        return f"FitResult({ps}; E={self.loss:.3e}, {self.timings.get('total', 0.0):.2f} s, stages={self.stages})"


class _StopRequestedError(Exception):
    """Raised inside scipy's callbacks when the user asked to stop."""


class _Problem:
    """The free parameters of a model, their box, and batched evaluations of f on points."""

    def __init__(self, model: Model, fixed: dict[str, float], box: dict[str, tuple]):
        self.model, self.fixed = model, fixed
        self.free = [k for k in model.names if k not in fixed]
        self.lower = np.array([box[k][0] for k in self.free])
        self.upper = np.array([box[k][1] for k in self.free])

    def to_params(self, u: torch.Tensor) -> torch.Tensor:
        """Normalized coordinates u in [0, 1]^P -> parameter values (same shape)."""
        lo = torch.as_tensor(self.lower, dtype=u.dtype, device=u.device)
        hi = torch.as_tensor(self.upper, dtype=u.dtype, device=u.device)
        return lo + u * (hi - lo)

    def to_unit(self, p: np.ndarray) -> np.ndarray:
        return (np.asarray(p, dtype=float) - self.lower) / (self.upper - self.lower)

    def named(self, p: torch.Tensor) -> dict[str, Any]:
        """Keyword arguments for the model: free values (scalars or (B,) batches) and the fixed ones."""
        values = {k: p[..., j] for j, k in enumerate(self.free)}
        values.update(self.fixed)
        return values

    def f(self, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """f(x; p): p (P,) -> (N,), p (B, P) -> (B, N)."""
        return self.model(x, **self.named(p))

    def as_dict(self, p: Sequence[float]) -> dict[str, float]:
        values = {k: float(v) for k, v in zip(self.free, p)}
        values.update({k: float(v) for k, v in self.fixed.items()})
        return {k: values[k] for k in self.model.names}


def _check_inputs(model: Any, points: Any, fixed, init, param_bounds, stages) -> tuple:
    if not isinstance(model, Model):
        raise TypeError(f"model must be a Model declared with @model (named, bounded parameters), got {model!r}")
    x, _ = as_tensor(points, "points")
    if x.ndim != 2 or x.shape[1] != model.dim:
        raise ValueError(f"points must have shape (N, {model.dim}), got {tuple(x.shape)}")
    if x.shape[0] == 0:
        raise ValueError("points is empty: nothing to fit")
    check_finite(x, "points")
    stages = (stages,) if isinstance(stages, str) else tuple(stages)
    bad = [s for s in stages if s not in STAGES]
    if bad or not stages or len(set(stages)) != len(stages):
        raise ValueError(f"stages must be distinct names among {STAGES}, got {stages!r}")
    for what, values in (("fixed", fixed), ("init", init), ("param_bounds", param_bounds)):
        unknown = [k for k in values if k not in model.params]
        if unknown:
            raise TypeError(
                f"{what} names {unknown[0]!r}, which {model.__name__} does not declare; "
                f"declared: {', '.join(model.names)}"
            )
    box = {k: (p.lower, p.upper) for k, p in model.params.items()}
    for k, b in param_bounds.items():
        try:
            lo, hi = (float(v) for v in b)
        except (TypeError, ValueError):
            raise ValueError(f"param_bounds[{k!r}] must be (lower, upper), got {b!r}") from None
        p = model.params[k]
        if not (math.isfinite(lo) and math.isfinite(hi)) or lo >= hi:
            raise ValueError(f"param_bounds[{k!r}]: lower {lo} must be below upper {hi}")
        if lo < p.lower or hi > p.upper:
            raise ValueError(f"param_bounds[{k!r}] = ({lo}, {hi}) leaves the declared range [{p.lower}, {p.upper}]")
        box[k] = (lo, hi)
    model.check(**{k: float(v) for k, v in fixed.items()})
    for k, v in init.items():
        lo, hi = box[k]
        if not (math.isfinite(float(v)) and lo <= float(v) <= hi):
            raise ValueError(f"init[{k!r}] = {v!r} is outside the bounds [{lo}, {hi}]")
    if len(fixed) == len(model.params):
        raise ValueError("every parameter is fixed: nothing to fit")
    return x, stages, box


def fit_error(model: Model, points: Any, params: Mapping[str, float] | None = None) -> np.ndarray:
    """Per-point residuals |f(x_i; p)| (float64 numpy, evaluated in chunks), the paper's Fig. 7 colours.

    Examples
    --------
    >>> from pyfrep_core import model, Param, sphere
    >>> @model(r=Param(1.0, 0.5, 2.0))
    ... def ball(x, r):
    ...     return sphere(x, r=r)
    >>> fit_error(ball, np.array([[1.0, 0, 0], [0, 2.0, 0]]))
    array([0., 3.])
    """
    if not isinstance(model, Model):
        raise TypeError(f"fit_error: model must be a Model declared with @model, got {model!r}")
    x, _ = as_tensor(points, "points", dtype=torch.float64)
    check_points(x, model.dim, "points")
    check_finite(x, "points")
    values = model.check(**dict(params or {}))
    with torch.no_grad():
        out = model(x, **values).abs()  # in chunks within the memory budget of one call (pyfrep_core.evaluate)
    return out.cpu().numpy()


def _evolution(prob: _Problem, x: torch.Tensor, gen: torch.Generator, cfg: dict, init_u, report) -> tuple:
    """Regularized evolution, batched: ``children`` tournaments per generation, one model call each.

    Real et al.'s algorithm adds one child per cycle and removes the oldest individual.  Here
    ``children`` tournaments are held on the current population, their mutated winners are
    evaluated together in one batched call (B parameter sets -> f of shape (B, M)), and each
    child replaces the oldest individual (the population is a ring buffer ordered by age).
    With ``children = 1`` this is exactly the sequential algorithm.  Scores are E(p) on one
    random subset of ``subsample`` points, fixed for the whole run so that scores compare; the
    best ``finalists`` of the history are then re-scored on a fresh subset for the final choice.
    """
    pop_size, sample_size = cfg["population_size"], cfg["sample_size"]
    k = min(cfg["children"], pop_size)  # a generation replaces at most the whole population
    n_points, n_free, dev, dt = x.shape[0], len(prob.free), x.device, x.dtype
    m = min(cfg["subsample"], n_points)
    xs = x[torch.randperm(n_points, generator=gen, device="cpu")[:m].to(dev)]

    def score(u: torch.Tensor) -> torch.Tensor:
        with torch.no_grad():
            e = prob.f(xs, prob.to_params(u)).square().mean(-1)
        return torch.nan_to_num(e, nan=math.inf)

    pop = torch.rand(pop_size, n_free, generator=gen, dtype=dt).to(dev)
    if init_u is not None:
        pop[0] = torch.as_tensor(init_u, dtype=dt, device=dev)
    scores = score(pop)
    hist_u, hist_s = [pop], [scores]
    oldest = 0  # ring buffer: pop[oldest] is the oldest individual
    n_children = max(0, cfg["cycles"] - pop_size)  # Real et al.: the history holds `cycles` models
    n_gen = math.ceil(n_children / k)
    lo_s, hi_s = math.log(cfg["mutation"][0]), math.log(cfg["mutation"][1])
    best = float(scores.min())
    with report(n_gen, "evolution") as progress:
        for g in range(n_gen):
            b = min(k, n_children - g * k)
            # tournaments: `sample_size` random members (with replacement), the fittest is the parent
            entrants = torch.randint(pop_size, (b, sample_size), generator=gen).to(dev)
            parents = entrants.gather(1, scores[entrants].argmin(1, keepdim=True)).squeeze(1)
            # mutation: Gaussian step in the unit box, its scale log-uniform per child (coarse and fine moves)
            sigma = torch.exp(lo_s + (hi_s - lo_s) * torch.rand(b, 1, generator=gen, dtype=dt)).to(dev)
            step = sigma * torch.randn(b, n_free, generator=gen, dtype=dt).to(dev)
            children = (pop[parents] + step).clamp(0.0, 1.0)
            child_scores = score(children)
            slots = (oldest + torch.arange(b, device=dev)) % pop_size  # each child replaces the oldest
            pop[slots], scores[slots] = children, child_scores
            oldest = (oldest + b) % pop_size
            hist_u.append(children)
            hist_s.append(child_scores)
            best = min(best, float(child_scores.min()))
            if progress.update(g, best, lambda: prob.as_dict(prob.to_params(pop[scores.argmin()]).tolist())):
                break
    hist_u, hist_s = torch.cat(hist_u), torch.cat(hist_s)
    finalists = hist_u[hist_s.topk(min(cfg["finalists"], hist_s.numel()), largest=False).indices]
    m2 = min(cfg["final_subsample"], n_points)
    xs = x[torch.randperm(n_points, generator=gen, device="cpu")[:m2].to(dev)]
    final = score(finalists)
    return finalists[final.argmin()], progress.stopped, progress.losses


def _sgd(prob: _Problem, x: torch.Tensor, gen: torch.Generator, cfg: dict, u0: torch.Tensor, report) -> tuple:
    """Adam on random batches of E~(p) = mean over a batch of f(x_i; p)^2, in the unit box (projected)."""
    n_points = x.shape[0]
    bs = min(cfg["batch_size"], n_points)
    per_epoch = math.ceil(n_points / bs)
    total = cfg["epochs"] * per_epoch
    u = u0.detach().clone().requires_grad_(True)
    opt = torch.optim.Adam([u], lr=cfg["lr"])
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 1.0 - s / max(total, 1))  # linear decay to 0
    losses: list[torch.Tensor] = []
    with report(cfg["epochs"], "sgd") as progress:
        for epoch in range(cfg["epochs"]):
            order = torch.randperm(n_points, generator=gen).to(x.device)
            epoch_loss = torch.zeros((), dtype=x.dtype, device=x.device)
            for batch in order.tensor_split(per_epoch):  # near-equal random batches
                xb = x[batch]
                opt.zero_grad(set_to_none=True)
                loss = prob.f(xb, prob.to_params(u)).square().mean()
                loss.backward()
                opt.step()
                sched.step()
                with torch.no_grad():
                    u.clamp_(0.0, 1.0)
                losses.append(loss.detach())
                epoch_loss += loss.detach()
            if progress.update(epoch, float(epoch_loss) / per_epoch, lambda: prob.as_dict(prob.to_params(u).tolist())):
                break
    history = torch.stack(losses).tolist() if losses else []
    return u.detach(), progress.stopped, history


def _residuals(prob: _Problem, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """f(x_i; p), (N,) (the model call chunks the points within its memory budget)."""
    with torch.no_grad():
        return prob.f(x, p)


def _jacobian(prob: _Problem, x: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """df(x_i)/dp (N, P) for the free parameters: the kernel's per-point parameter derivative
    (:func:`pyfrep_core.diff.param_grad`'s per-sample reverse mode, chunked, thread-safe)."""
    values = dict(zip(prob.free, p.detach().unbind(0)))
    values.update(prob.fixed)
    return _param_jacobian(prob.model.fn, x, values, prob.free, label=prob.model.__name__)


def _polish(prob: _Problem, x: torch.Tensor, u0: torch.Tensor, cfg: dict, report) -> tuple:
    """Bounded least squares on the residuals f(x_i; p): scipy's 'trf' with an autodiff Jacobian."""
    from scipy.optimize import least_squares

    x64 = x.to(torch.float64)
    losses: list[float] = []
    p0 = np.clip(prob.to_params(u0.to(torch.float64)).cpu().numpy(), prob.lower, prob.upper)
    last: dict[str, np.ndarray] = {}

    with report(cfg["polish_iters"], "polish", every=1) as progress:

        def fun(p: np.ndarray) -> np.ndarray:
            r = _residuals(prob, x64, torch.as_tensor(p, device=x.device)).cpu().numpy()
            losses.append(float(np.mean(r * r)))
            if losses[-1] <= min(losses):  # the best point so far: what an early stop returns
                last["p"], last["r"] = p.copy(), r
            best = last["p"]
            # every evaluation is reported (there are few), with the best loss and parameters so far
            if progress.update(len(losses) - 1, min(losses), lambda: prob.as_dict(best)):
                raise _StopRequestedError
            return r

        def jac(p: np.ndarray) -> np.ndarray:
            return _jacobian(prob, x64, torch.as_tensor(p, device=x.device)).cpu().numpy()

        stopped = False
        try:
            sol = least_squares(
                fun,
                p0,
                jac=jac,
                bounds=(prob.lower, prob.upper),
                method="trf",
                x_scale=prob.upper - prob.lower,
                xtol=cfg["xtol"],
                ftol=cfg["xtol"],
                gtol=cfg["xtol"],
                max_nfev=cfg["polish_iters"],
            )
            p, r = sol.x, sol.fun
            jmat = sol.jac
        except _StopRequestedError:
            stopped = True
            p, r = last["p"], last["r"]
            jmat = jac(p)
    cov = _sandwich_covariance(np.asarray(jmat), np.asarray(r))
    return p, stopped, losses, cov


def _sandwich_covariance(j: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """Covariance of a least-squares estimate, robust to per-point noise levels (White's HC0):
    ``(J^T J)^-1 J^T diag(r^2) J (J^T J)^-1``.  None when J^T J is singular."""
    jtj = j.T @ j
    try:
        inv = np.linalg.inv(jtj)
    except np.linalg.LinAlgError:
        return None
    meat = (j * (r * r)[:, None]).T @ j
    return inv @ meat @ inv


def fit(
    model: Model,
    points: Any,
    *,
    stages: Sequence[str] = STAGES,
    fixed: Mapping[str, float] | None = None,
    init: Mapping[str, float] | None = None,
    param_bounds: Mapping[str, tuple[float, float]] | None = None,
    cycles: int = 10_000,
    population_size: int = 100,
    sample_size: int = 10,
    children: int = 50,
    mutation: tuple[float, float] = (1e-3, 1.0),
    subsample: int = 256,
    final_subsample: int = 8192,
    finalists: int = 16,
    epochs: int = 100,
    batch_size: int = 16384,
    lr: float = 1e-3,
    polish_iters: int = 50,
    xtol: float = 1e-10,
    dtype: torch.dtype = torch.float32,
    num_threads: int | None = 1,
    seed: int | None = None,
    callback: Callable[[Event], Any] | None = None,
    every: int = 10,
    stop: StopFlag | None = None,
    progress: bool = True,
) -> FitResult:
    """Fit the free parameters of ``model`` so that its surface passes through ``points``.

    Minimizes the paper's E(p) = 1/N sum f(x_i; p)^2 over the box of the declared parameter
    ranges, by regularized evolution, then Adam on random batches, then a bounded
    least-squares polish (see the module docstring); any subset of the stages can be run.

    Parameters
    ----------
    model : Model with named, bounded parameters (``@model``).
    points : (N, dim) array or tensor of surface samples (length units).
    stages : stages to run, in order, among "evolution", "sgd", "polish" (e.g. ("sgd",) for the
        paper's SGD alone).
    fixed : name -> value of parameters held fixed (not fitted).
    init : name -> starting value: joins the initial population, or starts SGD/polish when no
        evolution runs (other free parameters then start at random, from ``seed``).
    param_bounds : name -> (lower, upper) narrowing the declared range for the search.
    cycles : regularized evolution's history length (initial population included, Real et al.).
    population_size, sample_size : population and tournament sizes.
    children : tournaments (children) per batched generation; 1 gives the sequential algorithm.
    mutation : (smallest, largest) standard deviation of the Gaussian mutation in the unit box;
        each child draws its own, log-uniformly.
    subsample : points used to score individuals (one random subset for the run).
    final_subsample, finalists : the best ``finalists`` of the history are re-scored on a fresh
        subset of this size; the best becomes the start of the next stage.
    epochs, batch_size, lr : Adam on random batches; an epoch is one pass over the points; the
        learning rate (in the unit box) decays linearly to 0.
    polish_iters, xtol : function evaluations and tolerance of the least-squares polish.
    dtype : dtype of the evolution and SGD stages (the polish and residuals use float64).
    num_threads : torch intra-op threads during the fit (restored afterwards); None keeps the
        current setting.  The fit's tensors are small (a batch, a subsample), so one thread is as
        fast and does not collapse when other processes share the cores (OpenMP spin-waits).
    seed : seeds every random choice (population, tournaments, mutations, subsets, batches).
    callback, every, stop, progress : see :mod:`pyfrep_core.progress`; events carry the stage,
        step (generation, epoch or evaluation), loss and current parameters.  A callback returning
        True or a set stop flag ends the run: the result holds the best parameters so far.

    Returns
    -------
    FitResult

    Raises
    ------
    TypeError : ``model`` is not a Model; ``fixed``/``init``/``param_bounds`` names an undeclared parameter.
    ValueError : points empty, of the wrong shape or not finite; inverted bounds; values out of range.
    """
    fixed, init, param_bounds = dict(fixed or {}), dict(init or {}), dict(param_bounds or {})
    x, stages, box = _check_inputs(model, points, fixed, init, param_bounds, stages)
    given = dict(cycles=cycles, population_size=population_size, sample_size=sample_size, children=children,
                 subsample=subsample, final_subsample=final_subsample, finalists=finalists, epochs=epochs,
                 batch_size=batch_size, polish_iters=polish_iters)  # fmt: skip
    cfg: dict[str, Any] = {
        k: check_option(v, k, "fit", "int", minimum=0 if k in ("cycles", "epochs") else 1) for k, v in given.items()
    }
    cfg["lr"] = check_option(lr, "lr", "fit", positive=True)
    cfg["xtol"] = check_option(xtol, "xtol", "fit", positive=True)
    cfg["dtype"] = check_option(dtype, "dtype", "fit", "choice", choices=(torch.float32, torch.float64))
    try:
        smallest, largest = (float(m) for m in mutation)
    except (TypeError, ValueError):
        raise TypeError(f"fit: mutation must be (smallest, largest), two numbers, got {mutation!r}") from None
    if not (math.isfinite(largest) and 0 < smallest <= largest):
        raise ValueError(
            f"fit: mutation must be (smallest, largest), finite, 0 < smallest <= largest, got {mutation!r}"
        )
    cfg["mutation"] = (smallest, largest)
    every = check_option(every, "every", "fit", "int", positive=True)
    num_threads = check_option(num_threads, "num_threads", "fit", "int", positive=True, none=True)
    seed = check_option(seed, "seed", "fit", "int", minimum=0, maximum=2**63 - 1, none=True)
    progress = check_option(progress, "progress", "fit", "bool")
    if callback is not None and not callable(callback):
        raise TypeError(f"fit: callback must be callable or None, got {callback!r}")
    if stop is not None and not callable(getattr(stop, "is_set", None)):
        raise TypeError(f"fit: stop must have an is_set() method (a threading.Event) or be None, got {stop!r}")
    prob = _Problem(model, {k: float(v) for k, v in fixed.items()}, box)
    gen = torch.Generator().manual_seed(seed if seed is not None else int(torch.randint(2**62, ()).item()))

    def report(total: int, stage: str, every: int = every) -> Progress:
        return _LazyProgress(total, stage, callback, every, stop, progress)

    with intra_op_threads(num_threads):
        return _run_stages(prob, x, stages, init, cfg, gen, report)


def _run_stages(prob: _Problem, x: torch.Tensor, stages: tuple, init: dict, cfg: dict, gen, report) -> FitResult:
    """The stages in order, each starting where the previous one ended (in the unit box)."""
    xw = x.detach().to(cfg["dtype"])
    # starting point in the unit box: init values, random for the rest
    u = torch.rand(len(prob.free), generator=gen, dtype=torch.float64)
    for j, k in enumerate(prob.free):
        if k in init:
            u[j] = (float(init[k]) - prob.lower[j]) / (prob.upper[j] - prob.lower[j])
    init_u = u.clone() if init else None
    history: dict[str, list[float]] = {}
    timings: dict[str, float] = {}
    standard_errors: dict[str, float] = {}
    covariance = None
    stopped = False
    start = time.perf_counter()
    for stage in stages:
        t0 = time.perf_counter()
        if stage == "evolution":
            best, stopped, history[stage] = _evolution(prob, xw, gen, cfg, init_u, report)
            u = best.to(torch.float64).cpu()
        elif stage == "sgd":
            uu, stopped, history[stage] = _sgd(prob, xw, gen, cfg, u.to(xw.dtype).to(x.device), report)
            u = uu.to(torch.float64).cpu()
        else:
            p, stopped, history[stage], covariance = _polish(prob, x, u, cfg, report)
            u = torch.as_tensor(prob.to_unit(p))
            if covariance is not None:
                standard_errors = {k: float(math.sqrt(max(covariance[j, j], 0.0))) for j, k in enumerate(prob.free)}
        timings[stage] = time.perf_counter() - t0
        if stopped:
            break
    params = prob.as_dict(prob.to_params(u.to(torch.float64)).tolist())
    t0 = time.perf_counter()
    residuals = fit_error(prob.model, x, params)
    timings["residuals"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - start
    return FitResult(
        params=params,
        loss=float(np.mean(residuals**2)),
        residuals=residuals,
        history=history,
        timings=timings,
        stages=tuple(s for s in stages if s in timings),
        stopped=stopped,
        standard_errors=standard_errors,
        covariance=covariance,
        free=tuple(prob.free),
    )


class _LazyProgress(Progress):
    """Progress whose ``params`` may be a function, called only when an event is emitted.

    Building the parameter dict needs a device sync; doing it only every ``every`` steps keeps
    the inner loops free of it.  Also records the loss of every step (``losses``).
    """

    def __init__(self, *args: Any, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.losses: list[float] = []

    def update(self, step: int, loss: float = float("nan"), params: Any = None, **extra) -> bool:
        self.losses.append(float(loss))
        emit = step % self.every == 0 or step == self.total - 1
        if callable(params):
            params = params() if (emit and self.callback is not None) else None
        return super().update(step, loss, params, **extra)
