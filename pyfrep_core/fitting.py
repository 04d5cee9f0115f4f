"""Fitting a model's named, bounded parameters to a point cloud (paper section 5.4).

The error of fit is the paper's ``E(p) = 1/N sum_i f(x_i; p)^2`` (paper eq. E(p)); for measured
data the residual may be the geometric distance ``f / |grad f|`` (the paper's delta_1) and the loss
robust to outliers (:mod:`pyfrep_core.residuals`), and the part's pose may be fitted with its shape
(:mod:`pyfrep_core.pose`).  :func:`fit` minimizes the loss in up to three stages:

1. ``"evolution"``: regularized evolution (Real et al. 2019) in the normalized parameter box,
   a global search that finds the basin of the minimum (``E`` is very oscillatory in the rod
   scales of the microstructure, so gradient descent alone stalls in a local minimum, Fig. 7);
2. ``"sgd"``: Adam on random batches of the points (the paper's SGD on ``E~``);
3. ``"polish"``: bounded least squares (scipy's trust-region reflective) on the residuals
   ``f(x_i; p)`` with the Jacobian ``df(x_i)/dp`` by per-sample reverse-mode autodiff (the
   kernel's one per-point parameter derivative, :func:`pyfrep_core.diff.param_grad`), since E
   is a sum of squares: it converges quadratically to the minimum instead of jittering around it.
   With a robust loss the polish is iteratively reweighted least squares: the same bounded least
   squares on ``sqrt(w_i) r_i``, the weights and the noise scale re-estimated between rounds.

Several starts (``starts=k``: pose candidates from :func:`pyfrep_core.pose.initial_pose` times
random shape draws) run through the evolution and Adam stages together, as one batch of parameter
sets (one model call per step for all of them); the best is polished.

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
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from ._array import as_tensor, check_finite, check_option, check_points
from ._threads import intra_op_threads
from .diff import _param_jacobian
from .evaluate import call_sets, evaluate
from .model import Model
from .pose import initial_pose, is_posed, posed
from .progress import Event, Progress, StopFlag
from .residuals import (
    LOSSES,
    RESIDUALS,
    geometric,
    inliers,
    objective,
    robust_scale,
    slopes,
    value_and_gradnorm,
    weights,
)

__all__ = ["FitResult", "IdentifiabilityWarning", "fit", "fit_error"]

STAGES = ("evolution", "sgd", "polish")
IRLS_ROUNDS = 12  # reweighting rounds of a robust polish at most (the weights settle in 3-6)
IRLS_TOL = 1e-5  # rounds stop when no parameter moves more than this fraction of its range (far below an SE)
RANK_RTOL = 1e-9  # singular values of the column-scaled Jacobian below this fraction of the largest are 0
POSE_SPREAD = 0.02  # std of a pose population around its start, in the unit box
POSE_STEP = 0.1  # a pose mutation's size relative to a shape mutation's
SHAPE_SPREAD = 0.1  # std of a pose population's shape around the declared defaults, in the unit box
PROBES = 2  # plateau probes (and re-polishes) after a robust polish at most
PROBE_VALUES = 24  # values of each dimension a probe tries across its range
PROBE_GAIN = 0.005  # a probe's move must lower the loss by this fraction (the re-polish must confirm it)
# the floor of an estimated noise scale, relative to the data's size (its bounding box diagonal):
# exact data (points on the surface) has residuals of rounding size, whose MAD would make most
# points outliers and the loss infinite; 1e-6 of the size is far above float64 rounding of the
# models' values and far below any measuring noise
SCALE_FLOOR = 1e-6
AUTO_STARTS = 8  # starts=None keeps at most this many pose candidates (those fitting the points best)
# defaults of the settings left None: the paper's protocol, and a local multi-start one for posed parts
PAPER_PROTOCOL = {"stages": STAGES, "cycles": 10_000, "population_size": 100, "children": 50, "final_subsample": 8192}
POSED_PROTOCOL = {
    "stages": ("evolution", "polish"),
    "cycles": 600,
    "population_size": 30,
    "children": 30,
    "final_subsample": 2000,
}


class IdentifiabilityWarning(RuntimeWarning):
    """The data cannot determine some parameters: the least-squares Jacobian is rank-deficient."""


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
        Where the Jacobian is rank-deficient it is the pseudo-inverse's (rows and columns of the
        ``unidentifiable`` parameters are meaningless).
    free : names of the fitted (not fixed) parameters.
    residual : "algebraic" (f) or "geometric" (f / |grad f|), the residual minimized.
    loss_function : "l2", "huber", "cauchy" or "trimmed" (``loss`` is its final value).
    loss_scale : the noise scale s of a robust loss (given, or 1.4826 median |r| at the end, at
        least ``SCALE_FLOOR`` x the data's size), in the residual's units; None for l2.
    rms, max_distance : root mean square and largest geometric distance |f| / |grad f| over the
        inliers, in the points' (the model's) units (NaN for a model torch.func cannot differentiate).
    inliers : (N,) bool numpy: |r| <= 3 s for a robust loss, every point for l2.
    outlier_fraction : fraction of the points that are not inliers.
    starts : one dict per start, always at least one: ``start`` (parameters it began from), ``params`` (where it ended),
        ``loss`` (its loss on a common subset of the points, or the polished loss), ``best`` (kept).
    termination : why the least-squares polish ended (scipy's message, with the reweighting
        rounds of a robust loss), or why there was no polish.
    std_error_reason : "" when every free parameter has a standard error; else why some or all
        are missing (no polish, stopped early, rank-deficient Jacobian naming the parameters).
    unidentifiable : names of the parameters a rank-deficient Jacobian cannot determine (a
        combination of them leaves every residual unchanged); an IdentifiabilityWarning names them.
    units : the points' length unit when given (``units="mm"``), else None.
    model : the model fitted: ``posed(model)`` when ``pose`` is on (its ``params`` include the pose).
    points : (N, d) float64 numpy, the points fitted (from a mesh: its vertices, then area samples).
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
    residual: str = "algebraic"
    loss_function: str = "l2"
    loss_scale: float | None = None
    rms: float = math.nan
    max_distance: float = math.nan
    inliers: np.ndarray | None = None
    outlier_fraction: float = 0.0
    starts: list[dict[str, Any]] = field(default_factory=list)
    termination: str = ""
    std_error_reason: str = ""
    unidentifiable: list[str] = field(default_factory=list)
    units: str | None = None
    model: Model | None = field(default=None, repr=False)
    points: np.ndarray | None = field(default=None, repr=False)

    @property
    def std_errors(self) -> dict[str, float]:
        """Standard errors by name (the same dict as ``standard_errors``); see ``std_error_reason``."""
        return self.standard_errors

    def __repr__(self) -> str:
        ps = ", ".join(f"{k}={v:.6g}" for k, v in self.params.items())
        return f"FitResult({ps}; E={self.loss:.3e}, {self.timings.get('total', 0.0):.2f} s, stages={self.stages})"


class _StopRequestedError(Exception):
    """Raised inside scipy's callbacks when the user asked to stop."""


class _Problem:
    """The free parameters of a model, their box, the residual and loss, and batched evaluations."""

    def __init__(
        self,
        model: Model,
        fixed: dict[str, float],
        box: dict[str, tuple],
        residual: str = "algebraic",
        loss: str = "l2",
        loss_scale: float | None = None,
    ):
        self.model, self.fixed = model, fixed
        self.free = [k for k in model.names if k not in fixed]
        self.lower = np.array([box[k][0] for k in self.free])
        self.upper = np.array([box[k][1] for k in self.free])
        self.residual, self.loss, self.loss_scale = residual, loss, loss_scale
        self._geometric = geometric(model.fn) if residual == "geometric" else None
        self.scale_floor = 0.0  # of an estimated noise scale, in the residual's units (set_scale_floor)

    def set_scale_floor(self, x: torch.Tensor) -> None:
        """``SCALE_FLOOR`` times the points' box diagonal, a length; for algebraic residuals times
        the median |grad f| at the declared defaults (f's value per unit length near the surface)."""
        pts = x.detach().to(torch.float64)
        size = float(torch.linalg.vector_norm(pts.max(0).values - pts.min(0).values))
        if self.model.bounds is not None:
            lo, hi = (torch.as_tensor(b, dtype=torch.float64) for b in self.model.bounds)
            size = max(size, float(torch.linalg.vector_norm(hi - lo)))
        per_length = 1.0
        if self.residual == "algebraic":
            values = {**self.model.defaults(), **self.fixed}
            values = {k: torch.tensor(float(v), dtype=torch.float64, device=x.device) for k, v in values.items()}
            try:
                with torch.no_grad():
                    _, g = value_and_gradnorm(self.model.fn, pts[:2000], values)
                per_length = float(g.median())
            except RuntimeError:  # a model torch.func cannot differentiate: f taken as a distance
                pass
            if not (math.isfinite(per_length) and per_length > 0):
                per_length = 1.0
        floor = SCALE_FLOOR * size * per_length
        self.scale_floor = floor if math.isfinite(floor) and floor > 0 else 0.0

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
        """The residuals r(x; p) (f, or f / |grad f| when geometric): p (P,) -> (N,), p (B, P) -> (B, N)."""
        if self._geometric is None:
            return self.model(x, **self.named(p))
        scalars, batched = {}, {}
        for k, v in self.named(p).items():
            if isinstance(v, torch.Tensor) and v.ndim == 1:
                batched[k] = v.to(x.dtype)
            elif isinstance(v, torch.Tensor):
                scalars[k] = v.to(x.dtype)
            else:
                scalars[k] = torch.tensor(float(v), dtype=x.dtype, device=x.device)
        if batched:
            return call_sets(self._geometric, x, scalars, batched, self.model.__name__)
        return evaluate(self._geometric, x, scalars, label=self.model.__name__)

    def objective(self, r: torch.Tensor) -> torch.Tensor:
        """The loss of residuals (..., N) over the last axis (mean r^2 for l2)."""
        return objective(r, self.loss, self.loss_scale, self.scale_floor)

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


def fit_error(
    model: Model, points: Any, params: Mapping[str, float] | None = None, residual: str = "algebraic"
) -> np.ndarray:
    """Per-point residuals |f(x_i; p)| (float64 numpy, evaluated in chunks), the paper's Fig. 7 colours.

    ``residual="geometric"``: the distances |f| / |grad f| (paper eq. delta1), in the points' units.

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
    residual = check_option(residual, "residual", "fit_error", "choice", choices=RESIDUALS)
    if residual == "geometric":
        scalars = {k: torch.tensor(float(v), dtype=torch.float64) for k, v in values.items()}
        with torch.no_grad():
            return evaluate(geometric(model.fn), x, scalars, label=model.__name__).abs().cpu().numpy()
    with torch.no_grad():
        out = model(x, **values).abs()  # in chunks within the memory budget of one call (pyfrep_core.evaluate)
    return out.cpu().numpy()


def _evolution(prob: _Problem, x: torch.Tensor, gen: torch.Generator, cfg: dict, init_u, report) -> tuple:
    """Regularized evolution, batched: ``children`` tournaments per generation, one model call each.

    Real et al.'s algorithm adds one child per cycle and removes the oldest individual.  Here
    ``children`` tournaments are held on the current population, their mutated winners are
    evaluated together in one batched call (B parameter sets -> f of shape (B, M)), and each
    child replaces the oldest individual (the population is a ring buffer ordered by age).
    With ``children = 1`` this is exactly the sequential algorithm.  Scores are the loss on one
    random subset of ``subsample`` points, fixed for the whole run so that scores compare; the
    best ``finalists`` of the history are then re-scored on a fresh subset for the final choice.

    ``init_u`` None or (P,): one population (seeded with it).  (S, P): S independent populations,
    one per start, evolved side by side (every generation's children of all of them in one call);
    in the pose coordinates (``cfg["pose_dims"]``) their members start around the start.
    Returns the best (S, P) (or (P,)) and its final scores (S,) (or 0-d).
    """
    pop_size, sample_size = cfg["population_size"], cfg["sample_size"]
    k = min(cfg["children"], pop_size)  # a generation replaces at most the whole population
    n_points, n_free, dev, dt = x.shape[0], len(prob.free), x.device, x.dtype
    m = min(cfg["subsample"], n_points)
    xs = x[torch.randperm(n_points, generator=gen, device="cpu")[:m].to(dev)]
    single = init_u is None or torch.as_tensor(init_u).ndim == 1
    starts = None if init_u is None else torch.as_tensor(init_u, dtype=dt).reshape(-1, n_free)
    n_pop = 1 if starts is None else starts.shape[0]

    def score(u: torch.Tensor) -> torch.Tensor:  # (S, K, P) -> (S, K)
        with torch.no_grad():
            e = prob.objective(prob.f(xs, prob.to_params(u.reshape(-1, n_free)))).reshape(u.shape[:-1])
        return torch.nan_to_num(e, nan=math.inf)

    pop = torch.rand(n_pop, pop_size, n_free, generator=gen, dtype=dt).to(dev)
    pose_mask = None
    if cfg.get("pose_dims"):
        pose_mask = torch.zeros(n_free, dtype=dt, device=dev)
        pose_mask[cfg["pose_dims"]] = 1.0
    if starts is not None:
        if pose_mask is not None:
            # a local search around each start: its pose candidate and the nominal (default) shape.  A
            # shape drawn anywhere in its range is no help here: a part drawn too large explains the
            # points inside it by its nearest wall, a minimum no local step leaves
            spread = POSE_SPREAD * pose_mask + SHAPE_SPREAD * (1.0 - pose_mask)
            near = starts[:, None, :].to(dev) + spread * torch.randn(
                n_pop, pop_size, n_free, generator=gen, dtype=dt
            ).to(dev)
            pop = near.clamp(0.0, 1.0)
        pop[:, 0] = starts.to(dev)
    scores = score(pop)
    hist_u, hist_s = [pop], [scores]
    oldest = 0  # ring buffer: pop[:, oldest] is the oldest individual
    n_children = max(0, cfg["cycles"] - pop_size)  # Real et al.: the history holds `cycles` models
    n_gen = math.ceil(n_children / k)
    lo_s, hi_s = math.log(cfg["mutation"][0]), math.log(cfg["mutation"][1])
    best = float(scores.min())

    def best_params() -> dict[str, float]:
        flat = scores.reshape(-1).argmin()
        return prob.as_dict(prob.to_params(pop.reshape(-1, n_free)[flat]).tolist())

    with report(n_gen, "evolution") as progress:
        for g in range(n_gen):
            b = min(k, n_children - g * k)
            # tournaments: `sample_size` random members (with replacement), the fittest is the parent
            entrants = torch.randint(pop_size, (n_pop, b, sample_size), generator=gen).to(dev)
            entrant_scores = scores.gather(1, entrants.reshape(n_pop, -1)).reshape(n_pop, b, sample_size)
            parents = entrants.gather(2, entrant_scores.argmin(2, keepdim=True)).squeeze(2)
            # mutation: Gaussian step in the unit box, its scale log-uniform per child (coarse and fine moves)
            sigma = torch.exp(lo_s + (hi_s - lo_s) * torch.rand(n_pop, b, 1, generator=gen, dtype=dt)).to(dev)
            step = sigma * torch.randn(n_pop, b, n_free, generator=gen, dtype=dt).to(dev)
            if pose_mask is not None:
                # a child moves its pose or one dimension of its shape: a part fitted but for one
                # dimension (a tube too long: its end's points explained by its walls) needs a large
                # step of that one alone; the pose, near its start already, moves by POSE_STEP of a step
                moves_pose = torch.rand(n_pop, b, 1, generator=gen, dtype=dt).to(dev) < 0.5
                shape_dims = torch.nonzero(pose_mask == 0).flatten()
                one = torch.zeros(n_pop, b, n_free, dtype=dt, device=dev)
                if len(shape_dims):
                    pick = shape_dims[torch.randint(len(shape_dims), (n_pop, b), generator=gen).to(dev)]
                    one.scatter_(2, pick[..., None], 1.0)
                step = step * torch.where(moves_pose, POSE_STEP * pose_mask, one)
            children = (pop.gather(1, parents[..., None].expand(n_pop, b, n_free)) + step).clamp(0.0, 1.0)
            child_scores = score(children)
            slots = (oldest + torch.arange(b, device=dev)) % pop_size  # each child replaces the oldest
            pop[:, slots], scores[:, slots] = children, child_scores
            oldest = (oldest + b) % pop_size
            hist_u.append(children)
            hist_s.append(child_scores)
            best = min(best, float(child_scores.min()))
            if progress.update(g, best, best_params):
                break
    hist_u, hist_s = torch.cat(hist_u, 1), torch.cat(hist_s, 1)
    top = hist_s.topk(min(cfg["finalists"], hist_s.shape[1]), dim=1, largest=False).indices
    finalists = hist_u.gather(1, top[..., None].expand(-1, -1, n_free))
    m2 = min(cfg["final_subsample"], n_points)
    xs = x[torch.randperm(n_points, generator=gen, device="cpu")[:m2].to(dev)]
    final = score(finalists)
    pick = final.argmin(1)
    chosen = finalists[torch.arange(n_pop, device=dev), pick]
    chosen_scores = final[torch.arange(n_pop, device=dev), pick]
    if single:
        return chosen[0], chosen_scores[0], progress.stopped, progress.losses
    return chosen, chosen_scores, progress.stopped, progress.losses


def _sgd(prob: _Problem, x: torch.Tensor, gen: torch.Generator, cfg: dict, u0: torch.Tensor, report) -> tuple:
    """Adam on random batches of E~(p) = mean over a batch of f(x_i; p)^2 (or the robust loss of the
    residuals), in the unit box (projected).  ``u0`` (P,), or (S, P) for S starts at once: their
    losses are summed, so each start gets its own gradient (Adam is elementwise) from one batched call."""
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
                per_start = prob.objective(prob.f(xb, prob.to_params(u)))
                loss = per_start.sum()
                loss.backward()
                opt.step()
                sched.step()
                with torch.no_grad():
                    u.clamp_(0.0, 1.0)
                losses.append(loss.detach())
                epoch_loss += loss.detach()

            def current(u: torch.Tensor = u, last: torch.Tensor = per_start) -> dict[str, float]:
                best = u if u.ndim == 1 else u[last.detach().argmin()]
                return prob.as_dict(prob.to_params(best).tolist())

            if progress.update(epoch, float(epoch_loss) / per_epoch, current):
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


def _polish(prob: _Problem, x: torch.Tensor, u0: torch.Tensor, cfg: dict, report, offset: int = 0) -> dict[str, Any]:
    """Bounded least squares on the residuals: scipy's 'trf' with an autodiff Jacobian.

    ``offset``: the evaluations of earlier polishes of the same fit (a probe's re-polish): its
    reported steps continue from there, so that the stage's step count never goes back.

    Geometric residuals ``r = f / |grad f|`` take the Jacobian ``(df/dp) / |grad f|``: the term
    ``-f d|grad f|/dp / |grad f|^2`` it leaves out is proportional to f, so it vanishes on the
    surface, where the fit ends (Gauss-Newton leaves out the residual's second derivatives
    likewise); it would cost second derivatives of f at every point.

    A robust round runs MINPACK's Levenberg-Marquardt ("lm", QR of J) and falls back to the
    bounded 'trf' when its answer leaves the parameter box: on a tall Jacobian (thousands of points,
    a dozen parameters) trf's SVD of each step costs more than the model's calls.

    A robust loss is minimized by iteratively reweighted least squares: each round solves the
    weighted problem ``sqrt(w_i) r_i`` with the weights w(r / s) of the previous round's residuals
    (:func:`pyfrep_core.residuals.weights`) and the scale s re-estimated from them (unless given),
    until no parameter moves more than ``IRLS_TOL`` of its range.  l2 is one round with w = 1.
    """
    from scipy.optimize import least_squares

    x64 = x.to(torch.float64)
    losses: list[float] = []
    p0 = np.clip(prob.to_params(u0.to(torch.float64)).cpu().numpy(), prob.lower, prob.upper)
    last: dict[str, Any] = {}
    robust = prob.loss != "l2"
    sw: list[np.ndarray | None] = [None]  # sqrt of the current round's weights (None: all 1)
    cache: dict[bytes, tuple[np.ndarray, np.ndarray | None]] = {}
    budget = cfg["polish_iters"]

    def raw(p: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Residuals r (N,) and, for geometric residuals, |grad f| (N,) at p (the last few cached)."""
        key = p.tobytes()
        if key not in cache:
            pt = torch.as_tensor(p, device=x.device)
            if prob.residual == "geometric":
                values = {
                    k: torch.as_tensor(v, dtype=torch.float64, device=x.device) for k, v in prob.named(pt).items()
                }
                with torch.no_grad():
                    f, g = value_and_gradnorm(prob.model.fn, x64, values)
                g = g.clamp_min(torch.finfo(g.dtype).tiny)
                cache[key] = ((f / g).cpu().numpy(), g.cpu().numpy())
            else:
                cache[key] = (_residuals(prob, x64, pt).cpu().numpy(), None)
            while len(cache) > 4:
                cache.pop(next(iter(cache)))
        return cache[key]

    def raw_jac(p: np.ndarray) -> np.ndarray:
        j = _jacobian(prob, x64, torch.as_tensor(p, device=x.device)).cpu().numpy()
        g = raw(p)[1]
        return j if g is None else j / g[:, None]

    def loss_of(r: np.ndarray) -> float:
        return float(prob.objective(torch.from_numpy(r)))

    with report(offset + budget, "polish", every=1) as progress:

        def fun(p: np.ndarray) -> np.ndarray:
            r = raw(p)[0]
            losses.append(loss_of(r))
            if losses[-1] <= min(losses):  # the best point so far: what an early stop returns
                last["p"], last["r"] = p.copy(), r
            best = last["p"]
            # every evaluation is reported (there are few), with the best loss and parameters so far
            if progress.update(offset + len(losses) - 1, min(losses), lambda: prob.as_dict(best)):
                raise _StopRequestedError
            return r if sw[0] is None else sw[0] * r

        def jac(p: np.ndarray) -> np.ndarray:
            j = raw_jac(p)
            return j if sw[0] is None else sw[0][:, None] * j

        def reweight(r: np.ndarray) -> float:
            rt = torch.from_numpy(r)
            s = float(robust_scale(rt, prob.scale_floor)) if prob.loss_scale is None else prob.loss_scale
            sw[0] = np.sqrt(weights(rt, prob.loss, s).numpy())
            return s

        stopped, rounds, message, settled = False, 0, "", not robust
        p, scale = p0, None
        jmat = rvec = None
        try:
            if robust:
                scale = reweight(fun(p0))  # the weights of the first round (sw is still None: raw residuals)
            while True:
                rounds += 1
                common = dict(
                    jac=jac,
                    x_scale=prob.upper - prob.lower,
                    xtol=cfg["xtol"],
                    ftol=cfg["xtol"],
                    gtol=cfg["xtol"],
                )
                sol = None
                if robust:
                    sol = least_squares(fun, p, method="lm", max_nfev=max(1, budget - len(losses)), **common)
                    if not np.all((sol.x >= prob.lower) & (sol.x <= prob.upper)):
                        sol = None
                if sol is None:
                    sol = least_squares(
                        fun,
                        np.clip(p, prob.lower, prob.upper),
                        bounds=(prob.lower, prob.upper),
                        method="trf",
                        max_nfev=max(1, budget - len(losses)),
                        **common,
                    )
                message = sol.message
                moved = float(np.max(np.abs(sol.x - p) / (prob.upper - prob.lower)))
                p = sol.x
                if not robust:
                    jmat, rvec = sol.jac, sol.fun
                    break
                scale = reweight(raw(p)[0])
                if moved <= IRLS_TOL and rounds > 1:
                    settled = True
                    break
                if rounds >= IRLS_ROUNDS or len(losses) >= budget:
                    break
        except _StopRequestedError:
            stopped = True
            p = last["p"]
            message = "stopped by the callback or the stop flag"
        bread = None
        if jmat is None:  # a robust loss: the M-estimator's sandwich at the final weights
            jmat, rvec = raw_jac(p), raw(p)[0]
            rt = torch.from_numpy(rvec)
            s = float(robust_scale(rt, prob.scale_floor)) if prob.loss_scale is None else prob.loss_scale
            w = weights(rt, prob.loss, s).numpy()
            bread = slopes(rt, prob.loss, s).numpy()
            jmat, rvec = np.sqrt(w)[:, None] * jmat, np.sqrt(w) * rvec  # meat: (w r)^2 = (rho'/2)^2
            bread = bread / np.where(w > 0, w, 1.0)  # on the weighted rows
    if robust and not stopped:
        state = "the weights settled" if settled else "the weights were still changing"
        message = f"{message} (reweighted least squares: {rounds} round{'s' * (rounds != 1)}, {state})"
    cov, null, zero_cols = _covariance(np.asarray(jmat), np.asarray(rvec), bread)
    return {
        "p": p,
        "stopped": stopped,
        "losses": losses,
        "covariance": cov,
        "null": null,
        "zero": zero_cols,
        "termination": message,
        "scale": scale,
    }


def _loss_at(prob: _Problem, x: torch.Tensor, p: np.ndarray, scale: float | None) -> float:
    """The loss of all the points at ``p`` for a given noise scale (so that two fits compare)."""
    with torch.no_grad():
        r = prob.f(x.to(torch.float64), torch.as_tensor(p, dtype=torch.float64, device=x.device))
    return float(objective(r, prob.loss, scale))


def _probe(prob: _Problem, x: torch.Tensor, p: np.ndarray, scale: float | None, cfg: dict) -> np.ndarray | None:
    """Each shape dimension alone across its range (``PROBE_VALUES`` values, all in one batched
    call), the rest held at ``p``, scored with the robust loss at the fitted noise scale: the first
    move that lowers the loss by more than ``PROBE_GAIN``, or None.

    A robust fit has plateaus a local method cannot leave: a dimension whose surface has lost its
    points to the outliers (a chamfer drawn past the corner it cuts, a tube drawn too long, whose
    end's points its walls then explain) changes no inlier's residual, so its gradient is 0.
    """
    shape = [j for j, k in enumerate(prob.free) if k not in getattr(prob.model, "pose_names", ())]
    if not shape or scale is None:
        return None
    grid = np.linspace(0.0, 1.0, PROBE_VALUES)
    sets = np.repeat(p[None, :], len(shape) * PROBE_VALUES + 1, axis=0)
    for i, j in enumerate(shape):
        sets[1 + i * PROBE_VALUES : 1 + (i + 1) * PROBE_VALUES, j] = prob.lower[j] + grid * (
            prob.upper[j] - prob.lower[j]
        )
    m = min(cfg["final_subsample"], x.shape[0])
    xs = x[torch.randperm(x.shape[0], generator=torch.Generator().manual_seed(0))[:m].to(x.device)]
    with torch.no_grad():
        r = prob.f(xs, torch.as_tensor(sets, dtype=x.dtype, device=x.device))
        scores = torch.nan_to_num(objective(r, prob.loss, scale).to(torch.float64).cpu(), nan=math.inf).numpy()
    best = int(np.argmin(scores))
    return sets[best] if scores[best] < (1.0 - PROBE_GAIN) * scores[0] else None


def _covariance(
    j: np.ndarray, r: np.ndarray, bread: np.ndarray | None = None
) -> tuple[np.ndarray | None, list[int], list[int]]:
    """Covariance of a least-squares estimate, robust to per-point noise levels (White's HC0),
    ``(J^T J)^-1 J^T diag(r^2) J (J^T J)^-1``, and the parameters the data cannot determine.

    With weighted rows ``sqrt(w) J`` and ``sqrt(w) r`` and ``bread`` the ratio of each point's
    loss curvature to its weight (``rho''/(2 w)``), it is the M-estimator's sandwich
    ``B^-1 (sum psi^2 J J^T) B^-1`` with ``B = J^T diag(rho''/2) J``.  The
    columns are scaled to unit length first (so that the parameters' units do not matter), then
    J = U S V^T: singular values below ``RANK_RTOL`` times the largest span directions along which
    the residuals do not change; a parameter with a component above 0.05 in them is unidentifiable
    (returned by index, those with an all-zero column separately).  The inverse is the
    pseudo-inverse over the other directions, so the identifiable parameters keep their errors.
    """
    n_par = j.shape[1]
    if n_par == 0 or not np.isfinite(j).all() or not np.isfinite(r).all():
        return None, list(range(n_par)), []
    norms = np.linalg.norm(j, axis=0)
    zero = [i for i in range(n_par) if not norms[i] > 0]
    d = np.where(norms > 0, 1.0 / np.where(norms > 0, norms, 1.0), 0.0)
    js = j * d
    _, sv, vt = np.linalg.svd(js, full_matrices=False)
    keep = sv > RANK_RTOL * (sv.max() if sv.size else 0.0)
    null_space = vt[~keep]
    weight = np.sqrt((null_space**2).sum(0)) if len(null_space) else np.zeros(n_par)
    null = sorted(set(zero) | {i for i in range(n_par) if weight[i] > 0.05})
    if not keep.any():
        return None, null, zero
    v = vt[keep].T
    if bread is None:
        inv = (v / sv[keep] ** 2) @ v.T  # (Js^T Js)^+
    else:  # (Js^T diag(bread) Js)^+ over the identifiable directions
        a = v.T @ ((js * bread[:, None]).T @ js) @ v
        try:
            inv = v @ np.linalg.inv(a) @ v.T
        except np.linalg.LinAlgError:
            return None, null, zero
    meat = (js * (r * r)[:, None]).T @ js
    cov_s = inv @ meat @ inv
    return cov_s * d[:, None] * d[None, :], null, zero


def fit(
    model: Model,
    points: Any,
    *,
    pose: bool | str = False,
    residual: str = "auto",
    loss: str = "l2",
    loss_scale: float | None = None,
    starts: int | None = None,
    units: str | None = None,
    mesh_samples: int = 5000,
    stages: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    init: Mapping[str, float] | None = None,
    param_bounds: Mapping[str, tuple[float, float]] | None = None,
    cycles: int | None = None,
    population_size: int | None = None,
    sample_size: int = 10,
    children: int | None = None,
    mutation: tuple[float, float] = (1e-3, 1.0),
    subsample: int = 256,
    final_subsample: int | None = None,
    finalists: int = 16,
    epochs: int = 100,
    batch_size: int = 16384,
    lr: float = 1e-3,
    polish_iters: int | None = None,
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
    points : the data: an (N, dim) array or tensor of surface samples (length units); a
        :class:`~pyfrep_core.Mesh` (its vertices and ``mesh_samples`` points drawn by area); a
        :class:`~pyfrep_core.io.PointCloud`; or the path of a mesh file (.stl .obj .ply .off .vtk,
        read by :func:`~pyfrep_core.load_mesh`) or of a point file (.xyz, or a .ply without faces,
        :func:`~pyfrep_core.load_points`).
    pose : fit the part's pose with its shape: True (rigid: ``tx, ty, tz, rx, ry, rz``) or
        "scale" (and a uniform scale ``s``), through :func:`pyfrep_core.pose.posed` with the
        translation range set from the data; starts from :func:`pyfrep_core.pose.initial_pose`.
        A model already posed gets the starts without being posed again.
    residual : "algebraic" (f, the paper's E(p)), "geometric" (f / |grad f|, Taubin's distance,
        the paper's delta_1: a length, independent of how f is scaled) or "auto": geometric when
        the points come with a unit (``units``) or from a file, a Mesh or a PointCloud (measured
        data), algebraic for a bare array (the paper's synthetic protocol, unchanged).
    loss : "l2", "huber", "cauchy" or "trimmed" (:mod:`pyfrep_core.residuals`); a robust loss
        bounds the pull of outliers, and ``inliers`` marks the points within 3 scales.
    loss_scale : the noise scale s of a robust loss, in the residual's units; None: estimated
        from the residuals (1.4826 x their median absolute value, never below ``SCALE_FLOOR`` = 1e-6
        of the data's size, so exact data stays finite with no outliers) and re-estimated as the
        fit moves.  Give it for exact data (a CAD mesh: its vertices lie on the surface, so the median residual
        is about 0 and every facet point would look like an outlier): the facets' deviation.
    starts : number of starts: pose candidates (when ``pose``) first, then the same with random
        shape parameters; evolution and Adam run for all of them together (one batch of parameter
        sets), the best one is polished; every start is summarized in ``result.starts``.  None:
        with ``pose``, the pose candidates (the 8 the points fit best at the declared defaults when
        there are more), else 1.
    units : the points' length unit ("mm"), carried to the result (and choosing the geometric
        residual under "auto").
    mesh_samples : points drawn by area on a mesh given as data (its vertices are kept as well).
    stages : stages to run, in order, among "evolution", "sgd", "polish" (e.g. ("sgd",) for the
        paper's SGD alone).  None: all three; ("evolution", "polish") with a pose.
    fixed : name -> value of parameters held fixed (not fitted).
    init : name -> starting value: joins the initial population, or starts SGD/polish when no
        evolution runs (other free parameters then start at random, from ``seed``).
    param_bounds : name -> (lower, upper) narrowing the declared range for the search.
    cycles : regularized evolution's history length (initial population included, Real et al.),
        per start.  None: 10,000 (the paper's), or 600 with a pose (each start's population then
        begins around its pose candidate: a local search, many starts side by side).
    population_size, sample_size : population and tournament sizes (population None: 100, 30
        with a pose).
    children : tournaments (children) per batched generation; 1 gives the sequential algorithm
        (None: 50, 30 with a pose).
    mutation : (smallest, largest) standard deviation of the Gaussian mutation in the unit box;
        each child draws its own, log-uniformly.
    subsample : points used to score individuals (one random subset for the run).
    final_subsample, finalists : the best ``finalists`` of the history are re-scored on a fresh
        subset of this size (None: 8192, 2000 with a pose); the best becomes the start of the next
        stage.  Starts are compared on such a subset too.
    epochs, batch_size, lr : Adam on random batches; an epoch is one pass over the points; the
        learning rate (in the unit box) decays linearly to 0.
    polish_iters, xtol : function evaluations (None: 50, 200 with a robust loss, shared by the
        reweighting rounds) and tolerance of the least-squares polish.
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
    ValueError : points empty, of the wrong shape or not finite; inverted bounds; values out of range;
        an unknown residual, loss or file format.

    Warns
    -----
    IdentifiabilityWarning : the Jacobian at the fit is rank-deficient; the message names the
        parameters the data cannot determine (they are also in ``result.unidentifiable``).

    Examples
    --------
    A ball measured off-centre, with one stray point: the pose is found from the cloud, the stray
    point is an outlier.

    >>> from pyfrep_core import model, Param, block
    >>> @model(bounds=((-1,) * 3, (1,) * 3), a=Param(1.0, 0.5, 1.5))
    ... def cube(x, a):
    ...     return block(x, vertex=(-a / 2, -a / 2, -a / 2), dx=a, dy=a, dz=a)
    >>> rng = np.random.default_rng(0)
    >>> pts = rng.uniform(-0.6, 0.6, (400, 3))
    >>> pts[np.arange(400), rng.integers(0, 3, 400)] = rng.choice([-0.6, 0.6], 400)  # on the faces
    >>> pts = np.vstack([pts + (3.0, 1.0, 0.0), [[3.0, 1.0, 0.0]]])      # moved, and one stray point
    >>> res = fit(cube, pts, pose=True, residual="geometric", loss="cauchy", stages=("polish",), progress=False)
    >>> round(res.params["a"], 6), [round(res.params[k], 6) for k in ("tx", "ty")], int((~res.inliers).sum())
    (1.2, [3.0, 1.0], 1)
    """
    fixed, init, param_bounds = dict(fixed or {}), dict(init or {}), dict(param_bounds or {})
    if not isinstance(model, Model):
        raise TypeError(f"model must be a Model declared with @model (named, bounded parameters), got {model!r}")
    points, source = _load_data(points, model.dim, mesh_samples)
    residual = check_option(residual, "residual", "fit", "choice", choices=(*RESIDUALS, "auto"))
    loss = check_option(loss, "loss", "fit", "choice", choices=LOSSES)
    loss_scale = check_option(loss_scale, "loss_scale", "fit", positive=True, none=True)
    starts = check_option(starts, "starts", "fit", "int", positive=True, none=True)
    pose = check_option(pose, "pose", "fit", "choice", choices=(False, True, "rigid", "scale"))
    if units is not None and not isinstance(units, str):
        raise TypeError(f"fit: units must be a string such as 'mm' or None, got {units!r}")
    if residual == "auto":
        residual = "geometric" if (units is not None or source != "array") else "algebraic"
    if polish_iters is None:
        polish_iters = 50 if loss == "l2" else 200
    posing = bool(pose) or is_posed(model)
    protocol = POSED_PROTOCOL if posing else PAPER_PROTOCOL
    stages = protocol["stages"] if stages is None else stages
    cycles = protocol["cycles"] if cycles is None else cycles
    population_size = protocol["population_size"] if population_size is None else population_size
    children = protocol["children"] if children is None else children
    final_subsample = protocol["final_subsample"] if final_subsample is None else final_subsample
    if pose and not is_posed(model):
        model = _posed_for(model, points, scale=pose == "scale")
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
    prob = _Problem(model, {k: float(v) for k, v in fixed.items()}, box, residual, loss, loss_scale)
    if loss != "l2" and loss_scale is None:
        prob.set_scale_floor(x)
    gen = torch.Generator().manual_seed(seed if seed is not None else int(torch.randint(2**62, ()).item()))
    candidates = _pose_candidates(model, x, init, fixed) if posing else []
    cfg["pose_dims"] = [j for j, k in enumerate(prob.free) if k in model.pose_names] if posing else []

    def report(total: int, stage: str, every: int = every) -> Progress:
        return _LazyProgress(total, stage, callback, every, stop, progress)

    with intra_op_threads(num_threads):
        result = _run_stages(prob, x, stages, init, cfg, gen, report, candidates, starts)
    result.units = units
    return result


def _load_data(data: Any, dim: int, mesh_samples: int) -> tuple[Any, str]:
    """The points to fit, and where they came from: "array", "mesh", "cloud" or "file"."""
    import os

    from .io import MESH_FORMATS, POINT_FORMATS, PointCloud, load_mesh, load_points
    from .meshing import Mesh
    from .sampling import sample_mesh

    source = "array"
    if isinstance(data, str | os.PathLike):
        ext = os.path.splitext(str(data))[1].lower()
        if ext in MESH_FORMATS:
            try:
                data = load_mesh(data)
            except ValueError as err:
                if ext not in POINT_FORMATS or "no triangles" not in str(err):
                    raise
                data = load_points(data)  # a PLY of vertices only: a point cloud
        elif ext in POINT_FORMATS:
            data = load_points(data)
        else:
            known = ", ".join(sorted(set(MESH_FORMATS) | set(POINT_FORMATS)))
            raise ValueError(f"fit: cannot tell the format of {str(data)!r} from its extension; supported: {known}")
        source = "file"
    if isinstance(data, Mesh):
        n = check_option(mesh_samples, "mesh_samples", "fit", "int", minimum=0)
        parts = [data.vertices]
        if n > 0 and not data.is_empty():
            parts.append(sample_mesh(data, n, np.random.default_rng(0)))
        data, source = np.concatenate(parts), "mesh" if source == "array" else source
    elif isinstance(data, PointCloud):
        data, source = data.points, "cloud" if source == "array" else source
    if source != "array" and dim == 2:
        raise ValueError("fit: a mesh or point file holds 3-D points; the model is planar (dim=2)")
    return data, source


def _posed_for(model: Model, points: Any, scale: bool) -> Model:
    """``posed(model)`` with the translation range the data's box widened by its size on every side."""
    x, _ = as_tensor(points, "points")
    check_points(x, model.dim, "points")
    check_finite(x, "points")
    if x.shape[0] == 0:
        raise ValueError("points is empty: nothing to fit")
    pts = x.detach().cpu().to(torch.float64).numpy()
    lo, hi = pts.min(0), pts.max(0)
    size = np.maximum(hi - lo, 1e-12 * (1.0 + np.abs(hi)))
    return posed(model, scale=scale, translation=(tuple(lo - size), tuple(hi + size)))


def _pose_candidates(model: Model, x: torch.Tensor, init: dict, fixed: dict) -> list[dict[str, float]]:
    """Starting poses: from ``init``/``fixed`` when they give the whole pose, else :func:`initial_pose`."""
    names = model.pose_names
    given = {**init, **fixed}
    if all(k in given for k in names):
        return [{k: float(given[k]) for k in names}]
    base = model.pose_base
    shape = {k: v for k, v in given.items() if k in base.params}
    try:
        candidates = initial_pose(x, base if base.dim == 3 else None, params=shape, scale=model.pose_scale)
    except (ValueError, RuntimeError):  # the model's surface could not be sampled at these values
        candidates = initial_pose(x, None, scale=model.pose_scale)
    out = []
    for c in candidates:
        c = {k: float(np.clip(v, model.params[k].lower, model.params[k].upper)) for k, v in c.items()}
        c.update({k: float(v) for k, v in given.items() if k in names})
        out.append(c)
    return out


def _start_vectors(prob: _Problem, init: dict, gen: torch.Generator, candidates: list, starts: int | None):
    """The starts in the unit box, (S, P) float64, or None for the single start of the paper's protocol.

    Start i takes pose candidate ``i mod C``; its shape parameters are ``init`` or the declared
    defaults on the first pass over the candidates, random draws (from the fit's seed) after.
    """
    n_cand = len(candidates)
    k = starts if starts is not None else max(1, n_cand)
    if k == 1 and n_cand == 0:
        return None
    defaults = prob.model.defaults()
    rows = []
    for i in range(k):
        u = torch.rand(len(prob.free), generator=gen, dtype=torch.float64)
        first_pass = i < max(1, n_cand)
        for j, name in enumerate(prob.free):
            value = None
            if n_cand and name in candidates[i % n_cand]:
                value = candidates[i % n_cand][name]
            elif name in init:
                value = init[name]
            elif first_pass and n_cand:
                value = defaults[name]
            if value is not None:
                u[j] = (float(value) - prob.lower[j]) / (prob.upper[j] - prob.lower[j])
        rows.append(u.clamp(0.0, 1.0))
    return torch.stack(rows)


def _run_stages(
    prob: _Problem,
    x: torch.Tensor,
    stages: tuple,
    init: dict,
    cfg: dict,
    gen,
    report,
    candidates: list | None = None,
    starts: int | None = None,
) -> FitResult:
    """The stages in order, each starting where the previous one ended (in the unit box).

    With several starts, evolution and Adam run for all of them at once; before the polish (or at
    the end) each is scored on one common subset of the points, and the best goes on.
    """
    xw = x.detach().to(cfg["dtype"])
    # starting point in the unit box: init values, random for the rest
    u = torch.rand(len(prob.free), generator=gen, dtype=torch.float64)
    for j, k in enumerate(prob.free):
        if k in init:
            u[j] = (float(init[k]) - prob.lower[j]) / (prob.upper[j] - prob.lower[j])
    init_u = u.clone() if init else None
    many = _start_vectors(prob, init, gen, candidates or [], starts)
    if many is not None and starts is None and many.shape[0] > AUTO_STARTS:
        # more pose candidates than automatic starts: keep those the points fit best as they are
        m = min(cfg["final_subsample"], x.shape[0])
        xs = xw[torch.randperm(x.shape[0], generator=gen)[:m].to(x.device)]
        with torch.no_grad():
            scores = prob.objective(prob.f(xs, prob.to_params(many.to(xw.dtype).to(x.device))))
        order = torch.nan_to_num(scores.to(torch.float64).cpu(), nan=math.inf).argsort()[:AUTO_STARTS]
        many = many[order.sort().values]
    if many is not None:
        u, init_u = many, many
    first = u.clone()
    history: dict[str, list[float]] = {}
    timings: dict[str, float] = {}
    polished: dict[str, Any] | None = None
    summaries: list[dict[str, Any]] = []
    stopped = False
    start = time.perf_counter()

    def choose() -> torch.Tensor:
        """Score every start on one subset (one batched call) and keep the best."""
        m = min(cfg["final_subsample"], x.shape[0])
        xs = xw[torch.randperm(x.shape[0], generator=gen)[:m].to(x.device)]
        with torch.no_grad():
            scores = prob.objective(prob.f(xs, prob.to_params(u.to(xw.dtype).to(x.device))))
        scores = torch.nan_to_num(scores.to(torch.float64).cpu(), nan=math.inf)
        best = int(scores.argmin())
        for i in range(u.shape[0]):
            summaries.append(
                {
                    "start": prob.as_dict(prob.to_params(first[i]).tolist()),
                    "params": prob.as_dict(prob.to_params(u[i]).tolist()),
                    "loss": float(scores[i]),
                    "best": i == best,
                }
            )
        return u[best]

    for stage in stages:
        t0 = time.perf_counter()
        if stage == "polish" and u.ndim == 2:
            u = choose()
        if stage == "evolution":
            best, _, stopped, history[stage] = _evolution(prob, xw, gen, cfg, init_u, report)
            u = best.to(torch.float64).cpu()
        elif stage == "sgd":
            uu, stopped, history[stage] = _sgd(prob, xw, gen, cfg, u.to(xw.dtype).to(x.device), report)
            u = uu.to(torch.float64).cpu()
        else:
            polished = _polish(prob, x, u, cfg, report)
            stopped, history[stage] = polished["stopped"], polished["losses"]
            for _ in range(PROBES if prob.loss != "l2" else 0):
                if stopped:
                    break
                jump = _probe(prob, xw, polished["p"], polished["scale"], cfg)
                if jump is None:
                    break
                again = _polish(prob, x, torch.as_tensor(prob.to_unit(jump)), cfg, report, len(history[stage]))
                history[stage] += again["losses"]
                stopped = again["stopped"]
                before, after = (_loss_at(prob, x, q["p"], polished["scale"]) for q in (polished, again))
                if after < before:
                    polished = again
            u = torch.as_tensor(prob.to_unit(polished["p"]))
        timings[stage] = time.perf_counter() - t0
        if stopped:
            break
    if u.ndim == 2:
        u = choose()
    params = prob.as_dict(prob.to_params(u.to(torch.float64)).tolist())
    t0 = time.perf_counter()
    result = _summarize(prob, x, params, polished, stopped)
    timings["residuals"] = time.perf_counter() - t0
    timings["total"] = time.perf_counter() - start
    if not summaries:  # one start (no pose, starts=1): listed all the same
        summaries.append({"start": prob.as_dict(prob.to_params(first.to(torch.float64)).tolist()), "best": True})
    if polished is not None or len(summaries) == 1:
        best = next(s for s in summaries if s["best"])
        best["params"], best["loss"], best["polished"] = dict(params), result.loss, polished is not None
    result.history, result.timings, result.starts = history, timings, summaries
    result.stages = tuple(s for s in stages if s in timings)
    return result


def _summarize(prob: _Problem, x: torch.Tensor, params: dict, polished: dict | None, stopped: bool) -> FitResult:
    """Residuals, loss, inliers, distances and the standard errors (with their reasons) at ``params``."""
    model = prob.model
    if prob.residual == "algebraic":
        signed = None
        residuals = fit_error(model, x, params)
    else:
        with torch.no_grad():
            signed = prob.f(x.to(torch.float64), torch.tensor([params[k] for k in prob.free], dtype=torch.float64))
        signed = signed.cpu().numpy()
        residuals = np.abs(signed)
    r = torch.from_numpy(residuals)
    scale = None
    if prob.loss != "l2":
        scale = prob.loss_scale if prob.loss_scale is not None else float(robust_scale(r, prob.scale_floor))
    loss = float(objective(r, prob.loss, scale))
    mask = inliers(r, prob.loss, scale if scale is not None else 1.0).numpy()
    if signed is not None:
        distance = residuals
    else:
        try:
            distance = fit_error(model, x, params, residual="geometric")
        except RuntimeError:  # a model torch.func cannot differentiate in x (.item() on a point's value)
            distance = np.full_like(residuals, math.nan)
    kept = distance[mask]
    free = tuple(prob.free)
    standard_errors: dict[str, float] = {}
    covariance, reason, null = None, "", []
    termination = "no least-squares polish (stages without 'polish')"
    if polished is not None:
        termination = polished["termination"]
        covariance = polished["covariance"]
        null = [free[i] for i in polished["null"]]
        if stopped:
            reason = "the fit was stopped before the polish ended: no standard errors"
            covariance = None
        elif covariance is None:
            reason = f"the Jacobian has no usable rank (parameters {', '.join(null) or 'all'}): no standard errors"
        else:
            standard_errors = {
                k: float(math.sqrt(covariance[j, j]))
                for j, k in enumerate(free)
                if k not in null and math.isfinite(covariance[j, j]) and covariance[j, j] >= 0.0
            }
            if null:
                zero = [free[i] for i in polished["zero"]]
                why = f" ({', '.join(zero)} change no residual at all)" if zero else ""
                reason = (
                    f"rank-deficient Jacobian: {', '.join(null)} cannot be determined from these points{why}; "
                    "a combination of them leaves every residual unchanged, so they have no standard error"
                )
        if null and not stopped:
            warnings.warn(f"fit: {model.__name__}: {reason}", IdentifiabilityWarning, stacklevel=4)
    elif not reason:
        reason = "standard errors come from the least-squares polish, which did not run"
    missing = [k for k in free if k not in standard_errors]
    if missing and not reason:  # every missing standard error comes with its reason
        reason = f"the covariance of {', '.join(missing)} is not finite or negative: no standard error"
    if not math.isfinite(loss):  # never silently: say why in the termination and the standard errors
        why = f"the final loss is {loss} (non-finite residuals at the fitted parameters)"
        warnings.warn(f"fit: {model.__name__}: {why}", RuntimeWarning, stacklevel=4)
        termination = f"{termination}; {why}" if termination else why
        reason = f"{reason}; {why}" if reason else why
    return FitResult(
        params=params,
        loss=loss,
        residuals=residuals,
        stopped=stopped,
        standard_errors=standard_errors,
        covariance=covariance,
        free=free,
        residual=prob.residual,
        loss_function=prob.loss,
        loss_scale=scale,
        rms=float(np.sqrt(np.mean(kept**2))) if kept.size else math.nan,
        max_distance=float(kept.max()) if kept.size else math.nan,
        inliers=mask,
        outlier_fraction=float(1.0 - mask.mean()),
        termination=termination,
        std_error_reason=reason,
        unidentifiable=null,
        model=model,
        points=x.detach().cpu().to(torch.float64).numpy(),
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
