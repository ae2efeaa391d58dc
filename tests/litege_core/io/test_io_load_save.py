import io

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from litege_core.errors import (
    ArrayShapeError,
    DegenerateShapeError,
    EmptyShapeError,
    FaceIndexError,
    InputError,
    NonFiniteError,
    ShapeFileError,
    ShapeTooLargeError,
    UnsupportedFormatError,
)
from litege_core.io import detect_format, load_shape, read_arrays, save_shape
from litege_core.shape import Shape, ShapeKind
from litege_core.validate import MIN_EXTENT, ShapeLimits


@pytest.fixture()
def mesh(sphere_mesh):
    vertices, faces = sphere_mesh
    # float32-representable coordinates: every format can then store them exactly.
    return Shape.from_arrays(vertices.astype(np.float32).astype(np.float64), faces)


@pytest.mark.parametrize("fmt", ["obj", "ply", "off", "glb", "gltf"])
def test_mesh_round_trip_keeps_vertex_order_exactly(tmp_path, mesh, fmt):
    path = tmp_path / f"shape.{fmt}"
    save_shape(mesh, path)
    loaded = load_shape(path)
    assert loaded.kind is ShapeKind.MESH
    np.testing.assert_array_equal(loaded.vertices, mesh.vertices)
    np.testing.assert_array_equal(loaded.faces, mesh.faces)
    assert loaded.content_hash == mesh.content_hash


def test_same_mesh_as_obj_and_ply_has_same_id(tmp_path, mesh):
    save_shape(mesh, tmp_path / "a.obj")
    save_shape(mesh, tmp_path / "a.ply")
    assert (
        load_shape(tmp_path / "a.obj").content_hash == load_shape(tmp_path / "a.ply").content_hash
    )


def test_stl_triangle_soup_is_merged_deterministically(tmp_path, mesh):
    path = tmp_path / "a.stl"
    save_shape(mesh, path)
    first, second = load_shape(path), load_shape(path)
    assert first.n_points == mesh.n_points and first.n_faces == mesh.n_faces
    assert first.content_hash == second.content_hash
    assert first.area == pytest.approx(mesh.area, rel=1e-6)
    # Merged corners must reproduce the same triangles in space.
    np.testing.assert_allclose(
        np.sort(first.vertices[first.faces].reshape(-1, 9), axis=0),
        np.sort(mesh.vertices[mesh.faces].reshape(-1, 9), axis=0),
        atol=1e-6,
    )


@pytest.mark.parametrize("fmt", ["ply", "xyz", "npy"])
def test_point_cloud_round_trip(tmp_path, mesh, fmt):
    cloud = mesh.as_point_cloud()
    save_shape(cloud, tmp_path / f"c.{fmt}")
    loaded = load_shape(tmp_path / f"c.{fmt}")
    assert loaded.kind is ShapeKind.POINT_CLOUD
    np.testing.assert_array_equal(loaded.vertices, cloud.vertices)


def test_save_shape_refuses_formats_that_cannot_hold_the_kind(tmp_path, mesh):
    """A cloud as STL (triangles only), a mesh as XYZ (points only): InputError, no file."""
    with pytest.raises(InputError, match=r"\.stl holds meshes only"):
        save_shape(mesh.as_point_cloud(), tmp_path / "c.stl")
    with pytest.raises(InputError, match=r"\.xyz holds point clouds only"):
        save_shape(mesh, tmp_path / "m.xyz")
    assert not list(tmp_path.iterdir())


def test_save_shape_to_a_missing_directory_is_an_input_error(tmp_path, mesh):
    with pytest.raises(InputError, match=r"cannot write .*No such file or directory"):
        save_shape(mesh, tmp_path / "no" / "dir" / "x.obj")


def test_obj_keeps_float64_precision(tmp_path, sphere_mesh):
    shape = Shape.from_arrays(*sphere_mesh)
    save_shape(shape, tmp_path / "x.obj")
    assert load_shape(tmp_path / "x.obj").content_hash == shape.content_hash


def test_bytes_and_kind_override(mesh):
    data = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")
    as_cloud = load_shape(data, file_format="ply", kind="point_cloud")
    assert as_cloud.kind is ShapeKind.POINT_CLOUD and as_cloud.n_points == mesh.n_points
    with pytest.raises(UnsupportedFormatError):
        load_shape(data)


def test_quads_are_fan_triangulated():
    obj = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
    shape = load_shape(obj, file_format="obj")
    assert shape.n_faces == 2 and shape.area == pytest.approx(1.0)


def test_xyz_with_normals_and_comments():
    text = b"# cloud\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n\n"
    shape = load_shape(text, file_format="xyz")
    assert shape.n_points == 3


@pytest.mark.parametrize(
    ("data", "fmt", "error"),
    [
        (b"", "obj", ShapeFileError),
        (b"hello world garbage\n\x00\x01", "obj", ShapeFileError),
        (b"hello world garbage\n\x00\x01", "ply", ShapeFileError),
        (b"hello world garbage\n\x00\x01", "off", ShapeFileError),
        (b"hello world garbage\n\x00\x01", "stl", ShapeFileError),
        (b"hello world garbage\n\x00\x01", "glb", ShapeFileError),
        (b"hello world garbage\n\x00\x01", "gltf", ShapeFileError),
        (b"[1, 2, 3]", "gltf", ShapeFileError),
        (b"\x93NUMPY garbage", "npy", ShapeFileError),
        (b"0 0\n1 1\n", "xyz", ShapeFileError),
        (b"0 0 x\n", "xyz", ShapeFileError),
        (b"\xff\xfe\x00", "xyz", ShapeFileError),
        (b"v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n", "obj", FaceIndexError),
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\n1 1 0\n3 0 1 7\n", "off", FaceIndexError),
        (b"v 0 0 0\nv 1 0 nan\nv 1 1 0\nf 1 2 3\n", "obj", NonFiniteError),
        (b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "obj", DegenerateShapeError),
        (b"# nothing\n", "xyz", EmptyShapeError),
        (b"dummy", "fbx", UnsupportedFormatError),
    ],
)
def test_bad_files_raise_precise_errors(data, fmt, error):
    with pytest.raises(error):
        load_shape(data, file_format=fmt)


@pytest.mark.parametrize("fmt", ["obj", "ply", "off"])
def test_truncated_files_are_rejected(mesh, fmt):
    data = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type=fmt)
    data = data.encode() if isinstance(data, str) else data
    with pytest.raises(ShapeFileError):
        load_shape(data[: len(data) // 2], file_format=fmt)


def test_pickled_npy_is_refused():
    buffer = io.BytesIO()
    np.save(buffer, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ShapeFileError):
        load_shape(buffer.getvalue(), file_format="npy")


def test_npy_wrong_shape():
    buffer = io.BytesIO()
    np.save(buffer, np.zeros((4, 2)))
    with pytest.raises(ArrayShapeError):
        load_shape(buffer.getvalue(), file_format="npy")


def test_limits_on_bytes_and_vertices(tmp_path, mesh):
    save_shape(mesh, tmp_path / "m.ply")
    with pytest.raises(ShapeTooLargeError):
        load_shape(tmp_path / "m.ply", limits=ShapeLimits(max_file_bytes=100))
    with pytest.raises(ShapeTooLargeError):
        load_shape(tmp_path / "m.ply", limits=ShapeLimits(max_vertices=100))


def test_missing_file_and_extension(tmp_path):
    with pytest.raises(ShapeFileError):
        load_shape(tmp_path / "missing.obj")
    with pytest.raises(UnsupportedFormatError):
        detect_format("mesh.3ds")
    assert detect_format("Mesh.OBJ") == "obj"


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    arrays(
        np.float32,
        st.tuples(st.integers(3, 40), st.just(3)),
        elements=st.floats(-100, 100, width=32),
    ),
    st.sampled_from(["ply", "xyz", "npy"]),
)
def test_point_cloud_loaders_round_trip(tmp_path_factory, points, fmt):
    points = points.astype(np.float64)
    assume(np.ptp(points, axis=0).max() >= MIN_EXTENT)  # smaller is refused as degenerate
    path = tmp_path_factory.mktemp("pc") / f"p.{fmt}"
    save_shape(Shape.from_arrays(points), path)
    np.testing.assert_array_equal(load_shape(path).vertices, points)


def test_read_arrays_returns_raw_arrays(mesh):
    data = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="off")
    vertices, faces = read_arrays(data.encode(), "off")
    assert vertices.shape == (mesh.n_points, 3) and faces.shape == (mesh.n_faces, 3)


def test_garbage_after_a_ply_magic_is_a_malformed_file():
    from litege_core.errors import FaceIndexError, ShapeFileError

    with pytest.raises(ShapeFileError) as error:
        load_shape(b"ply\nthis is not a ply file\n", file_format="ply")
    assert not isinstance(error.value, FaceIndexError)


def _binary_ply(vertices, faces, order="<", corners=3, extra_vertex_property=False):
    """A binary PLY with ``float x y z`` (+ a ``uchar red``) and ``uchar int`` face lists."""
    endian = "binary_little_endian" if order == "<" else "binary_big_endian"
    header = [f"ply\nformat {endian} 1.0\nelement vertex {len(vertices)}\n"]
    header.append("property float x\nproperty float y\nproperty float z\n")
    fields = [("xyz", f"{order}f4", (3,))]
    if extra_vertex_property:
        header.append("property uchar red\n")
        fields.append(("red", "u1"))
    header.append(f"element face {len(faces)}\nproperty list uchar int vertex_indices\n")
    header.append("end_header\n")
    table = np.zeros(len(vertices), dtype=fields)
    table["xyz"] = vertices
    lists = np.zeros(len(faces), dtype=[("n", "u1"), ("i", f"{order}i4", (corners,))])
    lists["n"], lists["i"] = corners, faces
    return "".join(header).encode() + table.tobytes() + lists.tobytes()


@pytest.mark.parametrize(
    ("order", "extra"), [("<", False), (">", False), ("<", True)], ids=["le", "be", "colour"]
)
def test_binary_ply_is_read_without_trimesh_and_as_trimesh_reads_it(
    mesh, monkeypatch, order, extra
):
    from litege_core.io import ply
    from litege_core.io.trimesh_backend import read_with_trimesh

    data = _binary_ply(mesh.vertices, mesh.faces, order, extra_vertex_property=extra)
    reference = read_with_trimesh(data, "ply")  # the slow reference

    def refuse(*_args):
        raise AssertionError("a plain binary PLY went to trimesh")

    monkeypatch.setattr(ply, "read_with_trimesh", refuse)
    vertices, faces = read_arrays(data, "ply")
    np.testing.assert_array_equal(vertices, reference[0])
    np.testing.assert_array_equal(faces, reference[1])
    cloud = _binary_ply(mesh.vertices, np.zeros((0, 3), int), order)
    vertices, faces = read_arrays(cloud, "ply")
    assert faces is None
    np.testing.assert_array_equal(vertices, reference[0])


def test_binary_ply_other_layouts_go_to_trimesh():
    quad = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    data = _binary_ply(quad, np.array([[0, 1, 2, 3]]), corners=4)
    vertices, faces = read_arrays(data, "ply")
    np.testing.assert_array_equal(vertices, quad)
    assert faces.shape == (2, 3)  # fan-triangulated by trimesh
    with pytest.raises(ShapeFileError):  # a body shorter than its header says
        read_arrays(data[:-10], "ply")
