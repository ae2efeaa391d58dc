"""The typed readers give exactly what trimesh gives, and untrusted files are bounded: sizes
checked from what the file declares before parsing, lying headers refused (issue 13, item 3).

Memory and time per format are measured in ``scripts/bench_parse.py``, not here."""

import io
import json
import struct

import numpy as np
import pytest
import trimesh

from litege_core.errors import (
    ArrayShapeError,
    FaceIndexError,
    ShapeFileError,
    ShapeTooLargeError,
)
from litege_core.io import load_shape, read_arrays
from litege_core.io.trimesh_backend import read_with_trimesh
from litege_core.validate import ShapeLimits

RNG = np.random.default_rng(0)


def _polygons(n_vertices: int, sizes: list[int], seed: int) -> list[list[int]]:
    rng = np.random.default_rng(seed)
    return [list(rng.choice(n_vertices, size, replace=False)) for size in sizes]


def _ply_ascii(
    vertices: np.ndarray,
    polygons: list[list[int]],
    *,
    vertex_type: str = "float",
    extra_vertex: tuple[str, ...] = (),
    face_before: tuple[str, ...] = (),
    face_after: tuple[str, ...] = (),
    edges: int = 0,
) -> bytes:
    lines = ["ply", "format ascii 1.0", "comment made by a test", f"element vertex {len(vertices)}"]
    lines += [f"property {vertex_type} {axis}" for axis in "xyz"]
    lines += [f"property uchar {name}" for name in extra_vertex]
    if polygons:
        lines.append(f"element face {len(polygons)}")
        lines += [f"property int {name}" for name in face_before]
        lines.append("property list uchar int vertex_indices")
        lines += [f"property float {name}" for name in face_after]
    if edges:
        lines += [f"element edge {edges}", "property int vertex1", "property int vertex2"]
    lines.append("end_header")
    for v in vertices:
        lines.append(" ".join(f"{c:.9g}" for c in v) + "".join(" 7" for _ in extra_vertex))
    for i, polygon in enumerate(polygons):
        before = " ".join(str(i) for _ in face_before)
        after = " ".join("0.5" for _ in face_after)
        lines.append(f"{before} {len(polygon)} {' '.join(map(str, polygon))} {after}".strip())
    lines += [f"{i} {i + 1}" for i in range(edges)]
    return ("\n".join(lines) + "\n").encode()


def _off(vertices: np.ndarray, polygons: list[list[int]], colors: bool = False) -> bytes:
    lines = ["OFF", "# a comment", f"{len(vertices)} {len(polygons)} 0"]
    for v in vertices:
        lines.append(" ".join(repr(float(c)) for c in v) + (" 0.1 0.2 0.3 1" if colors else ""))
    for polygon in polygons:
        lines.append(
            f"{len(polygon)} {' '.join(map(str, polygon))}" + (" 255 0 0" if colors else "")
        )
    return ("\n".join(lines) + "\n").encode()


def _assert_same_as_trimesh(data: bytes, fmt: str) -> None:
    vertices, faces = read_arrays(data, fmt)
    expected_vertices, expected_faces = read_with_trimesh(data, fmt)
    np.testing.assert_array_equal(vertices, expected_vertices)
    if expected_faces is None:
        assert faces is None
    else:
        np.testing.assert_array_equal(faces, expected_faces)


VERTICES = RNG.normal(size=(40, 3))
CASES = {
    "triangles": [3] * 30,
    "quads": [4] * 20,
    "pentagons": [5] * 9,
    "mixed": [3, 4, 5, 3, 6, 4, 3, 7, 4, 4, 3],
}


@pytest.mark.parametrize("sizes", list(CASES.values()), ids=list(CASES))
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"vertex_type": "double"},
        {"vertex_type": "int"},
        {"extra_vertex": ("red", "green", "blue")},
        {"face_before": ("material",), "face_after": ("quality",)},
        {"edges": 5},
    ],
    ids=["float", "double", "int", "colours", "face-props", "edges"],
)
def test_ascii_ply_reads_like_trimesh(sizes, options):
    polygons = _polygons(len(VERTICES), sizes, len(sizes))
    _assert_same_as_trimesh(_ply_ascii(VERTICES * 10, polygons, **options), "ply")


def test_ascii_ply_cloud_and_exported_mesh_read_like_trimesh(sphere_mesh):
    vertices, faces = sphere_mesh
    _assert_same_as_trimesh(_ply_ascii(vertices, []), "ply")
    exported = trimesh.Trimesh(vertices, faces, process=False).export(
        file_type="ply", encoding="ascii"
    )
    _assert_same_as_trimesh(exported, "ply")
    cloud = trimesh.PointCloud(vertices).export(file_type="ply", encoding="ascii")
    _assert_same_as_trimesh(cloud, "ply")


@pytest.mark.parametrize("sizes", list(CASES.values()), ids=list(CASES))
@pytest.mark.parametrize("colors", [False, True])
def test_off_reads_like_trimesh(sizes, colors):
    polygons = _polygons(len(VERTICES), sizes, len(sizes) + 1)
    data = _off(VERTICES, polygons, colors)
    vertices, faces = read_arrays(data, "off")
    np.testing.assert_array_equal(vertices, VERTICES)
    # trimesh's own triangulation (its OFF reader fails on mixed polygons with numpy 2)
    np.testing.assert_array_equal(faces, trimesh.geometry.triangulate_quads(polygons))
    if max(sizes) <= 4 or min(sizes) == max(sizes):
        _assert_same_as_trimesh(data, "off")


def test_exported_off_and_same_line_counts_read_like_trimesh(sphere_mesh):
    vertices, faces = sphere_mesh
    exported = trimesh.Trimesh(vertices, faces, process=False).export(file_type="off", digits=17)
    _assert_same_as_trimesh(exported.encode(), "off")
    one_line = b"OFF 3 1 0\r\n0 0 0\r\n1 0 0\r\n0 1 0\r\n3 0 1 2\r\n"
    _assert_same_as_trimesh(one_line, "off")


def _old_xyz(data: bytes) -> np.ndarray:
    """The reader before the typed one (Python lists), as the reference."""
    rows = [line.split() for line in data.decode("utf-8").splitlines()]
    rows = [row for row in rows if row and not row[0].startswith("#")]
    return np.array([[float(value) for value in row[:3]] for row in rows], dtype=np.float64)


def test_xyz_reads_like_before():
    points = RNG.normal(size=(50, 3)) * 1e3
    buffer = io.BytesIO()
    np.savetxt(buffer, points, fmt="%.17g")
    data = b"# header\n" + buffer.getvalue().replace(b"\n", b" 0 0 1\n", 3) + b"\n\n  "
    got = read_arrays(data, "xyz")[0]
    np.testing.assert_array_equal(got, _old_xyz(data))
    np.testing.assert_array_equal(got, points)
    tabs = b"1\t2\t3\r\n4 5 6 # trailing comment\r7 8 9"
    np.testing.assert_array_equal(read_arrays(tabs, "xyz")[0], [[1, 2, 3], [4, 5, 6], [7, 8, 9]])


def test_eval_meshes_read_like_trimesh(eval_data):
    files = sorted(eval_data.glob("*/*.off"))[:12]
    assert files
    for path in files:
        _assert_same_as_trimesh(path.read_bytes(), "off")


# ----------------------------------------------------------------------------- lying headers

PLY_TRIANGLE = _ply_ascii(np.eye(3), [[0, 1, 2]])


@pytest.mark.parametrize(
    "data",
    [
        PLY_TRIANGLE + b"0 0 1\n",  # one line more than declared
        PLY_TRIANGLE.replace(b"element vertex 3", b"element vertex 4"),  # one line missing
        PLY_TRIANGLE.replace(b"element vertex 3", b"element vertex 2"),  # a face as a vertex
        PLY_TRIANGLE.replace(b"\n1 0 0\n", b"\n1 0 0 5\n"),  # more values than properties
        PLY_TRIANGLE.replace(b"\n1 0 0\n", b"\n1 0\n"),  # fewer values
        PLY_TRIANGLE.replace(b"3 0 1 2", b"4 0 1 2"),  # list longer than its line
        PLY_TRIANGLE.replace(b"3 0 1 2", b"3 0 1 2 2"),  # list shorter than its line
        PLY_TRIANGLE.replace(b"3 0 1 2", b"2 0 1"),  # not a polygon
        PLY_TRIANGLE.replace(b"\n1 0 0\n", b"\n1 0 x\n"),  # not a number
        PLY_TRIANGLE.replace(b"format ascii", b"format text"),
        PLY_TRIANGLE.replace(b"end_header", b"end_of_header"),
        PLY_TRIANGLE.replace(b"property float y", b"property quaternion y"),
    ],
)
def test_ascii_ply_whose_header_lies_is_refused(data):
    with pytest.raises(ShapeFileError):
        load_shape(data, file_format="ply")


OFF_TRIANGLE = b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"


@pytest.mark.parametrize(
    "data",
    [
        OFF_TRIANGLE + b"3 2 1 0\n",
        OFF_TRIANGLE.replace(b"3 1 0", b"4 1 0"),
        OFF_TRIANGLE.replace(b"\n1 0 0\n", b"\n1 0\n"),
        OFF_TRIANGLE.replace(b"3 0 1 2", b"4 0 1 2"),
        OFF_TRIANGLE.replace(b"3 0 1 2", b"2 0 1"),
        OFF_TRIANGLE.replace(b"\n1 0 0\n", b"\n1 0 zero\n"),
    ],
)
def test_off_whose_header_lies_is_refused(data):
    with pytest.raises(ShapeFileError):
        load_shape(data, file_format="off")


def test_non_integer_face_indices_are_refused():
    with pytest.raises(FaceIndexError):
        load_shape(OFF_TRIANGLE.replace(b"3 0 1 2", b"3 0 1 1.5"), file_format="off")
    with pytest.raises(FaceIndexError):
        load_shape(PLY_TRIANGLE.replace(b"3 0 1 2", b"3 0 1 2.5"), file_format="ply")


# ----------------------------------------------------------------------------- declared sizes

SMALL = ShapeLimits(max_vertices=100, max_faces=100, max_scene_nodes=10)
GARBAGE = b"\x00 not numbers at all \xff\n" * 4


def test_ply_declared_counts_are_checked_before_the_body():
    # the body is garbage: refusing it as too large proves the header was checked first
    for header in (b"element vertex 101\n", b"element vertex 3\nelement face 101\n"):
        data = (
            b"ply\nformat ascii 1.0\n"
            + header.replace(b"\nelement face", b"\nproperty float x\nelement face")
            + b"property float x\nend_header\n"
            + GARBAGE
        )
        with pytest.raises(ShapeTooLargeError):
            load_shape(data, file_format="ply", limits=SMALL)
    binary = b"ply\nformat binary_little_endian 1.0\nelement vertex 101\nproperty float x\n"
    with pytest.raises(ShapeTooLargeError):
        load_shape(binary + b"end_header\n" + GARBAGE, file_format="ply", limits=SMALL)
    with pytest.raises(ShapeFileError):  # declares more bytes than it holds
        load_shape(binary.replace(b"101", b"90") + b"end_header\n" + GARBAGE, file_format="ply")


def test_off_obj_xyz_stl_counts_are_checked_before_parsing():
    with pytest.raises(ShapeTooLargeError):
        load_shape(b"OFF\n101 1 0\n" + GARBAGE, file_format="off", limits=SMALL)
    with pytest.raises(ShapeTooLargeError):
        load_shape(b"OFF\n3 101 0\n" + GARBAGE, file_format="off", limits=SMALL)
    with pytest.raises(ShapeTooLargeError):
        load_shape(b"v x\n" * 101 + GARBAGE, file_format="obj", limits=SMALL)
    with pytest.raises(ShapeTooLargeError):
        load_shape(b"f x\r" * 101 + GARBAGE, file_format="obj", limits=SMALL)
    with pytest.raises(ShapeTooLargeError):
        load_shape(b"x\n" * 101, file_format="xyz", limits=SMALL)
    binary_stl = b"\0" * 80 + struct.pack("<I", 101) + b"\0" * 50 * 101
    with pytest.raises(ShapeTooLargeError):
        load_shape(binary_stl, file_format="stl", limits=SMALL)
    with pytest.raises(ShapeTooLargeError):
        load_shape(b"solid x\n" + b"endfacet\n" * 101, file_format="stl", limits=SMALL)


def _npy(shape: tuple[int, ...], payload: bytes, descr: str = "<f8", fortran=False) -> bytes:
    header = f"{{'descr': '{descr}', 'fortran_order': {fortran}, 'shape': {shape}, }}".encode()
    header += b" " * (-(len(header) + 11) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + payload


def test_npy_header_is_checked_before_allocating():
    with pytest.raises(ShapeTooLargeError):
        load_shape(_npy((10**12, 3), b"\0" * 48), file_format="npy")
    with pytest.raises(ShapeTooLargeError):
        load_shape(_npy((101, 3), b""), file_format="npy", limits=SMALL)
    with pytest.raises(ShapeFileError):  # truncated
        load_shape(_npy((5, 3), b"\0" * 48), file_format="npy")
    with pytest.raises(ShapeFileError):  # trailing bytes
        load_shape(_npy((2, 3), b"\0" * 56), file_format="npy")
    with pytest.raises(ShapeFileError):
        load_shape(_npy((-1, 3), b"\0" * 48), file_format="npy")
    with pytest.raises(ShapeFileError):
        load_shape(_npy((1,), b"\0" * 8, descr="|O"), file_format="npy")
    with pytest.raises(ArrayShapeError):
        load_shape(_npy((2, 3), b"\0" * 6, descr="|V1"), file_format="npy")


@pytest.mark.parametrize("version", [(1, 0), (2, 0)])
@pytest.mark.parametrize("order", ["C", "F"])
@pytest.mark.parametrize("dtype", ["<f8", ">f4", "<i4"])
def test_npy_layouts_read_like_numpy(version, order, dtype):
    points = np.asarray(RNG.integers(-50, 50, (7, 3)), dtype=dtype)
    points = np.asfortranarray(points) if order == "F" else points
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, points, version=version)
    loaded = read_arrays(buffer.getvalue(), "npy")[0]
    np.testing.assert_array_equal(loaded, np.load(io.BytesIO(buffer.getvalue())))


def _glb(document: dict) -> bytes:
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32).tobytes()
    base = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(positions)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(positions)}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [1, 1, 0],
            }
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
    }
    chunk = json.dumps({**base, **document}).encode()
    chunk += b" " * (-len(chunk) % 4)
    body = struct.pack("<II", len(chunk), 0x4E4F534A) + chunk
    body += struct.pack("<II", len(positions), 0x004E4942) + positions
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def _instances(n: int) -> dict:
    return {
        "nodes": [{"mesh": 0, "translation": [float(i), 0.0, 0.0]} for i in range(n)],
        "scenes": [{"nodes": list(range(n))}],
    }


def test_glb_scene_size_is_checked_before_trimesh():
    shape = load_shape(_glb(_instances(10)), file_format="glb", limits=SMALL)
    assert shape.n_points == 30 and shape.n_faces == 10
    with pytest.raises(ShapeTooLargeError):  # nodes
        load_shape(_glb(_instances(11)), file_format="glb", limits=SMALL)
    # 15 nodes, each the parent of the next one twice: 2^14 instances of the last one
    chain = [{"children": [i + 1, i + 1]} for i in range(14)] + [{"mesh": 0}]
    with pytest.raises(ShapeTooLargeError):
        load_shape(_glb({"nodes": chain, "scenes": [{"nodes": [0]}]}), file_format="glb")
    cycle = [{"children": [1]}, {"children": [0], "mesh": 0}]
    with pytest.raises(ShapeTooLargeError):
        load_shape(_glb({"nodes": cycle, "scenes": [{"nodes": [0]}]}), file_format="glb")
    with pytest.raises(ShapeTooLargeError):  # instanced vertices
        load_shape(_glb(_instances(10)), file_format="glb", limits=ShapeLimits(max_vertices=29))
    huge = _glb({**_instances(1), "accessors": [{"count": 10**12, "type": "VEC3"}]})
    with pytest.raises(ShapeTooLargeError):
        load_shape(huge, file_format="glb")
    with pytest.raises(ShapeFileError):
        load_shape(_glb({"nodes": "not a list"}), file_format="glb")
