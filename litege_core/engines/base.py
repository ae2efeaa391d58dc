"""The common interface of the geodesic engines: :class:`GeodesicEngine` and its result.

An engine is built from a :class:`~litege_core.shape.Shape`, precomputes what every query
needs, builds expensive parts (factorisations, solver objects) lazily on the first query or on
:meth:`GeodesicEngine.prepare`, and answers :meth:`GeodesicEngine.distances` for any batch of
source indices. Distances are in the shape's units; a vertex or point that a source cannot
reach gets ``+inf``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import ClassVar, Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.arrays import frozen
from litege_core.engines._topology import MeshTopology
from litege_core.errors import (
    ArrayShapeError,
    ComputationError,
    InputError,
)
from litege_core.query import parse_indices
from litege_core.shape import Shape

ParamValue = bool | int | float | str


@dataclass(frozen=True, eq=False)
class GeodesicResult:
    """Distances from a batch of sources to every vertex (or point) of a shape.

    Attributes:
        distances: ``(S, N)`` float64, read-only; row ``i`` holds the distances from
            ``sources[i]`` to all ``N`` vertices, in the shape's units. ``+inf`` where the
            source cannot reach the vertex; ``0`` on the source itself.
        sources: ``(S,)`` int64, read-only; the query indices in the given order (repeats kept).
        method: engine name (``"exact"``, ``"heat"``, ``"pointcloud_heat"``, ``"knn_graph"``,
            ``"edge_dijkstra"``, ``"euclidean"``).
        params: the engine parameters used (e.g. ``{"backend": "pygeodesic"}``,
            ``{"t_coef": 1.0, "use_robust": True}``, ``{"k": 8}``), read-only.
    """

    distances: NDArray
    sources: NDArray
    method: str
    params: Mapping[str, ParamValue] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "distances", frozen(self.distances))
        object.__setattr__(self, "sources", frozen(self.sources))
        object.__setattr__(self, "params", MappingProxyType(dict(self.params)))

    def __repr__(self) -> str:
        return (
            f"GeodesicResult(method={self.method!r}, params={dict(self.params)!r}, "
            f"distances=<{self.distances.shape[0]}x{self.distances.shape[1]} float64>)"
        )


class GeodesicEngine(ABC):
    """A geodesic distance solver bound to one shape.

    Subclasses set :attr:`method` and :attr:`mesh_only`, validate their options in
    ``__init__``, build expensive state lazily in :meth:`prepare` and implement
    :meth:`_rows`. Construct through :func:`litege_core.engines.make_engine` or directly.
    """

    method: ClassVar[str]
    mesh_only: ClassVar[bool] = False

    def __init__(self, shape: Shape) -> None:
        if not isinstance(shape, Shape):
            raise InputError(f"a geodesic engine needs a litege Shape, got {type(shape).__name__}")
        if self.mesh_only and not shape.is_mesh:
            raise InputError(
                f"the {self.method!r} geodesic engine needs a triangle mesh, got a point cloud; "
                "use method='pointcloud_heat' or method='knn_graph' for point clouds"
            )
        self._shape = shape

    @property
    def shape(self) -> Shape:
        """The shape the engine answers for."""
        return self._shape

    @property
    def n_points(self) -> int:
        """Number of vertices/points ``N`` (the width of every distance row)."""
        return self._shape.n_points

    @property
    def params(self) -> Mapping[str, ParamValue]:
        """Parameters that change the result (reported in :class:`GeodesicResult`)."""
        return {}

    def prepare(self) -> Self:
        """Build the expensive, source-independent state now instead of on the first query."""
        return self

    def distances(self, sources: ArrayLike) -> GeodesicResult:
        """Distances from each source to all vertices/points.

        Args:
            sources: ``(S,)`` int vertex/point indices (or one int); repeats allowed.

        Returns:
            :class:`GeodesicResult` with ``distances (S, N)`` float64.

        Raises:
            InputError: no source; ArrayShapeError: non-integer indices;
            IndexOutOfRangeError: an index outside ``[0, N)``;
            ComputationError: the underlying solver failed or returned NaN.
        """
        indices = parse_indices(sources, self.n_points)
        unique, inverse = np.unique(indices, return_inverse=True)
        rows = np.asarray(self._solved_rows(unique), dtype=np.float64)
        if rows.shape != (unique.size, self.n_points):
            raise ComputationError(
                f"{self.method} solver returned shape {rows.shape}, "
                f"expected {(unique.size, self.n_points)}"
            )
        if np.isnan(rows).any():
            raise ComputationError(f"{self.method} solver returned NaN distances")
        return GeodesicResult(rows[inverse], indices, self.method, self.params)

    def distance(self, source: int) -> NDArray:
        """Distances ``(N,)`` float64 from one source (read-only); see :meth:`distances`."""
        array = np.asarray(source)
        if array.ndim != 0:
            raise ArrayShapeError("distance() takes one index; use distances() for a batch")
        return self.distances(array.reshape(1)).distances[0]

    @abstractmethod
    def _rows(self, sources: NDArray) -> NDArray:
        """``(S, N)`` distances for validated, unique, sorted ``(S,)`` int64 sources."""

    def _solved_rows(self, sources: NDArray) -> NDArray:
        """:meth:`_rows` as :meth:`distances` reads them (a mesh engine welds seams first)."""
        return self._rows(sources)

    def __repr__(self) -> str:
        params = ", ".join(f"{k}={v!r}" for k, v in self.params.items())
        return f"{type(self).__name__}(n_points={self.n_points}{', ' if params else ''}{params})"


class MeshGeodesicEngine(GeodesicEngine):
    """Base of the engines that need triangles; shares the cleaned :class:`MeshTopology`."""

    mesh_only: ClassVar[bool] = True

    def __init__(self, shape: Shape) -> None:
        super().__init__(shape)
        self._topology: MeshTopology | None = None

    @property
    def topology(self) -> MeshTopology:
        """The cleaned mesh (built on first use)."""
        if self._topology is None:
            assert self._shape.faces is not None  # mesh_only
            self._topology = MeshTopology.from_arrays(self._shape.vertices, self._shape.faces)
        return self._topology

    def _solved_rows(self, sources: NDArray) -> NDArray:
        """:meth:`_rows` on the mesh with its seams welded (:func:`~litege_core.seams.
        seam_welds`): a seam copy is solved as its first copy, and each copy's column is its
        first copy's (a triangle soup gets the welded mesh's distances)."""
        topology = self.topology
        if topology.welded.size == 0:
            return self._rows(sources)
        solved, back = np.unique(topology.welds[sources], return_inverse=True)
        rows = np.asarray(self._rows(solved), dtype=np.float64)[back.reshape(-1)]
        rows[:, topology.welded] = rows[:, topology.welded_to]
        return rows


def wrap_foreign(method: str, exc: Exception) -> ComputationError:
    """Translate an error of a third-party solver into :class:`ComputationError`."""
    return ComputationError(
        f"{method} geodesic solver failed: {type(exc).__name__}: {exc}",
        method=method,
        cause=type(exc).__name__,
    )


__all__ = [
    "GeodesicEngine",
    "GeodesicResult",
    "MeshGeodesicEngine",
    "ParamValue",
]
