"""Loading meshes and point clouds from files or bytes into validated :class:`Shape` objects.

Meshes: OBJ, PLY, OFF, STL, GLB. Point clouds: PLY (no faces), XYZ (text, first three
columns), NPY (``(N, 3)`` array, no pickle). trimesh processing is off: vertices keep the
user's order and are never merged, except for STL, which stores a triangle soup without shared
vertices; there exact duplicate corners are merged in first-occurrence order so the mesh is
connected (the same STL always gives the same vertex order). Polygons in OBJ/OFF/PLY files are
fan-triangulated by trimesh; triangles pass through unchanged.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import (
    FaceIndexError,
    LiteGEError,
    ShapeFileError,
    ShapeTooLargeError,
    UnsupportedFormatError,
)
from litege_core.shape import Shape, ShapeKind
from litege_core.validate import DEFAULT_LIMITS, ShapeLimits

MESH_FORMATS = frozenset({"obj", "ply", "off", "stl", "glb"})
POINT_FORMATS = frozenset({"ply", "xyz", "npy"})
SUPPORTED_FORMATS = MESH_FORMATS | POINT_FORMATS


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
        limits: size bounds (bytes, vertices, faces).

    Raises:
        UnsupportedFormatError, ShapeFileError, ShapeTooLargeError and every validation
        error of :meth:`Shape.from_arrays`.
    """
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
    file_format = file_format.lower().lstrip(".")
    if file_format not in SUPPORTED_FORMATS:
        raise UnsupportedFormatError(
            f"unsupported format {file_format!r}; supported: {sorted(SUPPORTED_FORMATS)}"
        )
    _check_size(len(data), limits)
    vertices, faces = read_arrays(data, file_format)
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


def read_arrays(data: bytes, file_format: str) -> tuple[NDArray, NDArray | None]:
    """Parse file bytes into raw ``(vertices, faces or None)`` arrays, without validation."""
    if file_format == "npy":
        return _read_npy(data), None
    if file_format == "xyz":
        return _read_xyz(data), None
    return _read_with_trimesh(data, file_format)


def _read_npy(data: bytes) -> NDArray:
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ShapeFileError(f"not a readable .npy array (pickled or truncated?): {exc}") from exc
    if not isinstance(array, np.ndarray):
        raise ShapeFileError("a .npy point cloud must hold a single (N, 3) array")
    return array


def _read_xyz(data: bytes) -> NDArray:
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ShapeFileError("an .xyz file must be UTF-8 text") from exc
    rows = [line.split() for line in text.splitlines()]
    rows = [row for row in rows if row and not row[0].startswith("#")]
    if not rows:
        return np.zeros((0, 3))
    widths = {len(row) for row in rows}
    if min(widths) < 3:
        raise ShapeFileError("every .xyz line needs at least three numbers (x y z)")
    try:
        return np.array([[float(value) for value in row[:3]] for row in rows], dtype=np.float64)
    except ValueError as exc:
        raise ShapeFileError(f"non-numeric value in .xyz file: {exc}") from exc


def _read_with_trimesh(data: bytes, file_format: str) -> tuple[NDArray, NDArray | None]:
    import trimesh

    try:
        loaded = trimesh.load(
            io.BytesIO(data), file_type=file_format, process=False, maintain_order=True
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
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
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


def save_shape(shape: Shape, path: str | os.PathLike) -> None:
    """Write a shape to ``path`` (format from the extension), preserving vertex order."""
    file_format = detect_format(path)
    if file_format == "npy":
        np.save(path, np.asarray(shape.vertices), allow_pickle=False)
        return
    if file_format == "xyz":
        np.savetxt(path, shape.vertices, fmt="%.17g")
        return
    import trimesh

    if shape.faces is None:
        geometry = trimesh.PointCloud(np.asarray(shape.vertices))
    else:
        geometry = trimesh.Trimesh(
            np.asarray(shape.vertices), np.asarray(shape.faces), process=False
        )
    # Text formats get 17 significant digits so float64 coordinates round-trip exactly;
    # PLY, STL and GLB store float32 (their writers' choice), so those round-trip to ~1e-7.
    options = {"digits": 17} if file_format in {"obj", "off"} else {}
    geometry.export(path, file_type=file_format, **options)
