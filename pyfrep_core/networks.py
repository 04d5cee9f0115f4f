"""Implicit networks: a small MLP g(x; theta) on coordinates scaled to [-1, 1], positive inside.

The one network class of the library, shared by the neural redistancing of section 5.3
(:class:`pyfrep_core.redistancing.RedistancedSDF`, which wraps it as ``sign(f) |g|``) and the
free-form fit (:func:`pyfrep_core.freeform.fit_freeform`, which uses g itself as the model).

``g(x) = s * mlp((x - c) / s)`` with c the centre of the box and s its largest half-extent:
the scaling is isotropic, so ``|grad g| = |grad mlp|`` and an eikonal loss means the same in
the box's units as in [-1, 1].  Optional random Fourier features of the scaled input
(Tancik et al. 2020) go before the first layer.

Two initialisations:

* ``"he"``: He-normal weights, zero biases (what redistancing trains from);
* ``"sphere"``: the geometric initialisation of Atzmon & Lipman (SAL, 2020), used by IGR
  (Gropp et al. 2020): hidden weights N(0, 2 / width), zero biases, last weights
  N(sqrt(pi / width), 1e-4^2) and last bias -radius make a wide ReLU-like (softplus, large
  beta) network start close to the signed distance of a sphere, ``|z| - radius``; here the
  sign is flipped (``radius - |z|``, positive inside, the library's convention).  Near z = 0
  the softplus' offset log(2) / beta per unit makes the start lower than the cone's tip; the
  zero set, where training starts, is the sphere.  The Fourier
  columns of the first layer start at 0, so the features leave that sphere alone until
  training uses them.  The start is a sphere up to the init's noise (about 0.1 s at width 256).

>>> import torch
>>> g = ImplicitNetwork(((-2.0,) * 3, (2.0,) * 3), width=256, depth=2, activation="softplus", init="sphere", radius=0.5)
>>> u = torch.nn.functional.normalize(torch.randn(1000, 3, generator=torch.Generator().manual_seed(0)), dim=1)
>>> [round(float(g.signed_network(r * u).mean().detach()), 1) for r in (0.5, 1.0, 2.0)]  # about 2 (0.5 - r / 2)
[0.4, -0.0, -0.9]
"""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import nn

from ._array import check_option
from .model import check_bounds

__all__ = ["ImplicitNetwork", "ACTIVATIONS", "INITS", "cosine_lr", "training_step"]

ACTIVATIONS = ("softplus", "silu", "tanh", "relu", "leaky_relu")
INITS = ("he", "sphere")
DTYPES = (torch.float32, torch.float64)
MAX_SEED = 2**63 - 2  # torch.Generator takes 64-bit seeds; training loops use seed + 1


class FourierFeatures(nn.Module):
    """x -> (x, sin(xB), cos(xB)) with a fixed random B (3, m) of scale sigma."""

    def __init__(self, m: int, sigma: float, generator: torch.Generator):
        super().__init__()
        self.register_buffer("B", torch.randn(3, m, generator=generator) * sigma)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = x @ self.B
        return torch.cat([x, torch.sin(z), torch.cos(z)], dim=-1)


def make_activation(name: str, beta: float) -> nn.Module:
    """The activation module of that name ("leaky_relu": slope 0.1; "softplus": sharpness ``beta``)."""
    if name == "relu":
        return nn.ReLU()
    if name == "leaky_relu":
        return nn.LeakyReLU(0.1)
    if name == "softplus":
        return nn.Softplus(beta=beta)
    if name == "silu":
        return nn.SiLU()
    return nn.Tanh()


class ImplicitNetwork(nn.Module):
    """g(x; theta) = s mlp((x - c) / s): an MLP on 3-D points, scaled isotropically to the box.

    Parameters
    ----------
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)): c is its centre, s its largest half-extent.
    width, depth : hidden units per layer and hidden layers.
    activation : "silu", "softplus", "tanh", "relu" or "leaky_relu" (slope 0.1).
    last_activation : activation of the last hidden layer (None: ``activation``).
    beta : sharpness of the softplus.
    fourier_features : random Fourier features of the scaled input (0: none), of scale ``fourier_scale``.
    seed : seeds the weights and the Fourier matrix.
    dtype : float32 or float64.
    init : "he" or "sphere" (geometric: g starts near ``s (radius - |z|)``, see the module docstring).
    radius : the sphere's radius in scaled units (fractions of s), for ``init="sphere"``.
    device : where the weights live (default: the CPU).

    Attributes
    ----------
    config : dict that rebuilds the architecture (bounds, width, depth, activation,
        last_activation, beta, fourier_features, fourier_scale, seed, dtype); the
        initialisation is not part of it (loaded weights replace it).
    history : list of float, the training loss per step.
    """

    def __init__(
        self,
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
        init: str = "he",
        radius: float = 0.5,
        device: Any = None,
        fn: str = "ImplicitNetwork",
    ):
        super().__init__()
        lo, hi = check_bounds(bounds, 3)
        width = check_option(width, "width", fn, "int", positive=True)
        depth = check_option(depth, "depth", fn, "int", positive=True)
        activation = check_option(activation, "activation", fn, "choice", choices=ACTIVATIONS)
        last_activation = check_option(last_activation, "last_activation", fn, "choice", choices=ACTIVATIONS, none=True)
        beta = check_option(beta, "beta", fn, positive=True)
        fourier_features = check_option(fourier_features, "fourier_features", fn, "int", minimum=0)
        fourier_scale = check_option(fourier_scale, "fourier_scale", fn, positive=True)
        seed = check_option(seed, "seed", fn, "int", minimum=0, maximum=MAX_SEED)
        dtype = check_option(dtype, "dtype", fn, "choice", choices=DTYPES)
        init = check_option(init, "init", fn, "choice", choices=INITS)
        radius = check_option(radius, "radius", fn, positive=True)
        self.config = {
            "bounds": [list(lo), list(hi)],
            "width": int(width),
            "depth": int(depth),
            "activation": activation,
            "last_activation": last_activation,
            "beta": float(beta),
            "fourier_features": int(fourier_features),
            "fourier_scale": float(fourier_scale),
            "seed": int(seed),
            "dtype": str(dtype).removeprefix("torch."),
        }
        self.history: list[float] = []
        gen = torch.Generator().manual_seed(int(seed))
        center = [(a + b) / 2 for a, b in zip(lo, hi)]
        half = max((b - a) / 2 for a, b in zip(lo, hi))
        self.register_buffer("center", torch.tensor(center, dtype=dtype))
        self.register_buffer("scale", torch.tensor(half, dtype=dtype))
        layers: list[nn.Module] = []
        d_in = 3
        if fourier_features:
            layers.append(FourierFeatures(int(fourier_features), float(fourier_scale), gen))
            d_in = 3 + 2 * int(fourier_features)
        for i in range(int(depth)):
            lin = nn.Linear(d_in, int(width))
            _init_hidden(lin, gen, init)
            if init == "sphere" and i == 0:
                with torch.no_grad():
                    lin.weight[:, 3:] = 0.0  # Fourier columns: the start stays a sphere
            name = last_activation if last_activation is not None and i == int(depth) - 1 else activation
            layers += [lin, make_activation(name, float(beta))]
            d_in = int(width)
        last = nn.Linear(d_in, 1)
        if init == "sphere":
            with torch.no_grad():
                # SAL's geometric init, sign flipped: radius - |z| (positive inside)
                last.weight.normal_(-math.sqrt(math.pi / d_in), 1e-4, generator=gen)
                last.bias.fill_(float(radius))
        else:
            _init_hidden(last, gen, "he")
        layers.append(last)
        self.net = nn.Sequential(*layers).to(dtype)
        if device is not None:
            self.to(device)

    @property
    def dtype(self) -> torch.dtype:
        return self.scale.dtype

    @property
    def device(self) -> torch.device:
        return self.scale.device

    def signed_network(self, x: torch.Tensor) -> torch.Tensor:
        """g(x; theta) (...,) for points (..., 3), in the network's dtype and on its device."""
        z = (x.to(device=self.device, dtype=self.dtype) - self.center) / self.scale
        return self.net(z).squeeze(-1) * self.scale

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """g(x; theta): see :meth:`signed_network`."""
        return self.signed_network(x)


def _init_hidden(lin: nn.Linear, gen: torch.Generator, init: str) -> None:
    """He-normal weights N(0, 2 / fan_in) ("he") or SAL's N(0, 2 / fan_out) ("sphere"); zero bias."""
    fan = lin.in_features if init == "he" else lin.out_features
    with torch.no_grad():
        lin.weight.normal_(0.0, math.sqrt(2.0 / fan), generator=gen)
        lin.bias.zero_()


def cosine_lr(k: int, steps: int, warmup: int = 20) -> float:
    """Learning-rate factor at step k: linear warm-up, then cosine decay to 1 % of the peak.

    >>> round(cosine_lr(0, 100), 3), cosine_lr(19, 100), round(cosine_lr(100, 100), 3)
    (0.05, 1.0, 0.01)
    """
    if k < warmup:
        return (k + 1) / warmup
    t = min(1.0, (k - warmup) / max(1, steps - warmup))
    return 0.01 + 0.99 * 0.5 * (1.0 + math.cos(math.pi * t))


def training_step(
    network: ImplicitNetwork, optimizer: Any, schedule: Any, loss: torch.Tensor, clip_grad: float | None = None
) -> float:
    """One optimizer step on ``loss``: backward, optional gradient clipping, step, schedule; the loss
    (a float) is appended to ``network.history`` and returned.

    >>> net = ImplicitNetwork(((-1.0,) * 3, (1.0,) * 3), width=8, depth=1)
    >>> opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    >>> sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda k: 1.0)
    >>> value = training_step(net, opt, sched, net(torch.zeros(4, 3)).pow(2).mean())
    >>> net.history == [value]
    True
    """
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if clip_grad is not None:
        # a few steps with a large gradient otherwise make Adam diverge at a high learning rate
        torch.nn.utils.clip_grad_norm_(network.parameters(), clip_grad)
    optimizer.step()
    schedule.step()
    value = float(loss.detach())
    network.history.append(value)
    return value
