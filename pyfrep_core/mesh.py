"""Temporary: the names of the former ``pyfrep_core.mesh``, now in :mod:`pyfrep_core.meshing`."""

from .meshing import *  # noqa: F403
from .meshing import __all__  # noqa: F401
from .meshing.grid import CHUNK_POINTS, CHUNK_POINTS_GPU, _evaluate_grid  # noqa: F401
from .meshing.roots import _normals, _project_vertices  # noqa: F401
from .meshing.sparse import SPARSE_GUARD, SPARSE_MAX_FRACTION, SPARSE_STEP, _exact_neighbours, _sparse_grid  # noqa: F401
