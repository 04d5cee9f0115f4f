"""Writing meshes to files (STL, OBJ, PLY, OFF, VTK through meshio): the layer under ``Mesh.save``.

:func:`pyfrep_core.io.save_mesh` checks its argument and calls :func:`write_mesh`; reading is in
:mod:`pyfrep_core.io` (guarded parsing in a worker process).  Point data is written under names
that read back as they are (see :mod:`pyfrep_core.io`).

>>> import os, tempfile
>>> import numpy as np
>>> from pyfrep_core import Mesh
>>> path = os.path.join(tempfile.mkdtemp(), "tri.off")
>>> write_mesh(Mesh(np.eye(3), np.array([[0, 1, 2]])), path)
>>> open(path).readline().strip()
'OFF'
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["MESH_FORMATS", "write_mesh"]

MESH_FORMATS = {".stl": "stl", ".obj": "obj", ".ply": "ply", ".off": "off", ".vtk": "vtk"}
_NORMAL_KEYS = {"vtk": "Normals", "obj": "obj:vn"}  # PLY: the usual nx, ny, nz properties
# names the formats use themselves: point data under them would not read back as point data
_RESERVED = {"ply": {"x", "y", "z", "nx", "ny", "nz"}, "vtk": {"Normals", "normals"}}


def _format(path: str | os.PathLike, formats: dict[str, str], fn: str) -> tuple[Path, str]:
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in formats:
        supported = ", ".join(formats)
        raise ValueError(f"{fn}: cannot tell the format of {str(path)!r} from its extension; supported: {supported}")
    return path, formats[ext]


def _join_columns(point_data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``name_0 .. name_{k-1}`` (k >= 2) back into one (V, k) array: how (V, k) point data is stored."""
    out = dict(point_data)
    groups: dict[str, list[int]] = {}
    for key in point_data:
        m = re.fullmatch(r"(.+)_(\d+)", key)
        if m:
            groups.setdefault(m.group(1), []).append(int(m.group(2)))
    for base, ks in groups.items():
        if len(ks) >= 2 and sorted(ks) == list(range(len(ks))) and base not in out:
            out[base] = np.column_stack([out.pop(f"{base}_{k}") for k in range(len(ks))])
    return out


def _file_point_data(mesh: Any, fmt: str) -> dict[str, np.ndarray]:
    """``mesh.point_data`` as the columns PLY / VTK store, once sure that they read back as they are.

    A (V, k) array becomes ``name_0 .. name_{k-1}`` (VTK keeps 3-vectors whole); booleans are
    stored as uint8, float16 as float32 and, in PLY (whose reader here knows no 8- and 16-bit
    signed types), int8 / int16 / uint16 as int32 / uint32.
    """
    columns: dict[str, np.ndarray] = {}
    for name, values in mesh.point_data.items():
        where = f"save_mesh: point_data[{name!r}]"
        if not isinstance(name, str):
            raise TypeError(f"{where}: a point-data name must be a str, got {type(name).__name__}")
        if not name or any(c.isspace() or not c.isprintable() for c in name):
            hint = re.sub(r"\s+", "_", name.strip()) or "a name"
            raise ValueError(
                f"{where}: {fmt.upper()} separates fields by spaces, so a point-data name must be non-empty "
                f"without spaces or control characters; got {name!r} (rename it, e.g. {hint!r})"
            )
        if name in _RESERVED[fmt]:
            raise ValueError(
                f"{where}: {name!r} is one of the names {fmt.upper()} uses itself "
                f"({', '.join(sorted(_RESERVED[fmt]))}); rename it"
            )
        arr = np.asarray(values)
        if arr.dtype.kind not in "biuf":
            raise ValueError(f"{where}: {fmt.upper()} holds numbers (bool, int, float), got dtype {arr.dtype}")
        wide = {np.dtype(np.float16): np.float32}
        if fmt == "ply":
            wide.update({np.dtype(np.int8): np.int32, np.dtype(np.int16): np.int32, np.dtype(np.uint16): np.uint32})
        arr = arr.astype(np.uint8 if arr.dtype == bool else wide.get(arr.dtype, arr.dtype), copy=False)
        if arr.ndim > 2 or (arr.ndim == 2 and arr.shape[1] < 2):
            raise ValueError(
                f"{where}: {fmt.upper()} stores (V,) and (V, k >= 2) arrays, got shape {arr.shape} "
                "(reshape it to one of those)"
            )
        if arr.ndim == 1 or (fmt == "vtk" and arr.shape[1] == 3):
            parts = {name: arr}
        else:
            parts = {f"{name}_{k}": arr[:, k] for k in range(arr.shape[1])}
        for key, part in parts.items():
            if key in columns or key in _RESERVED[fmt]:
                raise ValueError(f"{where}: its column {key!r} would clash with another column of that name; rename it")
            columns[key] = np.ascontiguousarray(part)
    back = _join_columns(columns)
    if set(back) != set(mesh.point_data):
        raise ValueError(
            f"save_mesh: point_data {sorted(mesh.point_data)} would read back from {fmt.upper()} as {sorted(back)} "
            "(a (V, k) array is stored as the columns name_0 .. name_{k-1}, joined again on reading); rename them"
        )
    return columns


def write_mesh(mesh: Any, path: str | os.PathLike) -> None:
    """Write a :class:`pyfrep_core.Mesh` to ``path``: the body of :func:`pyfrep_core.io.save_mesh` (see there).

    Parameters
    ----------
    mesh : Mesh (not checked here: ``save_mesh`` checks it).
    path : file name; the extension picks the format (.stl .obj .ply .off .vtk).
    """
    import meshio

    path, fmt = _format(path, MESH_FORMATS, "save_mesh")
    if mesh.is_empty():
        raise ValueError(f"save_mesh: cannot save an empty mesh (no faces) to {str(path)!r}")
    point_data: dict[str, np.ndarray] = {}
    if fmt == "ply" and mesh.normals is not None:
        point_data.update(nx=mesh.normals[:, 0].copy(), ny=mesh.normals[:, 1].copy(), nz=mesh.normals[:, 2].copy())
    elif fmt in _NORMAL_KEYS and mesh.normals is not None:
        point_data[_NORMAL_KEYS[fmt]] = mesh.normals
    if fmt in ("ply", "vtk"):
        point_data.update(_file_point_data(mesh, fmt))
    faces = mesh.faces.astype(np.int32) if fmt == "ply" else mesh.faces
    out = meshio.Mesh(mesh.vertices, [("triangle", faces)], point_data=point_data)
    kwargs: dict[str, Any] = {"binary": True} if fmt in ("stl", "ply", "vtk") else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # meshio's notes on formats (e.g. VTK 5.1 vs 4.2)
        meshio.write(path, out, file_format=fmt, **kwargs)
