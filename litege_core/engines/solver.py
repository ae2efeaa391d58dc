"""The classical methods behind the service's ``method`` switch: ``heat``, ``exact``, ``graph``.

::

    solver = ClassicalSolver(shape, "exact")          # cheap; engines are built on first use
    d = solver.distances([0, 17])                     # (2, N) float32, the shape's units
    d = solver.distances([[0.1, 0.2, 0.9]], [5, 6])   # xyz sources, snapped onto the surface
    p = solver.path(0, 4242)                          # ClassicalPath, (L, 3) source → target
    solver.engine                                     # "exact-mmp": what ran

It answers the same questions as :class:`litege_core.learned.Predictor` (``distances(sources,
targets)`` → ``(S, T)`` float32 in the user's units; ``path(source, target)``), with one of
the reference engines of :mod:`litege_core.engines`:

==========  ==========================================  ======================================
method      mesh                                        point cloud
==========  ==========================================  ======================================
``heat``    ``"heat"``: robust intrinsic heat method    ``"pointcloud-heat"``: point-cloud
            (intrinsic Delaunay + mollification)        heat method (potpourri3d)
``exact``   ``"exact-mmp"``: exact polyhedral geodesic  refused:
            (MMP, pygeodesic); refused above            :class:`MethodNotApplicableError`
            ``max_exact_vertices``:
            :class:`MethodSizeLimitError`
``graph``   ``"knn-graph"``: Dijkstra on the symmetric  ``"knn-graph"``: the same, on the
            ``k``-NN graph of the vertices              points
==========  ==========================================  ======================================

**Queries** go through :func:`litege_core.query.parse_query`: indices are used directly, and
xyz points follow the one snapping rule (:func:`litege_core.projection.snap`):

* point cloud: the nearest point (an index);
* mesh, ``exact`` and ``heat``: the closest point on the triangles. The distinct query points
  are inserted as vertices into a refined copy of the mesh
  (:func:`~litege_core.engines.insert_surface_points`; the surface does not move) and the
  engine is run there. The refined copy and its engine are kept for the **last query set
  only** (a path or a distance query with the same points reuses them);
* mesh, ``graph``: the closest point on the triangles joins the ``k``-NN graph of the
  vertices by straight segments (inside its triangle) to the triangle's corners and to the
  other query points of that triangle.

Pairs of identical points (same index, same snapped point, or two points at the same place)
get exactly ``0``; points on different connected components get ``+inf``.

**Paths** (:class:`ClassicalPath`, a polyline from the source to the target whose every
point lies on the surface, or is a cloud point):

* ``exact``: the exact geodesic (Kirsanov's MMP back-tracing); points on mesh edges;
* ``graph``: the Dijkstra shortest path on the same graph as the distances; points are
  vertices / cloud points (and the query points), its length is the graph distance;
* ``heat``: steepest descent of the heat distance field ``φ`` of the source, walked from the
  target. On a mesh it runs **through the triangles** (:class:`MeshDescent`: in each triangle
  a straight line along ``−∇φ`` of the piecewise-linear field, along an edge where the field
  has a valley there, straight to the source from any triangle that holds it); on a point
  cloud it runs **along a k-NN graph** (:func:`descend_field`: to the neighbour, among
  :data:`CLOUD_DESCENT_NEIGHBOURS`, of largest drop per unit length). A walk stuck in a
  local minimum is finished by the Dijkstra path along mesh edges / the ``k``-NN graph
  (``segments`` says so). Measured against the exact geodesic (30 random vertex pairs
  each): 0.3% longer on average (at most 1.4%) on icospheres, 0.7% (at most 4.9%) on tori
  (a pure edge walk: 8-20% on average); on a 2000-point cloud of the unit sphere, 2% (at
  most 7%) against the great circle.

**Cost** (``scripts/bench_methods.py``: 4-5K-vertex procedural and TOSCA meshes, one core):
build (lazy; :meth:`ClassicalSolver.prepare`) heat ~120 ms (one factorisation), graph ~35 ms
(k-d tree), exact ~75 ms; one source to every vertex: heat ~1.3 ms, graph ~1 ms, exact
~180 ms (growing faster than linearly with size, hence ``max_exact_vertices``); one path:
heat ~20 ms, exact ~165 ms, graph ~1 ms. xyz queries on a mesh add the refinement and, for
heat, a new factorisation per query set. Queries are serialised by a lock (the C++ solvers
keep state).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import cached_property
from typing import Self

import numpy as np
import scipy.sparse as sp
from numpy.typing import DTypeLike, NDArray

from litege_core.arrays import frozen
from litege_core.engines._topology import MeshTopology
from litege_core.engines.exact import DEFAULT_EXACT_BACKEND, EXACT_BACKENDS, ExactGeodesicEngine
from litege_core.engines.graph import (
    DEFAULT_K,
    KnnGraphEngine,
    dijkstra_path,
    dijkstra_rows,
    edge_graph,
)
from litege_core.engines.heat import HeatGeodesicEngine, PointCloudHeatEngine
from litege_core.engines.reference import EdgeDijkstraEngine
from litege_core.engines.surface_points import (
    DEFAULT_SNAP_TOL,
    check_surface_points,
    insert_surface_points,
)
from litege_core.errors import (
    ComputationError,
    InputError,
    MethodNotApplicableError,
    MethodSizeLimitError,
)
from litege_core.projection import CloudProjector, MeshProjector, snap
from litege_core.query import PointQuery, QueryLike, parse_query
from litege_core.seams import seam_welds
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits

CLASSICAL_METHODS: tuple[str, ...] = ("heat", "exact", "graph")
"""The ``method`` values a :class:`ClassicalSolver` serves (``learned`` is the Predictor's)."""

DEFAULT_MAX_EXACT_VERTICES = 20_000
"""Default bound on the vertices of a mesh for ``exact``: one exact solve takes about 0.1 s at
5K vertices, 0.4 s at 10K and 6 s at 41K (unit icosphere, one core)."""

CLOUD_DESCENT_NEIGHBOURS = 24
"""Neighbours per point of the graph a heat path descends on a point cloud. Measured on 2000
points of a sphere (40 pairs): k = 8 gives paths 11% longer than the great circle on average
(27% at most) and 3 stuck walks; k = 24 gives 2% (7% at most) and none."""

ENGINE_NAMES: tuple[str, ...] = ("heat", "pointcloud-heat", "exact-mmp", "knn-graph")
"""Every value of :attr:`ClassicalSolver.engine`."""

HEAT_DESCENT = "heat-descent"
"""Path part: descent of the heat distance field (through the triangles of a mesh, along
the k-NN graph of a cloud)."""
MESH_EDGES = "mesh-edges"
"""Path part: Dijkstra shortest path along mesh edges (finishes a stuck heat descent)."""
KNN_GRAPH = "knn-graph"
"""Path part: Dijkstra shortest path on the k-NN graph."""
EXACT_MMP = "exact-mmp"
"""Path part: exact geodesic (MMP back-tracing)."""


@dataclass(frozen=True, eq=False)
class ClassicalPath:
    """A path on the surface from the source to the target.

    Attributes:
        points: ``(L, 3)`` float64 polyline (read-only), ``L >= 2``, in the shape's frame;
            ``points[0]`` is the (snapped) source, ``points[-1]`` the (snapped) target.
        length: polyline length, shape units.
        distance: the engine's distance from the source to the target (exact: the exact
            geodesic, equal to ``length`` to rounding; graph: the graph distance, equal to
            ``length``; heat: the heat-method distance, usually a little below ``length``).
        engine: the engine that ran (:data:`ENGINE_NAMES`).
        segments: the parts of the polyline as ``(start_index, how)`` pairs in order, ``how``
            one of ``"exact-mmp"``, ``"knn-graph"``, ``"heat-descent"``, ``"mesh-edges"``;
            part ``k`` runs from ``points[start_k]`` to the next part's start (the last one to
            ``points[-1]``).
    """

    points: NDArray
    length: float
    distance: float
    engine: str
    segments: tuple[tuple[int, str], ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", frozen(self.points, np.float64))


def polyline_length(points: NDArray) -> float:
    """Length of a ``(L, 3)`` polyline."""
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def symmetric(graph: sp.csr_array) -> sp.csr_array:
    """Both directions of an upper-triangular graph (:func:`~.graph.edge_graph`), as CSR.

    Explicit zero-length edges (coincident points) are kept: the entries are assembled
    directly rather than by a sparse sum.
    """
    coo = graph.tocoo()
    rows = np.concatenate([coo.row, coo.col])
    cols = np.concatenate([coo.col, coo.row])
    data = np.concatenate([coo.data, coo.data])
    order = np.lexsort((cols, rows))
    n = graph.shape[0]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(indptr, rows + 1, 1)
    return sp.csr_array((data[order], cols[order], np.cumsum(indptr)), shape=(n, n))


def descend_field(
    neighbours: sp.csr_array, field: NDArray, source: int, target: int
) -> tuple[list[int], bool]:
    """Steepest descent of a distance ``field`` from ``target`` towards ``source`` on a graph.

    Args:
        neighbours: ``(M, M)`` symmetric CSR of edge lengths (:func:`symmetric`).
        field: ``(M,)`` float64 distances from ``source`` (``field[source]`` is the minimum).
        source: the node the walk must reach.
        target: the node it starts from.

    Returns:
        ``(nodes, reached)``: the visited nodes from ``target`` on, and whether the last one
        is ``source`` (``False``: stuck at a node without a lower neighbour). Each move goes
        to the neighbour with the largest ``(field[u] − field[v]) / |uv|`` (to ``source``
        directly when it is a neighbour), so the field strictly decreases and the walk ends.
    """
    indptr, indices, lengths = neighbours.indptr, neighbours.indices, neighbours.data
    node = int(target)
    nodes = [node]
    while node != source:
        lo, hi = int(indptr[node]), int(indptr[node + 1])
        around = indices[lo:hi]
        if np.any(around == source):
            nodes.append(int(source))
            return nodes, True
        if around.size == 0 or not np.isfinite(field[node]):
            return nodes, False
        drop = field[node] - field[around]
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(drop > 0, drop / lengths[lo:hi], -np.inf)
        if slope.max() == -np.inf:
            return nodes, False
        node = int(around[int(np.argmax(slope))])
        nodes.append(node)
    return nodes, True


class MeshDescent:
    """Integral curves of ``−∇φ`` of a piecewise-linear field ``φ`` on a triangle mesh.

    The walk starts at a vertex and, in each triangle, follows the triangle's (constant)
    steepest-descent direction in a straight line to the triangle's boundary; where no
    incident triangle admits the direction (a valley along an edge) it moves along the
    edge to the lower end, or from a vertex along the edge of steepest drop. Once the
    current point shares a triangle with the goal vertex it goes straight to it. Every move
    stays inside one triangle (or on one edge), so every point lies on the surface; ``φ``
    strictly decreases, so the walk ends (stuck in a local minimum, or at ``max_steps``).

    Args:
        vertices: ``(M, 3)`` float64.
        faces: ``(F, 3)`` int64 triangles without repeated corners.
    """

    def __init__(self, vertices: NDArray, faces: NDArray) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        m = self.vertices.shape[0]
        corners = self.vertices[self.faces]  # (F, 3, 3)
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        double_area = np.linalg.norm(normal, axis=1)
        scale = np.max(np.linalg.norm(corners - corners.mean(axis=1, keepdims=True), axis=2))
        self._usable = double_area > 1e-12 * max(scale, 1e-300) ** 2
        unit = normal / np.where(self._usable, double_area, 1.0)[:, None]
        # gradient of barycentric coordinate i: n × (p_{i+2} − p_{i+1}) / (2A)
        opposite = np.roll(corners, -2, axis=1) - np.roll(corners, -1, axis=1)
        self._basis = (
            np.cross(unit[:, None, :], opposite)
            / np.where(self._usable, double_area, 1.0)[:, None, None]
        )  # (F, 3, 3): rows are ∇λ_i
        flat = self.faces.reshape(-1)
        order = np.argsort(flat, kind="stable")
        self._vf_faces = order // 3
        self._vf_ptr = np.searchsorted(flat[order], np.arange(m + 1))
        half = np.sort(self.faces[:, [[0, 1], [1, 2], [2, 0]]], axis=2).reshape(-1, 2)
        keys = half[:, 0] * m + half[:, 1]
        order = np.argsort(keys, kind="stable")
        self._edge_keys = keys[order]
        self._edge_faces = np.repeat(np.arange(self.faces.shape[0]), 3)[order]
        self._m = m

    def _faces_of_vertex(self, v: int) -> NDArray:
        return self._vf_faces[self._vf_ptr[v] : self._vf_ptr[v + 1]]

    def _faces_of_edge(self, a: int, b: int) -> NDArray:
        key = min(a, b) * self._m + max(a, b)
        lo, hi = np.searchsorted(self._edge_keys, [key, key + 1])
        return self._edge_faces[lo:hi]

    def walk(
        self, field: NDArray, goal: int, start: int, max_steps: int | None = None
    ) -> tuple[NDArray, int, bool]:
        """Walk from vertex ``start`` down ``field (M,)`` towards vertex ``goal``.

        Returns:
            ``(points (L, 3), last_vertex, reached)``: the polyline from ``start`` on; when
            ``reached`` is ``False`` the walk stopped at the vertex ``last_vertex`` (a stuck
            walk on an edge first moves to that edge's lower end).
        """
        steps = 4 * self.faces.shape[0] + 16 if max_steps is None else max_steps
        points = [self.vertices[start]]
        support = [int(start)]  # the vertex, or the two ends of the edge, holding the point
        weights = np.ones(1)
        level = float(field[start])
        for _ in range(steps):
            if len(support) == 1 and support[0] == goal:
                return np.asarray(points), goal, True
            candidates = (
                self._faces_of_vertex(support[0])
                if len(support) == 1
                else self._faces_of_edge(support[0], support[1])
            )
            if np.any(self.faces[candidates] == goal):
                points.append(self.vertices[goal])
                return np.asarray(points), goal, True
            move = self._face_move(field, candidates, support, weights)
            if move is None:
                move = self._edge_move(field, support, level)
            if move is None:
                break
            new_support, new_weights = move
            position = new_weights @ self.vertices[new_support]
            new_level = float(new_weights @ field[new_support])
            if not new_level < level:
                break
            points.append(position)
            support, weights, level = new_support, new_weights, new_level
        if len(support) == 2:  # stuck on an edge: go to its lower end
            end = support[int(np.argmin(field[support]))]
            points.append(self.vertices[end])
            return np.asarray(points), int(end), False
        return np.asarray(points), int(support[0]), False

    def _face_move(
        self, field: NDArray, candidates: NDArray, support: list[int], weights: NDArray
    ) -> tuple[list[int], NDArray] | None:
        """Straight move along ``−∇φ`` of the steepest incident triangle that admits it."""
        best: tuple[float, int, NDArray, NDArray] | None = None
        for face in candidates.tolist():
            if not self._usable[face]:
                continue
            corners = self.faces[face]
            basis = self._basis[face]
            direction = -(field[corners] @ basis)  # (3,) = −∇φ in the triangle
            slope = float(np.linalg.norm(direction))
            if not np.isfinite(slope) or slope == 0.0:
                continue
            rate = basis @ direction  # dλ_i per unit move
            lam = np.zeros(3)
            for vertex, weight in zip(support, weights.tolist(), strict=True):
                lam[int(np.flatnonzero(corners == vertex)[0])] = weight
            rate[np.abs(rate) <= 1e-12 * np.abs(rate).max()] = 0.0
            free = lam == 0.0
            if np.any(rate[free] < 0) or not np.any(rate[free] > 0):
                continue
            if best is None or slope > best[0]:
                best = (slope, face, lam, rate)
        if best is None:
            return None
        _, face, lam, rate = best
        leaving = rate < 0
        if not leaving.any():
            return None
        times = np.where(leaving, -lam / np.where(leaving, rate, -1.0), np.inf)
        t = float(times.min())
        lam = np.maximum(lam + t * rate, 0.0)
        lam[times <= t * (1 + 1e-12)] = 0.0
        lam[lam < 1e-12 * lam.sum()] = 0.0
        if lam.sum() <= 0:
            return None
        lam /= lam.sum()
        keep = np.flatnonzero(lam > 0)
        corners = self.faces[face]
        return [int(c) for c in corners[keep]], lam[keep]

    def _edge_move(
        self, field: NDArray, support: list[int], level: float
    ) -> tuple[list[int], NDArray] | None:
        """Along an edge: to the lower end of the current edge, or from a vertex along the
        incident edge of steepest drop."""
        if len(support) == 2:
            end = support[int(np.argmin(field[support]))]
            return ([int(end)], np.ones(1)) if field[end] < level else None
        v = support[0]
        around = np.unique(self.faces[self._faces_of_vertex(v)])
        around = around[around != v]
        if around.size == 0:
            return None
        lengths = np.linalg.norm(self.vertices[around] - self.vertices[v], axis=1)
        drop = level - field[around]
        with np.errstate(divide="ignore", invalid="ignore"):
            slope = np.where(drop > 0, drop / lengths, -np.inf)
        if not slope.max() > -np.inf:
            return None
        return [int(around[int(np.argmax(slope))])], np.ones(1)


class _Domain:
    """The graph or mesh one query is solved on: the shape itself, or a refined / augmented
    copy whose nodes ``[0, N)`` are the shape's vertices.

    Attributes:
        positions: ``(M, 3)`` float64 node positions.
    """

    def __init__(self, positions: NDArray) -> None:
        self.positions = positions
        self._place: NDArray | None = None

    @property
    def place(self) -> NDArray:
        """``(M,)`` int64 id of each node's position: equal ids = the same point in space
        (distinct nodes share one only where the shape has duplicated vertices / points)."""
        if self._place is None:
            _, inverse = np.unique(self.positions, axis=0, return_inverse=True)
            self._place = inverse.reshape(-1).astype(np.int64)
        return self._place

    def rows(self, nodes: NDArray) -> NDArray:
        """``(S, M)`` float64 distances from each of ``nodes (S,)`` to every node."""
        raise NotImplementedError

    def path(self, source: int, target: int) -> tuple[NDArray, float, tuple[tuple[int, str], ...]]:
        """``(points (L, 3), engine distance, segments)`` from node ``source`` to ``target``."""
        raise NotImplementedError

    def prepare(self) -> None:
        """Build the expensive state now."""


def _unreachable(source: int, target: int) -> InputError:
    return InputError(
        "the source and the target lie on different connected components; "
        "no surface path joins them",
        source=source,
        target=target,
    )


class _ExactDomain(_Domain):
    def __init__(self, engine: ExactGeodesicEngine) -> None:
        super().__init__(np.asarray(engine.shape.vertices))
        self.engine = engine

    def prepare(self) -> None:
        self.engine.prepare()

    def rows(self, nodes: NDArray) -> NDArray:
        return np.asarray(self.engine.distances(nodes).distances)

    def path(self, source: int, target: int) -> tuple[NDArray, float, tuple[tuple[int, str], ...]]:
        points = self.engine.path(source, target)
        return points, polyline_length(points), ((0, EXACT_MMP),)


class _HeatDomain(_Domain):
    """Heat rows from ``engine``; paths by descent of the heat field: through the triangles
    of a mesh (:class:`MeshDescent`), along the k-NN graph of a cloud (:func:`descend_field`);
    a stuck walk is finished by Dijkstra on ``finish_graph`` (mesh edges / k-NN graph)."""

    def __init__(
        self,
        engine: HeatGeodesicEngine | PointCloudHeatEngine,
        finish_graph: KnnGraphEngine | EdgeDijkstraEngine,
    ) -> None:
        super().__init__(np.asarray(engine.shape.vertices))
        self.engine = engine
        self._finish = finish_graph
        self._descent: MeshDescent | None = None
        self._neighbours: sp.csr_array | None = None

    def prepare(self) -> None:
        self.engine.prepare()

    def rows(self, nodes: NDArray) -> NDArray:
        return np.asarray(self.engine.distances(nodes).distances)

    def _walk(self, field: NDArray, source: int, target: int) -> tuple[NDArray, int, bool]:
        """Points from ``target`` down to ``source`` (or to the vertex where it got stuck)."""
        if isinstance(self.engine, HeatGeodesicEngine):
            if self._descent is None:
                topology = self.engine.topology
                self._descent = MeshDescent(self.positions, topology.to_original[topology.faces])
            return self._descent.walk(field, source, target)
        if self._neighbours is None:
            wide = KnnGraphEngine(self.engine.shape, k=CLOUD_DESCENT_NEIGHBOURS)
            self._neighbours = symmetric(wide.graph)
        nodes, reached = descend_field(self._neighbours, field, source, target)
        return self.positions[np.asarray(nodes)], nodes[-1], reached

    def path(self, source: int, target: int) -> tuple[NDArray, float, tuple[tuple[int, str], ...]]:
        field = np.asarray(self.engine.distance(source))
        distance = float(field[target])
        if not np.isfinite(distance):
            raise _unreachable(source, target)
        if source == target:
            return self.positions[[source, source]], 0.0, ((0, HEAT_DESCENT),)
        walked, last, reached = self._walk(field, source, target)
        points = walked[::-1]  # source (or the stuck vertex) → target
        segments: tuple[tuple[int, str], ...] = ((0, HEAT_DESCENT),)
        if not reached:
            length, head = dijkstra_path(self._finish.graph, source, last)
            if not np.isfinite(length):
                raise _unreachable(source, target)
            finish = MESH_EDGES if isinstance(self._finish, EdgeDijkstraEngine) else KNN_GRAPH
            points = np.vstack([self.positions[head], points[1:]])
            segments = ((0, finish), (int(head.size) - 1, HEAT_DESCENT))
        if points.shape[0] == 1:
            points = np.vstack([points, points])
        return points, distance, segments


class _FixedGraph:
    """An already built graph, with the ``graph`` attribute of a :class:`KnnGraphEngine`."""

    def __init__(self, graph: sp.csr_array) -> None:
        self.graph = graph


class _GraphDomain(_Domain):
    """Dijkstra on an undirected graph (upper-triangular CSR of edge lengths), taken from a
    :class:`KnnGraphEngine` (built on first use) or a :class:`_FixedGraph`."""

    def __init__(self, graph_of: KnnGraphEngine | _FixedGraph, positions: NDArray) -> None:
        super().__init__(positions)
        self._graph_of = graph_of

    @property
    def graph(self) -> sp.csr_array:
        """``(M, M)`` upper-triangular CSR of edge lengths."""
        return self._graph_of.graph

    def prepare(self) -> None:
        _ = self.graph

    def rows(self, nodes: NDArray) -> NDArray:
        unique, inverse = np.unique(nodes, return_inverse=True)
        return dijkstra_rows(self.graph, unique)[inverse]

    def path(self, source: int, target: int) -> tuple[NDArray, float, tuple[tuple[int, str], ...]]:
        length, nodes = dijkstra_path(self.graph, source, target)
        if not np.isfinite(length):
            raise _unreachable(source, target)
        if nodes.size == 1:
            nodes = np.repeat(nodes, 2)
        return self.positions[nodes], length, ((0, KNN_GRAPH),)


class ClassicalSolver:
    """Precompute-then-query geodesics on one shape with a classical method.

    Args:
        shape: the mesh or point cloud.
        method: ``"heat"``, ``"exact"`` or ``"graph"`` (see the module docstring).
        max_exact_vertices: largest mesh (vertex count) ``exact`` accepts; ``None``: no bound.
        k: neighbours per point of the ``graph`` method's k-NN graph (and of the graph that
            finishes a stuck heat path on a point cloud).
        t_coef: heat diffusion time coefficient (potpourri3d's convention).
        backend: exact backend (``"pygeodesic"`` or ``"gdist"``; paths always use
            pygeodesic, which runs the same algorithm).

    Raises:
        InputError: unknown method or bad option;
        MethodNotApplicableError: ``exact`` on a point cloud;
        MethodSizeLimitError: ``exact`` on a mesh of more than ``max_exact_vertices``.

    Nothing expensive is built here: the engine (heat factorisation, k-NN graph, exact
    solvers) is built on the first query or by :meth:`prepare`, and kept.
    """

    def __init__(
        self,
        shape: Shape,
        method: str,
        *,
        max_exact_vertices: int | None = DEFAULT_MAX_EXACT_VERTICES,
        k: int = DEFAULT_K,
        t_coef: float = 1.0,
        backend: str = DEFAULT_EXACT_BACKEND,
    ) -> None:
        if not isinstance(shape, Shape):
            raise InputError(f"a classical solver needs a litege Shape, got {type(shape).__name__}")
        if method not in CLASSICAL_METHODS:
            raise InputError(
                f"unknown geodesic method {method!r} for a classical solver; expected one of "
                f"{list(CLASSICAL_METHODS)} ('learned' is served by litege_core.learned.Predictor)"
            )
        if max_exact_vertices is not None and (
            isinstance(max_exact_vertices, bool)
            or not isinstance(max_exact_vertices, int | np.integer)
            or max_exact_vertices < 1
        ):
            raise InputError(
                f"max_exact_vertices must be a positive integer or None, got {max_exact_vertices!r}"
            )
        if backend not in EXACT_BACKENDS:
            raise InputError(f"unknown exact backend {backend!r}; expected one of {EXACT_BACKENDS}")
        self._shape = shape
        self._method = method
        self._k = k
        self._t_coef = t_coef
        self._backend = backend
        self._max_exact = None if max_exact_vertices is None else int(max_exact_vertices)
        if method == "exact":
            if not shape.is_mesh:
                raise MethodNotApplicableError(
                    "method 'exact' needs a triangle mesh and this shape is a point cloud; "
                    "use method='heat' (point-cloud heat method) or 'graph'",
                    method=method,
                )
            if self._max_exact is not None and shape.n_points > self._max_exact:
                raise MethodSizeLimitError(
                    f"method 'exact' is limited to meshes of at most {self._max_exact} vertices "
                    f"and this one has {shape.n_points}; use method='heat' or 'graph' (or "
                    "'learned')",
                    method=method,
                    n_vertices=shape.n_points,
                    max_vertices=self._max_exact,
                )
        # validate the engine options now (cheap: engines build nothing in __init__)
        self._base: _Domain = self._make_domain(shape)
        self._lock = threading.RLock()
        self._topology: MeshTopology | None = None
        self._faces: NDArray | None = None
        self._projector: MeshProjector | CloudProjector | None = None
        self._last: tuple[bytes, _Domain, NDArray] | None = None
        self._last_projection: tuple[bytes, NDArray, NDArray] | None = None

    # ------------------------------------------------------------------ properties

    @property
    def shape(self) -> Shape:
        """The shape the solver answers for."""
        return self._shape

    @property
    def method(self) -> str:
        """The requested method: ``"heat"``, ``"exact"`` or ``"graph"``."""
        return self._method

    @property
    def engine(self) -> str:
        """The engine that runs: ``"heat"``, ``"pointcloud-heat"``, ``"exact-mmp"`` or
        ``"knn-graph"``."""
        if self._method == "exact":
            return "exact-mmp"
        if self._method == "graph":
            return "knn-graph"
        return "heat" if self._shape.is_mesh else "pointcloud-heat"

    @property
    def params(self) -> dict[str, bool | int | float | str]:
        """Engine parameters that change the answer."""
        if self._method == "exact":
            return {"backend": self._backend}
        if self._method == "graph":
            return {"k": int(self._k)}
        if self._shape.is_mesh:
            return {"t_coef": float(self._t_coef), "use_robust": True}
        return {"t_coef": float(self._t_coef)}

    def __repr__(self) -> str:
        return (
            f"ClassicalSolver(engine={self.engine!r}, n_points={self._shape.n_points}, "
            f"params={self.params!r})"
        )

    # ------------------------------------------------------------------ building

    def _make_domain(self, shape: Shape) -> _Domain:
        """The engine domain of ``shape`` (the input shape or a refined copy)."""
        if self._method == "exact":
            return _ExactDomain(ExactGeodesicEngine(shape, backend=self._backend))
        if self._method == "graph":
            return _GraphDomain(KnnGraphEngine(shape, k=self._k), np.asarray(shape.vertices))
        if shape.is_mesh:
            return _HeatDomain(
                HeatGeodesicEngine(shape, t_coef=self._t_coef, use_robust=True),
                EdgeDijkstraEngine(shape),
            )
        return _HeatDomain(
            PointCloudHeatEngine(shape, t_coef=self._t_coef), KnnGraphEngine(shape, k=self._k)
        )

    def prepare(self) -> Self:
        """Build the engine now (heat factorisation, k-NN graph, exact solvers)."""
        with self._lock:
            self._base.prepare()
        return self

    @property
    def topology(self) -> MeshTopology:
        """The cleaned mesh (faces with a repeated corner and duplicates dropped); meshes."""
        if self._topology is None:
            assert self._shape.faces is not None
            self._topology = MeshTopology.from_arrays(self._shape.vertices, self._shape.faces)
        return self._topology

    def _clean_faces(self) -> NDArray:
        """``(F', 3)`` int64 cleaned faces in the shape's vertex indices (cached)."""
        if self._faces is None:
            topology = self.topology
            self._faces = topology.to_original[topology.faces]
        return self._faces

    def _get_projector(self) -> MeshProjector | CloudProjector:
        if self._projector is None:
            if self._shape.is_mesh:
                self._projector = MeshProjector(self._shape.vertices, self._clean_faces())
            else:
                self._projector = CloudProjector(self._shape.vertices)
        return self._projector

    # ------------------------------------------------------------------ queries

    def _parse(self, value: QueryLike, what: str, single: bool) -> PointQuery:
        query = parse_query(value, what, allow_all=not single, single=single)
        return query.check(self._shape.n_points, what)

    def _resolve(self, queries: list[PointQuery]) -> tuple[_Domain, list[NDArray]]:
        """Node ids of each query on the domain that answers them all (``None``: all); a mesh's
        seam copy is answered as its first copy (:func:`~litege_core.seams.seam_welds`)."""
        domain, nodes = self._resolve_nodes(queries)
        welds = self._seam_welds
        if welds is not None:  # the shape's vertices are the domain's first nodes
            n = welds.size
            nodes = [np.where(q < n, welds[np.minimum(q, n - 1)], q) for q in nodes]
        return domain, nodes

    @cached_property
    def _seam_welds(self) -> NDArray | None:
        """A mesh's :func:`~litege_core.seams.seam_welds` where it has seam copies, else
        ``None`` (computed once; cheap where no position repeats: no topology is built)."""
        if self._shape.faces is None:
            return None
        welds = seam_welds(np.asarray(self._shape.vertices), self._shape.faces)
        return None if np.array_equal(welds, np.arange(welds.size)) else welds

    def _resolve_nodes(self, queries: list[PointQuery]) -> tuple[_Domain, list[NDArray]]:
        """:meth:`_resolve` before the welding."""
        n = self._shape.n_points
        projector = None
        if any(query.is_points for query in queries):
            projector = self._get_projector()
        if projector is None or isinstance(projector, CloudProjector):
            nodes = []
            for query in queries:
                if query.is_all:
                    nodes.append(np.arange(n, dtype=np.int64))
                elif query.indices is not None:
                    nodes.append(query.indices)
                else:
                    assert projector is not None and query.points is not None
                    indices = snap(projector, query.points).indices
                    assert indices is not None
                    nodes.append(np.asarray(indices, dtype=np.int64))
            return self._base, nodes
        # a mesh with xyz queries: one surface point set for the whole call
        points = np.vstack([q.points for q in queries if q.points is not None])
        key = points.tobytes()
        if self._last_projection is None or self._last_projection[0] != key:
            projection = projector.project(points)
            assert projection.face_index is not None and projection.barycentric is not None
            self._last_projection = (key, projection.face_index, projection.barycentric)
        _, face_index, barycentric = self._last_projection
        domain, point_nodes = self._surface_domain(face_index, barycentric)
        nodes, start = [], 0
        for query in queries:
            if query.is_all:
                nodes.append(np.arange(n, dtype=np.int64))
            elif query.indices is not None:
                nodes.append(query.indices)
            else:
                assert query.points is not None
                count = query.points.shape[0]
                nodes.append(point_nodes[start : start + count])
                start += count
        return domain, nodes

    def _surface_domain(self, face_index: NDArray, barycentric: NDArray) -> tuple[_Domain, NDArray]:
        """The domain with the surface points ``(P,)`` / ``(P, 3)`` (on the clean faces) as
        nodes, and the node of each point; reused while the point set does not change."""
        faces = self._clean_faces()
        face_index, weights = check_surface_points(face_index, barycentric, faces, DEFAULT_SNAP_TOL)
        table = np.column_stack([face_index.astype(np.float64), weights])
        unique, inverse = np.unique(table, axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        key = unique.tobytes()
        if self._last is not None and self._last[0] == key:
            return self._last[1], self._last[2][inverse]
        unique_face = unique[:, 0].astype(np.int64)
        unique_weights = unique[:, 1:]
        if self._method == "graph":
            domain, unique_nodes = self._augmented_graph(faces, unique_face, unique_weights)
        else:
            refined = insert_surface_points(
                self._shape.vertices, faces, unique_face, unique_weights, DEFAULT_SNAP_TOL
            )
            limits = ShapeLimits(
                max_vertices=refined.vertices.shape[0], max_faces=refined.faces.shape[0]
            )
            domain = self._make_domain(
                Shape.from_arrays(refined.vertices, refined.faces, limits=limits)
            )
            unique_nodes = refined.point_vertex
        self._last = (key, domain, unique_nodes)
        return domain, unique_nodes[inverse]

    def _augmented_graph(
        self, faces: NDArray, face_index: NDArray, weights: NDArray
    ) -> tuple[_Domain, NDArray]:
        """The k-NN graph of the vertices plus the surface points (distinct ``(P,)`` /
        ``(P, 3)``, snapped weights) as nodes, each joined by straight in-triangle segments to
        its triangle's corners and to the other points of that triangle."""
        base = self._base
        assert isinstance(base, _GraphDomain)
        graph = base.graph
        vertices = self._shape.vertices
        n = self._shape.n_points
        corners = faces[face_index]  # (P, 3)
        nonzero = weights > 0
        at_corner = nonzero.sum(axis=1) == 1
        positions = np.einsum("pk,pkd->pd", weights, vertices[corners])
        nodes = np.empty(face_index.size, dtype=np.int64)
        nodes[at_corner] = corners[at_corner, np.argmax(weights[at_corner], axis=1)]
        inside = np.flatnonzero(~at_corner)
        new_positions, new_of = np.unique(positions[inside], axis=0, return_inverse=True)
        nodes[inside] = n + new_of.reshape(-1)
        # edges: new point ↔ its triangle's corners, and points sharing a triangle
        point_node = nodes[inside]
        edges = [
            np.column_stack([np.repeat(point_node, 3), corners[inside].reshape(-1)]),
        ]
        order = np.argsort(face_index[inside], kind="stable")
        sorted_faces = face_index[inside][order]
        starts = np.flatnonzero(np.r_[True, sorted_faces[1:] != sorted_faces[:-1]])
        for group in np.split(point_node[order], starts[1:]):
            if group.size > 1:
                a, b = np.triu_indices(group.size, k=1)
                edges.append(np.column_stack([group[a], group[b]]))
        all_positions = np.vstack([vertices, new_positions])
        new_edges = np.concatenate(edges)
        lengths = np.linalg.norm(
            all_positions[new_edges[:, 0]] - all_positions[new_edges[:, 1]], axis=1
        )
        coo = graph.tocoo()
        augmented = edge_graph(
            all_positions.shape[0],
            np.concatenate([np.column_stack([coo.row, coo.col]), new_edges]),
            np.concatenate([coo.data, lengths]),
        )
        return _GraphDomain(_FixedGraph(augmented), all_positions), nodes

    def distances(
        self, sources: QueryLike, targets: QueryLike = None, *, dtype: DTypeLike = np.float32
    ) -> NDArray:
        """Geodesic distances ``(S, T)`` in the shape's units.

        Args:
            sources: ``(S,)`` indices, ``(S, 3)`` xyz points or ``"all"`` (anything
                :func:`~litege_core.query.parse_query` takes).
            targets: ``(T,)`` indices, ``(T, 3)`` xyz points, or ``None`` / ``"all"``
                (``T = N``: distance fields).
            dtype: ``float32`` (the service's answer, like the learned predictor's) or
                ``float64`` (evaluation).

        Returns:
            ``(S, T)`` array; ``[i, j]`` the distance from source ``i`` to target ``j``;
            exactly 0 where the two points coincide, ``+inf`` across components. One solve
            per distinct source.

        Raises:
            ArrayShapeError / NonFiniteError / IndexOutOfRangeError: a bad query;
            InputError: a bad dtype, or a mesh the exact engine refuses (non-manifold);
            ComputationError: the solver failed.
        """
        out_dtype = np.dtype(dtype)
        if out_dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise InputError(f"dtype must be float32 or float64, got {out_dtype}")
        source_query = self._parse(sources, "sources", single=False)
        target_query = self._parse(targets, "targets", single=False)
        with self._lock:
            domain, (source_nodes, target_nodes) = self._resolve([source_query, target_query])
            unique, inverse = np.unique(source_nodes, return_inverse=True)
            rows = domain.rows(unique)
            if rows.shape[0] != unique.size or np.isnan(rows).any():
                raise ComputationError(f"the {self.engine} solver returned bad rows")
            out = rows[:, target_nodes][inverse.reshape(-1)]
            # identical points get exactly 0 (also distinct nodes at one place)
            place = domain.place
            out[place[source_nodes][:, None] == place[target_nodes][None, :]] = 0.0
        return out.astype(out_dtype)

    def distance_field(self, source: QueryLike) -> NDArray:
        """``(N,)`` float32 distances from one source (index or ``(3,)`` xyz) to every
        vertex / point."""
        query = self._parse(source, "source", single=True)
        return self.distances(query)[0]

    def path(self, source: QueryLike, target: QueryLike) -> ClassicalPath:
        """A path on the surface from ``source`` to ``target`` (see the module docstring).

        Args:
            source: one index or one ``(3,)`` xyz point.
            target: one index or one ``(3,)`` xyz point.

        Returns:
            :class:`ClassicalPath`; ``points[0]`` is the source (snapped onto the surface),
            ``points[-1]`` the target.

        Raises:
            ArrayShapeError / IndexOutOfRangeError: a bad point; InputError: the two points
            lie on different connected components (no surface path); ComputationError: the
            solver failed.
        """
        source_query = self._parse(source, "source", single=True)
        target_query = self._parse(target, "target", single=True)
        with self._lock:
            domain, (source_node, target_node) = self._resolve([source_query, target_query])
            s, t = int(source_node[0]), int(target_node[0])
            points, distance, segments = domain.path(s, t)
        if domain.place[s] == domain.place[t]:
            distance = 0.0
        return ClassicalPath(
            points=points,
            length=polyline_length(points),
            distance=float(distance),
            engine=self.engine,
            segments=segments,
        )


__all__ = [
    "CLASSICAL_METHODS",
    "DEFAULT_MAX_EXACT_VERTICES",
    "ENGINE_NAMES",
    "ClassicalPath",
    "ClassicalSolver",
    "descend_field",
    "polyline_length",
    "symmetric",
]
