"""Loading meshes and point clouds from files or bytes into validated :class:`Shape` objects.

Meshes: OBJ, PLY, OFF, STL, GLB, glTF (``.gltf``: buffers embedded as ``data:`` URIs, or, when
loaded from a path, in files beside it). Point clouds: PLY (no faces), XYZ (text, first three
columns), NPY (``(N, 3)`` array, no pickle). trimesh processing is off: vertices keep the
user's order and are never merged, except for STL, which stores a triangle soup without shared
vertices; there exact duplicate corners are merged in first-occurrence order so the mesh is
connected (the same STL always gives the same vertex order). Polygons are fan-triangulated in
trimesh's order (all triangles, then the first and the second halves of all quads, then the
fans of larger polygons); triangles pass through unchanged.

**Untrusted input.** Files come from users (the service takes uploads), so loading is bounded
by :class:`~litege_core.validate.ShapeLimits` *before* anything of the declared size exists:

* Declared sizes are checked first: PLY element counts, OFF counts, the NPY header's shape
  and dtype (also against the bytes that follow it), binary STL's triangle count, the GLB's
  or glTF's JSON (nodes, node instances after expanding the scene graph, instanced vertices and
  triangles), and for OBJ, XYZ and ASCII STL the number of vertex and face lines counted in
  the raw bytes. Too large: :class:`~litege_core.errors.ShapeTooLargeError`.
* Headers must tell the truth: an ASCII PLY or OFF body must hold exactly the declared
  elements, one per line, each with the declared number of values (a lying header used to be
  accepted, trimesh reads what the header says and ignores the rest), and an NPY body exactly
  the declared array.
* ASCII PLY, OFF and XYZ are parsed by a typed numpy tokenizer (:func:`_line_counts`,
  :func:`_numbers`): a few byte masks and ``np.fromstring`` into float64, no Python object per
  number. Parse time and memory are then linear in the file with small constants (measured in
  ``scripts/bench_parse.py``); plain binary PLY (scalar vertices, triangle faces) is read as
  fixed-size records by ``np.frombuffer``; other binary PLY, STL, GLB and OBJ keep trimesh's
  numpy-based readers, behind the size checks above.
* Scene formats are bounded by :attr:`ShapeLimits.max_scene_nodes` (trimesh needs about a
  minute for a GLB of 200,000 nodes). Their materials and textures are never read.
* A ``.gltf`` loaded from bytes (an upload) must embed its buffers; loaded from a path, a
  buffer may be a file beside it, named by a relative URI that stays in the file's folder, and
  the file and its buffers together count against :attr:`ShapeLimits.max_file_bytes`.

These functions are synchronous and CPU-bound: a server must call them off its event loop.
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import (
    FaceIndexError,
    InputError,
    LiteGEError,
    ShapeFileError,
    ShapeTooLargeError,
    UnsupportedFormatError,
)
from litege_core.shape import Shape, ShapeKind
from litege_core.validate import DEFAULT_LIMITS, ShapeLimits

MESH_FORMATS = frozenset({"obj", "ply", "off", "stl", "glb", "gltf"})
POINT_FORMATS = frozenset({"ply", "xyz", "npy"})
SUPPORTED_FORMATS = MESH_FORMATS | POINT_FORMATS

MAX_HEADER_BYTES = 1 << 20
"""Largest accepted PLY header and NPY header dictionary (bytes)."""

_PLY_TYPES = {
    "char": "i1",
    "uchar": "u1",
    "short": "i2",
    "ushort": "u2",
    "int": "i4",
    "int8": "i1",
    "int16": "i2",
    "int32": "i4",
    "int64": "i8",
    "uint": "u4",
    "uint8": "u1",
    "uint16": "u2",
    "uint32": "u4",
    "uint64": "u8",
    "float": "f4",
    "float16": "f2",
    "float32": "f4",
    "float64": "f8",
    "double": "f8",
}
"""PLY property types → numpy type codes (trimesh's table)."""

_PLY_FACE_LISTS = ("vertex_index", "vertex_indices")
_PLY_TEXCOORDS = (("texture_u", "texture_v"), ("u", "v"), ("s", "t"))


def detect_format(name: str | os.PathLike) -> str:
    """File format from a file name's extension (lower case, without the dot)."""
    suffix = Path(name).suffix.lower().lstrip(".")
    if suffix not in SUPPORTED_FORMATS:
        raise UnsupportedFormatError(
            f"unsupported file extension {suffix!r}; supported: {sorted(SUPPORTED_FORMATS)}",
            format=suffix,
        )
    return suffix


def load_shape(
    source: str | os.PathLike | bytes,
    *,
    file_format: str | None = None,
    kind: str | ShapeKind | None = None,
    limits: ShapeLimits = DEFAULT_LIMITS,
) -> Shape:
    """Load and validate a shape.

    Args:
        source: a path, or the file's bytes (then ``file_format`` is required).
        file_format: one of :data:`SUPPORTED_FORMATS`; default from the path's extension.
        kind: force ``"mesh"`` or ``"point_cloud"``; default: mesh when the file has faces.
        limits: size bounds (bytes, vertices, faces, scene nodes), checked before parsing
            where the file declares its sizes (see the module docstring).

    Raises:
        UnsupportedFormatError, ShapeFileError, ShapeTooLargeError and every validation
        error of :meth:`Shape.from_arrays`.
    """
    folder = None  # where a glTF's external buffers lie (none for bytes)
    if isinstance(source, bytes | bytearray | memoryview):
        if file_format is None:
            raise UnsupportedFormatError("file_format is required when loading from bytes")
        data = bytes(source)
    else:
        path = Path(source)
        file_format = file_format or detect_format(path)
        try:
            size = path.stat().st_size
        except OSError as exc:
            raise ShapeFileError(f"cannot read {path}: {exc.strerror}") from exc
        _check_size(size, limits)
        data = path.read_bytes()
        folder = path.parent
    file_format = file_format.lower().lstrip(".")
    if file_format not in SUPPORTED_FORMATS:
        raise UnsupportedFormatError(
            f"unsupported format {file_format!r}; supported: {sorted(SUPPORTED_FORMATS)}"
        )
    _check_size(len(data), limits)
    if file_format == "gltf" and folder is not None:
        data = _embed_gltf_buffers(data, folder, limits)
    vertices, faces = read_arrays(data, file_format, limits)
    if kind is None:
        kind = ShapeKind.MESH if faces is not None else ShapeKind.POINT_CLOUD
    return Shape.from_arrays(vertices, faces, kind, limits)


def _check_size(n_bytes: int, limits: ShapeLimits) -> None:
    if n_bytes > limits.max_file_bytes:
        raise ShapeTooLargeError(
            f"file has {n_bytes} bytes, the limit is {limits.max_file_bytes}",
            n_bytes=n_bytes,
            limit=limits.max_file_bytes,
        )
    if n_bytes == 0:
        raise ShapeFileError("file is empty")


def _check_counts(
    file_format: str,
    limits: ShapeLimits,
    n_vertices: int = 0,
    n_faces: int = 0,
    what: str = "declares",
) -> None:
    """Refuse a file that declares (or holds) more vertices/faces than the limits allow."""
    if n_vertices > limits.max_vertices:
        raise ShapeTooLargeError(
            f"{file_format.upper()} file {what} {n_vertices} vertices, "
            f"the limit is {limits.max_vertices}",
            n_vertices=n_vertices,
            limit=limits.max_vertices,
        )
    if n_faces > limits.max_faces:
        raise ShapeTooLargeError(
            f"{file_format.upper()} file {what} {n_faces} faces, the limit is {limits.max_faces}",
            n_faces=n_faces,
            limit=limits.max_faces,
        )


def read_arrays(
    data: bytes, file_format: str, limits: ShapeLimits = DEFAULT_LIMITS
) -> tuple[NDArray, NDArray | None]:
    """Parse file bytes into raw ``(vertices, faces or None)`` arrays, without validation
    (but with the size checks of the module docstring)."""
    if file_format == "npy":
        return _read_npy(data, limits), None
    if file_format == "xyz":
        return _read_xyz(data, limits), None
    if file_format == "ply":
        return _read_ply(data, limits)
    if file_format == "off":
        return _read_off(data, limits)
    if file_format == "obj":
        _check_counts("obj", limits, _lines_starting(data, b"v "), _lines_starting(data, b"f "))
    elif file_format == "stl":
        _check_stl(data, limits)
    elif file_format == "glb":
        _check_glb(data, limits)
    elif file_format == "gltf":
        _check_gltf_json(data, limits)
    return _read_with_trimesh(data, file_format)


# ----------------------------------------------------------------------------- text tokens


_SPACE = np.zeros(256, dtype=bool)
_SPACE[[9, 10, 11, 12, 13, 32]] = True
_WINDOW = 1 << 20


def _line_counts(block: bytes) -> NDArray:
    """How many whitespace-separated tokens each non-empty line of ``block`` holds.

    Lines end at ``\\n``, ``\\r\\n`` or a lone ``\\r``; whitespace is ASCII space, tab,
    ``\\v``, ``\\f`` and the line ends. Works through windows of about
    :data:`_WINDOW` bytes cut at line ends, so its temporary memory is a few times the
    window, plus 8 bytes per line for the result.
    """
    parts = []
    start = 0
    while start < len(block):
        stop = block.find(b"\n", start + _WINDOW) + 1 or len(block)
        parts.append(_window_counts(np.frombuffer(block, np.uint8, stop - start, start)))
        start = stop
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def _window_counts(raw: NDArray) -> NDArray:
    """:func:`_line_counts` of one window ``raw`` (uint8) ending at a line end or the end."""
    space = _SPACE[raw]
    starts = ~space
    starts[1:] &= space[:-1]
    del space
    tokens = np.flatnonzero(starts)  # where each token starts
    del starts
    breaks = raw == 10
    lone_cr = raw == 13
    if lone_cr.any():
        lone_cr[:-1] &= raw[1:] != 10
        breaks |= lone_cr
    del lone_cr
    before_break = np.searchsorted(tokens, np.flatnonzero(breaks))  # tokens before each end
    counts = np.diff(before_break, prepend=0, append=tokens.size)
    return counts[counts > 0]


def _numbers(block: bytes, expected: int, what: str) -> NDArray:
    """All ``expected`` whitespace-separated numbers of ``block`` as float64 (no Python
    object per number).

    Raises:
        ShapeFileError: a token that is not a number.
    """
    if expected == 0:
        return np.zeros(0)
    try:
        values = np.fromstring(block, dtype=np.float64, sep=" ")
    except ValueError:
        values = None
    if values is None or values.size != expected:
        raise ShapeFileError(f"non-numeric value in {what}")
    return values


def _first_columns(values: NDArray, counts: NDArray, width: int) -> NDArray:
    """The first ``width`` values of every line (each line holds ``counts[i] >= width``)."""
    if counts.size and (counts == counts[0]).all():
        return values.reshape(counts.size, int(counts[0]))[:, :width]
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return values[offsets[:, None] + np.arange(width)]


def _strip_comments(data: bytes) -> bytes:
    """``data`` without ``#`` comments (to the end of their line)."""
    return re.sub(rb"#[^\r\n]*", b"", data) if b"#" in data else data


def _lines_starting(data: bytes, prefix: bytes) -> int:
    """Lines of ``data`` that start with ``prefix`` (a byte count, no parsing)."""
    return data.count(b"\n" + prefix) + data.count(b"\r" + prefix) + data.startswith(prefix)


# ----------------------------------------------------------------------------- polygons


def _triangulate(first: NDArray, sizes: NDArray, indices: NDArray, file_format: str) -> NDArray:
    """Triangles ``(T, 3)`` int64 of polygons in trimesh's order (see the module docstring).

    Args:
        first: ``(P,)`` offset of each polygon's first corner in ``indices``.
        sizes: ``(P,)`` corners of each polygon (each ``>= 3``).
        indices: the flat float64 values holding the corners (and possibly other values).
        file_format: for error messages.

    Raises:
        FaceIndexError: a corner that is not an integer.
    """
    return _indices(_fan(first, sizes, indices), file_format)


def _fan(first: NDArray, sizes: NDArray, indices: NDArray) -> NDArray:
    if sizes.size and (sizes == 3).all():
        return indices[first[:, None] + np.arange(3)]
    tri = first[sizes == 3]
    quad = first[sizes == 4]
    parts = [indices[tri[:, None] + np.arange(3)]]
    if quad.size:
        corners = indices[quad[:, None] + np.arange(4)]
        parts += [corners[:, [0, 1, 2]], corners[:, [2, 3, 0]]]
    big = sizes > 4
    if big.any():
        fan_first, fan_sizes = first[big], sizes[big]
        n_fan = fan_sizes - 2
        owner = np.repeat(np.arange(fan_first.size), n_fan)
        step = np.arange(owner.size) - np.repeat(np.cumsum(n_fan) - n_fan, n_fan) + 1
        base = fan_first[owner]
        parts.append(
            np.column_stack([indices[base], indices[base + step], indices[base + step + 1]])
        )
    return np.concatenate(parts)


def _indices(values: NDArray, file_format: str) -> NDArray:
    """Float64 tokens that must be integer vertex indices → int64."""
    if values.size == 0:
        return values.astype(np.int64)
    low, high = values.min(), values.max()  # NaN fails both comparisons
    integers = values.astype(np.int64) if (low > -(2.0**62) and high < 2.0**62) else None
    if integers is None or not np.array_equal(integers, values):
        raise FaceIndexError(f"{file_format.upper()} file has face indices that are not integers")
    return integers


# ----------------------------------------------------------------------------- NPY


def _read_npy(data: bytes, limits: ShapeLimits) -> NDArray:
    """An ``.npy`` array, header first: the declared dtype, shape and byte length are checked
    before any array exists; the array then views the bytes (no copy)."""
    from numpy.lib import format as npy_format

    stream = io.BytesIO(data)
    try:
        version = npy_format.read_magic(stream)
        if version == (1, 0):
            shape, fortran, dtype = npy_format.read_array_header_1_0(stream, MAX_HEADER_BYTES)
        elif version == (2, 0):
            shape, fortran, dtype = npy_format.read_array_header_2_0(stream, MAX_HEADER_BYTES)
        else:
            raise ValueError(f"unsupported .npy format version {version}")
    except (ValueError, OSError, EOFError, SyntaxError, TypeError) as exc:
        raise ShapeFileError(f"not a readable .npy array (truncated?): {exc}") from exc
    if dtype.hasobject:
        raise ShapeFileError("a .npy point cloud must not hold Python objects (pickle refused)")
    if any(not isinstance(n, int) or n < 0 for n in shape):
        raise ShapeFileError(f".npy header declares an invalid shape {shape}")
    count = math.prod(shape)
    if count > 3 * limits.max_vertices:
        raise ShapeTooLargeError(
            f".npy header declares an array of shape {shape}, more than the limit of "
            f"{limits.max_vertices} points",
            n_vertices=count // 3,
            limit=limits.max_vertices,
        )
    offset = stream.tell()
    needed = count * dtype.itemsize
    if len(data) - offset != needed:
        raise ShapeFileError(
            f".npy header declares {needed} bytes of data, the file holds {len(data) - offset}"
        )
    array = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
    return array.reshape(shape, order="F" if fortran else "C")


# ----------------------------------------------------------------------------- XYZ


def _read_xyz(data: bytes, limits: ShapeLimits) -> NDArray:
    """An ``.xyz`` cloud: the first three numbers of every non-empty line (``#`` comments)."""
    text = _strip_comments(data)
    counts = _line_counts(text)
    _check_counts("xyz", limits, int(counts.size), what="has")
    if counts.size == 0:
        return np.zeros((0, 3))
    if counts.min() < 3:
        raise ShapeFileError("every .xyz line needs at least three numbers (x y z)")
    values = _numbers(text, int(counts.sum()), ".xyz file")
    return _first_columns(values, counts, 3)


# ----------------------------------------------------------------------------- OFF


def _read_off(data: bytes, limits: ShapeLimits) -> tuple[NDArray, NDArray | None]:
    """ASCII ``OFF``: counts first, then exactly that many vertex and face lines."""
    text = _strip_comments(data)
    match = re.match(rb"\s*(\S*)", text)
    assert match is not None  # the pattern matches any text (possibly empty)
    magic = match.group(1)
    counts_match = re.compile(rb"\s*(\S+)[ \t]+(\S+)[^\r\n]*").match(text, match.end(1))
    declared = None
    if counts_match is not None:
        try:
            declared = int(counts_match.group(1)), int(counts_match.group(2))
        except ValueError:
            declared = None
    if magic != b"OFF" or declared is None or min(declared) < 0:
        if declared is not None:  # COFF, NOFF, ...: trimesh, after the size check
            _check_counts("off", limits, *declared)
        return _read_with_trimesh(data, "off")
    assert counts_match is not None  # `declared` was read from it
    n_vertices, n_faces = declared
    _check_counts("off", limits, n_vertices, n_faces)
    body = text[counts_match.end() :]
    counts = _line_counts(body)
    if counts.size != n_vertices + n_faces:
        raise ShapeFileError(
            f"OFF header declares {n_vertices} vertices and {n_faces} faces "
            f"({n_vertices + n_faces} lines), the file has {counts.size} lines"
        )
    if n_vertices == 0:
        raise ShapeFileError("no geometry found in OFF file")
    if counts[:n_vertices].min() < 3:
        raise ShapeFileError("every OFF vertex line needs three coordinates")
    values = _numbers(body, int(counts.sum()), "OFF file")
    n_vertex_values = int(counts[:n_vertices].sum())
    vertices = _first_columns(values[:n_vertex_values], counts[:n_vertices], 3)
    if n_faces == 0:
        return vertices, None
    face_counts = counts[n_vertices:]
    first = np.concatenate([[0], np.cumsum(face_counts)[:-1]])
    face_values = values[n_vertex_values:]
    sizes = _indices(face_values[first], "off")
    if sizes.min() < 3 or (face_counts < sizes + 1).any():
        raise ShapeFileError("an OFF face line must hold its corner count (>= 3) and corners")
    faces = _triangulate(first + 1, sizes, face_values, "off")
    return vertices, faces


# ----------------------------------------------------------------------------- PLY


@dataclass(frozen=True)
class _PlyProperty:
    name: str
    dtype: str  # numpy type code of the value (of the list items for lists)
    is_list: bool
    count_dtype: str = ""  # numpy type code of a list's length


@dataclass(frozen=True)
class _PlyElement:
    name: str
    count: int
    properties: tuple[_PlyProperty, ...]

    def find(self, name: str) -> _PlyProperty | None:
        return next((p for p in self.properties if p.name == name), None)


def _ply_header(data: bytes) -> tuple[str, list[_PlyElement], int]:
    """``(format, elements, offset of the body)`` of a PLY file.

    Raises:
        ShapeFileError: not a PLY header, or a malformed one.
    """
    end = re.compile(rb"end_header[ \t]*(\r\n|\n|\r)").search(data, 0, MAX_HEADER_BYTES)
    if not data.startswith(b"ply") or end is None:
        raise ShapeFileError("cannot parse PLY file: no 'ply' ... 'end_header' header")
    try:
        lines = data[: end.start()].decode("ascii").splitlines()
    except UnicodeDecodeError as exc:
        raise ShapeFileError("cannot parse PLY file: the header is not ASCII") from exc
    file_format = ""
    elements: list[tuple[str, int, list[_PlyProperty]]] = []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in {"comment", "obj_info"}:
            continue
        try:
            if words[0] == "format":
                file_format = words[1]
            elif words[0] == "element":
                elements.append((words[1], int(words[2]), []))
            elif words[0] == "property":
                if not elements:
                    raise ValueError("a property before any element")
                if words[1] == "list":
                    if words[2] not in _PLY_TYPES:
                        raise ValueError(f"unknown list count type {words[2]!r}")
                    prop = _PlyProperty(words[4], _PLY_TYPES[words[3]], True, _PLY_TYPES[words[2]])
                else:
                    prop = _PlyProperty(words[2], _PLY_TYPES[words[1]], False)
                elements[-1][2].append(prop)
        except (IndexError, KeyError, ValueError) as exc:
            raise ShapeFileError(f"cannot parse PLY header line {line!r}: {exc}") from exc
    if file_format not in {"ascii", "binary_little_endian", "binary_big_endian"}:
        raise ShapeFileError(f"cannot parse PLY file: unknown format {file_format!r}")
    parsed = [_PlyElement(name, count, tuple(props)) for name, count, props in elements]
    if any(e.count < 0 for e in parsed):
        raise ShapeFileError("PLY header declares a negative element count")
    return file_format, parsed, end.end()


def _read_ply(data: bytes, limits: ShapeLimits) -> tuple[NDArray, NDArray | None]:
    file_format, elements, offset = _ply_header(data)
    by_name = {e.name: e for e in elements}
    vertex, face = by_name.get("vertex"), by_name.get("face")
    _check_counts("ply", limits, vertex.count if vertex else 0, face.count if face else 0)
    body = len(data) - offset
    if file_format != "ascii":
        minimum = sum(
            e.count * sum(np.dtype(p.dtype).itemsize for p in e.properties if not p.is_list)
            for e in elements
        )
        if minimum > body:
            raise ShapeFileError(
                f"PLY header declares at least {minimum} bytes of data, the file holds {body}"
            )
        if vertex is not None and vertex.count and _ply_is_plain(vertex, face):
            records = _read_ply_binary(data, offset, file_format, elements, vertex, face)
            if records is not None:
                return records
        return _read_with_trimesh(data, "ply")
    text = data[offset:]
    counts = _line_counts(text)
    declared = sum(e.count for e in elements)
    if counts.size != declared:
        raise ShapeFileError(
            f"PLY header declares {declared} elements (one per line), "
            f"the file has {counts.size} lines"
        )
    if vertex is None or vertex.count == 0:
        raise ShapeFileError("no geometry found in PLY file")
    if not _ply_is_plain(vertex, face):
        return _read_with_trimesh(data, "ply")
    return _read_ply_ascii(text, counts, elements, vertex, face)


def _ply_is_plain(vertex: _PlyElement, face: _PlyElement | None) -> bool:
    """Whether the typed readers give what trimesh gives: scalar ``x y z`` vertices and
    faces with one list of corners and no per-face texture (texture unmerges vertices)."""
    if any(p.is_list for p in vertex.properties):
        return False
    if any(vertex.find(axis) is None for axis in "xyz"):
        return False
    if face is None or face.count == 0:
        return True
    lists = [p for p in face.properties if p.is_list]
    if len(lists) != 1 or lists[0].name not in _PLY_FACE_LISTS or face.find("texcoord"):
        return False
    return not any(vertex.find(u) and vertex.find(v) for u, v in _PLY_TEXCOORDS)


def _read_ply_ascii(
    text: bytes,
    counts: NDArray,
    elements: Sequence[_PlyElement],
    vertex: _PlyElement,
    face: _PlyElement | None,
) -> tuple[NDArray, NDArray | None]:
    """The typed reader of plain ASCII PLY (see :func:`_ply_ascii_is_plain`): one element per
    line (``counts`` values each), each line with exactly the declared values."""
    values = _numbers(text, int(counts.sum()), "PLY file")
    line = value = 0
    vertices = np.zeros((0, 3))
    faces: NDArray | None = None
    for element in elements:
        rows = counts[line : line + element.count]
        size = int(rows.sum())
        block = values[value : value + size]
        line += element.count
        value += size
        if any(p.is_list for p in element.properties):
            if element is face and element.count:
                faces = _ply_faces(block, rows, face)
            continue
        width = len(element.properties)
        if (rows != width).any():
            raise ShapeFileError(f"PLY {element.name} lines must hold the {width} declared values")
        if element is vertex:
            table = block.reshape(element.count, width)
            names = [p.name for p in element.properties]
            vertices = np.column_stack(
                [
                    # trimesh casts each value to its declared type (e.g. float32)
                    table[:, names.index(axis)].astype(element.properties[names.index(axis)].dtype)
                    for axis in "xyz"
                ]
            ).astype(np.float64)
    return vertices, faces


def _read_ply_binary(
    data: bytes,
    offset: int,
    file_format: str,
    elements: Sequence[_PlyElement],
    vertex: _PlyElement,
    face: _PlyElement | None,
) -> tuple[NDArray, NDArray | None] | None:
    """The typed reader of plain binary PLY (see :func:`_ply_is_plain`): every element a run
    of fixed-size records read by ``np.frombuffer`` (faces: triangles only), the body exactly
    as long as they are. ``None`` for any other layout (a list outside the faces, polygons
    other than triangles, trailing bytes): trimesh reads those. Equal to trimesh's result
    (``tests/litege_core/test_io.py``) and about 1 s less start-up: trimesh imports scipy."""
    order = "<" if file_format == "binary_little_endian" else ">"
    position = offset
    vertices, faces = np.zeros((0, 3)), None
    for element in elements:
        fields: list[tuple[str, str] | tuple[str, str, tuple[int]]] = []
        for i, prop in enumerate(element.properties):
            if prop.is_list and element is not face:
                return None
            if prop.is_list:
                fields += [(f"n{i}", order + prop.count_dtype), (f"p{i}", order + prop.dtype, (3,))]
            else:
                fields.append((f"p{i}", order + prop.dtype))
        record = np.dtype(fields)  # packed, as PLY stores them
        if position + record.itemsize * element.count > len(data):
            return None
        table = np.frombuffer(data, record, element.count, position)
        position += record.itemsize * element.count
        names = [prop.name for prop in element.properties]
        if element is vertex:
            vertices = np.column_stack(
                [table[f"p{names.index(axis)}"].astype(np.float64) for axis in "xyz"]
            )
        elif element is face and element.count:
            corners = next(i for i, prop in enumerate(element.properties) if prop.is_list)
            if (table[f"n{corners}"] != 3).any():
                return None
            faces = table[f"p{corners}"].astype(np.int64)
    return (vertices, faces) if position == len(data) else None


def _ply_faces(values: NDArray, counts: NDArray, face: _PlyElement) -> NDArray:
    """Triangles of the face lines ``values`` (per-line ``counts``)."""
    position = next(i for i, p in enumerate(face.properties) if p.is_list)
    trailing = len(face.properties) - position - 1
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]) + position
    sizes = _indices(values[first], "ply")
    if sizes.min() < 3 or (counts != position + 1 + sizes + trailing).any():
        raise ShapeFileError(
            "PLY face lines must hold the declared properties and a corner list of length >= 3"
        )
    return _triangulate(first + 1, sizes, values, "ply")


# ----------------------------------------------------------------------------- STL, glTF


def _check_stl(data: bytes, limits: ShapeLimits) -> None:
    """Triangle count of a binary STL (its header) or an ASCII one (``endfacet`` count)."""
    if len(data) >= 84:
        (declared,) = struct.unpack("<I", data[80:84])
        if 84 + 50 * declared == len(data):  # trimesh's test for binary STL
            _check_counts("stl", limits, n_faces=declared)
            return
    _check_counts("stl", limits, n_faces=data.count(b"endfacet"), what="has")


def _check_glb(data: bytes, limits: ShapeLimits) -> None:
    """Nodes, node instances, instanced vertices and triangles of a GLB, from its JSON chunk,
    before trimesh builds the scene."""
    if len(data) < 20 or data[:4] != b"glTF":
        return  # not a GLB: trimesh reports it
    length, kind = struct.unpack("<II", data[12:20])
    if kind != 0x4E4F534A or 20 + length > len(data):
        raise ShapeFileError("cannot parse GLB file: no JSON chunk")
    try:
        document = json.loads(data[20 : 20 + length])
        _check_gltf(document, limits)
    except LiteGEError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        raise ShapeFileError(f"cannot parse GLB file: {exc}") from exc


def _gltf_document(data: bytes) -> dict[str, Any]:
    """The JSON document of a ``.gltf`` file.

    Raises:
        ShapeFileError: not a JSON object.
    """
    try:
        document = json.loads(data)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ShapeFileError(f"cannot parse glTF file: {exc}") from exc
    if not isinstance(document, dict):
        raise ShapeFileError("cannot parse glTF file: the JSON is not an object")
    return document


def _external_buffers(document: dict[str, Any]) -> list[tuple[int, str]]:
    """``(index, uri)`` of the buffers of a glTF document stored outside it (not ``data:``)."""
    buffers = document.get("buffers", [])
    if not isinstance(buffers, list):
        raise ShapeFileError("cannot parse glTF file: 'buffers' is not a list")
    out = []
    for index, buffer in enumerate(buffers):
        uri = buffer.get("uri") if isinstance(buffer, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:"):
            out.append((index, uri))
    return out


def _check_gltf_json(data: bytes, limits: ShapeLimits) -> None:
    """Sizes of a ``.gltf`` (as :func:`_check_glb`), and every buffer embedded in it.

    Raises:
        ShapeFileError: not glTF JSON, or a buffer in a separate file (bytes cannot name it).
        ShapeTooLargeError: more nodes, vertices or faces than ``limits`` allow.
    """
    document = _gltf_document(data)
    external = _external_buffers(document)
    if external:
        index, uri = external[0]
        raise ShapeFileError(
            f"glTF buffer {index} is stored in a separate file ({uri!r}); send a .glb, or a "
            ".gltf whose buffers are embedded as data: URIs (or load the .gltf from its path)"
        )
    try:
        _check_gltf(document, limits, "gltf")
    except LiteGEError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        raise ShapeFileError(f"cannot parse glTF file: {exc}") from exc


def self_contained_gltf(path: str | os.PathLike, limits: ShapeLimits = DEFAULT_LIMITS) -> bytes:
    """The ``.gltf`` file at ``path`` with its buffer files embedded (:func:`load_shape`'s
    reading of it; also what identifies its content).

    Raises:
        ShapeFileError, ShapeTooLargeError: as :func:`_embed_gltf_buffers`.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ShapeFileError(f"cannot read {path}: {exc.strerror}") from exc
    return _embed_gltf_buffers(data, path.parent, limits)


def _embed_gltf_buffers(data: bytes, folder: Path, limits: ShapeLimits = DEFAULT_LIMITS) -> bytes:
    """A ``.gltf`` file's bytes with the buffers it keeps in files of ``folder`` embedded as
    ``data:`` URIs (the bytes themselves where it keeps none there).

    A buffer's URI must be relative and name a file inside ``folder`` (no ``..`` out of it, no
    scheme); the file and its buffers together must fit ``limits.max_file_bytes``.

    Raises:
        ShapeFileError: unparsable JSON, a URI outside ``folder``, an unreadable buffer file.
        ShapeTooLargeError: the file and its buffers exceed ``limits.max_file_bytes``.
    """
    document = _gltf_document(data)
    external = _external_buffers(document)
    if not external:
        return data
    root = folder.resolve()
    total = len(data)
    for index, uri in external:
        name = unquote(uri)
        target = (root / name).resolve()
        if urlparse(uri).scheme or Path(name).is_absolute() or not target.is_relative_to(root):
            raise ShapeFileError(
                f"glTF buffer {index} names {uri!r}: a buffer file must lie in the glTF's folder"
            )
        try:
            total += target.stat().st_size
            if total > limits.max_file_bytes:
                raise ShapeTooLargeError(
                    f"glTF file and its buffers have {total} bytes or more, the limit is "
                    f"{limits.max_file_bytes}",
                    n_bytes=total,
                    limit=limits.max_file_bytes,
                )
            raw = target.read_bytes()
        except OSError as exc:
            raise ShapeFileError(
                f"cannot read glTF buffer {index} ({uri!r}): {exc.strerror}"
            ) from exc
        encoded = base64.b64encode(raw).decode("ascii")
        document["buffers"][index]["uri"] = f"data:application/octet-stream;base64,{encoded}"
    return json.dumps(document).encode()


def _check_gltf(document: dict[str, Any], limits: ShapeLimits, file_format: str = "glb") -> None:
    """Nodes, node instances, instanced vertices and triangles of a glTF document (the JSON of
    a ``.gltf`` or of a GLB's first chunk) against ``limits``."""
    nodes = document.get("nodes", [])
    bound = limits.max_scene_nodes
    if len(nodes) > bound:
        raise ShapeTooLargeError(
            f"{file_format.upper()} file has {len(nodes)} nodes, the limit is {bound}",
            n_nodes=len(nodes),
            limit=bound,
        )
    accessors = document.get("accessors", [])

    def count(accessor: int) -> int:
        value = int(accessors[accessor]["count"])
        if value < 0:
            raise ValueError(f"accessor {accessor} has a negative count")
        return value

    mesh_sizes = []
    for mesh in document.get("meshes", []):
        n_vertices = n_faces = 0
        for primitive in mesh.get("primitives", []):
            points = count(primitive["attributes"]["POSITION"])
            corners = count(primitive["indices"]) if "indices" in primitive else points
            mode = primitive.get("mode", 4)
            n_vertices += points
            n_faces += corners // 3 if mode == 4 else max(corners - 2, 0) if mode in {5, 6} else 0
        mesh_sizes.append((n_vertices, n_faces))
    # trimesh reads every mesh, whether the scene uses it or not, then every instance
    defined_vertices = sum(v for v, _ in mesh_sizes)
    _check_counts(file_format, limits, defined_vertices, sum(f for _, f in mesh_sizes), "defines")
    scenes = document.get("scenes")
    if scenes:
        roots = list(scenes[int(document.get("scene", 0))].get("nodes", []))
    else:
        children = {c for node in nodes for c in node.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    n_vertices = n_faces = visited = 0
    stack = roots
    while stack:  # every instance of every node; a cycle or a shared subtree expands here
        index = int(stack.pop())
        visited += 1
        if visited > bound:
            raise ShapeTooLargeError(
                f"{file_format.upper()} scene expands to more than {bound} node instances, "
                "the limit",
                limit=bound,
            )
        node = nodes[index]
        if "mesh" in node:
            mesh_vertices, mesh_faces = mesh_sizes[int(node["mesh"])]
            n_vertices += mesh_vertices
            n_faces += mesh_faces
        stack.extend(node.get("children", []))
    _check_counts(file_format, limits, n_vertices, n_faces)


# ----------------------------------------------------------------------------- trimesh


def _read_with_trimesh(data: bytes, file_format: str) -> tuple[NDArray, NDArray | None]:
    import trimesh

    try:
        # materials and textures are never needed (and a glTF's images may be files we lack)
        scene_options: dict[str, Any] = (
            {"skip_materials": True} if file_format in {"glb", "gltf"} else {}
        )
        loaded = trimesh.load(
            io.BytesIO(data),
            file_type=file_format,
            process=False,
            maintain_order=True,
            **scene_options,
        )
    except LiteGEError:
        raise
    except Exception as exc:  # trimesh raises ValueError, IndexError, KeyError, struct.error...
        raise _translate_parse_error(exc, file_format) from exc
    if isinstance(loaded, trimesh.Scene):
        geometries = list(loaded.dump()) if loaded.geometry else []
        if not geometries:
            raise ShapeFileError(f"no geometry found in {file_format.upper()} file")
        meshes = [g for g in geometries if isinstance(g, trimesh.Trimesh)]
        if meshes:
            loaded = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
        else:
            loaded = geometries[0]
    # trimesh's Geometry declares no `vertices`; every kind it loads (Trimesh, PointCloud,
    # Path) has them
    vertices = np.asarray(loaded.vertices, dtype=np.float64)  # type: ignore[attr-defined]
    faces = getattr(loaded, "faces", None)
    if faces is None or len(faces) == 0:
        return vertices, None
    faces = np.asarray(faces, dtype=np.int64)
    if file_format == "stl":
        vertices, faces = _merge_exact_duplicates(vertices, faces)
    return vertices, faces


def _translate_parse_error(exc: Exception, file_format: str) -> LiteGEError:
    """Map a trimesh parsing exception onto the most precise LiteGE error."""
    message = str(exc)
    # OBJ faces beyond the vertex list surface as numpy IndexError ("index 7 is out of bounds
    # ..."), OFF as a ValueError; a plain "list index out of range" is a truncated header.
    numpy_bounds = isinstance(exc, IndexError) and "out of bounds" in message
    if numpy_bounds or "face index" in message.lower():
        return FaceIndexError(
            f"{file_format.upper()} file has a face index out of range: {message}"
        )
    return ShapeFileError(f"cannot parse {file_format.upper()} file: {message}")


def _merge_exact_duplicates(vertices: NDArray, faces: NDArray) -> tuple[NDArray, NDArray]:
    """Merge bit-identical vertices, keeping first-occurrence order."""
    _, first_index, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first_index, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    return vertices[first_index[order]], rank[inverse.reshape(-1)][faces]


def check_format_holds(file_format: str, kind: ShapeKind | str) -> None:
    """Check that files of ``file_format`` hold shapes of ``kind`` (meshes:
    :data:`MESH_FORMATS`, point clouds: :data:`POINT_FORMATS`).

    Raises:
        InputError: e.g. a point cloud for STL, which holds triangles only.
    """
    kind = ShapeKind.parse(kind)
    if kind is ShapeKind.MESH and file_format not in MESH_FORMATS:
        raise InputError(
            f".{file_format} holds point clouds only; write a mesh as one of "
            f"{', '.join('.' + f for f in sorted(MESH_FORMATS))}"
        )
    if kind is ShapeKind.POINT_CLOUD and file_format not in POINT_FORMATS:
        raise InputError(
            f".{file_format} holds meshes only; write a point cloud as one of "
            f"{', '.join('.' + f for f in sorted(POINT_FORMATS))}"
        )


def save_shape(shape: Shape, path: str | os.PathLike) -> None:
    """Write a shape to ``path`` (format from the extension), preserving vertex order.

    Raises:
        UnsupportedFormatError: an unknown extension.
        InputError: a format that cannot hold the shape's kind (:func:`check_format_holds`),
            or a file that cannot be written (missing directory, no permission, ...).
    """
    file_format = detect_format(path)
    check_format_holds(file_format, shape.kind)
    try:
        _write_shape(shape, path, file_format)
    except OSError as exc:
        raise InputError(f"cannot write {os.fspath(path)}: {exc.strerror or exc}") from exc


def _write_shape(shape: Shape, path: str | os.PathLike, file_format: str) -> None:
    if file_format == "npy":
        np.save(path, np.asarray(shape.vertices), allow_pickle=False)
        return
    if file_format == "gltf":
        _write_gltf(shape, path)
        return
    if file_format == "xyz":
        np.savetxt(path, shape.vertices, fmt="%.17g")
        return
    import trimesh

    geometry: trimesh.PointCloud | trimesh.Trimesh
    if shape.faces is None:
        geometry = trimesh.PointCloud(np.asarray(shape.vertices))
    else:
        geometry = trimesh.Trimesh(
            np.asarray(shape.vertices), np.asarray(shape.faces), process=False
        )
    # Text formats get 17 significant digits so float64 coordinates round-trip exactly;
    # PLY, STL and GLB store float32 (their writers' choice), so those round-trip to ~1e-7.
    options = {"digits": 17} if file_format in {"obj", "off"} else {}
    # trimesh's exporters take a str or a pathlib path, not any os.PathLike
    target = path if isinstance(path, str) else Path(path)
    geometry.export(target, file_type=file_format, **options)


def _write_gltf(shape: Shape, path: str | os.PathLike) -> None:
    """One self-contained ``.gltf`` (its buffer embedded as a ``data:`` URI; float32
    positions, as GLB)."""
    import trimesh
    from trimesh.exchange.gltf import export_gltf

    mesh = trimesh.Trimesh(np.asarray(shape.vertices), np.asarray(shape.faces), process=False)
    files = export_gltf(trimesh.Scene(mesh), embed_buffers=True)
    Path(path).write_bytes(files["model.gltf"])
