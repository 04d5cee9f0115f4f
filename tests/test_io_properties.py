"""Property-based tests of the mesh and point-cloud files (hypothesis).

Round trips: a random mesh (vertices anywhere in [-1e6, 1e6] down to subnormals, random
triangles, degenerate ones included, normals, point data of random names, widths and dtypes)
written and read back is the same mesh, to the precision the format stores:

- PLY and VTK are binary float64 (point data in its own dtype): bit for bit;
- OBJ and OFF are text written with Python's ``repr`` of each float64 (the shortest string
  that reads back as the same double) and read with a correctly rounded parser: bit for bit;
- STL stores float32 coordinates, each the float64 rounded to nearest float32: every corner of
  every triangle read back equals ``np.float32(x)`` exactly (vertices are merged on reading,
  so the comparison is per corner); STL keeps no normals and no point data.

Loaders never hang: random bytes (bare or behind each format's magic line or a valid header),
truncations and byte mutations of valid files either read or raise ValueError, each within
``PATIENCE`` seconds (less than the worker's time limit, so a hang that only the guard stops
fails here).  Files with counts in their header (OFF, PLY, VTK, binary STL) that lose any
byte other than trailing whitespace are refused, never read in part.

Examples are derandomized (the same on every run) and bounded, so the file runs in seconds.
"""

from __future__ import annotations

import contextlib
import io
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from test_io import within

from pyfrep_core import Mesh, load_mesh, load_points, save_mesh, save_points

COMMON = {
    "deadline": None,  # each load's time is checked against PATIENCE instead
    "derandomize": True,  # the same examples on every machine and every run
    "database": None,  # nothing read from or written to .hypothesis/
    "suppress_health_check": [HealthCheck.too_slow, HealthCheck.data_too_large],
}
FORMATS = [".ply", ".vtk", ".obj", ".off", ".stl"]
RESERVED = {"x", "y", "z", "nx", "ny", "nz", "Normals", "normals"}
OUTCOMES: Counter = Counter()  # inputs tried per outcome, printed at the end (pytest -s)


@pytest.fixture(scope="module", autouse=True)
def report_outcomes():
    yield
    print(f"\ntest_io_properties: inputs per outcome: {dict(sorted(OUTCOMES.items()))}")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("io_properties")


coordinates = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, width=64)


@st.composite
def meshes(draw, max_vertices=10):
    """A Mesh with random vertices, triangles (any indices, repeated ones too), normals and point data."""
    n = draw(st.integers(3, max_vertices))
    vertices = draw(hnp.arrays(np.float64, (n, 3), elements=coordinates))
    faces = draw(hnp.arrays(np.int64, (draw(st.integers(1, 12)), 3), elements=st.integers(0, n - 1)))
    normals = draw(st.none() | hnp.arrays(np.float64, (n, 3), elements=coordinates))
    names = draw(st.lists(st.from_regex(r"[A-Za-z][A-Za-z0-9.#-]{0,7}", fullmatch=True), max_size=3, unique=True))
    data = {}
    for name in names:
        if name in RESERVED:
            continue
        width = draw(st.sampled_from([1, 2, 3, 4]))
        dtype = draw(st.sampled_from([np.float64, np.float32, np.int32, np.uint8]))
        data[name] = draw(hnp.arrays(dtype, (n,) if width == 1 else (n, width)))  # NaN and inf included
    return Mesh(vertices, faces, normals, data)


@settings(max_examples=40, **COMMON)
@given(mesh=meshes(), ext=st.sampled_from(FORMATS))
def test_random_meshes_read_back_as_written(folder, mesh, ext):
    path = folder / f"round_trip{ext}"
    save_mesh(mesh, path)
    back, _ = within(load_mesh, path)
    assert isinstance(back, Mesh), back
    if ext == ".stl":  # float32 per corner, nothing else
        corners = mesh.vertices.astype(np.float32).astype(np.float64)[mesh.faces]
        np.testing.assert_array_equal(back.vertices[back.faces], corners)
        assert back.normals is None and back.point_data == {}
        OUTCOMES["correct result"] += 1
        return
    np.testing.assert_array_equal(back.vertices, mesh.vertices)
    np.testing.assert_array_equal(back.faces, mesh.faces)
    if ext == ".off" or mesh.normals is None:
        assert back.normals is None
    else:
        np.testing.assert_array_equal(back.normals, mesh.normals)
    kept = mesh.point_data if ext in (".ply", ".vtk") else {}
    assert set(back.point_data) == set(kept)
    for name, values in kept.items():
        np.testing.assert_array_equal(back.point_data[name], values)  # NaN where NaN
        assert back.point_data[name].dtype == values.dtype
    OUTCOMES["correct result"] += 1


@settings(max_examples=20, **COMMON)
@given(
    points=hnp.arrays(np.float64, st.tuples(st.integers(1, 20), st.just(3)), elements=coordinates),
    with_normals=st.booleans(),
    ext=st.sampled_from([".xyz", ".ply"]),
)
def test_random_point_clouds_read_back_as_written(folder, points, with_normals, ext):
    path = folder / f"cloud{ext}"
    normals = -points if with_normals else None
    save_points(points, path, normals)
    cloud, _ = within(load_points, path)
    np.testing.assert_array_equal(cloud.points, points)  # XYZ: %.17g; PLY: float64
    if with_normals:
        np.testing.assert_array_equal(cloud.normals, normals)
    else:
        assert cloud.normals is None
    OUTCOMES["correct result"] += 1


def outcome_of(load, path):
    """Load under the time limit: a result or a ValueError naming the file; anything else fails."""
    result, _ = within(load, path)
    if isinstance(result, ValueError):
        assert str(path) in str(result), result
        OUTCOMES["clear error"] += 1
    else:
        assert not isinstance(result, BaseException), repr(result)
    return result


def count_read(result):
    if not isinstance(result, ValueError):
        OUTCOMES["read, a valid file (values not checked)"] += 1


MAGIC = {  # what makes each reader go past its first line
    ".off": [b"OFF\n", b"OFF\n3 1 0\n"],
    ".ply": [
        b"ply\n",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        b"element face 1\nproperty list uchar int vertex_indices\nend_header\n",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
        b"property double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n",
    ],
    ".vtk": [
        b"# vtk DataFile Version 4.2\n",
        b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n",
        b"# vtk DataFile Version 5.1\nt\nBINARY\nDATASET UNSTRUCTURED_GRID\nPOINTS 3 double\n",
    ],
    ".obj": [b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf "],
    ".stl": [b"solid ", b"solid t\nfacet normal 0 0 1\nouter loop\nvertex "],
    ".xyz": [b"0 0 0\n"],
}


@settings(max_examples=100, **COMMON)
@given(ext=st.sampled_from(sorted(MAGIC)), prefix=st.integers(0, 3), body=st.binary(max_size=400))
@example(ext=".off", prefix=1, body=b"")  # "OFF\n": meshio's OFF reader looped forever on these
@example(ext=".off", prefix=1, body=b"#comment\n")
@example(ext=".ply", prefix=1, body=b"")  # "ply\n": so did its PLY reader
@example(ext=".ply", prefix=1, body=b"format ascii 1.0\n\n")
def test_random_bytes_read_or_refused_promptly(folder, ext, prefix, body):
    heads = [b""] + MAGIC[ext]
    path = folder / f"random{ext}"
    path.write_bytes(heads[min(prefix, len(heads) - 1)] + body)
    count_read(outcome_of(load_points if ext == ".xyz" else load_mesh, path))


@pytest.fixture(scope="module")
def valid_files(folder):
    """name -> (extension, bytes) of valid files of a small mesh with normals and point data, in every
    format and variant the loaders meet: as save_mesh writes them, ASCII PLY and STL (meshio), VTK
    POLYDATA binary and ASCII (pyvista, read by VTK), and point clouds (XYZ, PLY)."""
    import meshio

    rng = np.random.default_rng(7)
    mesh = Mesh(
        rng.normal(size=(6, 3)),
        np.array([[0, 1, 2], [0, 2, 3], [3, 4, 5], [5, 1, 0]]),
        rng.normal(size=(6, 3)),
        {"curvature": rng.normal(size=6), "k1k2": rng.normal(size=(6, 2))},
    )
    for ext in FORMATS:
        save_mesh(mesh, folder / f"valid{ext}")
    raw = meshio.Mesh(mesh.vertices, [("triangle", mesh.faces.astype(np.int32))], point_data={"c": mesh.normals[:, 0]})
    with contextlib.redirect_stderr(io.StringIO()):  # meshio's note that ASCII VTK is for debugging
        meshio.write(folder / "ascii.ply", raw, binary=False)
        meshio.write(folder / "ascii.stl", raw, binary=False)
        meshio.write(folder / "ascii.vtk", raw, binary=False)
    mesh.to_pyvista().save(folder / "polydata.vtk", binary=True)
    mesh.to_pyvista().save(folder / "polydata_ascii.vtk", binary=False)
    save_points(mesh.vertices, folder / "valid.xyz", mesh.normals)
    save_points(mesh.vertices, folder / "points.ply", mesh.normals)
    names = [f"valid{ext}" for ext in FORMATS]
    names += ["ascii.ply", "ascii.stl", "ascii.vtk", "polydata.vtk", "polydata_ascii.vtk", "valid.xyz", "points.ply"]
    return {name: (name[name.rindex(".") :], (folder / name).read_bytes()) for name in names}


FILES = [f"valid{ext}" for ext in FORMATS] + [
    "ascii.ply",
    "ascii.stl",
    "ascii.vtk",
    "polydata.vtk",
    "polydata_ascii.vtk",
    "valid.xyz",
    "points.ply",
]
COUNTED = {".off", ".ply", ".vtk"}  # formats whose header says how much data follows (and binary STL)
OPTIONAL_SECTIONS = {".vtk"}  # a VTK file cut between two sections is a valid file with fewer of them


def loader(name):
    return load_points if name in ("valid.xyz", "points.ply") else load_mesh


@settings(max_examples=80, **COMMON)
@given(name=st.sampled_from(FILES), cut=st.floats(0, 1, exclude_max=True))
def test_truncated_files_read_or_refused_promptly(folder, valid_files, name, cut):
    # A file whose header counts what follows (OFF, PLY, VTK, binary STL) and that lost any byte other
    # than trailing whitespace is refused, never read in part, with two exceptions that are valid files:
    # a VTK file cut between sections (it reads as the whole file's geometry with fewer arrays), and a
    # text file cut inside its very last number ("0.125" -> "0.12" is still a number).
    ext, data = valid_files[name]
    kept = data[: int(cut * len(data))]
    path = folder / f"truncated{ext}"
    path.write_bytes(kept)
    result = outcome_of(loader(name), path)
    lost = data[len(kept) :].strip()
    if isinstance(result, ValueError):
        return
    if not (ext in COUNTED or name == "valid.stl") or not lost:
        count_read(result)  # OBJ, XYZ, ASCII STL: no counts, a cut at a line's end is a smaller valid file
        return
    in_last_number = not binary(name) and not any(c in lost for c in b" \t\r\n")
    if ext in OPTIONAL_SECTIONS and not in_last_number:
        whole = load_mesh(folder / name)
        np.testing.assert_array_equal(result.vertices, whole.vertices)
        np.testing.assert_array_equal(result.faces, whole.faces)
        assert set(result.point_data) <= set(whole.point_data)
        for key, values in result.point_data.items():
            np.testing.assert_array_equal(values, whole.point_data[key])
        OUTCOMES["correct result"] += 1
        return
    assert in_last_number, f"{len(lost)} bytes cut from {name}, read as {result}"
    whole = load_mesh(folder / name)  # the text files with counts are meshes
    assert result.n_faces == whole.n_faces and result.n_vertices == whole.n_vertices
    OUTCOMES["correct result"] += 1


def binary(name):
    return name in ("valid.ply", "valid.vtk", "valid.stl", "polydata.vtk", "points.ply")


@settings(max_examples=100, **COMMON)
@given(
    name=st.sampled_from(FILES),
    edits=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=4),
)
def test_mutated_files_read_or_refused_promptly(folder, valid_files, name, edits):
    ext, data = valid_files[name]
    data = bytearray(data)
    for where, byte in edits:
        data[int(where * len(data))] = byte
    path = folder / f"mutated{ext}"
    path.write_bytes(bytes(data))
    count_read(outcome_of(loader(name), path))
