"""Size checks shared by the readers: bytes, declared vertices and faces (before parsing)."""

from __future__ import annotations

from litege_core.errors import ShapeFileError, ShapeTooLargeError
from litege_core.validate import ShapeLimits

MAX_HEADER_BYTES = 1 << 20
"""Largest accepted PLY header and NPY header dictionary (bytes)."""


def check_size(n_bytes: int, limits: ShapeLimits, what: str = "file") -> None:
    """Refuse ``n_bytes`` (of ``what``) above ``limits.max_file_bytes``, and an empty file."""
    if n_bytes > limits.max_file_bytes:
        raise ShapeTooLargeError(
            f"{what} has {n_bytes} bytes, the limit is {limits.max_file_bytes}",
            n_bytes=n_bytes,
            limit=limits.max_file_bytes,
        )
    if n_bytes == 0:
        raise ShapeFileError("file is empty")


def check_counts(
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


__all__ = [
    "MAX_HEADER_BYTES",
    "check_counts",
    "check_size",
]
