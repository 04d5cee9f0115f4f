"""The Mesh type: triangles in world coordinates, with normals, grad f and point data.

>>> import numpy as np
>>> m = Mesh(np.eye(3), np.array([[0, 1, 2]]))
>>> m.n_vertices, m.n_faces
(3, 1)
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from .files import write_mesh

__all__ = ["Mesh"]


@dataclass
class Mesh:
    """A triangle mesh in world coordinates.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (F, 3) int64, counter-clockwise seen from outside (normals by the right-hand rule point out)
    normals : (V, 3) float64 outward unit normals (from -grad f at the vertices), or None
    point_data : name -> (V,) or (V, k) arrays carried along (curvatures, residuals ...)
    gradient : (V, 3) float64 grad f at the vertices where :func:`polygonize` computed it
        (the normals are -gradient / |gradient|), so that callers need no second autograd
        pass (the shape panel's sensitivity -(df/dp) / |grad f|), or None.  Not written to files.

    Examples
    --------
    >>> import numpy as np
    >>> tet = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]),
    ...            np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    >>> round(tet.volume(), 6), tet.n_vertices, tet.n_faces
    (0.166667, 4, 4)
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    point_data: dict[str, np.ndarray] = field(default_factory=dict)
    gradient: np.ndarray | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.vertices = _as_array(self.vertices, np.float64, "vertices")
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise ValueError(f"vertices must have shape (V, 3), got {self.vertices.shape}")
        if not np.isfinite(self.vertices).all():
            raise ValueError("vertices contain NaN or inf")
        faces = np.asarray(self.faces)
        if faces.size == 0:
            faces = faces.reshape(0, 3)
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise ValueError(f"faces must have shape (F, 3), got {faces.shape}")
        if faces.dtype.kind not in "iu":
            if faces.dtype.kind != "f" or not np.array_equal(faces, np.round(faces)):
                raise ValueError(f"faces must hold integer vertex indices, got dtype {faces.dtype}")
        self.faces = faces.astype(np.int64, copy=False)
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise ValueError(
                f"faces index vertices {self.faces.min()}..{self.faces.max()}, "
                f"but there are {len(self.vertices)} vertices"
            )
        if self.normals is not None:
            self.normals = _as_array(self.normals, np.float64, "normals")
            if self.normals.shape != self.vertices.shape:
                raise ValueError(f"normals must have shape {self.vertices.shape}, got {self.normals.shape}")
        if self.gradient is not None:
            self.gradient = _as_array(self.gradient, np.float64, "gradient")
            if self.gradient.shape != self.vertices.shape:
                raise ValueError(f"gradient must have shape {self.vertices.shape}, got {self.gradient.shape}")
        data = {}
        for name, values in dict(self.point_data).items():
            arr = np.asarray(values)
            if arr.ndim == 0 or arr.shape[0] != len(self.vertices):
                raise ValueError(f"point_data[{name!r}] must have one row per vertex, got shape {arr.shape}")
            data[name] = arr
        self.point_data = data

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    def is_empty(self) -> bool:
        return self.n_faces == 0

    def volume(self) -> float:
        """Enclosed volume by the divergence theorem (exact for a closed, outward-oriented mesh)."""
        if self.is_empty():
            return 0.0
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)

    def area(self) -> float:
        """Total surface area."""
        if self.is_empty():
            return 0.0
        a, b, c = (self.vertices[self.faces[:, i]] for i in range(3))
        return float(0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())

    def to_pyvista(self) -> Any:
        """A ``pyvista.PolyData`` with the normals and point data attached."""
        import pyvista as pv

        faces = np.hstack([np.full((self.n_faces, 1), 3, dtype=np.int64), self.faces.astype(np.int64)])
        poly = pv.PolyData(self.vertices, faces.ravel())
        if self.normals is not None:
            poly.point_data["Normals"] = self.normals
        for name, values in self.point_data.items():
            poly.point_data[name] = values
        return poly

    def save(self, path: str | os.PathLike) -> None:
        """Write the mesh to ``path``; the format follows the extension: ``save_mesh(self, path)``.

        See :func:`pyfrep_core.io.save_mesh` for the formats and what each keeps.  It takes no
        other arguments (an unknown keyword is a TypeError).
        """
        write_mesh(self, path)


def _as_array(values: Any, dtype: type, name: str) -> np.ndarray:
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().numpy()
    try:
        return np.asarray(values, dtype=dtype)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a numeric array: {err}") from None
