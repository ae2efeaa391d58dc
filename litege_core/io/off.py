"""ASCII OFF meshes: counts first, then exactly that many vertex and face lines (other OFF
flavours go to trimesh after the size check)."""

from __future__ import annotations

import re

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ShapeFileError
from litege_core.io.limits import check_counts
from litege_core.io.tokens import (
    first_columns,
    integer_indices,
    line_counts,
    numbers,
    strip_comments,
    triangulate,
)
from litege_core.io.trimesh_backend import read_with_trimesh
from litege_core.validate import ShapeLimits


def read_off(data: bytes, limits: ShapeLimits) -> tuple[NDArray, NDArray | None]:
    """ASCII ``OFF``: counts first, then exactly that many vertex and face lines."""
    text = strip_comments(data)
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
            check_counts("off", limits, *declared)
        return read_with_trimesh(data, "off")
    assert counts_match is not None  # `declared` was read from it
    n_vertices, n_faces = declared
    check_counts("off", limits, n_vertices, n_faces)
    body = text[counts_match.end() :]
    counts = line_counts(body)
    if counts.size != n_vertices + n_faces:
        raise ShapeFileError(
            f"OFF header declares {n_vertices} vertices and {n_faces} faces "
            f"({n_vertices + n_faces} lines), the file has {counts.size} lines"
        )
    if n_vertices == 0:
        raise ShapeFileError("no geometry found in OFF file")
    if counts[:n_vertices].min() < 3:
        raise ShapeFileError("every OFF vertex line needs three coordinates")
    values = numbers(body, int(counts.sum()), "OFF file")
    n_vertex_values = int(counts[:n_vertices].sum())
    vertices = first_columns(values[:n_vertex_values], counts[:n_vertices], 3)
    if n_faces == 0:
        return vertices, None
    face_counts = counts[n_vertices:]
    first = np.concatenate([[0], np.cumsum(face_counts)[:-1]])
    face_values = values[n_vertex_values:]
    sizes = integer_indices(face_values[first], "off")
    if sizes.min() < 3 or (face_counts < sizes + 1).any():
        raise ShapeFileError("an OFF face line must hold its corner count (>= 3) and corners")
    faces = triangulate(first + 1, sizes, face_values, "off")
    return vertices, faces


__all__ = [
    "read_off",
]
