"""Fields on grids for ParaView: f (and derived fields) sampled on a regular grid, written as VTK image data.

:func:`save_field` samples a model on the grid points of a box and writes a ``.vti`` file
(VTK XML image data, through pyvista) with one point array per field: ``f`` itself and, when
asked, ``grad_norm`` (``|grad f|``, from one backward pass with f), a normalization of
:mod:`pyfrep_core.normalization` (``omega1``, ``omega2``, ``delta1`` ...) or any other function of
points, such as a redistanced network (:func:`pyfrep_core.redistance`).  ParaView opens it
directly (contours, slices, volume rendering).

The grid is evaluated in chunks of points within the memory budget of
:mod:`pyfrep_core.evaluate`, never as one (N, d) block.  With ``band=w`` only what is near the
surface is evaluated: the interval bounds of :mod:`pyfrep_core.interval` are computed for every
grid cell, and only the points of cells whose bounds meet [-w, w] are evaluated; every other
point is proved to have |f| > w (its cells' bounds say so), and gets ``f = +w`` or ``-w`` there
(the sign proved, i.e. f clamped to [-w, w], which is exact for contours at levels inside
(-w, w)) and NaN in the other arrays; the point array ``evaluated`` (1/0) says which points were
evaluated.  A model the bounds cannot handle (:class:`pyfrep_core.interval.IntervalUnsupported`)
is evaluated densely, with a warning naming the operation.

>>> import os, tempfile
>>> import pyvista as pv
>>> from pyfrep_core import sphere
>>> path = os.path.join(tempfile.mkdtemp(), "ball.vti")
>>> grid = save_field(path, lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 13, extra=("grad_norm",))
>>> back = pv.read(path)
>>> back.dimensions, sorted(back.point_data.keys())
((13, 13, 13), ['f', 'grad_norm'])
"""

from __future__ import annotations

import itertools
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ._array import check_option
from .diff import value_and_grad
from .evaluate import budget_points, evaluate, name_of
from .interval import IntervalUnsupported
from .interval import bounds as interval_bounds
from .model import Model, check_bounds
from .normalization import _KINDS, normalized
from .progress import Progress

__all__ = ["save_field"]

DERIVED_WORK = 4  # a chunk with derivatives (grad, normalizations) costs about this many plain calls


def _resolution(resolution: Any, dim: int) -> tuple[int, ...]:
    values = (resolution,) * dim if isinstance(resolution, int | np.integer) else tuple(resolution)
    if len(values) != dim or not all(isinstance(v, int | np.integer) and not isinstance(v, bool) for v in values):
        raise ValueError(f"save_field: resolution must be an int or {dim} ints, got {resolution!r}")
    if min(values) < 2:
        raise ValueError(f"save_field: resolution must be at least 2 samples per axis, got {resolution!r}")
    return tuple(int(v) for v in values)


def _extras(extra: Any, f: Callable) -> list[tuple[str, Callable | str]]:
    """(name, how) for every extra field: "grad_norm", a normalization kind, or a function of points."""
    items = list(extra.items()) if isinstance(extra, Mapping) else list(extra)
    out: list[tuple[str, Callable | str]] = []
    for item in items:
        if isinstance(item, str):
            kind = item.lower()
            if kind == "grad_norm":
                out.append(("grad_norm", "grad_norm"))
            elif _KINDS.match(kind):
                out.append((kind.replace("_", ""), normalized(f, kind)))
            else:
                raise ValueError(
                    f"save_field: extra field {item!r} is not 'grad_norm', a normalization ('omega1', 'omega2', "
                    "'delta1', ...) or a (name, function) pair"
                )
        elif isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], str) and callable(item[1]):
            out.append(item)
        else:
            raise TypeError(f"save_field: extra must hold names or (name, function) pairs, got {item!r}")
    names = ["f", *(n for n, _ in out)]
    if len(set(names)) != len(names) or "evaluated" in names:
        raise ValueError(f"save_field: field names must be distinct and not 'f' or 'evaluated', got {names}")
    return out


def _coordinates(index: torch.Tensor, axes: Sequence[torch.Tensor], shape: tuple[int, ...]) -> torch.Tensor:
    """Points (n, d) of flat grid indices; ``shape`` is the grid in (..., y, x) order (x fastest, as VTK)."""
    multi = torch.unravel_index(index, shape)[::-1]  # (x, y, ...) indices
    return torch.stack([axes[i][k] for i, k in enumerate(multi)], dim=-1)


def _band_points(
    g: Callable, axes: Sequence[torch.Tensor], shape: tuple[int, ...], width: float, chunk: int, bar: Progress
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Grid points to evaluate (bool, ``shape``) and, elsewhere, the proved sign; None when stopped."""
    cells = tuple(n - 1 for n in shape)
    total = int(np.prod(cells))
    near = torch.zeros(total, dtype=torch.bool)
    positive = torch.zeros(total, dtype=torch.bool)
    for step, start in enumerate(range(0, total, chunk)):
        index = torch.arange(start, min(total, start + chunk))
        multi = torch.unravel_index(index, cells)[::-1]
        lo = torch.stack([axes[i][k] for i, k in enumerate(multi)], dim=-1)
        hi = torch.stack([axes[i][k + 1] for i, k in enumerate(multi)], dim=-1)
        flo, fhi = interval_bounds(g, lo, hi)
        near[index] = (flo <= width) & (fhi >= -width)
        positive[index] = flo > width
        if bar.update(step):
            return None
    near, positive = near.reshape(cells), positive.reshape(cells)
    wanted = torch.zeros(shape, dtype=torch.bool)
    sign = torch.zeros(shape, dtype=torch.bool)
    for corner in itertools.product((0, 1), repeat=len(shape)):  # a point belongs to up to 2^d cells
        at = tuple(slice(c, c + n) for c, n in zip(corner, cells, strict=True))
        wanted[at] |= near
        sign[at] |= positive
    return wanted, sign


def save_field(
    path: str | os.PathLike,
    f: Callable,
    bounds: Any,
    resolution: int | Sequence[int],
    extra: Sequence[str | tuple[str, Callable]] | Mapping[str, Callable] = (),
    band: float | None = None,
    dtype: torch.dtype = torch.float64,
    callback: Callable | None = None,
    stop: Any = None,
    progress: bool = False,
    **params: Any,
) -> Any:
    """Sample ``f`` on a grid over ``bounds`` and write it as VTK image data (``.vti``) for ParaView.

    Parameters
    ----------
    path : output file, ending in ``.vti``.
    f : a model or a defining function ``f(x, **params)``, points (N, d) -> values (N,), d = 2 or 3.
    bounds : ((xmin, ymin[, zmin]), (xmax, ymax[, zmax])): the box, in model units; the grid's corner
        points lie on its corners.
    resolution : samples per axis (an int, or one per axis), at least 2.  Spacing
        ``(max - min) / (resolution - 1)``.
    extra : further point arrays: ``"grad_norm"`` (``|grad f|``), a normalization kind (``"omega1"``,
        ``"omega2"``, ``"delta1"``: :func:`pyfrep_core.normalized`), or ``(name, function)`` pairs
        (a mapping ``name -> function``) of functions of points (N, d) -> (N,), e.g. a
        :class:`pyfrep_core.RedistancedSDF`.
    band : w > 0: evaluate only near the surface, in the cells whose interval bounds meet [-w, w];
        other points get ``f = +-w`` (the proved sign) and NaN in the extra arrays (module
        docstring).  None: every point.
    dtype : float64 (default) or float32: the points' dtype, and the arrays'.
    callback, stop, progress : progress events per chunk (:class:`pyfrep_core.progress.Progress`);
        a stop request ends the work early and nothing is written (None is returned).
    **params : the model's parameters (numbers or 0-d tensors).

    Returns
    -------
    the :class:`pyvista.ImageData` written (point arrays ``f``, the extras, and ``evaluated`` with
    ``band``), or None when stopped.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from pyfrep_core.models import fig1_part
    >>> path = os.path.join(tempfile.mkdtemp(), "part.vti")
    >>> grid = save_field(path, fig1_part, fig1_part.bounds, 33, band=0.05, r=0.35)
    >>> bool(grid["evaluated"].mean() < 0.5)   # only the cells near the surface were evaluated
    True
    >>> bool(np.all(np.abs(grid["f"][grid["evaluated"] == 0]) == 0.05))
    True
    """
    import pyvista as pv

    path = Path(path)
    if path.suffix.lower() != ".vti":
        raise ValueError(f"save_field: path must end in .vti (VTK image data), got {str(path)!r}")
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"save_field: dtype must be torch.float32 or torch.float64, got {dtype}")
    if not callable(f):
        raise TypeError(f"save_field: f must be callable, got {type(f).__name__}")
    dim = f.dim if isinstance(f, Model) else None
    lo, hi = check_bounds(bounds, dim)
    dim = len(lo)
    if dim not in (2, 3):
        raise ValueError(f"save_field: VTK image data holds 2-D or 3-D grids, got bounds in {dim} dimensions")
    n = _resolution(resolution, dim)
    if band is not None:
        band = check_option(band, "band", "save_field", "float", positive=True)

    def g(x: torch.Tensor) -> torch.Tensor:
        return f(x, **params)

    g.__name__ = name_of(f)
    fields = _extras(extra, g)
    axes = [torch.linspace(a, b, k, dtype=dtype) for a, b, k in zip(lo, hi, n, strict=True)]
    shape = tuple(reversed(n))  # (z, y, x): x fastest, VTK's point order
    total = int(np.prod(n))
    work = DERIVED_WORK if fields else 1
    chunk = max(1, budget_points(dtype, dim) // work)
    wanted = sign = None
    with Progress(
        -(-total // chunk) * (2 if band is not None else 1), "save_field", callback, 1, stop, progress
    ) as bar:
        if band is not None:
            try:
                got = _band_points(g, axes, shape, band, chunk, bar)
            except IntervalUnsupported as err:
                warnings.warn(
                    f"save_field: the band needs interval bounds, which {name_of(f)} does not allow ({err}); "
                    "every grid point is evaluated",
                    RuntimeWarning,
                    stacklevel=2,
                )
                got = (torch.ones(shape, dtype=torch.bool), torch.zeros(shape, dtype=torch.bool))
            if got is None:
                return None
            wanted, sign = got
            index = torch.nonzero(wanted.reshape(-1)).reshape(-1)
        else:
            index = None
        count = total if index is None else int(index.numel())
        arrays = {name: torch.full((total,), float("nan"), dtype=dtype) for name in ["f", *(n for n, _ in fields)]}
        for step, start in enumerate(range(0, count, chunk)):
            part = torch.arange(start, min(count, start + chunk)) if index is None else index[start : start + chunk]
            x = _coordinates(part, axes, shape)
            if any(how == "grad_norm" for _, how in fields):
                value, gradient = value_and_grad(g, x)
                arrays["f"][part] = value.to(dtype)
            else:
                arrays["f"][part] = evaluate(g, x, label=g.__name__).to(dtype)
            for name, how in fields:
                if how == "grad_norm":
                    arrays[name][part] = torch.linalg.vector_norm(gradient, dim=-1).to(dtype)
                else:
                    arrays[name][part] = torch.as_tensor(how(x)).detach().reshape(-1).to(dtype)
            if bar.update(step + (0 if index is None else -(-total // chunk))):
                return None
    if wanted is not None:
        outside = ~wanted.reshape(-1)
        w = torch.tensor(band, dtype=dtype)
        arrays["f"][outside] = torch.where(sign.reshape(-1)[outside], w, -w)
    spacing = [(b - a) / (k - 1) for a, b, k in zip(lo, hi, n, strict=True)]
    grid = pv.ImageData(
        dimensions=(*n, 1) if dim == 2 else n,
        spacing=(*spacing, 1.0) if dim == 2 else spacing,
        origin=(*lo, 0.0) if dim == 2 else lo,
    )
    for name, values in arrays.items():
        grid.point_data[name] = values.numpy()
    if wanted is not None:
        grid.point_data["evaluated"] = wanted.reshape(-1).numpy().astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    grid.save(str(path))
    return grid
