"""Mesh and point-cloud files: round trips through every format, and unreadable files."""

import inspect
import os
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from scipy.spatial import cKDTree

import pyfrep_core.io as pio
from pyfrep_core import Mesh, load_mesh, load_points, polygonize, save_mesh, save_points
from pyfrep_core.io import MESH_FORMATS
from pyfrep_core.models import fig1_part


@pytest.fixture(scope="module")
def part():
    m = polygonize(fig1_part, resolution=40)
    radius = np.linalg.norm(m.vertices, axis=1)
    m.point_data["radius"] = radius  # a scalar per vertex, like a curvature
    m.point_data["k1k2"] = np.column_stack([radius, -radius])  # two columns, like principal curvatures
    return m


@pytest.mark.parametrize("ext", list(MESH_FORMATS))
def test_mesh_round_trip(tmp_path, part, ext):
    path = tmp_path / f"part{ext}"
    part.save(path)
    back = load_mesh(path)
    assert back.n_faces == part.n_faces and back.n_vertices == part.n_vertices
    assert back.vertices.dtype == np.float64 and back.faces.dtype == np.int64
    if ext == ".stl":  # binary STL: float32 coordinates, vertices repeated per facet and merged on reading
        distance, original = cKDTree(part.vertices).query(back.vertices)
        assert distance.max() < 1e-6
        np.testing.assert_array_equal(original[back.faces], part.faces)
        assert back.volume() == pytest.approx(part.volume(), abs=1e-6)
    else:  # text with every digit (OBJ, OFF) or binary float64 (PLY, VTK): exact
        np.testing.assert_array_equal(back.faces, part.faces)
        np.testing.assert_allclose(back.vertices, part.vertices, rtol=0, atol=1e-15)
    if ext in (".obj", ".ply", ".vtk"):
        np.testing.assert_allclose(back.normals, part.normals, rtol=0, atol=1e-15)
    if ext in (".ply", ".vtk"):
        assert set(back.point_data) == {"radius", "k1k2"}
        np.testing.assert_allclose(back.point_data["radius"], part.point_data["radius"], atol=1e-15)
        np.testing.assert_allclose(back.point_data["k1k2"], part.point_data["k1k2"], atol=1e-15)


def test_save_mesh_function_and_upper_case_extension(tmp_path, part):
    save_mesh(part, tmp_path / "PART.OFF")
    assert load_mesh(str(tmp_path / "PART.OFF")).volume() == pytest.approx(part.volume(), abs=1e-12)


def test_obj_quads_become_triangles(tmp_path):
    path = tmp_path / "square.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n")
    m = load_mesh(path)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 2, 3]])
    assert m.area() == pytest.approx(1.0)


@pytest.mark.parametrize("ext", [".xyz", ".ply"])
def test_point_cloud_round_trip(tmp_path, part, ext):
    path = tmp_path / f"cloud{ext}"
    save_points(part.vertices, path, part.normals)
    cloud = load_points(path)
    np.testing.assert_array_equal(cloud.points, part.vertices)
    np.testing.assert_array_equal(cloud.normals, part.normals)
    save_points(part.vertices[:10], path)
    points, normals = load_points(path)
    np.testing.assert_array_equal(points, part.vertices[:10])
    assert normals is None


def test_xyz_is_plain_text_with_three_or_six_columns(tmp_path):
    path = tmp_path / "cloud.xyz"
    save_points(np.array([[0.1, 0.2, 0.3]]), path, np.array([[0.0, 0.0, 1.0]]))
    assert path.read_text().split() == ["0.10000000000000001", "0.20000000000000001", "0.29999999999999999"] + [
        "0",
        "0",
        "1",
    ]
    path.write_text("# a comment\n1 2 3\n4 5 6\n")
    np.testing.assert_array_equal(load_points(path).points, [[1, 2, 3], [4, 5, 6]])


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("random.stl", np.random.default_rng(0).bytes(300), "cannot read"),
        ("random.ply", np.random.default_rng(1).bytes(300), "cannot read"),
        ("random.obj", np.random.default_rng(2).bytes(300), "cannot read"),
        ("random.vtk", np.random.default_rng(3).bytes(300), "cannot read"),
        ("random.off", np.random.default_rng(4).bytes(300), "cannot read"),
        ("text.off", b"hello world\n1 2\n", "the first line must be `OFF`"),
        ("text.vtk", b"hello world\n1 2\n", "the first line must be `# vtk DataFile Version"),
        ("text.stl", b"hello world\n1 2\n", "cannot read"),
        ("nofaces.obj", b"v 0 0 0\nv 1 0 0\n", "no triangles"),
        ("badindex.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "faces index vertices 0..7"),
        (
            "truncated.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n",
            "cannot read",
        ),
        ("empty.stl", b"", "is empty"),
    ],
)
def test_malformed_mesh_files(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(ValueError, match=match) as info:
        load_mesh(path)
    assert name in str(info.value)  # the message names the file


@pytest.mark.parametrize(
    "content, match",
    [
        (b"1 2 3 4\n", "3 .x y z. or 6"),
        (b"1 2 3\n4 5 nan\n", "NaN"),
        (b"1 2 3\n4 5\n", "cannot read"),
        (b"x y z\n", "cannot read"),
        (b"# only a comment\n", "no points"),
        (b"", "is empty"),
    ],
)
def test_malformed_xyz(tmp_path, content, match):
    path = tmp_path / "cloud.xyz"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=match) as info:
        load_points(path)
    assert "cloud.xyz" in str(info.value)


def test_missing_file_directory_and_unknown_extension(tmp_path, part):
    with pytest.raises(FileNotFoundError, match="nothere.stl"):
        load_mesh(tmp_path / "nothere.stl")
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(ValueError, match="not a file"):
        load_points(tmp_path / "dir.ply")
    for call in (lambda p: load_mesh(p), lambda p: part.save(p)):
        with pytest.raises(ValueError, match=r"supported: \.stl, \.obj, \.ply, \.off, \.vtk"):
            call(tmp_path / "part.step")
    with pytest.raises(ValueError, match=r"supported: \.xyz, \.ply"):
        save_points(part.vertices, tmp_path / "cloud.stl")


def test_bad_arguments_to_the_writers(tmp_path, part):
    with pytest.raises(TypeError, match="Mesh"):
        save_mesh(part.vertices, tmp_path / "a.stl")
    with pytest.raises(ValueError, match="empty mesh"):
        Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)).save(tmp_path / "a.stl")
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        save_points(np.zeros((4, 2)), tmp_path / "a.xyz")
    with pytest.raises(ValueError, match=r"normals must have shape \(4, 3\)"):
        save_points(np.zeros((4, 3)), tmp_path / "a.xyz", np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        save_points(np.full((2, 3), np.nan), tmp_path / "a.xyz")


# ---------------------------------------------------------------------------------------------
# Reading is guarded: the header is checked first, then the reader runs in a worker process that
# is stopped after a time proportional to the file's size.  The files below made meshio's readers
# loop forever at 100 % CPU; the helper runs each load in a thread and fails when it has not
# returned within PATIENCE seconds (less than pio.PARSE_SECONDS, so no test passes by the guard
# alone where a header check should answer at once).

PATIENCE = 8.0


def within(call, *args, seconds=PATIENCE):
    """``call(*args)``'s result or exception, or a test failure when it does not return in ``seconds``."""
    box = []

    def run():
        try:
            box.append(("result", call(*args)))
        except BaseException as err:  # handed to the test
            box.append(("raised", err))

    thread = threading.Thread(target=run, daemon=True)
    start = time.perf_counter()
    thread.start()
    thread.join(seconds)
    if thread.is_alive():
        pytest.fail(f"{call.__name__}{args} did not return within {seconds} s (a hang)")
    return box[0][1], time.perf_counter() - start


def test_the_guard_is_shorter_than_any_wait_here():
    assert pio.PARSE_SECONDS > PATIENCE


HANGED = [  # files that made meshio loop forever, and the reason the header check now gives
    ("four.off", b"OFF\n", "no count line"),
    ("comment.off", b"OFF\n#comment\n", "no count line"),
    ("blank.off", b"OFF\n\n\n", "no count line"),
    ("ply.ply", b"ply\n", "no `end_header`"),
    ("format.ply", b"ply\nformat ascii 1.0\n", "no `end_header`"),
    ("comment.ply", b"ply\nformat ascii 1.0\ncomment only\n", "no `end_header`"),
    (
        "noend.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n",
        "no `end_header`",
    ),
]


@pytest.mark.parametrize("name, content, reason", HANGED)
def test_files_that_made_the_readers_loop_forever_are_refused_at_once(tmp_path, name, content, reason):
    path = tmp_path / name
    path.write_bytes(content)
    loaders = [load_mesh] + ([load_points] if name.endswith(".ply") else [])
    for load in loaders:
        err, seconds = within(load, path)
        assert isinstance(err, ValueError), err
        assert str(path) in str(err) and reason in str(err) and load.__name__ in str(err)
        assert seconds < 2.0  # the header check answers; no reader ran


@pytest.mark.parametrize(
    "name, content, reason",
    [  # counts in the header that the file's size cannot hold (they would have made readers allocate or wait)
        ("huge.off", b"OFF\n1000000000 1 0\n0 0 0\n", "announces 1000000000 vertices and 1 faces, needing"),
        ("short.off", b"OFF\n4 2 0\n0 0 0\n1 0 0\n", "announces 4 vertices and 2 faces"),
        (
            "huge.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty double x\n"
            b"property double y\nproperty double z\nend_header\n" + bytes(48),
            "4000000000 vertex, which need at least 96000000000 bytes after it; the file has 48",
        ),
        ("nan.ply", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n", "x, y, z"),
        ("list.ply", b"ply\nformat ascii 1.0\nelement face 1\nproperty list int\nend_header\n3 0 1 2\n", "property"),
        ("bad.stl", b"\0" * 80 + np.uint32(3).tobytes() + bytes(10), "84 + 50 x 3 = 234 bytes; the file has 94"),
        ("tiny.stl", b"\0" * 50, "too short for binary STL"),
        (
            "huge.vtk",
            b"# vtk DataFile Version 4.2\nt\nBINARY\nDATASET POLYDATA\nPOINTS 100000000 double\n" + bytes(24),
            "POINTS 100000000 need at least 2400000000 bytes",
        ),
        ("nodataset.vtk", b"# vtk DataFile Version 4.2\nt\nASCII\nPOINTS 3 float\n0 0 0\n", "DATASET"),
        ("binary.obj", b"v 0 0 0\0\n", "NUL"),
    ],
)
def test_header_counts_are_checked_against_the_file_size(tmp_path, name, content, reason):
    path = tmp_path / name
    path.write_bytes(content)
    err, seconds = within(load_mesh, path)
    assert isinstance(err, ValueError) and reason in str(err) and str(path) in str(err), err
    assert seconds < 2.0


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="named pipes are POSIX")
def test_a_reader_that_never_returns_is_stopped_with_a_clear_error(tmp_path, monkeypatch, part):
    # A named pipe without a writer blocks open() forever: a real reader that never returns.  The
    # public loaders refuse it up front (not a regular file); the guard is called on it directly.
    fifo = tmp_path / "pipe.off"
    os.mkfifo(fifo)
    monkeypatch.setattr(pio, "PARSE_SECONDS", 1.0)
    err, seconds = within(pio._parse, "off", fifo, 0, "load_mesh")
    assert isinstance(err, ValueError), err
    assert "did not finish within 1 s" in str(err) and "stopped" in str(err) and str(fifo) in str(err)
    assert 1.0 <= seconds < 1.0 + PATIENCE
    with pytest.raises(ValueError, match="is not a file"):
        load_mesh(fifo)
    path = tmp_path / "part.off"  # the next load starts a fresh worker and reads as before
    part.save(path)
    np.testing.assert_array_equal(load_mesh(path).faces, part.faces)


def test_a_worker_ended_from_outside_is_replaced(tmp_path, part):
    path = tmp_path / "part.ply"
    part.save(path)
    load_mesh(path)
    assert pio._idle_workers, "a worker is kept for the next load"
    for worker in pio._idle_workers:
        worker.proc.kill()
        worker.proc.wait()
    np.testing.assert_array_equal(load_mesh(path).faces, part.faces)


def test_loads_from_many_threads_at_once(tmp_path, part):
    # the workbench loads from background threads: each load has its own worker while it runs
    paths = []
    for k, ext in enumerate([".ply", ".obj", ".off", ".vtk"]):
        m = Mesh(part.vertices + k, part.faces)
        paths.append(tmp_path / f"m{k}{ext}")
        m.save(paths[-1])
    with ThreadPoolExecutor(len(paths)) as pool:
        meshes = list(pool.map(load_mesh, paths))
    for k, m in enumerate(meshes):
        np.testing.assert_array_equal(m.vertices, part.vertices + k)
        np.testing.assert_array_equal(m.faces, part.faces)


def test_files_cut_short_are_refused_not_read_in_part(tmp_path, part):
    # found by the property tests: meshio read a binary PLY cut after a whole face as a mesh with one
    # face less, and VTK's reader filled a cut ASCII POLYDATA section with zeros, both without a word
    path = tmp_path / "part.ply"
    part.save(path)
    data = path.read_bytes()
    path.write_bytes(data[:-13])  # the last face: a uint8 count and three int32 indices
    with pytest.raises(ValueError, match=f"announces {part.n_faces} face elements, the file holds {part.n_faces - 1}"):
        load_mesh(path)
    path = tmp_path / "square.vtk"
    points = "0.0 0.0 0.0\n1.0 0.0 0.0\n1.0 1.0 0.0\n0.0 1.0 0.0\n"
    text = "# vtk DataFile Version 3.0\nsquare\nASCII\nDATASET POLYDATA\nPOINTS 4 float\n" + points
    path.write_text(text[:-5])
    with pytest.raises(ValueError, match="ends inside its POINTS section: 11 of its 12 numbers are there"):
        load_mesh(path)
    path.write_text(text + "POLYGONS 1 5\n4 0 1 2 3\nPOINT_DATA 4\nSCALARS h float 1\nLOOKUP_TABLE default\n0 0 1")
    with pytest.raises(ValueError, match="ends inside its LOOKUP_TABLE section: 3 of its 4 numbers"):
        load_mesh(path)
    path.write_text(text + "POLYGONS 1 5\n4 0 1 2 3\n")  # whole sections: a valid file
    assert load_mesh(path).area() == pytest.approx(1.0, rel=1e-15)


# ---------------------------------------------------------------------------------------------
# Valid files that were refused


def test_legacy_vtk_polydata_with_a_quad_and_normals(tmp_path):
    path = tmp_path / "square.vtk"
    path.write_text(
        "# vtk DataFile Version 3.0\nunit square and a triangle\nASCII\nDATASET POLYDATA\n"
        "POINTS 5 float\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n0.5 0.5 1\n"
        "POLYGONS 2 9\n4 0 1 2 3\n3 0 1 4\n"
        "POINT_DATA 5\nNORMALS Normals float\n0 0 1\n0 0 1\n0 0 1\n0 0 1\n0 -1 0\n"
        "SCALARS height float 1\nLOOKUP_TABLE default\n0 0 0 0 1\n"
    )
    m = load_mesh(path)
    np.testing.assert_array_equal(m.vertices, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]])
    assert m.n_faces == 3
    assert m.area() == pytest.approx(1.0 + 0.5 * np.sqrt(1.25), rel=1e-12)  # the square and the triangle (0,1,4)
    assert [0, 1, 4] in m.faces.tolist()  # the triangle as written; the square split in two
    np.testing.assert_array_equal(m.normals[:, 2], [1, 1, 1, 1, 0])
    np.testing.assert_array_equal(m.point_data["height"], [0, 0, 0, 0, 1])


def test_obj_with_relative_negative_indices(tmp_path):
    # -1 is the last vertex defined so far: the faces of the second group count from their own v lines
    path = tmp_path / "relative.obj"
    path.write_text(
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nvn 0 0 1\nvn 0 0 1\nf -3//-3 -2//-2 -1//-1\n"
        "v 0 0 1\nvn 0 0 1\nf -4 -1 -3\nf 1 2 -1\n"
    )
    m = load_mesh(path)
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 3, 1], [0, 1, 3]])
    np.testing.assert_array_equal(m.vertices[3], [0, 0, 1])


def test_off_with_quads_comments_colours_and_counts_on_the_first_line(tmp_path):
    path = tmp_path / "cube.off"
    corners = "".join(f"{x} {y} {z}  # corner\n" for x in (0, 1) for y in (0, 1) for z in (0, 1))
    quads = "4 0 1 3 2\n4 4 6 7 5\n4 0 4 5 1\n4 2 3 7 6 0.5 0.5 0.5\n4 0 2 6 4\n4 1 5 7 3\n"
    path.write_text("OFF 8 6 12\n# a unit cube\n" + corners + quads)
    m = load_mesh(path)
    assert m.n_faces == 12 and m.n_vertices == 8
    assert m.area() == pytest.approx(6.0, rel=1e-15)
    assert abs(m.volume()) == pytest.approx(1.0, rel=1e-15)


def test_off_with_triangles_and_a_pentagon(tmp_path):
    path = tmp_path / "mixed.off"
    path.write_text("OFF\n6 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n-1 0.5 0\n2 0 0\n3 1 5 2\n5 0 1 2 3 4\n")
    m = load_mesh(path)
    np.testing.assert_array_equal(m.faces, [[1, 5, 2], [0, 1, 2], [0, 2, 3], [0, 3, 4]])
    assert m.area() == pytest.approx(0.5 + 1.0 + 0.5, rel=1e-15)  # triangle, square, triangle (0,3,4)


def test_one_vertex_ascii_ply_with_normals(tmp_path):
    path = tmp_path / "one.ply"
    path.write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\nend_header\n0.5 -1 2 0 0 1\n"
    )
    cloud = load_points(path)
    np.testing.assert_array_equal(cloud.points, [[0.5, -1.0, 2.0]])
    np.testing.assert_array_equal(cloud.normals, [[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="no triangles"):  # a point is no mesh: said clearly
        load_mesh(path)


# ---------------------------------------------------------------------------------------------
# Writing: point-data names, Mesh.save's arguments, save_points' order


@pytest.fixture
def tri():
    return Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), normals=np.eye(3))


@pytest.mark.parametrize("ext", [".ply", ".vtk"])
@pytest.mark.parametrize(
    "data, match",
    [
        ({"mean curvature": np.ones(3)}, r"point_data\['mean curvature'\].*spaces.*e\.g\. 'mean_curvature'"),
        ({"tab\tname": np.ones(3)}, r"spaces or control characters; got 'tab\\tname'"),
        ({"": np.ones(3)}, "must be non-empty"),
        ({"k_0": np.ones(3), "k_1": np.ones(3)}, r"\['k_0', 'k_1'\] would read back from .* as \['k'\]"),
        ({"k": np.ones((3, 2)), "k_2": np.ones(3)}, r"\['k', 'k_2'\] would read back .* as \['k'\]"),
        ({"col": np.ones((3, 1))}, r"point_data\['col'\].*got shape \(3, 1\)"),
        ({"cube": np.ones((3, 2, 2))}, r"got shape \(3, 2, 2\)"),
        ({"text": np.array(["a", "b", "c"])}, "holds numbers.*got dtype <U1"),
        ({"z": np.ones(3)}, None),  # PLY: a coordinate's name; VTK: fine
        ({"Normals": np.ones((3, 3))}, None),  # VTK: its normals' name; PLY: fine
    ],
)
def test_point_data_that_would_not_read_back_is_refused_by_name(tmp_path, tri, ext, data, match):
    reserved = {".ply": {"z"}, ".vtk": {"Normals"}}[ext]
    if match is None:
        match = "is one of the names .* uses itself" if set(data) & reserved else None
    tri.point_data = data
    path = tmp_path / f"tri{ext}"
    if match is None:  # not reserved in this format: it reads back as it was
        tri.save(path)
        back = load_mesh(path)
        assert set(back.point_data) == set(data)
        for name, values in data.items():
            np.testing.assert_array_equal(back.point_data[name], values)
        return
    with pytest.raises(ValueError, match=match) as info:
        tri.save(path)
    assert str(info.value).startswith("save_mesh: ")
    assert not path.exists()


@pytest.mark.parametrize("ext", [".ply", ".vtk"])
def test_point_data_names_and_dtypes_that_round_trip(tmp_path, tri, ext):
    data = {
        "mean_curvature": np.array([0.5, -1.0, 2.0]),
        "k1k2": np.array([[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]),
        "grad": np.arange(9.0).reshape(3, 3),
        "label": np.array([1, 2, 3], dtype=np.int16),
        "inside": np.array([True, False, True]),
        "é.x-y#1": np.array([1.5, 2.5, 3.5], dtype=np.float32),
    }
    tri.point_data = dict(data)
    tri.save(tmp_path / f"tri{ext}")
    back = load_mesh(tmp_path / f"tri{ext}")
    assert set(back.point_data) == set(data)
    for name, values in data.items():
        np.testing.assert_array_equal(back.point_data[name], values)
    assert back.point_data["label"].dtype == (np.int32 if ext == ".ply" else np.int16)  # PLY: widened
    assert back.point_data["inside"].dtype == np.uint8
    assert back.point_data["é.x-y#1"].dtype == np.float32
    np.testing.assert_array_equal(back.normals, tri.normals)


def test_mesh_save_takes_save_mesh_arguments_only(tmp_path, tri):
    assert list(inspect.signature(Mesh.save).parameters) == ["self", "path"]
    assert list(inspect.signature(save_mesh).parameters) == ["mesh", "path"]
    with pytest.raises(TypeError, match="binary"):
        tri.save(tmp_path / "tri.ply", binary=False)
    assert not (tmp_path / "tri.ply").exists()


def test_save_points_takes_the_points_first(tmp_path):
    pts = np.array([[0.0, 0.5, 1.0], [2.0, 3.0, 4.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the new order warns about nothing
        save_points(pts, tmp_path / "a.xyz")
    np.testing.assert_array_equal(load_points(tmp_path / "a.xyz").points, pts)
    with pytest.warns(DeprecationWarning, match=r"save_points\(points, path\)"):
        save_points(str(tmp_path / "b.ply"), pts, -pts)  # the old order, told apart by the path's type
    np.testing.assert_array_equal(load_points(tmp_path / "b.ply").normals, -pts)
    with pytest.raises(TypeError, match="save_points: path must be a str or os.PathLike, got ndarray"):
        save_points(pts, pts)
    with pytest.raises(ValueError, match=r"save_points: points is empty \(shape \(0, 3\)\)"):
        save_points(np.zeros((0, 3)), tmp_path / "c.xyz")
