"""The immutable :class:`Shape`: a validated mesh or point cloud with a content hash."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.arrays import frozen
from litege_core.enums import ParsableEnum
from litege_core.errors import ArrayShapeError, EmptyShapeError
from litege_core.validate import DEFAULT_LIMITS, ShapeLimits, triangle_areas, validate_arrays

HASH_VERSION = b"litege-shape-v1"


class ShapeKind(ParsableEnum, noun="shape kind", error=ArrayShapeError):
    """What the vertices are: a triangle mesh or a bare point cloud."""

    MESH = "mesh"
    POINT_CLOUD = "point_cloud"


@dataclass(frozen=True, eq=False)
class Shape:
    """A validated mesh or point cloud in the user's frame and vertex order.

    Attributes:
        vertices: ``(N, 3)`` float64, read-only, in the user's units.
        faces: ``(F, 3)`` int64 triangle indices (read-only) for meshes, ``None`` for clouds.
        kind: :class:`ShapeKind`.

    Build with :meth:`from_arrays` (validates) or :func:`litege_core.io.load_shape`.
    Two shapes are equal when their content hashes are equal.
    """

    vertices: NDArray
    faces: NDArray | None
    kind: ShapeKind

    @classmethod
    def from_arrays(
        cls,
        vertices: ArrayLike,
        faces: ArrayLike | None = None,
        kind: str | ShapeKind | None = None,
        limits: ShapeLimits = DEFAULT_LIMITS,
    ) -> Shape:
        """Validate arrays and build a shape.

        ``kind`` defaults to mesh when faces are given, point cloud otherwise. Asking for a
        point cloud while passing faces drops the faces; asking for a mesh without faces
        raises :class:`EmptyShapeError`.
        """
        resolved = ShapeKind.parse(kind) if kind is not None else None
        if resolved is None:
            resolved = ShapeKind.POINT_CLOUD if faces is None else ShapeKind.MESH
        if resolved is ShapeKind.POINT_CLOUD:
            faces = None
        elif faces is None:
            raise EmptyShapeError("a mesh needs faces; pass kind='point_cloud' for a point set")
        checked_vertices, checked_faces = validate_arrays(vertices, faces, limits)
        return cls(
            vertices=frozen(checked_vertices),
            faces=None if checked_faces is None else frozen(checked_faces),
            kind=resolved,
        )

    @property
    def n_points(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return 0 if self.faces is None else int(self.faces.shape[0])

    @property
    def is_mesh(self) -> bool:
        return self.kind is ShapeKind.MESH

    @cached_property
    def content_hash(self) -> str:
        """Hex SHA-256 over version tag, kind, array shapes, vertices as little-endian
        float64 and faces as little-endian int64. Independent of the file format."""
        digest = hashlib.sha256(HASH_VERSION)
        digest.update(self.kind.value.encode())
        digest.update(np.asarray(self.vertices.shape, dtype="<i8").tobytes())
        digest.update(self.vertices.astype("<f8", copy=False).tobytes())
        if self.faces is not None:
            digest.update(np.asarray(self.faces.shape, dtype="<i8").tobytes())
            digest.update(self.faces.astype("<i8", copy=False).tobytes())
        return digest.hexdigest()

    @cached_property
    def face_areas(self) -> NDArray:
        """``(F,)`` triangle areas in squared input units (read-only); meshes only."""
        if self.faces is None:
            raise ArrayShapeError("a point cloud has no faces")
        return frozen(triangle_areas(self.vertices, self.faces))

    @cached_property
    def area(self) -> float:
        """Total surface area of a mesh, in squared input units."""
        return float(self.face_areas.sum())

    def with_vertices(self, vertices: ArrayLike) -> Shape:
        """Same faces and kind with new vertex positions (e.g. canonicalized), validated."""
        return Shape.from_arrays(vertices, self.faces, self.kind)

    def as_point_cloud(self) -> Shape:
        """The vertices alone, as a point cloud."""
        return Shape.from_arrays(self.vertices, None, ShapeKind.POINT_CLOUD)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Shape) and other.content_hash == self.content_hash

    def __hash__(self) -> int:
        return hash(self.content_hash)


__all__ = [
    "HASH_VERSION",
    "Shape",
    "ShapeKind",
]
