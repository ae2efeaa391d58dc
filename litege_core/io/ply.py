"""PLY meshes and clouds: the header parsed and checked against the body; plain ASCII and
binary files read by typed numpy code, the rest by trimesh."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ShapeFileError
from litege_core.io.limits import MAX_HEADER_BYTES, check_counts
from litege_core.io.tokens import integer_indices, line_counts, numbers, triangulate
from litege_core.io.trimesh_backend import read_with_trimesh
from litege_core.validate import ShapeLimits

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


def read_ply(data: bytes, limits: ShapeLimits) -> tuple[NDArray, NDArray | None]:
    file_format, elements, offset = _ply_header(data)
    by_name = {e.name: e for e in elements}
    vertex, face = by_name.get("vertex"), by_name.get("face")
    check_counts("ply", limits, vertex.count if vertex else 0, face.count if face else 0)
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
        return read_with_trimesh(data, "ply")
    text = data[offset:]
    counts = line_counts(text)
    declared = sum(e.count for e in elements)
    if counts.size != declared:
        raise ShapeFileError(
            f"PLY header declares {declared} elements (one per line), "
            f"the file has {counts.size} lines"
        )
    if vertex is None or vertex.count == 0:
        raise ShapeFileError("no geometry found in PLY file")
    if not _ply_is_plain(vertex, face):
        return read_with_trimesh(data, "ply")
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
    """The typed reader of plain ASCII PLY (see :func:`_ply_is_plain`): one element per
    line (``counts`` values each), each line with exactly the declared values."""
    values = numbers(text, int(counts.sum()), "PLY file")
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
    sizes = integer_indices(values[first], "ply")
    if sizes.min() < 3 or (counts != position + 1 + sizes + trailing).any():
        raise ShapeFileError(
            "PLY face lines must hold the declared properties and a corner list of length >= 3"
        )
    return triangulate(first + 1, sizes, values, "ply")


__all__ = [
    "read_ply",
]
