"""Scene and soup formats, bounded before trimesh reads them: STL triangle counts, the GLB's
and the ``.gltf``'s JSON (nodes, node instances, instanced vertices and triangles), and a
``.gltf``'s buffer files embedded from beside it."""

from __future__ import annotations

import base64
import json
import os
import struct
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

from litege_core.errors import LiteGEError, ShapeFileError, ShapeTooLargeError
from litege_core.io.limits import check_counts, check_size
from litege_core.validate import DEFAULT_LIMITS, ShapeLimits


def check_stl(data: bytes, limits: ShapeLimits) -> None:
    """Triangle count of a binary STL (its header) or an ASCII one (``endfacet`` count)."""
    if len(data) >= 84:
        (declared,) = struct.unpack("<I", data[80:84])
        if 84 + 50 * declared == len(data):  # trimesh's test for binary STL
            check_counts("stl", limits, n_faces=declared)
            return
    check_counts("stl", limits, n_faces=data.count(b"endfacet"), what="has")


def check_glb(data: bytes, limits: ShapeLimits) -> None:
    """Nodes, node instances, instanced vertices and triangles of a GLB, from its JSON chunk,
    before trimesh builds the scene."""
    if len(data) < 20 or data[:4] != b"glTF":
        return  # not a GLB: trimesh reports it
    length, kind = struct.unpack("<II", data[12:20])
    if kind != 0x4E4F534A or 20 + length > len(data):
        raise ShapeFileError("cannot parse GLB file: no JSON chunk")
    try:
        document = json.loads(data[20 : 20 + length])
    except ValueError as exc:
        raise ShapeFileError(f"cannot parse GLB file: {exc}") from exc
    _check_gltf(document, limits, "glb")


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


def check_gltf_json(data: bytes, limits: ShapeLimits) -> None:
    """Sizes of a ``.gltf`` (as :func:`check_glb`), and every buffer embedded in it.

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
    _check_gltf(document, limits, "gltf")


def self_contained_gltf(path: str | os.PathLike, limits: ShapeLimits = DEFAULT_LIMITS) -> bytes:
    """The ``.gltf`` file at ``path`` with its buffer files embedded (how
    :func:`~litege_core.io.load_shape` reads it; also what identifies its content).

    Raises:
        ShapeFileError, ShapeTooLargeError: as :func:`embed_gltf_buffers`.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ShapeFileError(f"cannot read {path}: {exc.strerror}") from exc
    return embed_gltf_buffers(data, path.parent, limits)


def embed_gltf_buffers(data: bytes, folder: Path, limits: ShapeLimits = DEFAULT_LIMITS) -> bytes:
    """A ``.gltf`` file's bytes with the buffers it keeps in files of ``folder`` embedded as
    ``data:`` URIs (the bytes themselves where it keeps none there), its scene sizes checked
    as :func:`check_gltf_json` checks them (the one parse of its JSON before trimesh's).

    A buffer's URI must be relative and name a file inside ``folder`` (no ``..`` out of it, no
    scheme); the file and its buffers together must fit ``limits.max_file_bytes``.

    Raises:
        ShapeFileError: unparsable JSON, a URI outside ``folder``, an unreadable buffer file.
        ShapeTooLargeError: more nodes, vertices or faces than ``limits`` allow, or the file
            and its buffers exceed ``limits.max_file_bytes``.
    """
    document = _gltf_document(data)
    external = _external_buffers(document)
    _check_gltf(document, limits, "gltf")
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
            check_size(total, limits, "the glTF file with its buffers so far")
            raw = target.read_bytes()
        except OSError as exc:
            raise ShapeFileError(
                f"cannot read glTF buffer {index} ({uri!r}): {exc.strerror}"
            ) from exc
        encoded = base64.b64encode(raw).decode("ascii")
        document["buffers"][index]["uri"] = f"data:application/octet-stream;base64,{encoded}"
    return json.dumps(document).encode()


def _check_gltf(document: Any, limits: ShapeLimits, file_format: str) -> None:
    """Nodes, node instances, instanced vertices and triangles of a glTF document (the JSON of
    a ``.gltf`` or of a GLB's first chunk) against ``limits``.

    Raises:
        ShapeTooLargeError: more than ``limits`` allow.
        ShapeFileError: a document whose structure is not glTF's (a list where an object
            belongs, a missing accessor, ...).
    """
    try:
        _check_scene_sizes(document, limits, file_format)
    except LiteGEError:
        raise
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        name = "GLB" if file_format == "glb" else "glTF"
        raise ShapeFileError(f"cannot parse {name} file: {exc}") from exc


def _check_scene_sizes(document: dict[str, Any], limits: ShapeLimits, file_format: str) -> None:
    """:func:`_check_gltf` without the translation of structural errors."""
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
    check_counts(file_format, limits, defined_vertices, sum(f for _, f in mesh_sizes), "defines")
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
    check_counts(file_format, limits, n_vertices, n_faces)


__all__ = [
    "check_glb",
    "check_gltf_json",
    "check_stl",
    "embed_gltf_buffers",
    "self_contained_gltf",
]
