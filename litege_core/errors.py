"""The one exception hierarchy of LiteGE.

Every error raised on purpose by ``litege_core`` is a :class:`LiteGEError`. Errors of
third-party libraries (trimesh, potpourri3d, pygeodesic, torch, safetensors) are translated
into these classes where they are called, so callers (the CLI, the service) need exactly one
mapping table: each class carries a stable ``code`` slug used for RFC 9457 ``type`` URIs and
gRPC status mapping.

::

    LiteGEError
    ├── InputError                     bad data from the user (4xx)
    │   ├── ShapeFileError             unreadable, truncated or malformed file
    │   │   └── UnsupportedFormatError unknown or unsupported file extension/format
    │   ├── EmptyShapeError            no vertices / no faces where required
    │   ├── NonFiniteError             NaN or inf coordinates
    │   │   └── CoordinateRangeError   finite coordinates too large for float64 arithmetic
    │   ├── ArrayShapeError            wrong array rank, width or dtype
    │   ├── FaceIndexError             face indices outside [0, n_vertices)
    │   ├── NonTriangularFacesError    polygons that are not triangles
    │   ├── DegenerateShapeError       zero total area, all points coincident, ...
    │   ├── ShapeTooLargeError         more vertices/faces/bytes than the configured bound
    │   ├── IndexOutOfRangeError       query indices outside the shape
    │   └── MethodNotApplicableError   the chosen geodesic method cannot serve this shape
    │       └── MethodSizeLimitError   the shape exceeds the method's configured size bound
    ├── ArtifactError                  corrupt or inconsistent saved artifact (basis, bundle)
    ├── ComputationError               a numerical routine failed on valid input
    └── MissingDependencyError         an optional extra is not installed
"""

from __future__ import annotations


class LiteGEError(Exception):
    """Base class of every error LiteGE raises on purpose."""

    code: str = "litege-error"

    def __init__(self, message: str, **details: object) -> None:
        super().__init__(message)
        self.message = message
        self.details = details

    def __str__(self) -> str:
        return self.message


class InputError(LiteGEError, ValueError):
    """The caller's data is invalid; retrying with the same input will fail again."""

    code = "invalid-input"


class ShapeFileError(InputError):
    code = "malformed-file"


class UnsupportedFormatError(ShapeFileError):
    code = "unsupported-format"


class EmptyShapeError(InputError):
    code = "empty-shape"


class NonFiniteError(InputError):
    code = "non-finite-coordinates"


class CoordinateRangeError(NonFiniteError):
    code = "coordinate-out-of-range"


class ArrayShapeError(InputError):
    code = "bad-array-shape"


class FaceIndexError(InputError):
    code = "face-index-out-of-range"


class NonTriangularFacesError(InputError):
    code = "non-triangular-faces"


class DegenerateShapeError(InputError):
    code = "degenerate-shape"


class ShapeTooLargeError(InputError):
    code = "shape-too-large"


class IndexOutOfRangeError(InputError):
    code = "index-out-of-range"


class MethodNotApplicableError(InputError):
    """The requested geodesic method cannot answer for this shape (e.g. exact on a cloud)."""

    code = "method-not-applicable"


class MethodSizeLimitError(MethodNotApplicableError):
    """The shape is valid but larger than the configured bound of the requested method
    (e.g. exact geodesics above ``max_exact_vertices``); another method may serve it."""

    code = "method-size-limit"


class ArtifactError(LiteGEError):
    code = "artifact-error"


class ComputationError(LiteGEError):
    code = "computation-failed"


class MissingDependencyError(LiteGEError, ImportError):
    code = "missing-dependency"


__all__ = [
    "ArrayShapeError",
    "ArtifactError",
    "ComputationError",
    "CoordinateRangeError",
    "DegenerateShapeError",
    "EmptyShapeError",
    "FaceIndexError",
    "IndexOutOfRangeError",
    "InputError",
    "LiteGEError",
    "MethodNotApplicableError",
    "MethodSizeLimitError",
    "MissingDependencyError",
    "NonFiniteError",
    "NonTriangularFacesError",
    "ShapeFileError",
    "ShapeTooLargeError",
    "UnsupportedFormatError",
]
