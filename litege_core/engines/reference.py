"""Slow, simple references that bound the exact geodesic from both sides.

For every pair of vertices of a mesh::

    euclidean <= exact geodesic <= edge-graph Dijkstra

The upper bound holds because a path along mesh edges is a path on the surface; the lower
bound because no surface path is shorter than the straight chord. The test-suite checks the
fast engines against these bounds.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.spatial.distance import cdist

from litege_core.engines.base import GeodesicEngine, MeshGeodesicEngine
from litege_core.engines.graph import dijkstra_rows, edge_graph
from litege_core.shape import Shape


class EdgeDijkstraEngine(MeshGeodesicEngine):
    """Dijkstra along the mesh edges (upper bound of the exact geodesic).

    Edges come from the cleaned faces (faces with a repeated corner and duplicates dropped,
    like the exact engine); unreferenced vertices and other components get ``+inf``.
    """

    method: ClassVar[str] = "edge_dijkstra"

    def __init__(self, shape: Shape) -> None:
        super().__init__(shape)
        self._graph: sp.csr_array | None = None

    @property
    def graph(self) -> sp.csr_array:
        """``(N, N)`` upper-triangular CSR of edge lengths (built on first use)."""
        if self._graph is None:
            edges = self.topology.edges
            vertices = self._shape.vertices
            lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
            self._graph = edge_graph(self.n_points, edges, lengths)
        return self._graph

    def prepare(self) -> EdgeDijkstraEngine:
        """Build the edge graph now."""
        _ = self.graph
        return self

    def _rows(self, sources: NDArray) -> NDArray:
        return dijkstra_rows(self.graph, sources)


class EuclideanEngine(GeodesicEngine):
    """Straight-line distances (lower bound of every surface geodesic); any shape."""

    method: ClassVar[str] = "euclidean"

    def _rows(self, sources: NDArray) -> NDArray:
        vertices = self._shape.vertices
        return cdist(vertices[sources], vertices)


__all__ = [
    "EdgeDijkstraEngine",
    "EuclideanEngine",
]
