"""Free-form fit: a neural implicit fitted to an (oriented) point cloud, the IGR way.

When no parametric model describes a scanned object, its surface can still be given as the
zero set of a small network g(x; theta) (:class:`pyfrep_core.networks.ImplicitNetwork`) fitted
to the points.  Implicit Geometric Regularization (Gropp et al. 2020, eq. 2) minimizes

    l(theta) = mean_i |g(x_i)| + tau mean_i |grad g(x_i) + n_i| + lambda E_x (|grad g(x)| - 1)^2

over the points x_i and their outward unit normals n_i (the middle term only when normals are
given): g vanishes on the points, its gradient follows the normals there, and the eikonal term
makes |grad g| = 1 at points x drawn around the cloud (each point moved by a Gaussian of
standard deviation its distance to its 50th neighbour, IGR's sampling) and uniformly in the box.
The library's sign convention (f >= 0 inside) flips IGR's: grad f points inward, hence
``+ n_i``.  Among the many functions with |grad g| = 1 almost everywhere, gradient descent from
the geometric initialisation (a sphere; SAL, Atzmon & Lipman 2020) finds a smooth signed
distance whose zero set passes through the points -- the "implicit regularization" of the paper.
The defaults are IGR's weights (tau = 1, lambda = 0.1) and its softplus (beta = 100), on a
smaller network (4 x 128 instead of 8 x 512) trained for fewer steps, to answer in tens of
seconds on a CPU.

The result is a :class:`pyfrep_core.Model` without parameters: it meshes
(:func:`pyfrep_core.polygonize`), differentiates (curvatures, normals), slices, redistances and
compiles like any model.  Evaluated without gradients it runs in chunks within the call budget
of :mod:`pyfrep_core.evaluate` (the network's layers, not the 128 values a point of that
module's estimate, set the chunk).

>>> import numpy as np
>>> from pyfrep_core import sphere, polygonize, sample_surface
>>> ball = lambda x: sphere(x, r=1.0)
>>> pts = sample_surface(ball, 2000, seed=0, bounds=((-1.2,) * 3, (1.2,) * 3), resolution=32)
>>> f = fit_freeform(pts, pts, steps=150, width=32, depth=2, progress=False)  # unit sphere: n = x
>>> r = np.linalg.norm(polygonize(f, resolution=32).vertices, axis=1)
>>> bool(abs(r - 1.0).max() < 0.05)
True
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from scipy.spatial import cKDTree

from ._array import as_tensor, check_finite, check_option, check_points, tracing
from ._threads import intra_op_threads
from .evaluate import call_budget
from .model import Model, check_bounds
from .networks import ACTIVATIONS, MAX_SEED, ImplicitNetwork, cosine_lr, training_step
from .progress import Event, Progress, StopFlag

__all__ = ["FreeformModel", "fit_freeform"]

NEIGHBOURS = 50  # IGR: the local sampling scale is the distance to the 50th nearest point
UNIFORM_FRACTION = 8  # one uniform eikonal sample in the box per 8 surface points (IGR: 1/8)
PADDING = 0.1  # the default box: the cloud's box grown by this fraction of its largest extent per side
QUERY_CHUNK = 1 << 16  # neighbour queries per KD-tree call: bounds the (chunk, k) distance table


class FreeformModel(Model):
    """A :class:`~pyfrep_core.Model` whose defining function is a trained implicit network.

    Built by :func:`fit_freeform`.  No parameters; ``bounds`` is the box it was trained in.

    Attributes
    ----------
    network : the :class:`~pyfrep_core.networks.ImplicitNetwork` (weights frozen after training;
        the model evaluates a copy in the dtype of the points it is given).
    history : the training loss per step (``network.history``).
    terms : dict of lists, per step: the surface, normal and eikonal terms of the loss.
    settings : the options it was trained with.
    stopped : True when a callback or the stop flag ended the training early.
    """

    def __init__(self, network: ImplicitNetwork, bounds: Any, settings: dict[str, Any] | None = None):
        if not isinstance(network, ImplicitNetwork):
            raise TypeError(f"FreeformModel: network must be an ImplicitNetwork, got {type(network).__name__}")
        self.network = network
        self.terms: dict[str, list[float]] = {"surface": [], "normal": [], "eikonal": []}
        self.settings = dict(settings or {})
        self.stopped = False
        self._variants: dict[torch.dtype, ImplicitNetwork] = {}
        units = network.config["width"] * network.config["depth"]

        def freeform(x: torch.Tensor) -> torch.Tensor:
            return _values(self._variants.get(x.dtype, network), x, units)

        super().__init__(freeform, {}, bounds=bounds, dim=3)
        self.freeze()

    def freeze(self) -> None:
        """Freeze the weights and keep a float32 and a float64 copy of the network.

        The model then computes in the dtype of the points it is called with: the same weights
        evaluated in float64 give f and grad f to float64 precision, so Newton projections onto
        f = 0 (polygonize, sampling) converge as for an analytic model.  :func:`fit_freeform`
        calls it after training.
        """
        self.network.requires_grad_(False)
        self.network.eval()
        variants = {}
        for dtype in (torch.float32, torch.float64):
            net = self.network if dtype == self.network.dtype else copy.deepcopy(self.network).to(dtype)
            variants[dtype] = net.requires_grad_(False).eval()
        self._variants = variants

    @property
    def history(self) -> list[float]:
        return self.network.history

    def __repr__(self) -> str:
        cfg = self.network.config
        return f"<freeform model: {cfg['depth']} x {cfg['width']} {cfg['activation']}, {len(self.history)} steps>"


def _values(network: ImplicitNetwork, x: torch.Tensor, units: int) -> torch.Tensor:
    """g(x) in x's dtype and on x's device; chunked within the call budget when no graph is built."""
    if tracing(x) or (torch.is_grad_enabled() and x.requires_grad):
        return network(x).to(device=x.device, dtype=x.dtype)
    # without gradients a layer's input and output (units values each) are alive at once
    per_point = 4 * (units + 3) * network.dtype.itemsize
    size = max(1024, call_budget(network.device) // per_point)
    with torch.no_grad():
        if x.shape[0] <= size:
            return network(x).to(device=x.device, dtype=x.dtype)
        return torch.cat([network(x[i : i + size]).to(device=x.device, dtype=x.dtype) for i in range(0, len(x), size)])


def _cloud(points: Any, normals: Any, fn: str) -> tuple[torch.Tensor, torch.Tensor | None, bool]:
    """Points (N, 3) and unit normals (N, 3) or None as tensors; an object with .points/.normals is unpacked."""
    if hasattr(points, "points") and not isinstance(points, torch.Tensor | np.ndarray):
        if normals is None:
            normals = getattr(points, "normals", None)
        points = points.points
    t, was_numpy = as_tensor(points, "points", fn=fn)
    check_points(t, 3, "points", fn=fn)
    check_finite(t, "points", fn)
    if t.shape[0] < 2:
        raise ValueError(f"{fn}: points must hold at least 2 points, got {t.shape[0]}")
    n = None
    if normals is not None:
        n, _ = as_tensor(normals, "normals", fn=fn)
        check_points(n, 3, "normals", fn=fn)
        check_finite(n, "normals", fn)
        if n.shape != t.shape:
            raise ValueError(f"{fn}: normals must have the points' shape {tuple(t.shape)}, got {tuple(n.shape)}")
        length = n.norm(dim=1)
        bad = torch.nonzero(~(length > 0)).flatten()
        if len(bad):
            raise ValueError(f"{fn}: normals must be non-zero vectors, got a zero normal at index {int(bad[0])}")
        n = n / length[:, None]
    return t, n, was_numpy


def _local_scale(z: np.ndarray, k: int) -> np.ndarray:
    """Distance of each point (N, 3) to its k-th nearest neighbour (N,), in chunks of queries."""
    tree = cKDTree(z)
    out = np.empty(len(z))
    for i in range(0, len(z), QUERY_CHUNK):
        d, _ = tree.query(z[i : i + QUERY_CHUNK], k=[k + 1])  # the point itself is its 1st neighbour
        out[i : i + QUERY_CHUNK] = d[:, 0]
    return out


def fit_freeform(
    points: Any,
    normals: Any = None,
    *,
    bounds: Any = None,
    steps: int = 1500,
    batch: int = 1024,
    lr: float = 5e-3,
    width: int = 128,
    depth: int = 4,
    activation: str = "softplus",
    beta: float = 100.0,
    fourier_features: int = 0,
    fourier_scale: float = 1.0,
    normal_weight: float = 1.0,
    eikonal_weight: float = 0.1,
    seed: int = 0,
    device: Any = None,
    dtype: torch.dtype = torch.float32,
    threads: int | None = 1,
    callback: Callable[[Event], Any] | None = None,
    every: int = 10,
    stop: StopFlag | None = None,
    progress: bool = True,
) -> FreeformModel:
    """Fit a neural implicit g(x; theta), g >= 0 inside, to an (oriented) point cloud (IGR).

    Parameters
    ----------
    points : (N, 3) points on the surface, numpy or torch, float32 or float64, in any length
        unit (the model is in the same unit); or an object with ``.points`` and ``.normals``
        (:func:`pyfrep_core.load_points`' PointCloud).
    normals : (N, 3) outward normals (any non-zero length), or None: then the loss has no
        normal term and the orientation comes from the initial sphere alone.
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)): the box of the uniform eikonal samples,
        of the input scaling and the model's default bounds.  Default: the cloud's box grown
        by 10 % of its largest extent on each side.
    steps : Adam steps (learning rate: linear warm-up, then cosine decay to 1 %).
    batch : cloud points per step (as many near-surface eikonal samples, batch / 8 uniform).
    lr : peak Adam learning rate.
    width, depth, activation, beta : the MLP (hidden units, hidden layers, activation of
        :data:`pyfrep_core.networks.ACTIVATIONS`, softplus sharpness).  The geometric
        initialisation assumes a ReLU-like unit: softplus (the default) or relu.
    fourier_features, fourier_scale : random Fourier features of the scaled input (0: none);
        their first-layer weights start at 0, so training still starts from the sphere.
    normal_weight : tau, the weight of ``|grad g + n|`` (ignored without normals).
    eikonal_weight : lambda, the weight of ``(|grad g| - 1)^2``.
    seed : seeds the initial weights and the samples of every step.
    device : where the network trains and runs (default: the points' device).
    dtype : the network's dtype, float32 (default) or float64.  The model then returns the
        dtype of the points it is called with.
    threads : torch intra-op threads while training (None: leave as set).  On the CPU one
        thread makes runs bit-for-bit repeatable and batches of a few thousand points run as
        fast on one as on two busy cores.
    callback, every, stop, progress : see :mod:`pyfrep_core.progress`; events have stage
        "freeform", the step, the loss and extra ``surface``, ``normal``, ``eikonal`` terms;
        returning True from the callback or setting ``stop`` ends the training after the step
        (the model trained so far comes back, ``stopped`` True).

    Returns
    -------
    FreeformModel : a parameter-free :class:`~pyfrep_core.Model` (positive inside), with the
    network, the loss ``history`` and its ``terms``.

    Raises
    ------
    TypeError : an option of the wrong type; points or normals that are not float arrays.
    ValueError : points not (N, 3) with N >= 2, NaN/inf, normals of another shape or zero,
        bounds that do not contain every point, an option out of range; the message names it.

    Examples
    --------
    >>> import torch
    >>> from pyfrep_core import sphere, sample_surface
    >>> pts = sample_surface(lambda x: sphere(x, r=0.5), 1000, seed=1, bounds=((-1,) * 3, (1,) * 3), resolution=24)
    >>> f = fit_freeform(pts, 2 * pts, steps=100, width=32, depth=2, seed=3, progress=False)
    >>> values = f(torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.9]], dtype=torch.float64))
    >>> values.dtype, bool(values[0] > 0 > values[1])  # the points' dtype; positive inside
    (torch.float64, True)
    """
    fn = "fit_freeform"
    pts, nrm, _ = _cloud(points, normals, fn)
    steps = check_option(steps, "steps", fn, "int", positive=True)
    batch = check_option(batch, "batch", fn, "int", positive=True)
    lr = check_option(lr, "lr", fn, positive=True)
    check_option(activation, "activation", fn, "choice", choices=ACTIVATIONS)
    normal_weight = check_option(normal_weight, "normal_weight", fn, minimum=0.0)
    eikonal_weight = check_option(eikonal_weight, "eikonal_weight", fn, minimum=0.0)
    seed = check_option(seed, "seed", fn, "int", minimum=0, maximum=MAX_SEED)
    threads = check_option(threads, "threads", fn, "int", positive=True, none=True)
    every = check_option(every, "every", fn, "int", positive=True)
    progress = check_option(progress, "progress", fn, "bool")
    if callback is not None and not callable(callback):
        raise TypeError(f"{fn}: callback must be callable or None, got {callback!r}")
    if stop is not None and not callable(getattr(stop, "is_set", None)):
        raise TypeError(f"{fn}: stop must have an is_set() method (a threading.Event) or be None, got {stop!r}")
    try:
        device = pts.device if device is None else torch.device(device)
    except (TypeError, RuntimeError) as err:
        raise ValueError(f"{fn}: device must name a torch device, got {device!r} ({err})") from None

    cloud = pts.detach().to(device="cpu", dtype=torch.float64)
    lo_c, hi_c = cloud.min(0).values, cloud.max(0).values
    if bounds is None:
        pad = PADDING * float((hi_c - lo_c).max())
        if not pad > 0:
            raise ValueError(f"{fn}: points must not all coincide (the cloud has no extent)")
        bounds = (tuple((lo_c - pad).tolist()), tuple((hi_c + pad).tolist()))
    lo, hi = check_bounds(bounds, 3)
    if (lo_c < torch.tensor(lo, dtype=torch.float64)).any() or (hi_c > torch.tensor(hi, dtype=torch.float64)).any():
        raise ValueError(
            f"{fn}: bounds {(lo, hi)} must contain every point (the cloud spans {lo_c.tolist()} to {hi_c.tolist()})"
        )
    settings = {
        "steps": steps, "batch": batch, "lr": lr, "normal_weight": normal_weight,
        "eikonal_weight": eikonal_weight, "seed": seed, "oriented": nrm is not None,
    }  # fmt: skip
    center = torch.tensor([(a + b) / 2 for a, b in zip(lo, hi)], dtype=torch.float64)
    half = max((b - a) / 2 for a, b in zip(lo, hi))
    z64 = (cloud - center) / half  # the network's scaled coordinates: the losses do not depend on the unit
    radius = float(z64.norm(dim=1).median())
    network = ImplicitNetwork(
        (lo, hi), width=width, depth=depth, activation=activation, beta=beta, fourier_features=fourier_features,
        fourier_scale=fourier_scale, seed=seed, dtype=dtype, init="sphere", radius=max(radius, 1e-3),
        device=device, fn=fn,
    )  # fmt: skip
    terms: dict[str, list[float]] = {"surface": [], "normal": [], "eikonal": []}
    if stop is not None and stop.is_set():
        return _finished(network, (lo, hi), settings, terms, stopped=True)

    sigma = torch.as_tensor(_local_scale(z64.numpy(), min(NEIGHBOURS, len(z64) - 1)))
    z = z64.to(device=device, dtype=dtype)
    sigma = sigma.to(device=device, dtype=dtype)[:, None]
    normals_t = None if nrm is None else nrm.detach().to(device=device, dtype=dtype)
    box_lo = torch.tensor([(a - c) / half for a, c in zip(lo, center.tolist())], dtype=dtype, device=device)
    box_hi = torch.tensor([(b - c) / half for b, c in zip(hi, center.tolist())], dtype=dtype, device=device)
    gen = torch.Generator(device=device).manual_seed(seed + 1)
    n_uniform = max(1, batch // UNIFORM_FRACTION)
    mlp = network.net
    optimizer = torch.optim.Adam(mlp.parameters(), lr=lr)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda k: cosine_lr(k, int(steps)))
    with intra_op_threads(threads), Progress(int(steps), "freeform", callback, every, stop, progress) as bar:
        for step in range(int(steps)):
            idx = torch.randint(len(z), (batch,), generator=gen, device=device)
            on = z[idx]
            near = on + sigma[idx] * torch.randn(on.shape, generator=gen, device=device, dtype=dtype)
            uniform = box_lo + (box_hi - box_lo) * torch.rand(n_uniform, 3, generator=gen, device=device, dtype=dtype)
            x = torch.cat([on, near, uniform]).requires_grad_(True)
            g = mlp(x).squeeze(-1)
            (dg,) = torch.autograd.grad(g.sum(), x, create_graph=True)
            surface = g[:batch].abs().mean()
            eikonal = ((dg[batch:].norm(dim=1) - 1.0) ** 2).mean()
            loss = surface + eikonal_weight * eikonal
            if normals_t is not None:
                normal = (dg[:batch] + normals_t[idx]).norm(dim=1).mean()  # outward n = -grad g on the surface
                loss = loss + normal_weight * normal
            value = training_step(network, optimizer, schedule, loss)
            step_terms = {"surface": float(surface.detach()), "eikonal": float(eikonal.detach())}
            if normals_t is not None:
                step_terms["normal"] = float(normal.detach())
            for k, v in step_terms.items():
                terms[k].append(v)
            if bar.update(step, value, **step_terms):
                return _finished(network, (lo, hi), settings, terms, stopped=True)
    return _finished(network, (lo, hi), settings, terms, stopped=False)


def _finished(network: ImplicitNetwork, bounds: Any, settings: dict, terms: dict, stopped: bool) -> FreeformModel:
    result = FreeformModel(network, bounds, settings)  # freezes the weights
    result.terms, result.stopped = terms, stopped
    return result
