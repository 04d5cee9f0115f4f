"""Four machined parts as parametric models, in millimetres: test pieces for fitting measured data.

Each is written with the exact distance functions of :mod:`pyfrep_core.sdf` (``f > 0`` inside,
``|grad f| = 1`` on the faces) joined by min/max, as a CAD program would build it, and declares
4 to 6 dimensions with a range around a nominal size.  Each part sits in its own frame, its main axis
along z, the origin at its centre or on a datum face.  ``TRUTH`` holds one set of dimensions inside the declared
ranges and away from their defaults (what a fit should recover); ``SIZE`` each part's largest
extent (mm), the scale of its noise.  :func:`scan` makes the synthetic measurement the tests, the
benchmark and the lessons fit: surface points in a random pose, noise and stray points.

- :func:`flanged_bushing`: a tube with a flange at one end (axisymmetric: its turn about z is free);
- :func:`hex_nut`: a hexagonal prism with a bore and the 30-degree chamfers of a nut on both faces;
- :func:`l_bracket`: two plates at a right angle, a hole through each;
- :func:`bearing_ring`: a torus flattened by two planes, a race groove turned in its bore
  (axisymmetric).

>>> import torch
>>> sorted(PARTS)
['bearing_ring', 'flanged_bushing', 'hex_nut', 'l_bracket']
>>> bool(flanged_bushing(torch.tensor([[11.0, 0.0, 20.0]]))[0] > 0)   # in the tube's wall
True
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np
import torch

from .. import sdf
from ..model import Param, model

__all__ = ["flanged_bushing", "hex_nut", "l_bracket", "bearing_ring", "PARTS", "TRUTH", "SIZE", "scan"]


def _slab(h: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """Distance-like field of ``|h| <= half`` (positive inside)."""
    return half - h.abs()


def _radius(x: torch.Tensor) -> torch.Tensor:
    # the parts have a bore along z, so rho = 0 lies outside the material; the floor keeps its gradient finite
    return torch.sqrt(x[:, 0] ** 2 + x[:, 1] ** 2 + 1e-12)


@model(
    bounds=((-35.0, -35.0, -5.0), (35.0, 35.0, 50.0)),
    bore=Param(8.0, 5.0, 10.0, label="bore radius (mm)"),
    outer=Param(12.0, 10.5, 15.0, label="tube outer radius (mm)"),
    flange=Param(22.0, 17.0, 28.0, label="flange radius (mm)"),
    flange_t=Param(5.0, 3.0, 8.0, label="flange thickness (mm)"),
    length=Param(36.0, 28.0, 44.0, label="overall length (mm)"),
)
def flanged_bushing(x, bore, outer, flange, flange_t, length):
    """A flanged bushing: a tube of ``outer`` radius and ``length`` along z from its datum, the
    flange's lower face at z = 0, a flange of radius ``flange`` and thickness ``flange_t``, a
    through ``bore``.  Each dimension moves one face (as a drawing dimensions a part from a datum).

    Examples
    --------
    >>> import torch
    >>> flanged_bushing(torch.tensor([[20.0, 0.0, 2.0], [20.0, 0.0, 20.0]])) > 0   # flange, beside the tube
    tensor([ True, False])
    """
    rho, z = _radius(x), x[:, 2]
    tube = torch.minimum(outer - rho, _slab(z - length / 2, length / 2))
    fl = torch.minimum(flange - rho, _slab(z - flange_t / 2, flange_t / 2))
    return sdf.difference(sdf.union(tube, fl), bore - rho)


@model(
    bounds=((-16.0, -16.0, -10.0), (16.0, 16.0, 10.0)),
    flats=Param(12.0, 9.0, 14.0, label="half across-flats (mm)"),
    thickness=Param(13.0, 9.0, 16.0, label="thickness (mm)"),
    bore=Param(6.0, 4.0, 8.0, label="bore radius (mm)"),
    chamfer=Param(12.8, 11.0, 15.0, label="chamfer circle radius on the faces (mm)"),
)
def hex_nut(x, flats, thickness, bore, chamfer):
    """A hexagon nut: a prism across ``2 flats`` (two faces normal to x), ``thickness`` along z,
    a ``bore``, and on both faces a 30-degree chamfer cone meeting the face on a circle of radius
    ``chamfer`` (between ``flats`` and the corner radius ``2 flats / sqrt 3``, it cuts the corners).

    Examples
    --------
    >>> import torch
    >>> hex_nut(torch.tensor([[10.0, 0.0, 0.0], [13.4, 0.0, 0.0]])) > 0
    tensor([ True, False])
    """
    hexagon = None
    for k in range(3):  # three pairs of flat faces, 60 degrees apart
        a = k * math.pi / 3
        slab = _slab(x[:, 0] * math.cos(a) + x[:, 1] * math.sin(a), flats)
        hexagon = slab if hexagon is None else torch.minimum(hexagon, slab)
    rho, z = _radius(x), x[:, 2]
    prism = torch.minimum(hexagon, _slab(z, thickness / 2))
    # the chamfer cone: rho <= chamfer + (thickness / 2 - |z|) cot(30 deg), as a distance to its side
    cot = math.sqrt(3.0)
    cone = (chamfer + (thickness / 2 - z.abs()) * cot - rho) / math.sqrt(1.0 + cot * cot)
    return sdf.difference(torch.minimum(prism, cone), bore - rho)


@model(
    bounds=((-5.0, -25.0, -5.0), (55.0, 25.0, 45.0)),
    length=Param(45.0, 35.0, 52.0, label="horizontal leg length (mm)"),
    height=Param(35.0, 28.0, 42.0, label="vertical leg height (mm)"),
    width=Param(30.0, 22.0, 40.0, label="width (mm)"),
    thick=Param(5.0, 3.0, 7.0, label="plate thickness (mm)"),
    hole=Param(4.0, 2.5, 6.0, label="hole radius (mm)"),
    offset=Param(25.0, 15.0, 28.0, label="hole centres' distance from the inner corner (mm)"),
)
def l_bracket(x, length, height, width, thick, hole, offset):
    """An L-bracket: a horizontal plate (``length`` along x) and a vertical one (``height`` along
    z), both ``width`` wide (along y) and ``thick``, meeting at the origin's edge; a hole of radius
    ``hole`` through each, on the middle line, ``offset`` from the inner corner.

    Examples
    --------
    >>> import torch
    >>> l_bracket(torch.tensor([[20.0, 0.0, 2.5], [28.0, 0.0, 2.5]])) > 0   # in the plate, in its hole
    tensor([ True, False])
    """
    px, py, pz = x[:, 0], x[:, 1], x[:, 2]
    side = _slab(py, width / 2)
    base = torch.minimum(torch.minimum(_slab(px - length / 2, length / 2), _slab(pz - thick / 2, thick / 2)), side)
    wall = torch.minimum(torch.minimum(_slab(px - thick / 2, thick / 2), _slab(pz - height / 2, height / 2)), side)
    solid = sdf.union(base, wall)
    hole_base = hole - torch.sqrt((px - thick - offset) ** 2 + py**2 + 1e-12)  # through the base, along z
    hole_wall = hole - torch.sqrt((pz - thick - offset) ** 2 + py**2 + 1e-12)  # through the wall, along x
    return sdf.difference(sdf.difference(solid, hole_base), hole_wall)


@model(
    bounds=((-35.0, -35.0, -8.0), (35.0, 35.0, 8.0)),
    R=Param(20.0, 16.0, 24.0, label="torus centre radius (mm)"),
    r=Param(7.0, 5.0, 9.0, label="torus tube radius (mm)"),
    half_height=Param(5.0, 3.5, 6.5, label="half height between the flats (mm)"),
    groove_R=Param(13.0, 10.0, 15.0, label="race groove centre radius (mm)"),
    groove_r=Param(3.0, 2.0, 4.5, label="race groove radius (mm)"),
)
def bearing_ring(x, R, r, half_height, groove_R, groove_r):
    """A bearing ring: the torus (``R``, ``r``) about z cut flat at ``|z| = half_height``, with a
    race groove (a torus of centre radius ``groove_R`` and radius ``groove_r``) turned in its bore.

    Examples
    --------
    >>> import torch
    >>> bearing_ring(torch.tensor([[20.0, 0.0, 0.0], [13.5, 0.0, 0.0]])) > 0   # in the ring, in the groove
    tensor([ True, False])
    """
    ring = torch.minimum(sdf.torus(x, R=R, r=r), _slab(x[:, 2], half_height))
    return sdf.difference(ring, sdf.torus(x, R=groove_R, r=groove_r))


PARTS = {m.__name__: m for m in (flanged_bushing, hex_nut, l_bracket, bearing_ring)}

TRUTH = {
    "flanged_bushing": {"bore": 7.3, "outer": 12.6, "flange": 20.5, "flange_t": 4.2, "length": 33.0},
    "hex_nut": {"flats": 11.2, "thickness": 11.5, "bore": 5.4, "chamfer": 12.0},
    "l_bracket": {"length": 48.0, "height": 32.0, "width": 27.0, "thick": 4.2, "hole": 3.3, "offset": 22.0},
    "bearing_ring": {"R": 21.0, "r": 6.4, "half_height": 4.6, "groove_R": 12.5, "groove_r": 3.4},
}

SIZE = {"flanged_bushing": 41.0, "hex_nut": 25.9, "l_bracket": 48.0, "bearing_ring": 54.8}


@functools.lru_cache(maxsize=16)
def _surface(name: str, n: int, seed: int) -> np.ndarray:
    from ..sampling import sample_surface

    points = sample_surface(PARTS[name], n, params=TRUTH[name], seed=seed, resolution=96)
    points.flags.writeable = False  # shared by the calls that hit the cache
    return points


def scan(
    name: str, n: int = 5000, noise: float = 1e-3, outliers: float = 0.05, seed: int = 0, noise_seed: int | None = None
) -> dict[str, Any]:
    """A synthetic scan of part ``name`` at its ``TRUTH``: what a measured cloud looks like.

    ``n`` points on the true surface (area-uniform, exact to rounding), moved by a random rigid
    pose (a uniform rotation, a translation within 50 mm), Gaussian noise of ``noise`` times the
    part's ``SIZE`` on each coordinate, then stray points (a fraction ``outliers`` of the cloud)
    uniform in the noisy cloud's bounding box, after the surface points.

    Parameters
    ----------
    name : one of ``PARTS``.
    n : surface points.
    noise : noise standard deviation as a fraction of the part's size.
    outliers : fraction of the returned points that are stray (0 <= outliers < 1).
    seed : seeds the surface sample, the pose, the noise and the stray points.
    noise_seed : another noise draw on the same surface points and pose (refits); default ``seed``.

    Returns
    -------
    dict: ``points`` (M, 3) float64 mm; ``outlier`` (M,) bool; ``surface`` (n, 3) the posed points
    before noise; ``sigma`` the noise (mm); ``pose`` the truth's ``tx, ty, tz, rx, ry, rz``
    (:func:`pyfrep_core.pose.posed`'s parameters); ``rotation`` (3, 3); ``truth`` the dimensions.

    Examples
    --------
    >>> s = scan("hex_nut", n=200, seed=1)
    >>> s["points"].shape, int(s["outlier"].sum()), round(s["sigma"], 4)
    ((211, 3), 11, 0.0259)
    """
    from scipy.spatial.transform import Rotation

    if name not in PARTS:
        raise ValueError(f"scan: name must be one of {', '.join(sorted(PARTS))}, got {name!r}")
    if not 0.0 <= outliers < 1.0:
        raise ValueError(f"scan: outliers must be in [0, 1), got {outliers!r}")
    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    t = rng.uniform(-50.0, 50.0, 3)
    sigma = noise * SIZE[name]
    surface = _surface(name, n, seed) @ rotation.T + t
    noise_rng = np.random.default_rng([seed, noise_seed]) if noise_seed is not None else rng
    noisy = surface + noise_rng.normal(0.0, sigma, surface.shape)
    n_out = round(outliers / (1.0 - outliers) * n)
    stray = rng.uniform(noisy.min(0), noisy.max(0), (n_out, 3))
    return {
        "points": np.vstack([noisy, stray]),
        "outlier": np.r_[np.zeros(n, bool), np.ones(n_out, bool)],
        "surface": surface,
        "sigma": sigma,
        "pose": dict(zip(("tx", "ty", "tz", "rx", "ry", "rz"), [*t, *Rotation.from_matrix(rotation).as_rotvec()])),
        "rotation": rotation,
        "truth": dict(TRUTH[name]),
    }
