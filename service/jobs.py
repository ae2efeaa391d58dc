"""The compute jobs :class:`~service.runtime.Runtime` hands its micro-batcher: one request's
work on one shape (or pair), in blocks small enough that other requests interleave."""

from __future__ import annotations

from dataclasses import dataclass

from litege_core.query import PointQuery
from service.answers import NO_REFINEMENT
from service.batcher import CancelToken


@dataclass(frozen=True)
class GeodesicJob:
    """Distances ``sources × targets`` on one shape. With ``max_pairs`` set, a job larger than
    that answers :class:`Split` instead of computing (the caller then sends row blocks)."""

    shape_id: str
    model: str | None
    sources: PointQuery
    targets: PointQuery
    token: CancelToken
    max_pairs: int | None = None


@dataclass(frozen=True)
class ClassicalGeodesicJob:
    """Distances ``sources × targets`` by a classical method. With ``max_rows`` set, a job of
    more sources than that or more pairs than ``max_pairs`` answers :class:`Split`."""

    shape_id: str
    method: str
    sources: PointQuery
    targets: PointQuery
    token: CancelToken
    max_rows: int | None = None
    max_pairs: int | None = None


@dataclass(frozen=True)
class Split:
    """The answer of a geodesic job too large for one compute job: its target count."""

    n_targets: int


@dataclass(frozen=True)
class PathJob:
    shape_id: str
    model: str | None
    source: PointQuery
    target: PointQuery


@dataclass(frozen=True)
class ClassicalPathJob:
    shape_id: str
    method: str
    source: PointQuery
    target: PointQuery
    token: CancelToken


@dataclass(frozen=True)
class PrepareJob:
    """Prepare both shapes of a correspondence; answers the source's point count."""

    source_id: str
    target_id: str
    model: str
    token: CancelToken


@dataclass(frozen=True)
class CorrespondJob:
    source_id: str
    target_id: str
    model: str
    queries: PointQuery
    token: CancelToken
    refine: str = NO_REFINEMENT
