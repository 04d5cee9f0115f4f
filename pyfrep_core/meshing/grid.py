"""Regular grids: axes, memory estimate, and f evaluated on them in cache-sized chunks.

>>> from pyfrep_core import sphere
>>> v = evaluate_grid(lambda x: sphere(x, r=1.0), ((-1, -1, -1), (1, 1, 1)), 3)
>>> float(v[1, 1, 1])
1.0
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from .. import _array
from .._array import available_memory, check_option, validated_inputs
from ..evaluate import budget_points, evaluate, name_of
from ..model import check_bounds

__all__ = ["GridTooLargeError", "evaluate_grid", "grid_axes", "grid_memory", "available_memory"]


# points per call of f on the CPU: the temporaries stay in cache (see _map)
CHUNK_POINTS = 1 << 15

CHUNK_POINTS_GPU = 1 << 22

GiB = float(1 << 30)

GRID_DTYPES = (torch.float32, torch.float64)


class GridTooLargeError(ValueError, MemoryError):
    """A grid that would not fit in memory (a ValueError for bad input, and a MemoryError)."""


def _device(device: Any, fn: str) -> torch.device:
    """``torch.device(device)``, with an error naming the option."""
    try:
        return torch.device(device)
    except (RuntimeError, TypeError) as err:
        raise ValueError(
            f"{fn}: device must be a torch device or its name ('cpu', 'cuda'), got {device!r}: {err}"
        ) from None


def _resolution(resolution: Any, dim: int) -> tuple[int, ...]:
    """Validate samples per axis: an integer >= 2, or one per axis."""
    values = (resolution,) * dim if np.ndim(resolution) == 0 else tuple(resolution)
    if len(values) != dim:
        raise ValueError(f"resolution must be one integer or {dim} integers, got {resolution!r}")
    out = []
    for r in values:
        ok = isinstance(r, int | np.integer | float | np.floating) and not isinstance(r, bool | np.bool_)
        if not ok or not math.isfinite(r) or int(r) != r or r < 2:
            raise ValueError(f"resolution must be an integer >= 2 per axis, got {resolution!r}")
        out.append(int(r))
    return tuple(out)


def grid_axes(bounds: Any, resolution: int | tuple[int, ...], dim: int = 3) -> list[np.ndarray]:
    """Sample positions along each axis: ``resolution`` points from lower to upper bound inclusive.

    Examples
    --------
    >>> grid_axes(((0, 0, 0), (1, 2, 1)), 3)[1]
    array([0., 1., 2.])
    """
    dim = check_option(dim, "dim", "grid_axes", "int", positive=True)
    lo, hi = check_bounds(bounds, dim)
    res = _resolution(resolution, dim)
    return [np.linspace(a, b, r) for a, b, r in zip(lo, hi, res)]


def grid_memory(resolution: int | tuple[int, ...], dtype: torch.dtype = torch.float32) -> int:
    """Estimated peak bytes to evaluate and mesh a grid of ``resolution`` samples per axis.

    The grid itself (4 or 8 bytes a sample; marching cubes needs a float32 copy of a
    float64 grid) and a quarter more for marching cubes, 256 MiB for the temporaries of the
    chunked evaluation and autograd passes, and 400 bytes a vertex for the projection and
    the mesh's arrays (measured: 390-430 bytes a vertex from 5e4 to 1e6 vertices).

    Marching cubes puts one vertex on each grid edge the surface crosses.  A closed part
    spanning the box crosses about 2/3 of the grid lines along each axis, twice each (a
    sphere inscribed in a cube: pi/4 of them), but a line of ``n`` samples has only ``n - 1``
    edges: the count is ``2/3 sum_a min(2, n_a - 1) N / n_a`` for N samples, 4 n^2 for a cube
    of n^3 (n >= 3) and one crossing per line across a slab two samples thick (a face of the
    part lying in the slab).  A lattice has more.

    Examples
    --------
    >>> round(grid_memory(512) / 2**30, 2)
    1.27
    >>> round(grid_memory((4096, 4096, 2)) / 2**30, 2)  # 11.2 million vertices at most
    4.58
    """
    res = _resolution(resolution, 3)
    dtype = check_option(dtype, "dtype", "grid_memory", "choice", choices=GRID_DTYPES)
    per_sample = 4 if dtype == torch.float32 else 8 + 4
    n = math.prod(res)
    vertices = 2 * sum(min(2, r - 1) * (n // r) for r in res) // 3
    return int(n * per_sample * 1.25) + (256 << 20) + 400 * vertices


def _check_memory(resolution: tuple[int, ...], dtype: torch.dtype) -> None:
    need = grid_memory(resolution, dtype)
    have = _array.available_memory()
    if have is not None and need > have:
        shown = resolution[0] if len(set(resolution)) == 1 else resolution
        raise GridTooLargeError(
            f"resolution {shown} needs about {need / GiB:.3g} GiB for the grid and marching cubes, "
            f"but only {have / GiB:.3g} GiB of memory is available; lower the resolution"
        )


def _return_freed_memory() -> None:
    """Hand the C heap's free pages back to the system (glibc's ``malloc_trim``; nothing elsewhere).

    Arrays of a few MB, freed between the meshers' passes, stay in the heap as free pages that
    still count as resident: the next pass's arrays then come on top of them, and the peak grows
    with what was already freed.
    """
    libc = _glibc()
    if libc is not None:
        libc.malloc_trim(0)


# glibc's malloc returns a freed block above its mmap threshold to the system at once, and the heap's
# free top beyond its trim threshold; it raises both itself after freeing a large block (to that
# block's size and twice it, up to 32 MiB and 64 MiB on 64-bit), so how much a mesh's freed arrays
# keep depends on the sizes met before.  After a 64^3 mesh (as benchmarks/mesh.py warms up), every
# 128^3 mesh of the Fig. 1 part faulted in some 24 MB of fresh pages again: 6,000 page faults,
# 54-57 ms, against about 100 and 43-47 ms pinned (peak 2-4 MiB higher).  Pinned from the start at
# the ceiling glibc's own rule reaches, the heap keeps no more than it would keep anyway.
HEAP_MMAP_THRESHOLD = 32 << 20
HEAP_TRIM_THRESHOLD = 64 << 20
_MALLOC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_")


@functools.lru_cache(maxsize=1)
def _steady_heap() -> bool:
    """Pin glibc's mmap and trim thresholds (once per process; nothing elsewhere, or where the
    environment sets malloc's settings itself); whether they are pinned now.

    >>> _steady_heap() == (_glibc() is not None and not _malloc_set_by_environment())
    True
    """
    libc = _glibc()
    if libc is None or _malloc_set_by_environment():
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # glibc's <malloc.h>
    return bool(libc.mallopt(m_mmap_threshold, HEAP_MMAP_THRESHOLD)) and bool(
        libc.mallopt(m_trim_threshold, HEAP_TRIM_THRESHOLD)
    )


def _malloc_set_by_environment() -> bool:
    """Whether the environment sets glibc malloc's thresholds (its variables, or a malloc tunable).

    >>> import unittest.mock
    >>> with unittest.mock.patch.dict(os.environ, {"GLIBC_TUNABLES": "glibc.cpu.x86_shstk=on"}, clear=True):
    ...     cpu_only = _malloc_set_by_environment()
    >>> with unittest.mock.patch.dict(os.environ, {"GLIBC_TUNABLES": "glibc.malloc.trim_threshold=1"}, clear=True):
    ...     malloc = _malloc_set_by_environment()
    >>> cpu_only, malloc
    (False, True)
    """
    return any(k in os.environ for k in _MALLOC_VARIABLES) or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", "")


@functools.lru_cache(maxsize=1)
def _glibc() -> Any:
    """The C library when it is glibc (``malloc_trim``, ``mallopt``); None elsewhere."""
    import ctypes
    import ctypes.util

    try:
        if not os.confstr("CS_GNU_LIBC_VERSION").startswith("glibc"):
            return None
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.malloc_trim, libc.mallopt  # noqa: B018  (both there, or None)
    except (OSError, AttributeError, ValueError):
        return None
    return libc


def _map(fn: Callable, items: list, device: torch.device) -> list:
    """``[fn(item) for item in items]``: chunks one after the other.

    On the CPU, polygonize runs them on one intra-op thread (see :func:`polygonize`): chunks of
    2^15 points stay in cache, and at that size the cost is torch's per-operation dispatch,
    which holds the GIL, so neither torch's second thread nor a pool of workers made the 2-core
    machine faster (measured: 0.37 s one thread vs 0.71 s two workers for the 256^3 grid).
    """
    return [fn(item) for item in items]


def _chunk_points(f: Callable, default: int) -> int:
    """Points per call: ``default``, or the ``chunk_points`` that f (or the model a
    ``functools.partial`` binds) declares (a compiled model's fused loop wants larger chunks)."""
    while isinstance(f, functools.partial):
        f = f.func
    hint = getattr(f, "chunk_points", None)
    return max(default, int(hint)) if isinstance(hint, int) and hint > 0 else default


def _grid_chunks(shape: tuple[int, int, int], max_points: int):
    """Blocks (i, kx, j, ky) of whole z-rows with at most ``max_points`` points (at least one row)."""
    nx, ny, nz = shape
    if ny * nz <= max_points:
        kx = max(1, max_points // (ny * nz))
        for i in range(0, nx, kx):
            yield i, min(kx, nx - i), 0, ny
    else:
        ky = max(1, max_points // nz)
        for i in range(nx):
            for j in range(0, ny, ky):
                yield i, 1, j, min(ky, ny - j)


def _call(f: Callable, pts: torch.Tensor) -> tuple[torch.Tensor, float, float]:
    """f on component-first points (3, ...) (so that x[:, 0] etc. are contiguous), its min and max.

    f is handed the points flattened to (N, 3) (the model contract); the values come back in
    the block's shape.  Raises ValueError for a wrong output shape (naming f, the input and the
    output shapes) or a non-finite value (naming the point).
    """
    shape = tuple(pts.shape[1:])
    with torch.no_grad():
        # f sees the block as a list of points (N, 3): a view, x[:, 0] etc. still contiguous
        points = pts.reshape(3, -1).t()
        with validated_inputs():  # grid points from checked bounds: the primitives of f need not read them
            vals = evaluate(f, points, chunk=points.shape[0], label=name_of(f))
        _check_values_dtype(f, vals, pts.dtype)
        vals = vals.reshape(shape)
        lo, hi = torch.aminmax(vals)
        lo, hi = float(lo), float(hi)
        if not (math.isfinite(lo) and math.isfinite(hi)):
            bad = tuple(int(t) for t in torch.nonzero(~torch.isfinite(vals))[0])
            where = pts[(slice(None), *bad)].tolist()
            raise ValueError(f"f is not finite at x = {tuple(where)}: {float(vals[bad])}")
    return vals, lo, hi


def _check_values_dtype(f: Callable, values: torch.Tensor, dtype: torch.dtype) -> None:
    """Refuse values that are not floating point: an integer or boolean f has no gradient, so
    neither the vertices' projection onto f = 0 nor the normals (-grad f) exist."""
    if not values.is_floating_point():
        raise TypeError(
            f"f ({name_of(f)}) returned {str(values.dtype).removeprefix('torch.')} values for "
            f"{str(dtype).removeprefix('torch.')} points; a defining function must return floating-point "
            "values (meshing needs its gradient: the normals, and the vertices' projection onto f = 0)"
        )


def _check_grid_options(fn: str, f: Any, dtype: Any) -> torch.dtype:
    """f callable and the grid dtype float32 or float64 (an integer grid rounds f and loses its zero set)."""
    if not callable(f):
        raise TypeError(f"{fn}: f must be callable (points (N, 3) -> values (N,)), got {type(f).__name__}")
    return check_option(dtype, "dtype", fn, "choice", choices=GRID_DTYPES)


class Stopped(Exception):  # noqa: N818  (not an error: the caller asked to stop)
    """Raised out of a chunk loop when its progress reports a stop request (callback or stop flag)."""


def _evaluate_grid(
    f: Callable,
    axes: list[np.ndarray],
    dtype: torch.dtype,
    device: Any,
    max_points: int | None,
    progress: Callable[[int], Any] | None = None,
) -> tuple[np.ndarray, float, float]:
    """f on the grid of ``axes`` plus its min and max; raises on a non-finite value.

    ``progress(n_chunks)``, when given, returns a :class:`pyfrep_core.progress.Progress` advanced
    once per chunk; :class:`Stopped` is raised when it asks to stop.
    """
    device = torch.device(device)
    if max_points is None:  # cache-sized on the CPU, and never above the memory budget of one call
        default = _chunk_points(f, CHUNK_POINTS if device.type == "cpu" else CHUNK_POINTS_GPU)
        max_points = min(default, budget_points(dtype, len(axes)))
    shape = tuple(len(a) for a in axes)
    out = np.empty(shape, dtype=np.float32 if dtype == torch.float32 else np.float64)
    gx, gy, gz = (torch.as_tensor(a, dtype=dtype, device=device) for a in axes)

    def chunk(block: tuple[int, int, int, int]) -> tuple[float, float]:
        i, kx, j, ky = block
        pts = torch.empty((3, kx, ky, shape[2]), dtype=dtype, device=device)
        pts[0] = gx[i : i + kx, None, None]
        pts[1] = gy[j : j + ky, None]
        pts[2] = gz
        vals, lo, hi = _call(f, pts)
        out[i : i + kx, j : j + ky] = vals.cpu().numpy()
        return lo, hi

    blocks = list(_grid_chunks(shape, max_points))
    if progress is None:
        ranges = _map(chunk, blocks, device)
    else:
        ranges = []
        with progress(len(blocks)) as bar:
            for step, block in enumerate(blocks):
                ranges.append(chunk(block))
                if bar.update(step):
                    raise Stopped
    return out, min(r[0] for r in ranges), max(r[1] for r in ranges)


def evaluate_grid(
    f: Callable,
    bounds: Any,
    resolution: int | tuple[int, int, int],
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    max_points: int | None = None,
) -> np.ndarray:
    """f on a regular 3-D grid, evaluated in chunks of at most ``max_points`` points.

    Parameters
    ----------
    f : callable, torch points (N, 3) -> values (N,) (a Model too).
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)); the grid's end points lie on them.
    resolution : samples per axis (>= 2), or one per axis.
    dtype : torch.float32 (fast) or torch.float64.
    max_points : points per call of f (default 2^15 on the CPU, 2^22 on accelerators, at most
        :func:`pyfrep_core.evaluate.budget_points`: the memory budget of one call).  f gets
        them as a list of points (N, 3), never as a grid block.

    Returns
    -------
    (nx, ny, nz) numpy array of ``dtype``: ``values[i, j, k] = f(x_i, y_j, z_k)``.

    Raises
    ------
    ValueError (GridTooLargeError) before allocating when the grid cannot fit in memory;
    ValueError naming the point where f is NaN or inf.

    Examples
    --------
    >>> from pyfrep_core import sphere
    >>> v = evaluate_grid(lambda x: sphere(x, r=1.0), ((-1, -1, -1), (1, 1, 1)), 3)
    >>> v.shape, float(v[1, 1, 1]), float(v[0, 0, 0])
    ((3, 3, 3), 1.0, -2.0)
    """
    dtype = _check_grid_options("evaluate_grid", f, dtype)
    max_points = check_option(max_points, "max_points", "evaluate_grid", "int", positive=True, none=True)
    device = _device(device, "evaluate_grid")
    res = _resolution(resolution, 3)
    _check_memory(res, dtype)
    axes = grid_axes(bounds, res)
    return _evaluate_grid(f, axes, dtype, device, max_points)[0]
