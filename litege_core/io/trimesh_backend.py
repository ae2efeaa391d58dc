"""Reading and writing through trimesh (its processing off: vertex order kept), with its
parse errors mapped onto LiteGE's."""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import FaceIndexError, LiteGEError, ShapeFileError
from litege_core.shape import Shape


def read_with_trimesh(data: bytes, file_format: str) -> tuple[NDArray, NDArray | None]:
    """Raw ``(vertices, faces or None)`` of a file trimesh reads (a scene's meshes
    concatenated in its order; an STL's repeated corners merged).

    Raises:
        FaceIndexError, ShapeFileError: what trimesh could not parse.
    """
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


def write_shape(shape: Shape, path: str | os.PathLike, file_format: str) -> None:
    """Write ``shape`` as ``file_format`` (NPY and XYZ by numpy, glTF as one self-contained
    file, the others by trimesh's exporters), keeping its vertex order."""
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


__all__ = [
    "read_with_trimesh",
    "write_shape",
]
