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
* ASCII PLY, OFF and XYZ are parsed by a typed numpy tokenizer
  (:func:`~litege_core.io.tokens.line_counts`, :func:`~litege_core.io.tokens.numbers`): a few
  byte masks and ``np.fromstring`` into float64, no Python object per number. Parse time and
  memory are then linear in the file with small constants (measured in
  ``scripts/bench_parse.py``); plain binary PLY (scalar vertices, triangle faces) is read as
  fixed-size records by ``np.frombuffer``; other binary PLY, STL, GLB and OBJ keep trimesh's
  numpy-based readers, behind the size checks above.
* Scene formats are bounded by :attr:`ShapeLimits.max_scene_nodes` (trimesh needs about a
  minute for a GLB of 200,000 nodes). Their materials and textures are never read.
* A ``.gltf`` loaded from bytes (an upload) must embed its buffers; loaded from a path, a
  buffer may be a file beside it, named by a relative URI that stays in the file's folder, and
  the file and its buffers together count against :attr:`ShapeLimits.max_file_bytes`.

These functions are synchronous and CPU-bound: a server must call them off its event loop.

Modules: :mod:`~litege_core.io.limits` (size checks), :mod:`~litege_core.io.tokens` (the ASCII
tokenizer, polygon triangulation), :mod:`~litege_core.io.point_files` (NPY, XYZ),
:mod:`~litege_core.io.off`, :mod:`~litege_core.io.ply`, :mod:`~litege_core.io.scenes` (STL,
GLB and glTF bounds, glTF buffer files) and :mod:`~litege_core.io.trimesh_backend` (trimesh's
readers and writers); this package holds the public functions.
"""

from __future__ import annotations

import os
from pathlib import Path

from numpy.typing import NDArray

from litege_core.errors import InputError, ShapeFileError, UnsupportedFormatError
from litege_core.io.limits import check_counts, check_size
from litege_core.io.off import read_off
from litege_core.io.ply import read_ply
from litege_core.io.point_files import read_npy, read_xyz
from litege_core.io.scenes import (
    check_glb,
    check_gltf_json,
    check_stl,
    embed_gltf_buffers,
    self_contained_gltf,
)
from litege_core.io.tokens import lines_starting
from litege_core.io.trimesh_backend import read_with_trimesh, write_shape
from litege_core.shape import Shape, ShapeKind
from litege_core.validate import DEFAULT_LIMITS, ShapeLimits

MESH_FORMATS = frozenset({"obj", "ply", "off", "stl", "glb", "gltf"})
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
        check_size(size, limits)
        data = path.read_bytes()
        folder = path.parent
    file_format = file_format.lower().lstrip(".")
    if file_format not in SUPPORTED_FORMATS:
        raise UnsupportedFormatError(
            f"unsupported format {file_format!r}; supported: {sorted(SUPPORTED_FORMATS)}"
        )
    check_size(len(data), limits)
    if file_format == "gltf" and folder is not None:  # checked as it is embedded
        vertices, faces = read_with_trimesh(embed_gltf_buffers(data, folder, limits), "gltf")
    else:
        vertices, faces = read_arrays(data, file_format, limits)
    if kind is None:
        kind = ShapeKind.MESH if faces is not None else ShapeKind.POINT_CLOUD
    return Shape.from_arrays(vertices, faces, kind, limits)


def read_arrays(
    data: bytes, file_format: str, limits: ShapeLimits = DEFAULT_LIMITS
) -> tuple[NDArray, NDArray | None]:
    """Parse file bytes into raw ``(vertices, faces or None)`` arrays, without validation
    (but with the size checks of the module docstring)."""
    if file_format == "npy":
        return read_npy(data, limits), None
    if file_format == "xyz":
        return read_xyz(data, limits), None
    if file_format == "ply":
        return read_ply(data, limits)
    if file_format == "off":
        return read_off(data, limits)
    if file_format == "obj":
        check_counts("obj", limits, lines_starting(data, b"v "), lines_starting(data, b"f "))
    elif file_format == "stl":
        check_stl(data, limits)
    elif file_format == "glb":
        check_glb(data, limits)
    elif file_format == "gltf":
        check_gltf_json(data, limits)
    return read_with_trimesh(data, file_format)


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
        write_shape(shape, path, file_format)
    except OSError as exc:
        raise InputError(f"cannot write {os.fspath(path)}: {exc.strerror or exc}") from exc


__all__ = [
    "MESH_FORMATS",
    "POINT_FORMATS",
    "SUPPORTED_FORMATS",
    "check_format_holds",
    "detect_format",
    "load_shape",
    "read_arrays",
    "save_shape",
    "self_contained_gltf",
]
