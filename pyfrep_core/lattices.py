"""Triply periodic minimal surfaces (TPMS) and spinodoids: fields for microstructures (paper section 3).

A TPMS field is a trigonometric polynomial of the scaled coordinates

    X = 2 pi alpha x,   Y = 2 pi beta y,   Z = 2 pi gamma z,

so with the default frequencies alpha = beta = gamma = 1 the field has unit period along each
axis (period 1/alpha along x, ...).  The paper's Schwarz D example writes sin(x) ..., which is
``SchwarzD(x, alpha=1/(2 pi), ...)``.  Every TPMS here takes an iso-level offset ``c``
(default 0) added to the field: ``f = T(X, Y, Z) + c``; f >= 0 is the solid (HyperFun
convention), so a larger ``c`` gives a larger volume fraction.  A TPMS is unbounded: clip it
with a solid (``intersection(block(x, ...), gyroid(x))``) before meshing or printing.

Frequencies and ``c`` may be floats or tensors (with ``requires_grad`` for fitting); a (B, 1)
tensor gives (B, N) values for B parameter sets at once.
"""

from __future__ import annotations

import math

import torch

from ._array import check_memory, check_param, check_points, frep, param_array, shown
from .operations import difference

Scalar = float | torch.Tensor

__all__ = [
    "gyroid",
    "SchwarzP",
    "SchwarzD",
    "lidinoid",
    "gyroidSheet",
    "spinodoid",
    "spinodoid_directions",
]

TWO_PI = 2.0 * math.pi

# Peak bytes per wave of a spinodoid, measured (peak RSS, float64, 1e6 to 8e6 waves, 1 to 1000
# points): 310 to 380.  Rejection sampling draws 4 N + 64 directions a round (24 bytes each, and
# their norms, absolute values and mask), then keeps N directions and phases; evaluation holds
# chunk x N temporaries of at most max(2^22, N) entries.  Rounded up to 400.
SPINODOID_BYTES_PER_WAVE = 400


def _scaled(
    x: torch.Tensor, alpha: Scalar, beta: Scalar, gamma: Scalar, fn: str, **offsets: Scalar
) -> tuple[torch.Tensor, ...]:
    check_points(x, empty=True)  # no points give no values
    # a zero frequency has no period (the field is constant along that axis); a negative one mirrors
    for name, value in (("alpha", alpha), ("beta", beta), ("gamma", gamma)):
        check_param(value, name, fn, nonzero=True)
    for name, value in offsets.items():
        check_param(value, name, fn)
    return TWO_PI * alpha * x[..., 0], TWO_PI * beta * x[..., 1], TWO_PI * gamma * x[..., 2]


@frep
def gyroid(
    x: torch.Tensor, alpha: Scalar = 1.0, beta: Scalar = 1.0, gamma: Scalar = 1.0, c: Scalar = 0.0
) -> torch.Tensor:
    """Schoen's gyroid: ``c - (sin X cos Y + sin Y cos Z + sin Z cos X)``.

    Parameters
    ----------
    x : (..., 3) points, torch tensor or numpy array.
    alpha, beta, gamma : frequencies along x, y, z (periods 1/alpha, 1/beta, 1/gamma).
    c : iso-level offset; the solid is ``sin X cos Y + ... <= c``.  Values lie in [-1.5, 1.5].

    Returns
    -------
    (...) field values, same dtype and device as ``x``.

    Examples
    --------
    >>> import torch
    >>> gyroid(torch.tensor([[0.0, 0.0, 0.0], [0.125, 0.125, 0.125]], dtype=torch.float64))
    tensor([ 0.0000, -1.5000], dtype=torch.float64)
    """
    X, Y, Z = _scaled(x, alpha, beta, gamma, "gyroid", c=c)
    return c - (torch.sin(X) * torch.cos(Y) + torch.sin(Y) * torch.cos(Z) + torch.sin(Z) * torch.cos(X))


@frep
def SchwarzP(
    x: torch.Tensor, alpha: Scalar = 1.0, beta: Scalar = 1.0, gamma: Scalar = 1.0, c: Scalar = 0.0
) -> torch.Tensor:
    """Schwarz P ("primitive") surface: ``cos X + cos Y + cos Z + c``.

    Parameters
    ----------
    x : (..., 3) points.
    alpha, beta, gamma : frequencies along x, y, z.
    c : iso-level offset (the field lies in [-3, 3]).

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> SchwarzP(torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.5, 0.5]]))
    tensor([ 3., -3.])
    """
    X, Y, Z = _scaled(x, alpha, beta, gamma, "SchwarzP", c=c)
    return torch.cos(X) + torch.cos(Y) + torch.cos(Z) + c


@frep
def SchwarzD(
    x: torch.Tensor, alpha: Scalar = 1.0, beta: Scalar = 1.0, gamma: Scalar = 1.0, c: Scalar = 0.0
) -> torch.Tensor:
    """Schwarz D ("diamond") surface, the four-term formula of the paper (section 4.1).

    ``sin X sin Y sin Z + sin X cos Y cos Z + cos X sin Y cos Z + cos X cos Y sin Z + c``.
    The paper's example uses sin(x) directly: ``SchwarzD(x, 1/(2 pi), 1/(2 pi), 1/(2 pi))``.

    Parameters
    ----------
    x : (..., 3) points.
    alpha, beta, gamma : frequencies along x, y, z.
    c : iso-level offset.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> SchwarzD(torch.tensor([[0.0, 0.0, 0.0], [0.25, 0.25, 0.25]]))
    tensor([0., 1.])
    """
    X, Y, Z = _scaled(x, alpha, beta, gamma, "SchwarzD", c=c)
    sx, sy, sz = torch.sin(X), torch.sin(Y), torch.sin(Z)
    cx, cy, cz = torch.cos(X), torch.cos(Y), torch.cos(Z)
    return sx * sy * sz + sx * cy * cz + cx * sy * cz + cx * cy * sz + c


@frep
def lidinoid(
    x: torch.Tensor, alpha: Scalar = 1.0, beta: Scalar = 1.0, gamma: Scalar = 1.0, c: Scalar = 0.0
) -> torch.Tensor:
    """Lidinoid (Lidin & Larsson's trigonometric approximation) plus the offset ``c``.

    ``0.5 (sin 2X cos Y sin Z + sin 2Y cos Z sin X + sin 2Z cos X sin Y)
    - 0.5 (cos 2X cos 2Y + cos 2Y cos 2Z + cos 2Z cos 2X) + 0.15 + c``.
    Its mean over a period is 0.15 + c.

    Parameters
    ----------
    x : (..., 3) points.
    alpha, beta, gamma : frequencies along x, y, z.
    c : iso-level offset added to the standard constant 0.15.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> lidinoid(torch.tensor([[0.0, 0.0, 0.0]]))
    tensor([-1.3500])
    """
    X, Y, Z = _scaled(x, alpha, beta, gamma, "lidinoid", c=c)
    sx, sy, sz = torch.sin(X), torch.sin(Y), torch.sin(Z)
    cx, cy, cz = torch.cos(X), torch.cos(Y), torch.cos(Z)
    c2x, c2y, c2z = torch.cos(2 * X), torch.cos(2 * Y), torch.cos(2 * Z)
    odd = torch.sin(2 * X) * cy * sz + torch.sin(2 * Y) * cz * sx + torch.sin(2 * Z) * cx * sy
    even = c2x * c2y + c2y * c2z + c2z * c2x
    return 0.5 * odd - 0.5 * even + 0.15 + c


@frep
def gyroidSheet(
    x: torch.Tensor,
    alpha: Scalar = 1.0,
    beta: Scalar = 1.0,
    gamma: Scalar = 1.0,
    c1: Scalar = 0.5,
    c2: Scalar = -0.5,
) -> torch.Tensor:
    """Gyroid sheet: the solid between the two level sets ``G = c2`` and ``G = c1``.

    With ``G = sin X cos Y + sin Y cos Z + sin Z cos X`` the sheet is ``c2 <= G <= c1``
    (f >= 0 there), built as the R-difference ``gyroid(c=c1) \\ gyroid(c=c2)`` as in the
    reference code.  Wall thickness grows with ``c1 - c2``; ``c1 <= c2`` gives an empty set.

    Parameters
    ----------
    x : (..., 3) points.
    alpha, beta, gamma : frequencies along x, y, z.
    c1, c2 : upper and lower levels of G.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> pts = torch.tensor([[0.0, 0.0, 0.0], [0.125, 0.125, 0.125]])
    >>> gyroidSheet(pts, c1=0.8, c2=-0.8) > 0
    tensor([ True, False])
    """
    _scaled(x, alpha, beta, gamma, "gyroidSheet", c1=c1, c2=c2)
    return difference(gyroid(x, alpha, beta, gamma, c1), gyroid(x, alpha, beta, gamma, c2))


def _check_numwaves(numwaves: int, fn: str) -> None:
    """ValueError unless ``numwaves`` is a positive integer whose waves fit in the available memory."""
    if isinstance(numwaves, bool) or not isinstance(numwaves, int | float) or int(numwaves) != numwaves or numwaves < 1:
        raise ValueError(f"{fn}: numwaves must be a positive integer, got {numwaves!r}")
    check_memory(
        SPINODOID_BYTES_PER_WAVE * float(numwaves) + (256 << 20),
        fn,
        f"numwaves={numwaves!r}",
        "use fewer waves (a few thousand give a Gaussian random field)",
    )


def spinodoid_directions(
    numwaves: int,
    theta: tuple[float, float, float] = (math.pi / 2, math.pi / 2, math.pi / 2),
    seed: int = 0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Random wave directions in the cone set and random phases of a spinodoid (float64, CPU).

    Directions ``n`` are uniform on the unit sphere, kept when ``|n . e_k| >= cos(theta_k)`` for
    at least one axis k (Kumar et al. 2020): theta_k = pi/2 allows every direction (isotropic),
    theta_k = 0 forbids waves around axis k, small angles give a columnar/lamellar structure.

    Parameters
    ----------
    numwaves : number of waves N (> 0).
    theta : cone half-angles (radians, in [0, pi/2]) around x, y, z.
    seed : seed of the torch generator; the same seed gives the same directions and phases.

    Returns
    -------
    directions : (N, 3) unit vectors.
    phases : (N,) phases in [0, 2 pi).

    Examples
    --------
    >>> n, ph = spinodoid_directions(4, seed=1)
    >>> n.shape, ph.shape, bool(((n * n).sum(-1) - 1).abs().max() < 1e-12)
    (torch.Size([4, 3]), torch.Size([4]), True)
    """
    _check_numwaves(numwaves, "spinodoid_directions")
    cones = torch.as_tensor(theta, dtype=torch.float64).reshape(-1)
    if cones.numel() != 3 or not bool(((cones >= 0) & (cones <= math.pi / 2 + 1e-12)).all()):
        raise ValueError(f"theta must be three cone angles in [0, pi/2] (radians), got {theta!r}")
    if not bool((cones > 0).any()):
        raise ValueError(f"theta must allow at least one cone (some angle > 0), got {theta!r}")
    cos_cone = torch.cos(cones)
    gen = torch.Generator().manual_seed(int(seed))
    kept: list[torch.Tensor] = []
    count = 0
    # Rejection sampling: the accepted fraction is at least 3 (1 - cos(theta_max)) / 3 > 0;
    # a bounded number of rounds guards against vanishingly small cones.
    for _ in range(1000):
        n = torch.randn(4 * int(numwaves) + 64, 3, generator=gen, dtype=torch.float64)
        n = n / n.norm(dim=-1, keepdim=True)
        ok = (n.abs() >= cos_cone).any(dim=-1)
        kept.append(n[ok])
        count += int(ok.sum())
        if count >= numwaves:
            break
    else:
        raise ValueError(f"theta={theta!r} leaves too small a set of directions to sample")
    directions = torch.cat(kept)[: int(numwaves)]
    phases = TWO_PI * torch.rand(int(numwaves), generator=gen, dtype=torch.float64)
    return directions, phases


@frep
def spinodoid(
    x: torch.Tensor,
    wavenumber: Scalar = 10.0 * math.pi,
    numwaves: int = 1000,
    density: Scalar = 0.5,
    theta: tuple[float, float, float] = (math.pi / 2, math.pi / 2, math.pi / 2),
    seed: int = 0,
) -> torch.Tensor:
    """Spinodoid: a thresholded Gaussian random field of random cosine waves (Kumar et al. 2020).

    ``phi(x) = sqrt(2 / N) sum_i cos(wavenumber n_i . x + phase_i)`` with N waves whose
    directions ``n_i`` are drawn in the cone set ``theta`` (see :func:`spinodoid_directions`);
    phi is close to a standard normal variable, so with the level
    ``phi_0 = sqrt(2) erfinv(2 density - 1)`` the solid ``f = phi_0 - phi >= 0`` fills about
    ``density`` of the volume.  Deterministic for a given ``seed``; not periodic.

    Parameters
    ----------
    x : (..., 3) points.
    wavenumber : beta, radians per length unit (feature size ~ 2 pi / wavenumber); a float or
        a 0-d tensor (batched (B, 1) values are for ``density`` only).
    numwaves : N, number of waves (evaluated in chunks of points: temporaries of ~4M entries).
        About 400 bytes a wave; more than the available memory raises
        :class:`~pyfrep_core._array.MemoryBudgetError` (a ValueError) before allocating.
    density : target solid volume fraction in (0, 1); a tensor is differentiable.
    theta : cone half-angles (radians) around x, y, z; (pi/2,)*3 is isotropic.
    seed : random seed of the directions and phases.

    Returns
    -------
    (...) field values.

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(20000, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    >>> f = spinodoid(x, wavenumber=20.0, numwaves=200, density=0.3, seed=2)
    >>> bool(abs((f >= 0).double().mean() - 0.3) < 0.1)
    True
    """
    check_points(x, empty=True)  # no points give no values
    _check_numwaves(numwaves, "spinodoid")
    check_param(wavenumber, "wavenumber", "spinodoid", positive=True)
    check_param(density, "density", "spinodoid", positive=True)
    rho = param_array(density, "density", "spinodoid")
    if rho is not None and not (rho < 1).all():  # the level erfinv(2 density - 1) is +-inf at 0 and 1
        raise ValueError(f"spinodoid: density must be below 1 (a volume fraction), got {shown(density)!r}")
    directions, phases = spinodoid_directions(numwaves, theta, seed)
    directions = directions.to(device=x.device, dtype=x.dtype)
    phases = phases.to(device=x.device, dtype=x.dtype)
    rho = torch.as_tensor(density, dtype=x.dtype, device=x.device)
    level = math.sqrt(2.0) * torch.erfinv(2.0 * rho - 1.0)
    flat = x.reshape(-1, 3)
    chunk = max(1, (1 << 22) // int(numwaves))
    phi = torch.cat(
        [
            torch.cos(wavenumber * (part @ directions.T) + phases).sum(-1)
            for part in torch.split(flat, chunk)  # chunks of points bound the (n, N) memory
        ]
    ) * math.sqrt(2.0 / numwaves)
    return level - phi.reshape(x.shape[:-1])
