"""Reading and writing meshes and point clouds; the format follows the file's extension.

Meshes (through meshio): STL (binary, float32 coordinates), OBJ, PLY (binary), OFF and
legacy VTK (binary).  Normals survive OBJ, PLY and VTK; other point data (curvatures,
residuals ...) survives PLY and VTK.  Point clouds: XYZ (plain text, ``x y z`` or
``x y z nx ny nz`` per line) and PLY.

>>> import os, tempfile
>>> from pyfrep_core import polygonize, sphere
>>> m = polygonize(lambda x: sphere(x, r=1.0), ((-1.2,) * 3, (1.2,) * 3), 24)
>>> path = os.path.join(tempfile.mkdtemp(), "ball.ply")
>>> m.save(path)
>>> back = load_mesh(path)
>>> bool((back.vertices == m.vertices).all() and (back.faces == m.faces).all())
True
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .mesh import Mesh

__all__ = [
    "MESH_FORMATS",
    "POINT_FORMATS",
    "PointCloud",
    "save_mesh",
    "load_mesh",
    "save_points",
    "load_points",
]

MESH_FORMATS = {".stl": "stl", ".obj": "obj", ".ply": "ply", ".off": "off", ".vtk": "vtk"}
POINT_FORMATS = {".xyz": "xyz", ".ply": "ply"}
_NORMAL_KEYS = {"vtk": "Normals", "obj": "obj:vn"}  # PLY: the usual nx, ny, nz properties


class PointCloud(NamedTuple):
    """Points (N, 3) float64 and their normals (N, 3) float64, or None."""

    points: np.ndarray
    normals: np.ndarray | None


def _format(path: str | os.PathLike, formats: dict[str, str], what: str) -> tuple[Path, str]:
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in formats:
        supported = ", ".join(formats)
        raise ValueError(f"cannot tell the {what} format of {str(path)!r} from its extension; supported: {supported}")
    return path, formats[ext]


def _check_read(path: Path) -> None:
    if not path.exists():
        raise FileNotFoundError(f"no such file: {str(path)!r}")
    if not path.is_file():
        raise ValueError(f"{str(path)!r} is not a file")
    if path.stat().st_size == 0:
        raise ValueError(f"{str(path)!r} is empty")


def _split_columns(point_data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """(V, k) arrays as k arrays ``name_0 .. name_{k-1}`` (PLY properties are scalars)."""
    out = {}
    for name, values in point_data.items():
        arr = np.asarray(values)
        if arr.dtype == bool:
            arr = arr.astype(np.uint8)
        if arr.ndim == 1:
            out[name] = np.ascontiguousarray(arr)
        else:
            arr = arr.reshape(len(arr), -1)
            for k in range(arr.shape[1]):
                out[f"{name}_{k}"] = np.ascontiguousarray(arr[:, k])
    return out


def _join_columns(point_data: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Inverse of :func:`_split_columns`: ``name_0 .. name_{k-1}`` (k >= 2) back into one (V, k) array."""
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


def save_mesh(mesh: Mesh, path: str | os.PathLike) -> None:
    """Write ``mesh`` to ``path``; the format follows the extension (.stl .obj .ply .off .vtk).

    Parameters
    ----------
    mesh : Mesh
    path : file name; STL is written binary (float32 coordinates), PLY and VTK binary
        (float64), OBJ and OFF as text with every digit of the float64 coordinates.

    Raises
    ------
    ValueError for an unknown extension (the message lists the supported ones) or an
    empty mesh; TypeError when ``mesh`` is not a Mesh.
    """
    import meshio

    if not isinstance(mesh, Mesh):
        raise TypeError(f"mesh must be a pyfrep_core Mesh, got {type(mesh).__name__}")
    path, fmt = _format(path, MESH_FORMATS, "mesh")
    if mesh.is_empty():
        raise ValueError(f"cannot save an empty mesh (no faces) to {str(path)!r}")
    point_data: dict[str, np.ndarray] = {}
    if fmt == "ply":
        if mesh.normals is not None:
            point_data.update(nx=mesh.normals[:, 0], ny=mesh.normals[:, 1], nz=mesh.normals[:, 2])
        point_data.update(_split_columns(mesh.point_data))
        point_data = {k: np.ascontiguousarray(v) for k, v in point_data.items()}
    elif fmt in _NORMAL_KEYS and mesh.normals is not None:
        point_data[_NORMAL_KEYS[fmt]] = mesh.normals
    if fmt == "vtk":  # scalars and 3-vectors as they are, other widths split into columns
        point_data.update(_split_columns({k: v for k, v in mesh.point_data.items() if v.ndim > 1 and v.shape[1] != 3}))
        point_data.update(_split_columns({k: v for k, v in mesh.point_data.items() if v.ndim == 1}))
        point_data.update({k: v for k, v in mesh.point_data.items() if v.ndim == 2 and v.shape[1] == 3})
    faces = mesh.faces.astype(np.int32) if fmt == "ply" else mesh.faces
    out = meshio.Mesh(mesh.vertices, [("triangle", faces)], point_data=point_data)
    kwargs: dict[str, Any] = {"binary": True} if fmt in ("stl", "ply", "vtk") else {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # meshio's notes on formats (e.g. VTK 5.1 vs 4.2)
        meshio.write(path, out, file_format=fmt, **kwargs)


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read a triangle mesh; the format follows the extension (.stl .obj .ply .off .vtk).

    Quads and polygons are split into triangles (fans).  Normals are taken from the file
    where it has them (VTK ``Normals``, PLY ``nx ny nz``, OBJ ``vn``); other point data is
    kept in ``point_data``.  STL repeats vertices per triangle: they are merged.

    Raises
    ------
    ValueError naming the path and the problem for an unknown extension, an empty,
    malformed or truncated file, or one without triangles; FileNotFoundError when it is
    missing.
    """
    import meshio

    path, fmt = _format(path, MESH_FORMATS, "mesh")
    _check_read(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # the format's own reader: meshio.read() exits the interpreter on some errors
            raw = getattr(meshio, fmt).read(str(path))
    except Exception as err:  # meshio raises many kinds (ReadError, struct.error, IndexError ...)
        raise ValueError(f"cannot read {str(path)!r} as {fmt.upper()}: {type(err).__name__}: {err}") from None
    try:
        return _to_mesh(raw, fmt)
    except ValueError as err:
        raise ValueError(f"{str(path)!r} is not a valid triangle mesh: {err}") from None


def _to_mesh(raw: Any, fmt: str) -> Mesh:
    blocks = []
    for block in raw.cells:
        data = np.asarray(block.data)
        if block.type == "triangle":
            blocks.append(data)
        elif block.type in ("quad", "polygon") or block.type.startswith("polygon"):
            k = data.shape[1]  # fan: (0, i, i + 1)
            blocks.extend(data[:, [0, i, i + 1]] for i in range(1, k - 1))
    if not blocks:
        kinds = ", ".join(sorted({b.type for b in raw.cells})) or "none"
        raise ValueError(f"no triangles in the file (cells: {kinds})")
    faces = np.concatenate(blocks).astype(np.int64)
    points = np.asarray(raw.points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise ValueError(f"points must have 3 coordinates, got shape {points.shape}")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    data = {k: _native(v) for k, v in raw.point_data.items()}
    normals = None
    if all(k in data for k in ("nx", "ny", "nz")):
        normals = np.column_stack([data.pop("nx"), data.pop("ny"), data.pop("nz")]).astype(np.float64)
    for key in ("Normals", "obj:vn", "normals"):
        if key in data and normals is None and np.shape(data[key]) == points.shape:
            normals = np.asarray(data.pop(key), dtype=np.float64)
    data.pop("obj:vt", None)
    if fmt in ("ply", "vtk"):
        data = _join_columns(data)
    return Mesh(points, faces, normals, data)


def _native(values: Any) -> np.ndarray:
    """An array in native byte order (legacy VTK is big-endian)."""
    arr = np.asarray(values)
    return arr.astype(arr.dtype.newbyteorder("="), copy=False)


def _points_array(values: Any, name: str, n: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(values.detach().cpu() if hasattr(values, "detach") else values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be a numeric array: {err}") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and len(arr) != n):
        want = "(N, 3)" if n is None else f"({n}, 3)"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contain NaN or inf (row {int(np.flatnonzero(~np.isfinite(arr).all(1))[0])})")
    return arr


def save_points(path: str | os.PathLike, points: Any, normals: Any = None) -> None:
    """Write a point cloud (N, 3), with optional normals (N, 3), as XYZ text or binary PLY.

    XYZ: one point per line, ``x y z`` or ``x y z nx ny nz``, every digit of float64.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> path = os.path.join(tempfile.mkdtemp(), "cloud.xyz")
    >>> save_points(path, np.array([[0.0, 0.5, 1.0]]), np.array([[0.0, 0.0, 1.0]]))
    >>> load_points(path).normals
    array([[0., 0., 1.]])
    """
    path, fmt = _format(path, POINT_FORMATS, "point cloud")
    pts = _points_array(points, "points")
    nrm = None if normals is None else _points_array(normals, "normals", len(pts))
    if fmt == "xyz":
        table = pts if nrm is None else np.column_stack([pts, nrm])
        np.savetxt(path, table, fmt="%.17g")
        return
    import meshio

    data = {} if nrm is None else {"nx": nrm[:, 0].copy(), "ny": nrm[:, 1].copy(), "nz": nrm[:, 2].copy()}
    meshio.write(path, meshio.Mesh(pts, [], point_data=data), file_format="ply", binary=True)


def load_points(path: str | os.PathLike) -> PointCloud:
    """Read a point cloud written as XYZ text (3 or 6 columns) or PLY (vertices; nx ny nz if present).

    Returns
    -------
    PointCloud(points (N, 3) float64, normals (N, 3) float64 or None).

    Raises
    ------
    ValueError naming the path and the problem (unknown extension, empty or malformed
    file, a wrong number of columns, NaN); FileNotFoundError when it is missing.
    """
    path, fmt = _format(path, POINT_FORMATS, "point cloud")
    _check_read(path)
    if fmt == "xyz":
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # loadtxt warns on an input without data
                table = np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
        except (ValueError, UnicodeDecodeError) as err:
            raise ValueError(f"cannot read {str(path)!r} as XYZ: {err}") from None
        if table.size == 0:
            raise ValueError(f"{str(path)!r} holds no points")
        if table.shape[1] not in (3, 6):
            raise ValueError(
                f"{str(path)!r}: XYZ rows need 3 (x y z) or 6 (x y z nx ny nz) numbers, got {table.shape[1]}"
            )
        points, normals = table[:, :3], (table[:, 3:] if table.shape[1] == 6 else None)
    else:
        import meshio

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                raw = meshio.ply.read(str(path))
        except Exception as err:
            raise ValueError(f"cannot read {str(path)!r} as PLY: {type(err).__name__}: {err}") from None
        points = np.asarray(raw.points, dtype=np.float64)
        data = raw.point_data
        normals = None
        if all(k in data for k in ("nx", "ny", "nz")):
            normals = np.column_stack([data["nx"], data["ny"], data["nz"]]).astype(np.float64)
    try:
        pts = _points_array(points, "points")
        nrm = None if normals is None else _points_array(normals, "normals", len(pts))
    except ValueError as err:
        raise ValueError(f"{str(path)!r}: {err}") from None
    return PointCloud(pts, nrm)
