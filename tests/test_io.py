"""Mesh and point-cloud files: round trips through every format, and unreadable files."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

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
    save_points(path, part.vertices, part.normals)
    cloud = load_points(path)
    np.testing.assert_array_equal(cloud.points, part.vertices)
    np.testing.assert_array_equal(cloud.normals, part.normals)
    save_points(path, part.vertices[:10])
    points, normals = load_points(path)
    np.testing.assert_array_equal(points, part.vertices[:10])
    assert normals is None


def test_xyz_is_plain_text_with_three_or_six_columns(tmp_path):
    path = tmp_path / "cloud.xyz"
    save_points(path, np.array([[0.1, 0.2, 0.3]]), np.array([[0.0, 0.0, 1.0]]))
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
        ("text.off", b"hello world\n1 2\n", "Expected the first line to be `OFF`"),
        ("text.vtk", b"hello world\n1 2\n", "Illegal VTK header"),
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
        save_points(tmp_path / "cloud.stl", part.vertices)


def test_bad_arguments_to_the_writers(tmp_path, part):
    with pytest.raises(TypeError, match="Mesh"):
        save_mesh(part.vertices, tmp_path / "a.stl")
    with pytest.raises(ValueError, match="empty mesh"):
        Mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)).save(tmp_path / "a.stl")
    with pytest.raises(ValueError, match=r"points must have shape \(N, 3\)"):
        save_points(tmp_path / "a.xyz", np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"normals must have shape \(4, 3\)"):
        save_points(tmp_path / "a.xyz", np.zeros((4, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        save_points(tmp_path / "a.xyz", np.full((2, 3), np.nan))
