"""The one query type: which points of a shape a request is about.

Every caller (the learned predictor, path tracing, matching, the reference engines, REST,
gRPC and the CLI) turns what it received into a :class:`PointQuery` with :func:`parse_query`
and nothing else, so one rule decides everywhere:

* ``None`` or ``"all"``: every vertex / point of the shape (where the caller allows it);
* a 0-D or 1-D array of **integers**: vertex / point indices (``1.0`` is refused: an index is
  an integer, not a float that happens to be whole);
* a 2-D ``(Q, 3)`` array of numbers: xyz points in the shape's own frame and units, finite and
  of magnitude at most :data:`MAX_ABS_COORDINATE`; a ``(3,)`` array of floats is one xyz point
  (it cannot be indices, which are integers).

Indices are checked against the shape with :meth:`PointQuery.check` once the shape is known.
xyz points are put on the surface by the one snapping rule,
:func:`litege_core.projection.snap` (after mapping them to whatever frame the caller works in): on
a mesh, the exact closest point on its triangles (a new surface point); on a point cloud, its
nearest point (an index).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import (
    ArrayShapeError,
    CoordinateRangeError,
    IndexOutOfRangeError,
    InputError,
    NonFiniteError,
)

QueryLike = Any
"""What :func:`parse_query` takes: ``None`` / ``"all"``, ``(Q,)`` indices, ``(Q, 3)`` xyz
points (array-likes or torch tensors), or a :class:`PointQuery`."""

MAX_ABS_COORDINATE = 1e12
"""Largest accepted absolute xyz coordinate: beyond it a point is a unit error, not a place on
a shape (and squared distances of float64 coordinates near 1e154 overflow)."""


@dataclass(frozen=True)
class PointQuery:
    """Points of one shape: all of them, some indices, or xyz points.

    Attributes:
        indices: ``(Q,)`` int64 indices, or ``None``.
        points: ``(Q, 3)`` float64 finite xyz points in the shape's frame, or ``None``.
        Both ``None`` means every vertex / point.
    """

    indices: NDArray | None = None
    points: NDArray | None = None

    @property
    def is_all(self) -> bool:
        return self.indices is None and self.points is None

    @property
    def is_points(self) -> bool:
        return self.points is not None

    def count(self, n_points: int) -> int:
        """Number of query points on a shape of ``n_points`` points."""
        if self.indices is not None:
            return int(self.indices.shape[0])
        if self.points is not None:
            return int(self.points.shape[0])
        return int(n_points)

    def check(self, n_points: int, what: str = "query") -> PointQuery:
        """This query, its indices checked to lie in ``[0, n_points)``.

        Raises:
            IndexOutOfRangeError: an index outside ``[0, n_points)`` (negative indices are not
                wrapped).
        """
        if self.indices is not None:
            check_index_range(self.indices, n_points, what)
        return self


ALL = PointQuery()
"""Every vertex / point of the shape."""


def parse_query(
    value: Any, what: str = "query", *, allow_all: bool = True, single: bool = False
) -> PointQuery:
    """Parse ``value`` into a :class:`PointQuery` (see the module docstring for the rule).

    Args:
        value: ``None`` / ``"all"``, indices, xyz points, or a :class:`PointQuery`.
        what: the word used in error messages (``"sources"``, ``"targets"``, ...).
        allow_all: whether ``None`` / ``"all"`` is accepted.
        single: the caller wants one point: one index, or one ``(3,)`` xyz point.

    Raises:
        InputError: ``"all"`` where it is not allowed.
        ArrayShapeError: not numbers, non-integer indices, wrong shape, or empty.
        NonFiniteError: NaN or infinite xyz (:class:`CoordinateRangeError`: larger than
            :data:`MAX_ABS_COORDINATE`).
    """
    if isinstance(value, PointQuery):
        query = value
    elif value is None or (isinstance(value, str) and value == "all"):
        query = ALL
    elif isinstance(value, str | bytes):
        raise ArrayShapeError(f"{what} must be indices, xyz points or 'all', got {value!r}")
    else:
        query = _parse_array(_as_array(value, what), what)
    if query.is_all and not allow_all:
        raise InputError(f"{what} must be indices or xyz points; 'all' is not allowed here")
    if single and query.count(0 if query.is_all else 1) != 1:
        raise ArrayShapeError(f"{what} must be one index or one [x, y, z] point")
    return query


def _as_array(value: Any, what: str) -> NDArray:
    if hasattr(value, "detach") and hasattr(value, "cpu"):  # a torch tensor
        value = value.detach().cpu().numpy()
    try:
        array = np.asarray(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ArrayShapeError(f"{what} is not a regular array of numbers: {exc}") from exc
    if array.dtype == object or array.dtype == bool or array.dtype.kind not in "iuf":
        raise ArrayShapeError(f"{what} must be numbers (indices or xyz points)")
    if array.size == 0:
        raise ArrayShapeError(f"{what} is empty; pass at least one index or point")
    return array


def _parse_array(array: NDArray, what: str) -> PointQuery:
    if array.shape == (3,) and array.dtype.kind == "f":
        return PointQuery(points=check_points(array[None], what))
    if array.ndim == 2:
        if array.shape[1] != 3:
            raise ArrayShapeError(f"{what} points must have shape (Q, 3), got {array.shape}")
        return PointQuery(points=check_points(array, what))
    if array.ndim > 2:
        raise ArrayShapeError(
            f"{what} must be (Q,) indices or (Q, 3) xyz points, got shape {array.shape}"
        )
    if array.dtype.kind not in "iu":
        raise ArrayShapeError(f"{what} indices must be integers, got dtype {array.dtype}")
    return PointQuery(indices=array.reshape(-1).astype(np.int64))


def check_points(points: ArrayLike, what: str = "points") -> NDArray:
    """``(Q, 3)`` finite float64 xyz points of sane magnitude (a read-only copy).

    Raises:
        ArrayShapeError: not numeric or not ``(Q, 3)`` with ``Q ≥ 1``.
        NonFiniteError: NaN or infinite (:class:`CoordinateRangeError`: larger than
            :data:`MAX_ABS_COORDINATE`).
    """
    try:
        array = np.array(points, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ArrayShapeError(f"{what} must be a numeric (Q, 3) array: {exc}") from exc
    if array.ndim != 2 or array.shape[1] != 3 or array.shape[0] == 0:
        raise ArrayShapeError(f"{what} must have shape (Q, 3) with Q ≥ 1, got {array.shape}")
    if not np.isfinite(array).all():
        raise NonFiniteError(f"{what} have NaN or infinite coordinates")
    if np.abs(array).max() > MAX_ABS_COORDINATE:
        raise CoordinateRangeError(
            f"{what} have a coordinate beyond ±{MAX_ABS_COORDINATE:g}; points must lie near "
            "the shape, in its own units"
        )
    array.flags.writeable = False
    return array


def check_index_range(indices: NDArray, n_points: int, what: str = "query") -> NDArray:
    """Raise :class:`IndexOutOfRangeError` unless every index lies in ``[0, n_points)``."""
    bad = np.flatnonzero((indices < 0) | (indices >= n_points))
    if bad.size:
        value = int(indices[bad[0]])
        raise IndexOutOfRangeError(
            f"{what} index {value} is outside [0, {n_points}) ({bad.size} out of range)",
            index=value,
            n_points=n_points,
            count=int(bad.size),
        )
    return indices


def parse_indices(value: Any, n_points: int, what: str = "source") -> NDArray:
    """Indices only (no xyz, no ``"all"``): ``(Q,)`` int64, checked against ``n_points``."""
    query = parse_query(value, what, allow_all=False)
    if query.indices is None:
        raise ArrayShapeError(f"{what} must be vertex/point indices here, not xyz points")
    return check_index_range(query.indices, n_points, what)


__all__ = [
    "ALL",
    "MAX_ABS_COORDINATE",
    "PointQuery",
    "QueryLike",
    "check_index_range",
    "check_points",
    "parse_indices",
    "parse_query",
]
