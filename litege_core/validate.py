"""Validation of raw vertex/face arrays at the library boundary.

Every constructor of :class:`~litege_core.shape.Shape` calls :func:`validate_arrays` first,
so the rest of the core can assume finite float64 ``(N, 3)`` vertices and in-range int64
``(F, 3)`` triangles. Each failure raises a precise :mod:`litege_core.errors` class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import (
    ArrayShapeError,
    CoordinateRangeError,
    DegenerateShapeError,
    EmptyShapeError,
    FaceIndexError,
    NonFiniteError,
    NonTriangularFacesError,
    ShapeTooLargeError,
)

MAX_ABS_COORDINATE = 1e12
"""Largest accepted ``|coordinate|``: squares and covariances of larger values overflow or
lose all precision in float64 (e.g. 1e200 gives an infinite PCA covariance)."""

MIN_EXTENT = 1e-9
"""Smallest accepted bounding-box extent (largest side), in the input units."""


@dataclass(frozen=True)
class ShapeLimits:
    """Upper bounds on accepted input (the service sets them from its settings)."""

    max_vertices: int = 250_000
    max_faces: int = 500_000
    max_file_bytes: int = 64 * 1024 * 1024
    max_scene_nodes: int = 10_000
    """Nodes of a scene file (GLB), and node instances once its scene graph is expanded."""


DEFAULT_LIMITS = ShapeLimits()


def validate_vertices(vertices: ArrayLike, limits: ShapeLimits = DEFAULT_LIMITS) -> NDArray:
    """Return ``vertices`` as a C-contiguous float64 ``(N, 3)`` array or raise.

    Raises:
        ArrayShapeError: not numeric, or not of shape ``(N, 3)``.
        EmptyShapeError: ``N == 0``.
        ShapeTooLargeError: ``N > limits.max_vertices``.
        NonFiniteError: any NaN or infinite coordinate.
        CoordinateRangeError: a coordinate beyond ``±MAX_ABS_COORDINATE``.
    """
    try:
        array = np.asarray(vertices)
    except (ValueError, TypeError) as exc:  # ragged nested lists
        raise ArrayShapeError(f"vertices are not a rectangular array: {exc}") from exc
    if array.dtype == object or not (
        np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)
    ):
        raise ArrayShapeError(f"vertices must be numeric, got dtype {array.dtype}")
    if array.size == 0:
        raise EmptyShapeError("shape has no vertices")
    if array.ndim != 2 or array.shape[1] != 3:
        raise ArrayShapeError(f"vertices must have shape (N, 3), got {array.shape}")
    if array.shape[0] > limits.max_vertices:
        raise ShapeTooLargeError(
            f"shape has {array.shape[0]} vertices, the limit is {limits.max_vertices}",
            n_vertices=int(array.shape[0]),
            limit=limits.max_vertices,
        )
    array = np.ascontiguousarray(array, dtype=np.float64)
    finite = np.isfinite(array).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise NonFiniteError(
            f"{bad.size} vertices have NaN or infinite coordinates (first: {int(bad[0])})",
            first_index=int(bad[0]),
            count=int(bad.size),
        )
    largest = float(np.abs(array).max())
    if largest > MAX_ABS_COORDINATE:
        raise CoordinateRangeError(
            f"coordinates up to {largest:.3g} in magnitude; the limit is {MAX_ABS_COORDINATE:g} "
            "(rescale the shape)"
        )
    return array


def validate_faces(
    faces: ArrayLike, n_vertices: int, limits: ShapeLimits = DEFAULT_LIMITS
) -> NDArray:
    """Return ``faces`` as a C-contiguous int64 ``(F, 3)`` array or raise.

    Raises:
        EmptyShapeError: no faces.
        NonTriangularFacesError: polygons with other than 3 corners.
        ArrayShapeError: not an integer array of rank 2.
        ShapeTooLargeError: ``F > limits.max_faces``.
        FaceIndexError: an index outside ``[0, n_vertices)``.
    """
    try:
        array = np.asarray(faces)
    except (ValueError, TypeError) as exc:
        raise NonTriangularFacesError(f"faces are ragged (mixed polygon sizes): {exc}") from exc
    if array.dtype == object:
        if array.ndim == 2 and array.shape[1] == 3:  # rectangular: Python ints beyond int64
            raise FaceIndexError("face indices must be integers within the int64 range")
        raise NonTriangularFacesError("faces are ragged (mixed polygon sizes)")
    if array.size == 0:
        raise EmptyShapeError("mesh has no faces")
    if array.ndim != 2:
        raise ArrayShapeError(f"faces must have shape (F, 3), got {array.shape}")
    if array.shape[1] != 3:
        raise NonTriangularFacesError(
            f"faces must be triangles, got polygons with {array.shape[1]} corners"
        )
    if np.issubdtype(array.dtype, np.floating):
        if not np.isfinite(array).all() or not np.all(array == np.round(array)):
            raise ArrayShapeError("face indices must be integers")
    elif not np.issubdtype(array.dtype, np.integer):
        raise ArrayShapeError(f"face indices must be integers, got dtype {array.dtype}")
    if array.shape[0] > limits.max_faces:
        raise ShapeTooLargeError(
            f"mesh has {array.shape[0]} faces, the limit is {limits.max_faces}",
            n_faces=int(array.shape[0]),
            limit=limits.max_faces,
        )
    array = np.ascontiguousarray(array, dtype=np.int64)
    low, high = int(array.min()), int(array.max())
    if low < 0 or high >= n_vertices:
        bad = low if low < 0 else high
        raise FaceIndexError(
            f"face index {bad} is outside [0, {n_vertices}) for a mesh with {n_vertices} vertices",
            index=bad,
            n_vertices=n_vertices,
        )
    return array


def triangle_areas(vertices: NDArray, faces: NDArray) -> NDArray:
    """Areas of the triangles, ``(F,)`` in squared input units."""
    corners = vertices[faces]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return 0.5 * np.linalg.norm(cross, axis=1)


def validate_arrays(
    vertices: ArrayLike,
    faces: ArrayLike | None,
    limits: ShapeLimits = DEFAULT_LIMITS,
) -> tuple[NDArray, NDArray | None]:
    """Validate a mesh (``faces`` given) or a point cloud (``faces is None``).

    Returns ``(vertices float64 (N, 3), faces int64 (F, 3) or None)``.

    Raises:
        DegenerateShapeError: a mesh with zero total area, a point cloud whose points
            all coincide, or a bounding box smaller than ``MIN_EXTENT``.
        (and everything :func:`validate_vertices` / :func:`validate_faces` raise)
    """
    checked_vertices = validate_vertices(vertices, limits)
    extent = float(np.ptp(checked_vertices, axis=0).max())
    if faces is None and not extent > 0.0:
        raise DegenerateShapeError("all points of the point cloud coincide")
    if not extent >= MIN_EXTENT:
        raise DegenerateShapeError(
            f"the shape's largest extent is {extent:.3g}, below {MIN_EXTENT:g}: rescale it"
        )
    if faces is None:
        return checked_vertices, None
    checked_faces = validate_faces(faces, checked_vertices.shape[0], limits)
    total_area = float(triangle_areas(checked_vertices, checked_faces).sum())
    if not total_area > 0.0:
        raise DegenerateShapeError("mesh has zero total surface area")
    return checked_vertices, checked_faces


__all__ = [
    "DEFAULT_LIMITS",
    "MAX_ABS_COORDINATE",
    "MIN_EXTENT",
    "ShapeLimits",
    "triangle_areas",
    "validate_arrays",
    "validate_faces",
    "validate_vertices",
]
