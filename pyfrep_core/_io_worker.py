"""The mesh readers behind :func:`pyfrep_core.io.load_mesh`, run in a worker process.

:mod:`pyfrep_core.io` starts this file as a script (``python -P _io_worker.py``) and sends it
requests, a pickled ``(fmt, path)`` each, on stdin; it answers each with a pickled
``("ok", {"points", "cells", "point_data"})`` or ``("error", message)`` on stdout.  A reader
that loops forever or crashes takes only this process with it: the caller waits a time
proportional to the file's size, then kills it and reports the file (see ``io._parse``).
Importing this module is cheap (numpy only); meshio and pyvista load on first use.

The header checks (:func:`header_problem`) run in the caller before any reader: they refuse
files whose header is missing, cut short or inconsistent (counts that need more bytes than
the file has) with the reason, in milliseconds.  meshio 5.3 needs them: its OFF and PLY
readers loop forever on a file that ends inside the header (``OFF\\n`` is four bytes).

Where meshio refuses valid files, the reader here mends the input or reads it another way:
OFF with quads or polygons (meshio reads triangles only) has its own reader below, the whole
format being a count line, one vertex per line and one ``k i1 .. ik`` face per line; OBJ
relative (negative) indices are rewritten as absolute ones before meshio reads the text;
legacy VTK ``POLYDATA`` (meshio reads unstructured grids only) is read by pyvista (VTK's own
reader); an ASCII PLY with one vertex (meshio's per-vertex arrays come out 0-d) is mended
by :func:`_mesh_with_1d_point_data`.
"""

from __future__ import annotations

import io
import os
import pickle
import re
import sys
from typing import Any

import numpy as np

HEADER_BYTES = 1 << 16  # the header checks look at the file's first 64 KiB

# bytes per value of each PLY property type
_PLY_SIZES = {
    "char": 1,
    "uchar": 1,
    "int8": 1,
    "uint8": 1,
    "short": 2,
    "ushort": 2,
    "int16": 2,
    "uint16": 2,
    "int": 4,
    "uint": 4,
    "int32": 4,
    "uint32": 4,
    "float": 4,
    "float32": 4,
    "int64": 8,
    "uint64": 8,
    "double": 8,
    "float64": 8,
}
_VTK_SIZES = {
    "bit": 1,
    "unsigned_char": 1,
    "char": 1,
    "unsigned_short": 2,
    "short": 2,
    "unsigned_int": 4,
    "int": 4,
    "float": 4,
    "unsigned_long": 8,
    "long": 8,
    "double": 8,
    "vtktypeint64": 8,
    "vtktypeuint64": 8,
    "vtkidtype": 8,
}


class ReadError(ValueError):
    """A file this module cannot read; the message says why."""


def _lines(text: str) -> list[str]:
    """The non-empty lines of ``text`` with ``#`` comments removed (OFF)."""
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            out.append(line)
    return out


def _off_header(head: bytes) -> tuple[int, int, int]:
    """(vertices, faces, index of the first vertex line) from an OFF file's start; ReadError if malformed."""
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        raise ReadError("not an ASCII text file (OFF is text)") from None
    lines = _lines(text[: text.rfind("\n") + 1] if len(head) == HEADER_BYTES else text)
    if not lines or lines[0].split()[0] != "OFF":
        raise ReadError("the first line must be `OFF`")
    tokens = lines[0].split()[1:]  # the counts may follow OFF on its line
    first = 1
    if not tokens:
        if len(lines) < 2:
            raise ReadError("no count line (vertices faces edges) after `OFF`: the file ends in its header")
        tokens, first = lines[1].split(), 2
    try:
        counts = [int(t) for t in tokens]
    except ValueError:
        raise ReadError(f"the count line must hold integers (vertices faces edges), got {' '.join(tokens)!r}") from None
    if len(counts) not in (2, 3) or min(counts) < 0:
        raise ReadError(f"the count line must be 'vertices faces [edges]' >= 0, got {' '.join(tokens)!r}")
    return counts[0], counts[1], first


def _off_size_problem(head: bytes, size: int) -> str | None:
    nv, nf, _ = _off_header(head)
    need = 6 * nv + 8 * nf - 1  # at least "x y z\n" per vertex and "3 i j k\n" per face
    if need > size:
        return f"the count line announces {nv} vertices and {nf} faces, needing {need}+ bytes; the file has {size}"
    return None


def _ply_header(head: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, ...]]]], int]:
    """(format, [(element, count, properties)], header length in bytes) of a PLY file; ReadError if malformed."""
    if not re.match(rb"ply[ \t]*\r?\n", head):
        raise ReadError("the first line must be `ply`")
    end = re.search(rb"(?m)^end_header[ \t]*(\r?\n|$)", head)
    if end is None:
        raise ReadError(f"no `end_header` line in the first {len(head)} bytes: the header is cut short")
    try:
        lines = head[: end.start()].decode("utf-8").splitlines()[1:]
    except UnicodeDecodeError:
        raise ReadError("the header is not text") from None
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, ...]]]] = []
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in ("ascii", "binary_little_endian", "binary_big_endian"):
                raise ReadError(f"unknown format line {line.strip()!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ReadError(f"an element line is 'element <name> <count>', got {line.strip()!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise ReadError(f"property before any element: {line.strip()!r}")
            is_list = len(words) > 1 and words[1] == "list"
            types = words[2:4] if is_list else words[1:2]
            if len(words) != (5 if is_list else 3) or any(t not in _PLY_SIZES for t in types):
                raise ReadError(f"a property line is 'property <type> <name>' with a PLY type, got {line.strip()!r}")
            elements[-1][2].append(tuple(words[1:]))
        else:
            raise ReadError(f"unexpected header line {line.strip()!r}")
    if fmt is None:
        raise ReadError("no format line in the header")
    return fmt, elements, end.end()


def _ply_size_problem(head: bytes, size: int) -> str | None:
    fmt, elements, start = _ply_header(head)
    need = 0
    for name, count, props in elements:
        if fmt == "ascii":  # a value and a separator per property (a list: its length)
            row = 2 * len(props)
        else:  # the scalars' sizes; a list at least its length's
            row = sum(_PLY_SIZES[p[1]] if p[0] == "list" else _PLY_SIZES[p[0]] for p in props)
        need += count * row
        if name == "vertex" and [p[-1] for p in props[:3]] != ["x", "y", "z"]:
            raise ReadError("the vertex element must start with the properties x, y, z")
    if fmt == "ascii":
        need -= 1  # the last value needs no separator
    if need > size - start:
        counts = ", ".join(f"{count} {name}" for name, count, _ in elements)
        return f"the header announces {counts}, which need at least {need} bytes after it; the file has {size - start}"
    return None


def _vtk_header(head: bytes) -> dict[str, Any]:
    """The dataset type and the POINTS count of a legacy VTK file; ReadError if malformed."""
    lines = head.split(b"\n", 4)
    if not lines[0].startswith(b"# vtk DataFile Version"):
        raise ReadError("the first line must be `# vtk DataFile Version x.y`")
    if len(lines) < 5:
        raise ReadError("the file ends in its header (version, title, ASCII|BINARY, DATASET)")
    kind = lines[2].strip().upper()
    if kind not in (b"ASCII", b"BINARY"):
        raise ReadError(f"the third line must be ASCII or BINARY, got {lines[2][:40]!r}")
    dataset = re.match(rb"\s*DATASET\s+(\w+)", lines[3] + b"\n" + lines[4])
    if dataset is None:
        raise ReadError(f"the fourth line must be `DATASET <type>`, got {lines[3][:40]!r}")
    info: dict[str, Any] = {"dataset": dataset.group(1).decode().upper(), "binary": kind == b"BINARY"}
    points = re.search(rb"(?m)^\s*POINTS\s+(\d+)\s+(\w+)", head)
    if points is not None:
        info["points"] = int(points.group(1)), points.group(2).decode().lower(), points.end()
    return info


def _vtk_size_problem(head: bytes, size: int) -> str | None:
    info = _vtk_header(head)
    if "points" in info:
        n, kind, at = info["points"]
        if kind not in _VTK_SIZES:
            raise ReadError(f"unknown POINTS data type {kind!r}")
        need = 3 * n * _VTK_SIZES[kind] if info["binary"] else 6 * n - 1
        if need > size - at:
            return f"POINTS {n} need at least {need} bytes; {size - at} follow"
    return None


def _stl_size_problem(head: bytes, size: int) -> str | None:
    if size >= 84:
        n = int(np.frombuffer(head[80:84], dtype="<u4")[0])
        if 84 + 50 * n == size:
            return None  # binary: 80-byte header, count, 50 bytes per triangle
        if not head.lstrip().startswith(b"solid"):
            return (
                f"neither binary STL (its count, {n} triangles, needs 84 + 50 x {n} = {84 + 50 * n} bytes; "
                f"the file has {size}) nor ASCII STL (which starts with `solid`)"
            )
    elif not head.lstrip().startswith(b"solid"):
        return f"too short for binary STL ({size} < 84 bytes) and not ASCII STL (which starts with `solid`)"
    return None


def header_problem(fmt: str, head: bytes, size: int) -> str | None:
    """Why a file of ``size`` bytes starting with ``head`` cannot be a valid ``fmt`` file, or None.

    ``head`` is the file's first :data:`HEADER_BYTES` bytes (or the whole file).  Counts in the
    header are checked against the size (each vertex and face needs a minimum of bytes).

    >>> header_problem("off", b"OFF\\n", 4)
    'no count line (vertices faces edges) after `OFF`: the file ends in its header'
    >>> header_problem("off", b"OFF\\n3 1 0\\n0 0 0\\n1 0 0\\n0 1 0\\n3 0 1 2\\n", 38) is None
    True
    """
    checks = {"off": _off_size_problem, "ply": _ply_size_problem, "vtk": _vtk_size_problem, "stl": _stl_size_problem}
    try:
        if fmt in checks:
            return checks[fmt](head, size)
        if fmt in ("obj", "xyz") and b"\0" in head:
            return "binary data (NUL bytes) in a text format"
    except ReadError as err:
        return str(err)
    return None


def read_off(path: str) -> dict[str, Any]:
    """An OFF file's vertices and faces (triangles, quads, polygons), comments and face colours ignored."""
    with open(path, "rb") as f:
        data = f.read()
    nv, nf, first = _off_header(data)
    try:
        lines = _lines(data.decode("ascii"))
    except UnicodeDecodeError:
        raise ReadError("not an ASCII text file (OFF is text)") from None
    vlines, flines = lines[first : first + nv], lines[first + nv : first + nv + nf]
    if len(vlines) < nv or len(flines) < nf:
        raise ReadError(
            f"truncated: the count line announces {nv} vertices and {nf} faces, "
            f"the file has {len(vlines)} vertex and {len(flines)} face lines"
        )
    try:
        points = _off_vertices(vlines)
        groups = _off_faces(flines)
    except ValueError as err:
        if isinstance(err, ReadError):
            raise
        raise ReadError(f"a vertex or face line holds something else than numbers: {err}") from None
    names = {3: "triangle", 4: "quad"}
    cells = [(names.get(k, "polygon"), faces) for k, faces in sorted(groups.items())]
    return {"points": points, "cells": cells, "point_data": {}}


def _off_vertices(lines: list[str]) -> np.ndarray:
    """(N, 3) coordinates from OFF vertex lines (``x y z``, anything after ignored)."""
    try:  # numpy's parser, when every line has as many numbers
        table = np.loadtxt(lines, dtype=np.float64, ndmin=2, comments=None)
        if table.shape[1] >= 3 or not lines:
            return table[:, :3].reshape(len(lines), 3)
    except ValueError:
        pass
    rows = [line.split() for line in lines]
    bad = next((i for i, r in enumerate(rows) if len(r) < 3), None)
    if bad is not None:
        raise ReadError(f"vertex {bad} needs 3 coordinates, got {lines[bad]!r}")
    return np.array([r[:3] for r in rows], dtype=np.float64).reshape(len(lines), 3)


def _off_faces(lines: list[str]) -> dict[int, np.ndarray]:
    """Faces by their number of corners k from OFF face lines (``k i1 .. ik``, a colour after ignored)."""
    try:  # numpy's parser, when every face has as many corners (and integers only)
        table = np.loadtxt(lines, dtype=np.int64, ndmin=2, comments=None)
        k = int(table[0, 0]) if len(table) else 3
        if len(table) and (table[:, 0] == k).all() and k >= 3 and table.shape[1] > k:
            return {k: table[:, 1 : k + 1]}
    except ValueError:
        pass
    groups: dict[int, list[list[int]]] = {}
    for i, line in enumerate(lines):
        words = line.split()
        k = int(words[0])
        if k < 3 or len(words) < k + 1:
            raise ReadError(f"face {i} must be 'k i1 .. ik' with k >= 3, got {line!r}")
        groups.setdefault(k, []).append([int(w) for w in words[1 : k + 1]])
    return {k: np.array(faces, dtype=np.int64) for k, faces in groups.items()}


_OBJ_FACE = re.compile(r"(?m)^[ \t]*f[ \t][^\n]*-")


def _absolute_obj_indices(text: str) -> str:
    """OBJ text with relative face indices (``-1`` = the last vertex so far) made absolute."""
    out, counts = [], {"v": 0, "vt": 0, "vn": 0}
    for line in text.splitlines(keepends=True):
        words = line.split()
        if words and words[0] in counts:
            counts[words[0]] += 1
        elif words and words[0] == "f" and "-" in line:
            corners = []
            for word in words[1:]:
                parts = word.split("/")
                for j, (part, key) in enumerate(zip(parts, ("v", "vt", "vn"))):
                    if part.startswith("-"):
                        parts[j] = str(counts[key] + 1 + int(part))
                corners.append("/".join(parts))
            line = "f " + " ".join(corners) + "\n"
        out.append(line)
    return "".join(out)


def read_obj(path: str) -> dict[str, Any]:
    import meshio

    with open(path, encoding="utf-8") as f:
        text = f.read()
    if _OBJ_FACE.search(text):
        text = _absolute_obj_indices(text)
    return _plain(meshio.obj.read(io.StringIO(text)))  # meshio takes a text buffer as a file


_VTK_FIELD_ARRAY = re.compile(r"\S+\s+(\d+)\s+(\d+)\s+[A-Za-z_]\w*")
_VTK_CELLS = ("POLYGONS", "LINES", "VERTICES", "TRIANGLE_STRIPS", "CELLS")


def _vtk_ascii_cut(text: str) -> str | None:
    """Why an ASCII legacy VTK file ends inside a section (it was cut short), or None.

    Sections announce their sizes (``POINTS n``: 3n numbers, ``SCALARS`` after ``POINT_DATA n``:
    n per component ...); a file cut short lacks numbers at the end of its last section.  VTK's
    own reader fills what is missing without a word, so this is checked before it runs.

    >>> _vtk_ascii_cut("DATASET POLYDATA\\nPOINTS 2 float\\n0 0 0\\n1 0\\n")
    'the file ends inside its POINTS section: 5 of its 6 numbers are there'
    """
    lines = text.splitlines()
    n = ncomp = 0
    cells = (0, 0)
    last: tuple[int, str, int] | None = None  # (line, section, numbers it announces)
    for i, line in enumerate(lines):
        words = line.split()
        if not words or not words[0][0].isalpha() or words[0].lower() in ("nan", "inf", "infinity"):
            continue
        key = words[0].upper()
        try:
            if key == "POINTS":
                expected = 3 * int(words[1])
            elif key in _VTK_CELLS:
                cells = (int(words[1]), int(words[2]))
                expected = cells[1]
            elif key in ("OFFSETS", "CONNECTIVITY", "CELL_TYPES"):  # VTK 5.1 cells; 4.2 unstructured grids
                expected = cells[0] if key == "OFFSETS" else cells[1] if key == "CONNECTIVITY" else int(words[1])
            elif key in ("POINT_DATA", "CELL_DATA"):
                n, expected = int(words[1]), 0
            elif key == "SCALARS":
                ncomp = int(words[3]) if len(words) > 3 else 1
                expected = n * ncomp
            elif key == "LOOKUP_TABLE":
                expected = 4 * int(words[2]) if len(words) > 2 else n * ncomp
            elif key in ("VECTORS", "NORMALS"):
                expected = 3 * n
            elif key in ("TEXTURE_COORDINATES", "COLOR_SCALARS"):
                expected = int(words[2]) * n
            elif key in ("TENSORS", "TENSORS6"):
                expected = (6 if key == "TENSORS6" else 9) * n
            elif key == "FIELD":
                expected = 0
            elif _VTK_FIELD_ARRAY.fullmatch(line.strip()):
                expected = int(words[1]) * int(words[2])
            else:  # DATASET, METADATA and its lines
                continue
        except (IndexError, ValueError):
            return f"malformed section line {line.strip()[:60]!r}"
        last = (i, key, expected)
    if last is None:
        return None
    i, key, expected = last
    found = sum(len(line.split()) for line in lines[i + 1 :])
    if found < expected:
        return f"the file ends inside its {key} section: {found} of its {expected} numbers are there"
    return None


def read_vtk(path: str) -> dict[str, Any]:
    with open(path, "rb") as f:
        data = f.read()
    info = _vtk_header(data[:HEADER_BYTES])
    if not info["binary"]:
        problem = _vtk_ascii_cut(data.decode("ascii", errors="replace"))
        if problem is not None:
            raise ReadError(problem)
    if info["dataset"] != "POLYDATA":
        import meshio

        return _plain(meshio.vtk.read(path))
    import warnings

    import pyvista as pv

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a VTK warning (below) is a failed read too
        with pv.VtkErrorCatcher(raise_errors=True, emit_warnings=True, send_to_logging=False):
            poly = pv.read(path)
    if not isinstance(poly, pv.PolyData) or poly.n_points == 0:
        raise ReadError("VTK's reader found no points in the POLYDATA")
    n = info.get("points", (poly.n_points,))[0]
    if poly.n_points != n:
        raise ReadError(f"POINTS announces {n} points, VTK's reader found {poly.n_points}")
    tri = poly.triangulate()
    faces = np.asarray(tri.faces, dtype=np.int64).reshape(-1, 4)
    if faces.size and not (faces[:, 0] == 3).all():
        raise ReadError("the polygons could not be split into triangles")
    point_data = {name: np.asarray(tri.point_data[name]) for name in tri.point_data.keys()}
    return {
        "points": np.asarray(tri.points, dtype=np.float64),
        "cells": [("triangle", faces[:, 1:])],
        "point_data": point_data,
    }


def read_ply(path: str) -> dict[str, Any]:
    """meshio's PLY reader, its result checked against the header's counts (it reads a cut face list short)."""
    import meshio

    with open(path, "rb") as f:
        _, elements, _ = _ply_header(f.read(HEADER_BYTES))
    out = _plain(meshio.ply.read(path))
    counts = {name: count for name, count, _ in elements}
    found = {"vertex": len(out["points"]), "face": sum(len(data) for _, data in out["cells"])}
    for name in ("vertex", "face"):
        if counts.get(name, 0) != found[name]:
            raise ReadError(f"the header announces {counts.get(name, 0)} {name} elements, the file holds {found[name]}")
    return out


def _read_with(module: str) -> Any:
    def read(path: str) -> dict[str, Any]:
        import meshio

        return _plain(getattr(meshio, module).read(path))

    return read


READERS = {"off": read_off, "obj": read_obj, "vtk": read_vtk, "ply": read_ply, "stl": _read_with("stl")}


def _plain(raw: Any) -> dict[str, Any]:
    """A meshio Mesh as plain arrays (what crosses the pipe)."""
    return {
        "points": np.asarray(raw.points),
        "cells": [(block.type, np.asarray(block.data)) for block in raw.cells],
        "point_data": {k: np.asarray(v) for k, v in raw.point_data.items()},
    }


def read(fmt: str, path: str) -> dict[str, Any]:
    """Read ``path`` as ``fmt`` (see :data:`READERS`), in this process."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # meshio's and pyvista's notes on formats
        return READERS[fmt](path)


def _mesh_with_1d_point_data(points: Any, cells: Any, point_data: Any = None, **kwargs: Any) -> Any:
    """meshio.Mesh with every point-data array at least 1-d (a one-row PLY gives 0-d ones)."""
    import meshio

    point_data = {k: np.atleast_1d(v) for k, v in (point_data or {}).items()}
    return meshio.Mesh(points, cells, point_data=point_data, **kwargs)


def _limit_memory(size: int) -> None:
    """Cap this process's address space for one request: a count mutated into 10^12 fails here, not in swap."""
    try:
        import resource

        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        soft = used + (2 << 30) + 64 * size  # importing pyvista (VTK) adds ~0.2 GiB
        resource.setrlimit(resource.RLIMIT_AS, (soft if hard == resource.RLIM_INFINITY else min(soft, hard), hard))
    except (ImportError, OSError, ValueError):
        pass  # not Linux: no cap


def main() -> None:
    """Serve requests until stdin closes (the caller exited or let this worker go)."""
    out = os.fdopen(os.dup(1), "wb")  # the answers; C code printing to stdout must not mix into them
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import meshio.ply._ply

    meshio.ply._ply.Mesh = _mesh_with_1d_point_data  # this process only
    pickle.dump(("ready", os.getpid()), out)
    out.flush()
    stdin = sys.stdin.buffer
    while True:
        try:
            fmt, path = pickle.load(stdin)
        except EOFError:
            return
        try:
            _limit_memory(os.path.getsize(path) if os.path.isfile(path) else 0)
            answer: tuple = ("ok", read(fmt, path))
        except MemoryError:
            answer = ("error", "MemoryError: the file's counts need more memory than its size explains")
        except Exception as err:  # every reader's own error kinds (ReadError, struct.error, IndexError ...)
            answer = ("error", f"{type(err).__name__}: {err}")
        pickle.dump(answer, out, protocol=pickle.HIGHEST_PROTOCOL)
        out.flush()


if __name__ == "__main__":
    main()
