"""Neural redistancing (paper section 5.3): the signed distance to {f = 0} as a small network.

The paper's ansatz (Fayolle 2021) is ``d(x) = sign(f(x)) h(x; theta)`` with h >= 0 a network:
multiplying by sign(f) keeps the zero set of f exactly, whatever the network does.  Here
``h = |g|`` where g is a small MLP trained to be the *signed* distance: g is smooth across
the surface (|d| has a crease there, d has not), so a small network fits it well, and
``sign(f) |g|`` equals g wherever their signs agree.  sign(f) is evaluated without gradient.

Two modes.  ``mode="paper"`` is the paper's method: the eikonal loss with no distance labels,
every target from f (g = 0 and grad g = -grad f/|grad f| on projected surface samples; see
:func:`redistance`).  ``mode="supervised"`` (the default) minimizes, over minibatches,

* the eikonal loss ``E (|grad d| - 1)^2`` (paper eq. ``loss_eik``) on uniform samples of the
  bounds, grad d by one backward pass with ``create_graph=True``; or, with
  ``loss="p-poisson"``, the p-Poisson energy ``E (|grad d|^p / p - |d|)``, whose minimizer
  (-Delta_p |d| = 1, |d| = 0 on the surface) tends to the distance as p grows (Fayolle 2021
  uses both); it needs only first derivatives, but for a finite p its minimizer only
  approximates the distance (in 1-D its slope is (distance to the medial axis)^(1/(p-1))),
  so keep the supervised term on with it;
* a supervised term ``E (g(x) - d*(x))^2`` on a pool of points whose distance d* is known:
  the distance to dense projected surface samples refined by closest-point steps
  (:func:`pyfrep_core.distance.true_distance`), plus g = 0 on surface points.  It is what
  makes a small network accurate in seconds, and it is the reference the errors are scored
  against.  Without labels use ``mode="paper"`` (with sign(f) h and nothing else, h =
  |distance + c| satisfies the eikonal equation for any c: the surface terms pin c = 0).

Choices measured on the ellipsoid (1, 0.6, 0.4) in [-1.5, 1.5]^3 on 2 CPU cores
(benchmarks/redistance.py; mean absolute error on a 40^3 grid, exact distance):

* the paper's 8 x 512 softplus network: 147 ms per step (the issue's figure); torch's Softplus
  is also ~10x slower than SiLU in the double backward of the eikonal term (measured at
  3 x 128), so SiLU; a softplus written with elementary ops (beta 10): 7.0e-3 vs 8.1e-3 on the
  box after 600 steps, at ~2.5x the time;
* 3 x 128 SiLU, inputs scaled to [-1, 1], float32;
* Adam with a cosine decay: peak lr 1e-2 -> 3.7e-3 after 1500 steps, 3e-2 -> 2.1e-3,
  5e-2 -> 1.5e-3, 1e-1 -> 1.5e-3 (so 5e-2); eikonal weight 0.01 (1e-3: 4.0e-3);
  width 192: no better at equal time; Fourier features (16-32): worse at equal steps;
* eikonal loss alone (the paper's training, plus g = 0 on the surface): 0.25 after 1500
  steps at lr 1e-3 or 5e-3 -- the eikonal equation has many a.e. solutions, the supervised
  term picks the distance;
* the exact last-layer least-squares refit (~0.1 s): 3.9e-2 -> 6.7e-3 after 200 steps at lr
  5e-3, 5.9e-3 -> 5.1e-3 after 1000 steps at lr 1e-2;
* with 2048 pool + 512 eikonal points per step (~6 ms): 1500 steps (~9 s) 1.5e-3.

The box [-0.6, 0.6] x [-0.5, 0.5] x [-0.4, 0.4] is harder: its distance has sharp interior
ridges (the medial planes, meeting the surface at the edges) that a smooth network rounds
off, and the error spreads over the whole domain (with all-SiLU units, 600 steps of 2048:
8.1e-3, 97 % of it outside the box).  Measured on it (one thread, seed 0 unless said):

* units of the last hidden layer, 600 steps of 2048 points: SiLU 8.1e-3, ReLU 6.1e-3 (seeds
  0-1: 6.1e-3, 7.1e-3), leaky ReLU (slope 0.1) 5.9e-3, |x| 6.8e-3, half SiLU half ReLU
  6.5e-3, max/min pairs (GroupSort) 7.1e-3; ReLU everywhere 8.2e-3; a 512-wide last layer
  4.9e-3 at twice the time; 4 x 96 or 2 x 256: worse; first layer weights x2: worse;
* the error is under-fitting, not sampling: the MAE on the pool equals the grid's; refitting
  the last layer on 4x the pool, by IRLS for the L1 error, or on exact labels: 6.1e-3 ->
  6.0e-3, 6.0e-3, 5.7e-3; sampling the pool by current error (hard-example mining): 6.3e-3;
  L1 or Huber supervised loss: 9.0e-3, 8.9e-3;
* smaller batches, more steps, at equal time: 2048 x 1200 steps 4.8e-3; 1024 x 1200 (half
  the time) 4.9e-3; 512 x 2400 4.1e-3; 256 (+ 64 eikonal points) x 4000 3.3e-3 (~2.2 ms a
  step on one thread; two threads took 2.4x longer on the busy machine, hence ``threads=1``);
  with leaky ReLU over seeds 0-2: 3.3e-3, 3.4e-3, 3.5e-3 (ReLU 3.3e-3, 4.0e-3, 4.1e-3); lr
  2e-2: 3.8e-3, 1e-1: 1.2e-2;
* at this lr and batch a few large-gradient steps can make Adam diverge (8000 steps: loss
  6.5e4 at step 2500, MAE 0.2); clipping the gradient norm to 0.1 prevents it and helps:
  3.3e-3 -> 2.3e-3 after 4000 steps (seeds 0-2: 2.3e-3, 2.4e-3, 2.6e-3), 2.1e-3 after 8000;
  clip 1.0 still diverged, 0.03: 2.6e-3, 3.0e-3.

Paper mode (``mode="paper"``: the eikonal loss, every target from f, no distance labels),
measured on the pawn (mean |d - true distance| over a 32^3 grid of its bounds; omega_1 = f /
sqrt(f^2 + |grad f|^2): 1.31e-1; seed 0, 1500 steps unless said; CPU seconds of one thread,
the machine under a load of 6-17):

* eikonal (weight 0.01) + g = 0 on the surface, as ``supervised=0`` trained before: 1.29e-1;
* eikonal weight 1, g = 0 (weight 100) and grad g = -n (the unit normal from grad f, weight 1)
  on surface samples, 256 uniform + 256 points within 0.05 of the surface a step: 1.77e-2
  (without the normal term 2.26e-2, normal weight 10: 2.28e-2); lr 2e-2 with clip 0.1 (5e-3:
  3.1e-2 after 800 steps, 5e-2: 2.4e-2);
* last hidden layer SiLU instead of leaky ReLU: 1.41e-2 (tanh: 1.1e-1); a hinge sign(g) =
  sign(f), g = f/|grad f| near the surface (first-order omega), L1 eikonal, SAL's sphere
  initialisation: no better (1.73e-2, 2.0e-2, 1.45e-2, 2.8e-2);
* 88 % of the error is outside, |d| > 0.2, a slope bias: |d| too large past the concave
  parts' medial axis (the neck), where a smooth g overshoots.  The distance is the largest
  1-Lipschitz function vanishing on the surface, so slopes above 1 are the error that
  spreads: weighting relu(|grad g| - 1)^2 3x more (``over_slope=3``): 1.26e-2 (10x: 2.2e-2,
  the bias turns into an underestimate);
* 128 + 128 points a step (half): 1.50e-2 at 0.7x the time; near points spread 0.2 (8 % of
  the box) instead of 0.05: 9.8e-3 (0.1: 1.16e-2, 0.3: 1.23e-2); 2000 steps: 9.9e-3.

Paper-mode defaults from these: 1500 steps, 128 uniform + 128 near (std 8 % of the box's
longest side) eikonal points + 128 surface samples, all SiLU, lr 2e-2, clip 0.1: pawn 1.04e-2,
1.06e-2, 1.26e-2 for seeds 0-2 (omega_1 / 12.6, / 12.4, / 10.4) after 14-16 s of CPU.

Supervised-mode defaults from the measurements above: 4000 steps of 256 pool + 64 eikonal
points, last hidden layer leaky ReLU, clip 0.1, one thread (~9 s).  Box 2.3e-3, sphere 9.2e-4
after 1500 steps; ellipsoid below 4.6e-3 after 3.5-4.0 s and 7.7e-4 after 10 s (scikit-fmm 128^3: 1.5e-3 on its grid).

>>> import torch
>>> from pyfrep_core import sphere
>>> ball = lambda x: sphere(x, r=1.0)
>>> d = redistance(ball, ((-1.5,) * 3, (1.5,) * 3), steps=300, progress=False, surface_resolution=32)
>>> out = d(torch.tensor([[0.0, 0.0, 0.5], [1.3, 0.0, 0.0]]))
>>> bool(torch.allclose(out, torch.tensor([0.5, -0.3]), atol=0.03))
True
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch

from ._array import as_tensor, check_finite, check_option, check_points, skip_checks, validated_inputs
from ._threads import intra_op_threads
from .diff import value_and_grad
from .distance import MAX_RESOLUTION, surface_samples, true_distance
from .evaluate import evaluate
from .model import check_bounds
from .networks import MAX_SEED, ImplicitNetwork, cosine_lr, training_step
from .progress import Event, Progress, StopFlag

__all__ = ["RedistancedSDF", "redistance", "load_redistanced"]

FORMAT = "pyfrep-redistanced-1"
# per-mode defaults of redistance (module docstring: the measurements behind them)
MODE_DEFAULTS: dict[str, dict[str, Any]] = {
    "supervised": {"steps": 4000, "batch": 256, "lr": 5e-2, "eikonal": 0.01, "surface_resolution": 64,
                   "last_activation": "leaky_relu"},
    "paper": {"steps": 1500, "batch": 128, "lr": 2e-2, "eikonal": 1.0, "surface_resolution": 48,
              "last_activation": None},
}  # fmt: skip
PAPER_WEIGHTS = {"boundary": 100.0, "normal": 1.0, "over_slope": 3.0}
NEAR_SCALE = 0.08  # paper mode: std of the near-surface points, a fraction of the box's longest side


class RedistancedSDF(ImplicitNetwork):
    """``d(x) = sign(f(x)) |g(x; theta)|``: a signed distance whose zero set is that of f.

    g is an :class:`~pyfrep_core.networks.ImplicitNetwork` (He-initialised).  Call it on
    points (..., 3) (torch, any float dtype, or numpy) for d (...).  The network
    is float32 by default; inputs of another dtype are converted and the result converted
    back.  ``history`` holds the training loss per step; ``config`` rebuilds the
    architecture (:func:`load_redistanced`).

    Attributes
    ----------
    f : the defining function (code: not saved; give it again to :func:`load_redistanced`).
    config : dict of the architecture (bounds, width, depth, activation, last_activation,
        beta, fourier ...).
    history : list of float, loss per training step.
    """

    def __init__(
        self,
        f: Callable,
        bounds: Any,
        width: int = 128,
        depth: int = 3,
        activation: str = "silu",
        last_activation: str | None = None,
        beta: float = 100.0,
        fourier_features: int = 0,
        fourier_scale: float = 2.0,
        seed: int = 0,
        dtype: torch.dtype = torch.float32,
    ):
        if not callable(f):
            raise TypeError(f"f must be callable (points (N, 3) -> values (N,)), got {type(f).__name__}")
        super().__init__(
            bounds, width=width, depth=depth, activation=activation, last_activation=last_activation, beta=beta,
            fourier_features=fourier_features, fourier_scale=fourier_scale, seed=seed, dtype=dtype,
            fn="RedistancedSDF",
        )  # fmt: skip
        self.f = f

    def h(self, x: torch.Tensor) -> torch.Tensor:
        """The ansatz's magnitude h = |g| >= 0."""
        return self.signed_network(x).abs()

    def sign(self, x: torch.Tensor) -> torch.Tensor:
        """sign(f(x)) without gradient, in x's dtype; x (..., 3) is handed to f as (N, 3)."""
        with torch.no_grad():
            return torch.sign(evaluate(self.f, x.detach()))

    def forward(self, x: Any) -> Any:
        """The redistanced field at points x (..., 3), checked as a model call checks them.

        float32/float64 and finite (ValueError naming the first bad point); no points give no values.
        """
        t, was_numpy = as_tensor(x, "x", fn="RedistancedSDF")
        check_points(t, 3, "x", fn="RedistancedSDF", empty=True)
        check_finite(t, "x", "RedistancedSDF")
        with contextlib.nullcontext() if skip_checks(t) else validated_inputs():
            d = (self.sign(t).to(self.dtype) * self.h(t)).to(t.dtype)
        return d.detach().cpu().numpy() if was_numpy else d

    def save(self, path: str | Path) -> None:
        """Write the weights, the architecture and the loss history (``torch.save``).

        f is code and is not saved: pass it again to :func:`load_redistanced`.
        """
        torch.save(
            {"format": FORMAT, "config": self.config, "state_dict": self.state_dict(), "history": self.history},
            Path(path),
        )


def load_redistanced(path: str | Path, f: Callable) -> RedistancedSDF:
    """Load a network written by :meth:`RedistancedSDF.save`; ``f`` is the same defining function.

    Raises ValueError for a file that is not a saved redistanced network.

    Examples
    --------
    >>> import tempfile, torch
    >>> from pyfrep_core import sphere
    >>> ball = lambda x: sphere(x, r=1.0)
    >>> d = RedistancedSDF(ball, ((-1.5,) * 3, (1.5,) * 3), width=16, depth=2)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     d.save(tmp + "/d.pt")
    ...     e = load_redistanced(tmp + "/d.pt", ball)
    >>> x = torch.rand(5, 3)
    >>> bool(torch.equal(d(x), e(x)))
    True
    """
    if not callable(f):
        raise TypeError(f"f must be callable (points (N, 3) -> values (N,)), got {type(f).__name__}")
    try:
        data = torch.load(Path(path), map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as err:
        raise ValueError(f"{path} is not a saved redistanced network: {err}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path} is not a saved redistanced network (format {FORMAT!r} expected)")
    cfg = dict(data["config"])
    cfg.setdefault("last_activation", None)  # files written before it existed: one activation
    dtype = getattr(torch, cfg.pop("dtype"))
    model = RedistancedSDF(f, cfg.pop("bounds"), dtype=dtype, **cfg)
    model.load_state_dict(data["state_dict"])
    model.history = [float(v) for v in data.get("history", [])]
    return model


def _uniform(n: int, lo: torch.Tensor, hi: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(n, 3, generator=gen, dtype=lo.dtype)


def _training_pool(
    f: Callable, lo: tuple, hi: tuple, size: int, surface_resolution: int, seed: int, stop: StopFlag | None = None
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Points (size, 3) float64 and their signed distances: uniform, near-surface and on-surface.

    None when ``stop`` is set: it is checked after the surface samples and before each
    closest-point step of the reference distance (the pool's long part, in ``refine_steps``
    steps over all its points).
    """
    reference = true_distance(f, (lo, hi), resolution=surface_resolution, seed=seed)
    if stop is not None and stop.is_set():
        return None
    surf = torch.as_tensor(reference.samples.points)
    gen = torch.Generator().manual_seed(seed)
    lo_t, hi_t = torch.tensor(lo, dtype=torch.float64), torch.tensor(hi, dtype=torch.float64)
    n_surface, n_near = size // 8, size // 4
    n_uniform = size - n_surface - n_near
    on = surf[torch.randint(len(surf), (n_surface,), generator=gen)]
    # near the surface, where |d| has to be right and the uniform samples are few
    sigma = 0.05 * float((hi_t - lo_t).max())
    near = surf[torch.randint(len(surf), (n_near,), generator=gen)]
    near = near + sigma * torch.randn(n_near, 3, generator=gen, dtype=torch.float64)
    near = torch.minimum(torch.maximum(near, lo_t), hi_t)
    off = torch.cat([_uniform(n_uniform, lo_t, hi_t, gen), near])
    unsigned = torch.as_tensor(reference.unsigned(off.numpy(), stop=stop))
    if stop is not None and stop.is_set():
        return None
    with torch.no_grad():
        d_off = torch.sign(evaluate(f, off)).to(torch.float64) * unsigned
    x = torch.cat([on, off])
    d = torch.cat([torch.zeros(n_surface, dtype=torch.float64), d_off])
    return x, d


def redistance(
    f: Callable,
    bounds: Any = None,
    steps: int | None = None,
    loss: str = "eikonal",
    p: float = 8.0,
    mode: str = "supervised",
    supervised: float | None = None,
    eikonal: float | None = None,
    boundary: float | None = None,
    normal: float | None = None,
    over_slope: float | None = None,
    batch: int | None = None,
    lr: float | None = None,
    clip_grad: float | None = 0.1,
    width: int = 128,
    depth: int = 3,
    activation: str = "silu",
    last_activation: str | None = "auto",
    fourier_features: int = 0,
    surface_resolution: int | None = None,
    pool_size: int = 1 << 15,
    refit: bool = True,
    seed: int = 0,
    dtype: torch.dtype = torch.float32,
    threads: int | None = 1,
    callback: Callable[[Event], Any] | None = None,
    every: int = 10,
    stop: StopFlag | None = None,
    progress: bool = True,
) -> RedistancedSDF:
    """Train ``d(x) = sign(f(x)) h(x; theta)`` to be the signed distance to {f = 0} in ``bounds``.

    Two modes (the module docstring has the measurements behind each default):

    * ``mode="paper"``: the paper's method (eq. ``loss_eik``), no distance labels.  Every
      target comes from f: the eikonal loss ``(|grad g| - 1)^2 + over_slope relu(|grad g| - 1)^2``
      (weight ``eikonal``, default 1) on ``batch`` uniform points of the box and ``batch``
      points near the surface; on ``batch`` surface samples of f = 0 (projected by Newton steps)
      g = 0 (weight ``boundary``, default 100) and grad g = the inward unit normal
      -grad f/|grad f| (weight ``normal``, default 1).  Defaults: 1500 steps, batch 128, lr 2e-2,
      all-SiLU network, surface_resolution 48.
    * ``mode="supervised"`` (the default): adds distance labels: ``E (g - d*)^2`` (weight
      ``supervised``, default 1) on a pool whose distances d* come from
      :func:`pyfrep_core.distance.true_distance`, the eikonal term a light regularizer (weight
      0.01), then a least-squares refit of the last layer.  Defaults: 4000 steps, batch 256,
      lr 5e-2, last hidden layer leaky ReLU, surface_resolution 64.

    Parameters
    ----------
    f : callable (N, 3) -> (N,), f >= 0 inside (a Model gives its default bounds).
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)): the box sampled during training.
    steps : Adam steps (the learning rate decays along a cosine over them); None: the mode's.
    loss : "eikonal" (``(|grad d| - 1)^2``) or "p-poisson" (energy ``|grad d|^p / p - |d|``).
    p : exponent of the p-Poisson energy.
    mode : "paper" (no distance labels) or "supervised" (labels from the true distance).
    supervised : weight of the supervised term (supervised mode; None: 1, must be > 0 there;
        paper mode: None or 0).
    eikonal : weight of the eikonal (or p-Poisson) term (None: 1 in paper mode, 0.01 supervised).
    boundary, normal : paper mode: weights of g = 0 and of grad g = -n on the surface samples
        (None: 100 and 1).
    over_slope : paper mode: extra weight of |grad g| > 1 in the eikonal term (None: 3): the
        distance is the largest 1-Lipschitz function that vanishes on the surface, so a slope
        above 1 (overshooting past the medial axis) is the error that spreads outward.
    batch : supervised mode: pool points per step, plus batch / 4 fresh uniform points for the
        eikonal term; paper mode: points per group (uniform, near, on the surface).  None: the mode's.
    lr : peak Adam learning rate (None: the mode's).
    clip_grad : the gradient (over all weights) is clipped to this norm before each Adam
        step (None: not clipped).
    width, depth, activation : the MLP g (hidden width, hidden layers, activation: "silu",
        "softplus", "tanh", "relu" or "leaky_relu" (slope 0.1)).
    last_activation : activation of the last hidden layer (None: ``activation``; "auto": leaky
        ReLU in supervised mode, ``activation`` in paper mode); piecewise linear units there let
        g follow the distance's creases (medial axis) when labels pin them.
    fourier_features : number of random Fourier features of the input (0: none).
    surface_resolution : marching-cubes resolution of the surface samples (None: the mode's).
    pool_size : supervised mode: points with known distance (a quarter near the surface, an
        eighth on it).
    refit : supervised mode: after the Adam steps, solve the supervised term exactly for the
        last layer (linear least squares; the hidden layers are kept): a large gain for no time.
    seed : seeds the pool, the batches and the initial weights.
    dtype : dtype of the network (float32 is faster on a CPU).
    threads : torch intra-op threads while training (restored after; None: leave as set).
        Batches of a few hundred points run fastest on one thread: 2 threads took 2.4x
        longer on a busy 2-core machine.
    callback, every, stop, progress : see :mod:`pyfrep_core.progress`; events have stage
        "redistance", the step and the loss; returning True from the callback stops.  The stop
        flag is also checked while the training pool is built (before each closest-point step
        of its reference distance); stopped there, the untrained network comes back, with an
        empty ``history``.

    Returns
    -------
    RedistancedSDF ; ``history`` holds the loss per step run.

    Raises
    ------
    TypeError : f not callable; an option of the wrong type (a string for a number, a number
        for a flag).  ValueError : bad bounds (NaN, inverted), f without zero set in the bounds,
        an option out of its range (every number finite; steps, batch, pool_size, every, lr,
        clip_grad positive; supervised, eikonal, boundary, normal, over_slope >= 0; supervised
        > 0 in supervised mode (without labels: ``mode="paper"``), 0 in paper mode; counts and
        seed integers), a paper-mode weight given in supervised mode, an unknown mode, loss or
        activation; the message names the option and its value.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere
    >>> ball = lambda x: sphere(x, r=1.0)
    >>> d = redistance(ball, ((-1.5,) * 3, (1.5,) * 3), mode="paper", steps=300, progress=False)
    >>> out = d(torch.tensor([[0.0, 0.0, 0.5], [1.3, 0.0, 0.0]]))
    >>> bool(torch.allclose(out, torch.tensor([0.5, -0.3]), atol=0.05))
    True
    """
    if not callable(f):
        raise TypeError(f"f must be callable (points (N, 3) -> values (N,)), got {type(f).__name__}")
    if bounds is None:
        bounds = getattr(f, "bounds", None)
        if bounds is None:
            raise ValueError("bounds must be given for a function without default bounds")
    lo, hi = check_bounds(bounds, 3)
    fn = "redistance"
    mode = check_option(mode, "mode", fn, "choice", choices=tuple(MODE_DEFAULTS))
    defaults = MODE_DEFAULTS[mode]
    steps, batch, lr, eikonal, surface_resolution = (
        defaults[name] if value is None else value
        for name, value in zip(
            ("steps", "batch", "lr", "eikonal", "surface_resolution"), (steps, batch, lr, eikonal, surface_resolution)
        )
    )
    if isinstance(last_activation, str) and last_activation == "auto":
        last_activation = defaults["last_activation"]
    loss = check_option(loss, "loss", fn, "choice", choices=("eikonal", "p-poisson"))
    steps = check_option(steps, "steps", fn, "int", positive=True)
    batch = check_option(batch, "batch", fn, "int", positive=True)
    pool_size = check_option(pool_size, "pool_size", fn, "int", positive=True)
    surface_resolution = check_option(
        surface_resolution, "surface_resolution", fn, "int", minimum=2, maximum=MAX_RESOLUTION
    )
    threads = check_option(threads, "threads", fn, "int", positive=True, none=True)
    every = check_option(every, "every", fn, "int", positive=True)
    lr = check_option(lr, "lr", fn, positive=True)
    clip_grad = check_option(clip_grad, "clip_grad", fn, positive=True, none=True)
    p = check_option(p, "p", fn)
    if loss == "p-poisson" and not p > 1:
        raise ValueError(f"redistance: p must be > 1 for the p-Poisson energy, got {p!r}")
    supervised = check_option(supervised, "supervised", fn, minimum=0.0, none=True)
    eikonal = check_option(eikonal, "eikonal", fn, minimum=0.0)
    weights = {
        name: check_option(value, name, fn, minimum=0.0, none=True)
        for name, value in (("boundary", boundary), ("normal", normal), ("over_slope", over_slope))
    }
    if mode == "paper":
        if supervised:
            raise ValueError(
                f"redistance: supervised must be 0 or None in paper mode (no distance labels), got {supervised}"
            )
        weights = {name: PAPER_WEIGHTS[name] if value is None else value for name, value in weights.items()}
        if eikonal == 0 or weights["boundary"] == 0:
            raise ValueError(
                f"redistance: paper mode needs eikonal > 0 and boundary > 0, got {eikonal}, {weights['boundary']}"
            )
    else:
        supervised = 1.0 if supervised is None else supervised
        if supervised == 0:
            raise ValueError(
                "redistance: supervised must be > 0 in supervised mode, got 0.0 (supervised and eikonal must not "
                "both be 0; for training without distance labels use mode='paper')"
            )
        given = [f"{name}={value!r}" for name, value in weights.items() if value is not None]
        if given:
            raise ValueError(f"redistance: {', '.join(given)} weigh paper-mode terms; pass mode='paper' to use them")
    refit = check_option(refit, "refit", fn, "bool")
    progress = check_option(progress, "progress", fn, "bool")
    seed = check_option(seed, "seed", fn, "int", minimum=0, maximum=MAX_SEED)
    if callback is not None and not callable(callback):
        raise TypeError(f"redistance: callback must be callable or None, got {callback!r}")
    if stop is not None and not callable(getattr(stop, "is_set", None)):
        raise TypeError(f"redistance: stop must have an is_set() method (a threading.Event) or be None, got {stop!r}")

    torch_dtype = dtype
    model = RedistancedSDF(
        f, (lo, hi), width=width, depth=depth, activation=activation, last_activation=last_activation,
        fourier_features=fourier_features,
        seed=seed, dtype=torch_dtype,
    )  # fmt: skip
    if stop is not None and stop.is_set():
        return model.eval()  # stopped before the pool was built: the untrained network, empty history
    if mode == "paper":
        _train_paper(model, f, lo, hi, steps, loss, p, eikonal, weights, batch, lr, clip_grad,
                     surface_resolution, seed, threads, callback, every, stop, progress)  # fmt: skip
        return model.eval()
    pool = _training_pool(f, lo, hi, pool_size, surface_resolution, seed, stop)
    fit_weight = supervised
    if pool is None or (stop is not None and stop.is_set()):
        return model.eval()  # stopped while the pool was built: the untrained network, empty history
    pool_x, pool_d = pool
    pool_x, pool_d = pool_x.to(torch_dtype), pool_d.to(torch_dtype)
    gen = torch.Generator().manual_seed(seed + 1)
    lo_t, hi_t = torch.tensor(lo, dtype=torch_dtype), torch.tensor(hi, dtype=torch_dtype)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda k: cosine_lr(k, int(steps)))
    # the supervised term needs g only; the eikonal term needs grad g (double backward, ~3x
    # the cost per point), so it gets a smaller batch of fresh uniform points
    n_pool, n_pde = batch, max(64, batch // 4)
    with intra_op_threads(threads), Progress(int(steps), "redistance", callback, every, stop, progress) as bar:
        for step in range(int(steps)):
            x = _uniform(n_pde, lo_t, hi_t, gen)
            g, dg = value_and_grad(model.signed_network, x, create_graph=True)
            grad_norm = dg.norm(dim=-1)
            if loss == "eikonal":
                pde = ((grad_norm - 1.0) ** 2).mean()
            else:
                pde = (grad_norm**p / p - g.abs()).mean()
            total = eikonal * pde
            idx = torch.randint(len(pool_x), (n_pool,), generator=gen)
            fit = ((model.signed_network(pool_x[idx]) - pool_d[idx]) ** 2).mean()
            total = total + fit_weight * fit
            value = training_step(model, optimizer, schedule, total, clip_grad)
            if bar.update(step, value, supervised=float(fit.detach()), pde=float(pde.detach())):
                break
    if refit:
        _refit_last_layer(model, pool_x, pool_d)
    model.eval()
    return model


def _train_paper(
    model: RedistancedSDF,
    f: Callable,
    lo: tuple,
    hi: tuple,
    steps: int,
    loss: str,
    p: float,
    eikonal: float,
    weights: dict[str, float],
    batch: int,
    lr: float,
    clip_grad: float | None,
    surface_resolution: int,
    seed: int,
    threads: int | None,
    callback: Callable[[Event], Any] | None,
    every: int,
    stop: StopFlag | None,
    progress: bool,
) -> None:
    """The paper's training (eq. ``loss_eik``): every target from f, no distance labels.

    Each step: the eikonal term on ``batch`` uniform points and ``batch`` points within about
    NEAR_SCALE x the box's longest side of the surface; g = 0 and grad g = -n (n = grad f/|grad f|
    negated: the outward normal; g > 0 inside) on ``batch`` projected surface samples.
    """
    samples = surface_samples(f, (lo, hi), surface_resolution, seed=seed)
    if stop is not None and stop.is_set():
        return
    dtype = model.dtype
    surf = torch.as_tensor(samples.points, dtype=dtype)
    inward = -torch.as_tensor(samples.normals, dtype=dtype)
    lo_t, hi_t = torch.tensor(lo, dtype=dtype), torch.tensor(hi, dtype=dtype)
    sigma = NEAR_SCALE * float((hi_t - lo_t).max())
    gen = torch.Generator().manual_seed(seed + 1)
    optimizer = torch.optim.Adam(model.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda k: cosine_lr(k, int(steps)))
    n = int(batch)
    with intra_op_threads(threads), Progress(int(steps), "redistance", callback, every, stop, progress) as bar:
        for step in range(int(steps)):
            on = torch.randint(len(surf), (n,), generator=gen)
            near = surf[torch.randint(len(surf), (n,), generator=gen)]
            near = near + sigma * torch.randn(n, 3, generator=gen, dtype=dtype)
            near = torch.minimum(torch.maximum(near, lo_t), hi_t)
            x = torch.cat([_uniform(n, lo_t, hi_t, gen), near, surf[on]])
            g, dg = value_and_grad(model.signed_network, x, create_graph=True)
            slope = dg[: 2 * n].norm(dim=-1)
            if loss == "eikonal":
                pde = ((slope - 1.0) ** 2 + weights["over_slope"] * torch.relu(slope - 1.0) ** 2).mean()
            else:
                pde = (slope**p / p - g[: 2 * n].abs()).mean()
            zero = (g[2 * n :] ** 2).mean()
            normal = ((dg[2 * n :] - inward[on]) ** 2).sum(-1).mean()
            total = eikonal * pde + weights["boundary"] * zero + weights["normal"] * normal
            value = training_step(model, optimizer, schedule, total, clip_grad)
            if bar.update(step, value, pde=float(pde.detach()), boundary=float(zero.detach())):
                break


def _refit_last_layer(model: RedistancedSDF, x: torch.Tensor, d: torch.Tensor, ridge: float = 1e-8) -> None:
    """Solve the supervised term exactly for the last (linear) layer: ridge least squares.

    g is linear in the last layer's weights, so ``min sum (g(x_i) - d_i)^2`` over them is a
    linear least-squares problem (normal equations in float64, width + 1 unknowns).
    """
    last = model.net[-1]
    with torch.no_grad():
        z = (x - model.center) / model.scale
        feats = model.net[:-1](z).double()
        a = torch.cat([feats, torch.ones(len(feats), 1, dtype=torch.float64)], dim=1)
        lhs = a.T @ a
        lhs += ridge * torch.trace(lhs) / len(lhs) * torch.eye(len(lhs), dtype=torch.float64)
        sol = torch.linalg.solve(lhs, a.T @ (d.double() / model.scale.double()))
        last.weight.copy_(sol[:-1].reshape(1, -1).to(last.weight.dtype))
        last.bias.copy_(sol[-1:].to(last.bias.dtype))
