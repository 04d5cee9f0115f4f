"""Reading and writing meshes and point clouds; the format follows the file's extension.

Meshes (through meshio): STL (binary, float32 coordinates), OBJ, PLY (binary), OFF and
legacy VTK (binary).  Normals survive OBJ, PLY and VTK; other point data (curvatures,
residuals ...) survives PLY and VTK.  Point clouds: XYZ (plain text, ``x y z`` or
``x y z nx ny nz`` per line) and PLY.

Reading is guarded, since a reader is a parser of whatever bytes it is given: the file's
header is checked first (counts against the file's size: ``OFF\\n`` is refused in
milliseconds where meshio's reader loops forever), then the reader runs in a worker process
(``_io_worker.py``, kept for the next call) that is stopped after :data:`PARSE_SECONDS` plus
one second per :data:`PARSE_BYTES_PER_SECOND` bytes.  Whatever goes wrong (a malformed,
truncated or empty file, a reader that loops or crashes) comes back as a ValueError that
names the path and the reason; the caller's process and threads are never touched (no
signals), so the workbench's background threads can load files.

Point-data names are written as they are, so they must be names the formats can hold: PLY and
legacy VTK separate fields by spaces, and a (V, k) array is stored as the columns
``name_0 .. name_{k-1}`` (joined again on reading).  :func:`save_mesh` refuses, naming the
array, what would not read back as it was: names with spaces or control characters, the
formats' own names (PLY ``x y z nx ny nz``, VTK ``Normals``), names that would merge on
reading (``a_0`` and ``a_1`` beside each other read back as one array ``a``), arrays of
more than two dimensions or of one column.  Rename them (``"mean curvature"`` ->
``"mean_curvature"``); nothing is renamed silently.

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

import atexit
import os
import pickle
import subprocess
import sys
import threading
import warnings
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ._io_worker import HEADER_BYTES, header_problem
from .meshing.files import MESH_FORMATS, _format, _join_columns, write_mesh
from .meshing.mesh_type import Mesh

__all__ = [
    "MESH_FORMATS",
    "POINT_FORMATS",
    "PointCloud",
    "save_mesh",
    "load_mesh",
    "save_points",
    "load_points",
]

POINT_FORMATS = {".xyz": "xyz", ".ply": "ply"}

# A parse may take PARSE_SECONDS plus one second per PARSE_BYTES_PER_SECOND bytes of file.  The
# slowest readers here (meshio's ASCII PLY and OBJ, Python per line) read 4-6 MB/s on a 2-core
# AMD EPYC (10 MB files of 10^5 vertices); 100 kB/s leaves a margin of 40 for slower or busy
# machines.  The fixed part covers the first VTK POLYDATA file (pyvista loads in the worker, ~1 s).
PARSE_SECONDS = 10.0
PARSE_BYTES_PER_SECOND = 1e5
START_SECONDS = 120.0  # a worker's start (Python, numpy, meshio), not counted in the parse's time
_KEEP_WORKERS = 2  # idle workers kept for the next calls (more start when threads read at once)
_WORKER_SCRIPT = str(Path(__file__).with_name("_io_worker.py"))


class PointCloud(NamedTuple):
    """Points (N, 3) float64 and their normals (N, 3) float64, or None."""

    points: np.ndarray
    normals: np.ndarray | None


def _check_read(path: Path, fmt: str, fn: str) -> int:
    """The file's size, once it exists, is a regular file and its header is plausible for ``fmt``."""
    if not path.exists():
        raise FileNotFoundError(f"{fn}: no such file: {str(path)!r}")
    if not path.is_file():
        raise ValueError(f"{fn}: {str(path)!r} is not a file")
    size = path.stat().st_size
    if size == 0:
        raise ValueError(f"{fn}: {str(path)!r} is empty")
    with open(path, "rb") as f:
        head = f.read(HEADER_BYTES)
    problem = header_problem(fmt, head, size)
    if problem is not None:
        raise ValueError(f"{fn}: cannot read {str(path)!r} as {fmt.upper()}: {problem}")
    return size


class _Worker:
    """One reader process (``_io_worker.py``) and its pipes; used by one thread at a time."""

    def __init__(self) -> None:
        env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)  # the caller's meshio, numpy
        # -P: not the script's folder on sys.path (pyfrep_core/io.py would shadow the standard io)
        self.proc = subprocess.Popen(
            [sys.executable, "-P", _WORKER_SCRIPT],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=env,
        )
        self.started = False

    def _receive(self, seconds: float) -> tuple | None:
        """The worker's next answer; None (and the worker stopped) after ``seconds`` without one."""
        box: list[tuple] = []

        def receive() -> None:
            try:
                box.append(pickle.load(self.proc.stdout))
            except Exception:  # EOF or a cut message: the process died
                box.append(("died", self.proc.wait()))

        reader = threading.Thread(target=receive, name="pyfrep-io-reader", daemon=True)
        reader.start()
        reader.join(seconds)
        if reader.is_alive():
            self.stop()
            reader.join()
            return None
        return box[0]

    def ask(self, fmt: str, path: str, seconds: float) -> tuple:
        """("ok", raw) or ("error", message) or ("died", returncode) or ("timeout", seconds)."""
        if not self.started:
            answer = self._receive(START_SECONDS)
            if answer is None or answer[0] != "ready":
                how = "in time" if answer is None else f"(exit status {answer[1]})"
                raise OSError(
                    f"the reader process did not start {how}; `{sys.executable} -P {_WORKER_SCRIPT}` shows why"
                )
            self.started = True
        try:
            pickle.dump((fmt, path), self.proc.stdin)
            self.proc.stdin.flush()
        except OSError:
            return ("died", self.proc.wait())
        answer = self._receive(seconds)
        return ("timeout", seconds) if answer is None else answer

    def stop(self) -> None:
        self.proc.kill()
        self.proc.wait()
        for pipe in (self.proc.stdin, self.proc.stdout):
            try:
                pipe.close()
            except OSError:
                pass

    def close(self) -> None:
        """Let the worker go: it exits when its stdin closes."""
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        self.proc.stdout.close()


_idle_workers: list[_Worker] = []
_idle_lock = threading.Lock()


@atexit.register
def _close_workers() -> None:
    with _idle_lock:
        workers = _idle_workers[:]
        _idle_workers.clear()
    for worker in workers:
        worker.close()


def _parse(fmt: str, path: Path, size: int, fn: str) -> dict[str, Any]:
    """Read ``path`` in a worker process within the time its size allows; ValueError for whatever fails."""
    seconds = PARSE_SECONDS + size / PARSE_BYTES_PER_SECOND
    for attempt in range(2):
        with _idle_lock:
            worker = _idle_workers.pop() if _idle_workers else None
        pooled = worker is not None and worker.proc.poll() is None
        if worker is not None and not pooled:
            worker.stop()  # ended from outside while idle
        if not pooled:
            try:
                worker = _Worker()
            except OSError as err:
                raise OSError(f"{fn}: cannot start a reader process ({sys.executable}): {err}") from None
        try:
            answer = worker.ask(fmt, str(path), seconds)
        except OSError as err:  # it did not start
            worker.stop()
            raise OSError(f"{fn}: {err}") from None
        if answer[0] in ("ok", "error"):
            with _idle_lock:
                if len(_idle_workers) < _KEEP_WORKERS:
                    _idle_workers.append(worker)
                    worker = None
            if worker is not None:
                worker.close()
            break
        worker.stop()
        if answer[0] == "died" and pooled and attempt == 0:
            continue  # an idle worker that was ended from outside: once more with a fresh one
        break
    where = f"{fn}: cannot read {str(path)!r} as {fmt.upper()}"
    if answer[0] == "ok":
        return answer[1]
    if answer[0] == "error":
        raise ValueError(f"{where}: {answer[1]}")
    if answer[0] == "timeout":
        raise ValueError(
            f"{where}: the reader did not finish within {seconds:.0f} s (for {size} bytes) and was stopped; "
            "the file is malformed in a way that makes the reader loop"
        )
    code = answer[1]
    how = f"signal {-code}" if code < 0 else f"exit status {code}"
    raise ValueError(f"{where}: the reader process died ({how}) on this file")


def save_mesh(mesh: Mesh, path: str | os.PathLike) -> None:
    """Write ``mesh`` to ``path``; the format follows the extension (.stl .obj .ply .off .vtk).

    Parameters
    ----------
    mesh : Mesh
    path : file name; STL is written binary (float32 coordinates), PLY and VTK binary
        (float64), OBJ and OFF as text with every digit of the float64 coordinates.
        Normals are written to OBJ, PLY and VTK, other point data to PLY and VTK only
        (under names that read back as they are: see the module's docstring).

    Raises
    ------
    ValueError for an unknown extension (the message lists the supported ones), an empty
    mesh, or point data PLY / VTK cannot hold under its name, shape or dtype (the message
    names the array); TypeError when ``mesh`` is not a Mesh.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> tri = Mesh(np.eye(3), np.array([[0, 1, 2]]), point_data={"mean curvature": np.ones(3)})
    >>> save_mesh(tri, os.path.join(tempfile.mkdtemp(), "tri.ply"))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ValueError: save_mesh: point_data['mean curvature']: PLY separates fields by spaces, ... 'mean_curvature')
    """
    if not isinstance(mesh, Mesh):
        raise TypeError(f"save_mesh: mesh must be a pyfrep_core Mesh, got {type(mesh).__name__}")
    write_mesh(mesh, path)


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read a triangle mesh; the format follows the extension (.stl .obj .ply .off .vtk).

    Quads and polygons are split into triangles (fans), in OFF, OBJ, PLY and VTK alike.
    Normals are taken from the file where it has them (VTK ``Normals``, PLY ``nx ny nz``,
    OBJ ``vn``); other point data is kept in ``point_data``.  STL repeats vertices per
    triangle: they are merged.  OBJ relative indices (``-1``: the last vertex so far) and
    legacy VTK ``POLYDATA`` (read by VTK itself) are read too.

    The header is checked first, then the file is read in a worker process that is stopped
    after a time proportional to the file's size (see the module's docstring): a reader
    that would loop forever gives a ValueError instead.

    Raises
    ------
    ValueError naming the path and the problem for an unknown extension, an empty,
    malformed or truncated file, or one without triangles; FileNotFoundError when it is
    missing.

    Examples
    --------
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "square.off")
    >>> with open(path, "w") as f:
    ...     _ = f.write("OFF\\n4 1 0\\n0 0 0\\n1 0 0\\n1 1 0\\n0 1 0\\n4 0 1 2 3\\n")
    >>> load_mesh(path).faces
    array([[0, 1, 2],
           [0, 2, 3]])
    >>> with open(path, "w") as f:
    ...     _ = f.write("OFF\\n")
    >>> load_mesh(path)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ValueError: load_mesh: cannot read '...square.off' as OFF: no count line (vertices faces edges) after `OFF`...
    """
    path, fmt = _format(path, MESH_FORMATS, "load_mesh")
    size = _check_read(path, fmt, "load_mesh")
    raw = _parse(fmt, path, size, "load_mesh")
    try:
        return _to_mesh(raw, fmt)
    except (ValueError, TypeError, IndexError) as err:
        raise ValueError(f"load_mesh: {str(path)!r} is not a valid triangle mesh: {err}") from None


def _to_mesh(raw: dict[str, Any], fmt: str) -> Mesh:
    blocks = []
    for kind, data in raw["cells"]:
        data = np.asarray(data)
        if data.ndim != 2 or data.dtype.kind not in "iu":
            raise ValueError(f"{kind} cells must be a table of integer indices, got {data.dtype} {data.shape}")
        if kind == "triangle":
            blocks.append(data)
        elif kind in ("quad", "polygon") or kind.startswith("polygon"):
            k = data.shape[1]  # fan: (0, i, i + 1)
            blocks.extend(data[:, [0, i, i + 1]] for i in range(1, k - 1))
    if not blocks:
        kinds = ", ".join(sorted({kind for kind, _ in raw["cells"]})) or "none"
        raise ValueError(f"no triangles in the file (cells: {kinds})")
    faces = np.concatenate(blocks).astype(np.int64)
    if len(faces) == 0:
        raise ValueError("no triangles in the file (its face lists are empty)")
    with np.errstate(invalid="ignore", over="ignore"):  # NaN and inf are refused by Mesh, by name
        points = np.asarray(raw["points"], dtype=np.float64)
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise ValueError(f"points must have 3 coordinates, got shape {points.shape}")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    data = {k: _native(v) for k, v in raw["point_data"].items()}
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


def _points_array(values: Any, name: str, fn: str, n: int | None = None) -> np.ndarray:
    """(N >= 1, 3) finite float64 ``values`` (numpy or torch), or an error naming ``fn`` and ``name``."""
    try:
        arr = np.asarray(values.detach().cpu() if hasattr(values, "detach") else values, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{fn}: {name} must be a numeric array: {err}") from None
    if arr.ndim != 2 or arr.shape[1] != 3 or (n is not None and len(arr) != n):
        want = "(N, 3)" if n is None else f"({n}, 3)"
        raise ValueError(f"{fn}: {name} must have shape {want}, got {arr.shape}")
    if len(arr) == 0:
        raise ValueError(f"{fn}: {name} is empty (shape {arr.shape}); give at least one point")
    if not np.isfinite(arr).all():
        raise ValueError(f"{fn}: {name} contain NaN or inf (row {int(np.flatnonzero(~np.isfinite(arr).all(1))[0])})")
    return arr


def save_points(points: Any, path: str | os.PathLike, normals: Any = None) -> None:
    """Write a point cloud (N, 3), with optional normals (N, 3), as XYZ text or binary PLY.

    The data first, then the file, as in :func:`save_mesh` (``save_mesh(mesh, path)``).
    XYZ: one point per line, ``x y z`` or ``x y z nx ny nz``, every digit of float64.

    Parameters
    ----------
    points : (N, 3) array (numpy or torch), finite
    path : file name ending in .xyz or .ply.  The old order ``save_points(path, points)``
        still works (a path where the points belong cannot be points) with a DeprecationWarning.
    normals : (N, 3) array or None

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> path = os.path.join(tempfile.mkdtemp(), "cloud.xyz")
    >>> save_points(np.array([[0.0, 0.5, 1.0]]), path, np.array([[0.0, 0.0, 1.0]]))
    >>> load_points(path).normals
    array([[0., 0., 1.]])
    """
    if isinstance(points, str | os.PathLike) and not isinstance(path, str | os.PathLike):
        warnings.warn(
            "save_points(path, points) is deprecated: the points come first, as in save_mesh(mesh, path); "
            "call save_points(points, path)",
            DeprecationWarning,
            stacklevel=2,
        )
        points, path = path, points
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"save_points: path must be a str or os.PathLike, got {type(path).__name__}")
    path, fmt = _format(path, POINT_FORMATS, "save_points")
    pts = _points_array(points, "points", "save_points")
    nrm = None if normals is None else _points_array(normals, "normals", "save_points", len(pts))
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
    path, fmt = _format(path, POINT_FORMATS, "load_points")
    size = _check_read(path, fmt, "load_points")
    if fmt == "xyz":  # numpy's C parser: it cannot loop, so it runs here
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # loadtxt warns on an input without data
                table = np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
        except (ValueError, UnicodeDecodeError) as err:
            raise ValueError(f"load_points: cannot read {str(path)!r} as XYZ: {err}") from None
        if table.size == 0:
            raise ValueError(f"load_points: {str(path)!r} holds no points")
        if table.shape[1] not in (3, 6):
            raise ValueError(
                f"load_points: {str(path)!r}: XYZ rows need 3 (x y z) or 6 (x y z nx ny nz) numbers, "
                f"got {table.shape[1]}"
            )
        points, normals = table[:, :3], (table[:, 3:] if table.shape[1] == 6 else None)
    else:
        raw = _parse(fmt, path, size, "load_points")
        points = raw["points"]
        data = raw["point_data"]
        normals = None
        if all(k in data for k in ("nx", "ny", "nz")):
            normals = np.column_stack([np.ravel(data["nx"]), np.ravel(data["ny"]), np.ravel(data["nz"])])
    try:
        pts = _points_array(points, "points", "load_points")
        nrm = None if normals is None else _points_array(normals, "normals", "load_points", len(pts))
    except (ValueError, TypeError) as err:
        raise ValueError(f"load_points: {str(path)!r}: {str(err).removeprefix('load_points: ')}") from None
    return PointCloud(pts, nrm)
