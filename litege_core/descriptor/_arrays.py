"""Boundary checks shared by the descriptor modules (raise :mod:`litege_core.errors` only)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import ArrayShapeError, EmptyShapeError, InputError, NonFiniteError


def as_numeric(array: ArrayLike, name: str) -> NDArray:
    """``array`` as a numeric (integer, float or bool) ndarray, or raise ArrayShapeError."""
    try:
        out = np.asarray(array)
    except (ValueError, TypeError) as exc:
        raise ArrayShapeError(f"{name} is not a rectangular array: {exc}") from exc
    if out.dtype == object or not (
        np.issubdtype(out.dtype, np.number) or np.issubdtype(out.dtype, np.bool_)
    ):
        raise ArrayShapeError(f"{name} must be numeric, got dtype {out.dtype}")
    if np.issubdtype(out.dtype, np.complexfloating):
        raise ArrayShapeError(f"{name} must be real, got dtype {out.dtype}")
    return out


def as_points(points: ArrayLike, name: str = "points", dtype: type = np.float64) -> NDArray:
    """Validate a ``(P, 3)`` finite, non-empty point array; return it C-contiguous in ``dtype``.

    Raises:
        ArrayShapeError: not numeric or not ``(P, 3)``.
        EmptyShapeError: ``P == 0``.
        NonFiniteError: a NaN or infinite coordinate.
    """
    out = as_numeric(points, name)
    if out.ndim != 2 or out.shape[1] != 3:
        raise ArrayShapeError(f"{name} must have shape (P, 3), got {out.shape}")
    if out.shape[0] == 0:
        raise EmptyShapeError(f"{name} is empty")
    out = np.ascontiguousarray(out, dtype=dtype)
    if not np.isfinite(out).all():
        raise NonFiniteError(f"{name} contains NaN or infinite coordinates")
    return out


def as_clouds(clouds: ArrayLike, name: str = "clouds", dtype: type = np.float32) -> NDArray:
    """Validate a ``(B, P, 3)`` finite batch of point clouds with ``B, P >= 1``."""
    out = as_numeric(clouds, name)
    if out.ndim != 3 or out.shape[2] != 3:
        raise ArrayShapeError(f"{name} must have shape (B, P, 3), got {out.shape}")
    if out.shape[0] == 0 or out.shape[1] == 0:
        raise EmptyShapeError(f"{name} has shape {out.shape}: no clouds or no points")
    out = np.ascontiguousarray(out, dtype=dtype)
    if not np.isfinite(out).all():
        raise NonFiniteError(f"{name} contains NaN or infinite coordinates")
    return out


def as_faces(faces: ArrayLike, n_vertices: int) -> NDArray:
    """Validate ``(F, 3)`` integer triangle indices in ``[0, n_vertices)``; return int64."""
    from litege_core.validate import validate_faces

    return validate_faces(faces, n_vertices)


def positive_int(value: object, name: str) -> int:
    """``value`` as a positive Python int, or raise InputError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < 1:
        raise InputError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def positive_float(value: object, name: str) -> float:
    """``value`` as a finite positive float, or raise InputError."""
    try:
        out = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a number, got {value!r}") from exc
    if not np.isfinite(out) or out <= 0.0:
        raise InputError(f"{name} must be finite and positive, got {value!r}")
    return out
