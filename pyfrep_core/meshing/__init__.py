"""Meshing f = 0 (one module per idea): the Mesh type, grids, root finding onto f = 0, marching cubes,
the certified octree, dual contouring; ``polygonize`` picks the method.

>>> from pyfrep_core import sphere
>>> m = polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 32)
>>> round(m.volume(), 1)
4.2
"""

from .grid import GridTooLargeError, available_memory, evaluate_grid, grid_axes, grid_memory
from .mesh_type import Mesh
from .polygonize import polygonize

__all__ = [
    "Mesh",
    "GridTooLargeError",
    "polygonize",
    "evaluate_grid",
    "grid_axes",
    "grid_memory",
    "available_memory",
]
