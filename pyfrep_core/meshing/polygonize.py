"""``polygonize``: mesh f = 0 by marching cubes or by octree dual contouring.

``method="mc"`` (the default) is marching cubes on the grid with vertices moved onto f = 0
(:mod:`pyfrep_core.meshing.marching_cubes`); ``"dc"`` is dual contouring on a certified octree
(:mod:`pyfrep_core.meshing.octree`, :mod:`pyfrep_core.meshing.dual_contouring`): f is sampled
only in blocks the interval bounds cannot prove empty, and sharp edges and corners are kept;
``"auto"`` takes ``"dc"`` when f has an interval extension (:func:`pyfrep_core.interval.supports`),
``"mc"`` otherwise.

>>> from pyfrep_core.models import fig1_part
>>> mc = polygonize(fig1_part, resolution=64)
>>> dc = polygonize(fig1_part, resolution=64, method="dc")
>>> abs(dc.volume() - 0.98879) < abs(mc.volume() - 0.98879) / 10   # edges and corners kept
True
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from .._array import check_option
from .._threads import intra_op_threads
from ..interval import supports
from ..progress import Progress
from .dual_contouring import dual_contour
from .grid import Stopped, _check_grid_options, _device, _steady_heap
from .marching_cubes import _polygonize
from .mesh_type import Mesh

__all__ = ["polygonize", "METHODS"]

METHODS = ("auto", "dc", "mc")
PROGRESS_DELAY = 1.0  # seconds before the progress bar shows


def polygonize(
    f: Callable,
    bounds: Any = None,
    resolution: int | tuple[int, int, int] = 128,
    project: bool = True,
    dtype: torch.dtype = torch.float32,
    device: str | torch.device = "cpu",
    sparse: bool = False,
    tol: float | None = None,
    method: str = "mc",
    callback: Callable | None = None,
    stop: Any = None,
    progress: bool = True,
) -> Mesh:
    """Mesh the surface f = 0 inside ``bounds``: marching cubes with vertices moved onto f = 0, or dual contouring.

    Parameters
    ----------
    f : callable (N, 3) -> (N,) on torch tensors, or a Model (its default bounds are used when
        ``bounds`` is None).  f is only ever called with lists of points (N, 3), in chunks.
    bounds : ((xmin, ymin, zmin), (xmax, ymax, zmax)); the grid's end points lie on them.
    resolution : grid samples per axis (an integer >= 2, or three).
    project : move the vertices onto f = 0 in float64 (root finding along each marching-cubes
        edge, Newton steps along grad f where that does not apply), to a first-order distance
        |f| / |grad f| below 100 ulp of the largest coordinate (2.4e-14 in [-1.1, 1.1]^3);
        False keeps marching cubes' linear interpolation.  Normals come from -grad f either way.
    dtype : dtype of the grid evaluation (float32 is fast; vertices are float64 either way).
    device : where f is evaluated.
    sparse : evaluate f exactly only near the surface (coarse-to-fine, blocks of
        ``SPARSE_STEP``^3 cells; see :func:`_sparse_grid` for what it assumes); the mesh is
        the dense grid's whenever that assumption holds (tested on the paper's shapes).
    tol : distance to f = 0 (length units) at which a projected vertex is accepted; None (the
        default) is the 100-ulp tolerance above.  A display-grade value (e.g. 1e-3 of a cell,
        as the workbench uses while a slider moves) saves most of the root-finding steps.
        With ``"dc"``: the step at which an edge's root is accepted (None: 1e-7 cells).
    method : ``"mc"`` marching cubes (the default); ``"dc"`` octree dual contouring at the same
        voxel size (``resolution`` samples per axis; cells the interval bounds prove free of
        surface are never sampled, sharp edges and corners are reproduced, one vertex per cell
        and surface component, inside its cell (on f = 0 on smooth patches), and one on f = 0 at
        each crossing edge's root, which cuts that edge's quad into four triangles: about twice
        marching cubes' triangles; no two faces without a common vertex intersect (proved in
        cells crossed by one sheet, searched and mended in the others); ``project`` and
        ``sparse`` do not apply); ``"auto"``: ``"dc"`` when f has an interval extension, else ``"mc"``.
    callback, stop, progress : see :mod:`pyfrep_core.progress`: events (stage "polygonize", one
        per chunk of samples; returning True stops), a stop flag (``is_set()``), and a tqdm bar
        shown once the sampling has run 1 s.  Stopped, an empty mesh comes back (no warning).

    Returns
    -------
    Mesh with vertices (V, 3) float64 in world coordinates, faces (F, 3) int64 oriented
    outward, unit normals (V, 3).  Empty (with a RuntimeWarning) when f does not change
    sign inside the bounds.  Vertices whose projection does not converge keep their
    marching-cubes position; their number is given in a RuntimeWarning.

    Raises
    ------
    ValueError for bad bounds, resolution or method, for a grid that cannot fit in memory (before
    allocating; the message gives the GiB needed), and where f is NaN or inf.

    Notes
    -----
    With glibc, the first call pins malloc's mmap and trim thresholds for the process at 32 and 64 MiB,
    the ceiling glibc's own adaptive rule reaches (unless ``MALLOC_*_`` or ``GLIBC_TUNABLES`` set them):
    left adaptive, a 128^3 mesh after a 64^3 one faulted in some 24 MB of fresh pages every time
    (a fifth of its time).

    Examples
    --------
    >>> from pyfrep_core.models import fig1_part
    >>> m = polygonize(fig1_part, resolution=64)      # the model's default bounds
    >>> abs(m.volume() - 0.98879) < 0.01, m.vertices.dtype, m.faces.shape[1]
    (True, dtype('float64'), 3)
    """
    dtype = _check_grid_options("polygonize", f, dtype)
    project = check_option(project, "project", "polygonize", "bool")
    sparse = check_option(sparse, "sparse", "polygonize", "bool")
    tol = check_option(tol, "tol", "polygonize", positive=True, none=True)
    method = check_option(method, "method", "polygonize", "choice", choices=METHODS)
    progress = check_option(progress, "progress", "polygonize", "bool")
    if callback is not None and not callable(callback):
        raise TypeError(f"polygonize: callback must be callable or None, got {callback!r}")
    if stop is not None and not callable(getattr(stop, "is_set", None)):
        raise TypeError(f"polygonize: stop must have an is_set() method (a threading.Event) or be None, got {stop!r}")
    cpu = _device(device, "polygonize").type == "cpu"
    if bounds is None:
        bounds = getattr(f, "bounds", None)
        if bounds is None:
            raise ValueError("bounds must be given for a function without default bounds")
    if method == "auto":
        method = "dc" if supports(f) else "mc"

    def bar(total: int) -> Progress:
        return Progress(total, "polygonize", callback, every=1, stop=stop, progress=progress, delay=PROGRESS_DELAY)

    _steady_heap()  # freed arrays reused, not faulted in again, whatever size was meshed before
    # one intra-op thread on the CPU: at 2^15-point chunks torch's dispatch, not arithmetic, is the cost
    # (the Fig. 1 part at 256^3: 0.91 s on one thread, 1.29 s on two)
    with intra_op_threads(1 if cpu else None):
        if method == "dc":
            dim = getattr(f, "dim", None)
            if dim is not None and dim != 3:
                raise ValueError(f"polygonize meshes 3-D models; this one has dim={dim}")
            return dual_contour(f, bounds, resolution, dtype, device, tol, progress=bar)
        try:
            return _polygonize(f, bounds, resolution, project, dtype, device, sparse, tol, bar)
        except Stopped:
            return Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros((0, 3)))
