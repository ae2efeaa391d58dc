"""Graph geodesics: Dijkstra on a symmetric k-nearest-neighbour graph of the points.

A baseline for point clouds: shortest paths through straight chords between neighbours, so
always ``>= `` the Euclidean distance and, on densely sampled smooth surfaces, a slight
over-estimate of the geodesic (zig-zag paths). A cloud whose kNN graph is disconnected gets
``+inf`` between components.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from pykdtree.kdtree import KDTree  # 1.4x faster than scipy's cKDTree on 2K-point clouds
from scipy.sparse.csgraph import dijkstra

from litege_core.engines.base import GeodesicEngine, ParamValue
from litege_core.errors import InputError
from litege_core.sampling import OUTLIER_NEIGHBOURS, first_copies
from litege_core.seams import (
    consistently_wound,
    half_edges,
    oriented_faces,
    seam_welds,
    vertex_normals,
)
from litege_core.shape import Shape

DEFAULT_K = 8


def edge_rows(graph: sp.csr_array) -> NDArray:
    """``(E,)`` int64 the row of each stored edge of a CSR graph, in CSR order."""
    return np.repeat(np.arange(graph.shape[0], dtype=np.int64), np.diff(graph.indptr))


def edge_subgraph(graph: sp.csr_array, rows: NDArray, keep: NDArray) -> sp.csr_array:
    """``graph`` with only its stored edges where ``keep`` (``(E,)`` bool in CSR order;
    ``rows``: :func:`edge_rows`), order and shape kept."""
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows[keep], minlength=graph.shape[0]))])
    return sp.csr_array((graph.data[keep], graph.indices[keep], indptr), shape=graph.shape)


def edge_graph(n: int, edges: NDArray, weights: NDArray) -> sp.csr_array:
    """Undirected weighted graph on ``n`` nodes as an upper-triangular CSR array.

    Args:
        n: number of nodes.
        edges: ``(E, 2)`` int node pairs (any order, repeats allowed, self-loops dropped).
        weights: ``(E,)`` float64 non-negative lengths; a repeated pair keeps its smallest.

    Returns:
        ``(n, n)`` CSR with one entry per unordered pair ``i < j``, indices sorted within rows;
        explicit zeros are kept and mean zero-length edges (coincident points), as scipy's
        csgraph reads them.
    """
    low = np.minimum(edges[:, 0], edges[:, 1]).astype(np.int64)
    high = np.maximum(edges[:, 0], edges[:, 1]).astype(np.int64)
    if not np.any(low != high):
        return sp.csr_array((n, n), dtype=np.float64)
    order = np.argsort(low * max(n, 1) + high)  # one int64 key per unordered pair
    low, high, weights = low[order], high[order], np.asarray(weights, np.float64)[order]
    first = np.empty(low.size, dtype=bool)
    first[0] = True
    np.not_equal(low[1:], low[:-1], out=first[1:])
    first[1:] |= high[1:] != high[:-1]
    starts = np.flatnonzero(first)
    lightest = run_minima(weights, starts)  # the lightest edge of each pair
    low, high = low[starts], high[starts]
    pair = low != high  # self-loops sort into runs of their own: dropped here
    low, high, lightest = low[pair], high[pair], lightest[pair]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(low, minlength=n))])
    return sp.csr_array((lightest, high, indptr), shape=(n, n))


RUN_LOOP_MAX = 8
"""Longest run :func:`run_minima` walks by offsets (longer: ``numpy.minimum.reduceat``)."""


def run_minima(values: NDArray, starts: NDArray) -> NDArray:
    """The smallest of each run of ``values`` (``(E,)``) that begins at ``starts`` (``(R,)``
    increasing, ``starts[0] == 0``): ``(R,)``, as ``numpy.minimum.reduceat`` gives it.

    Walks the runs by offsets, one vectorized step per element of the longest run: several
    times faster than ``reduceat`` when runs are short (a k-NN graph's pairs: one or two
    entries each); longer runs go to ``reduceat``."""
    sizes = np.diff(starts, append=values.size)
    longest = int(sizes.max(initial=0))
    if longest > RUN_LOOP_MAX:
        return np.minimum.reduceat(values, starts)
    minima = values[starts]
    for offset in range(1, longest):
        following = values[np.minimum(starts + offset, values.size - 1)]
        minima = np.where(sizes > offset, np.minimum(minima, following), minima)
    return minima


def dijkstra_rows(graph: sp.csr_array, sources: NDArray, directed: bool = False) -> NDArray:
    """``(S, n)`` float64 shortest-path lengths on ``graph`` (``inf`` if cut): undirected, or
    along its stored directions with ``directed``."""
    rows = dijkstra(graph, directed=directed, indices=sources)
    return np.atleast_2d(np.asarray(rows, dtype=np.float64))


def dijkstra_tree(
    graph: sp.csr_array, sources: NDArray, directed: bool = False
) -> tuple[NDArray, NDArray]:
    """:func:`dijkstra_rows` and the ``(S, n)`` int predecessors of each node on its shortest
    path from each source (``-9999``: the source itself, or unreachable)."""
    rows, predecessors = dijkstra(
        graph, directed=directed, indices=sources, return_predecessors=True
    )
    return (
        np.atleast_2d(np.asarray(rows, dtype=np.float64)),
        np.atleast_2d(np.asarray(predecessors, dtype=np.int64)),
    )


def dijkstra_path(graph: sp.csr_array, source: int, target: int) -> tuple[float, NDArray]:
    """Shortest path between two nodes of the undirected ``graph`` (Dijkstra predecessors).

    Args:
        graph: ``(n, n)`` CSR of non-negative edge lengths (e.g. :func:`edge_graph`).
        source: start node.
        target: end node.

    Returns:
        ``(length, nodes)``: the path length (graph units) and ``(L,)`` int64 nodes from
        ``source`` to ``target`` (``[source]`` when they are equal); ``(inf, [])`` when no
        path joins them.
    """
    lengths, predecessors = dijkstra(
        graph, directed=False, indices=int(source), return_predecessors=True
    )
    length = float(lengths[target])
    if not np.isfinite(length):
        return length, np.empty(0, dtype=np.int64)
    nodes = [int(target)]
    while nodes[-1] != source:
        nodes.append(int(predecessors[nodes[-1]]))
    return length, np.asarray(nodes[::-1], dtype=np.int64)


def knn_neighbours(points: NDArray, k: int) -> tuple[NDArray, NDArray]:
    """Each point's ``k`` nearest points (clamped to ``N - 1``), itself first.

    Returns:
        ``(N, k + 1)`` float64 distances and ``(N, k + 1)`` int64 indices, nearest first.
    """
    n = points.shape[0]
    k = min(k, n - 1)
    points = np.ascontiguousarray(points, dtype=np.float64)
    lengths, neighbours = KDTree(points).query(points, k=k + 1)
    return lengths.reshape(n, -1), neighbours.reshape(n, -1).astype(np.int64)


def knn_graph(
    points: NDArray, k: int, neighbours: tuple[NDArray, NDArray] | None = None
) -> sp.csr_array:
    """Symmetric k-NN graph: ``i ~ j`` when either is among the other's ``k`` nearest.

    Without ``neighbours``, a position stored more than once (a cloud sent twice, a mesh's
    seam copies) and the twins of a cloud of twins count once (:func:`graph_nodes`): the graph
    joins the distinct nodes, and each other point joins its node by a straight edge (length 0
    for a copy; copies would otherwise fill each other's neighbour lists and split the
    graph).

    Args:
        points: ``(N, 3)`` float64.
        k: neighbours per point (clamped to ``N - 1``).
        neighbours: :func:`knn_neighbours` of ``points`` for ``k`` or more, if already known.

    Returns:
        ``(N, N)`` upper-triangular CSR of Euclidean edge lengths (see :func:`edge_graph`).
    """
    n = points.shape[0]
    if neighbours is None:
        (first, index), neighbours = graph_nodes(points, k)
        if index.size < n:
            return with_copies(knn_graph(points[index], k, neighbours), points, index, first)
    k = min(k, n - 1)
    lengths, nearest = neighbours[0][:, : k + 1], neighbours[1][:, : k + 1]
    sources = np.repeat(np.arange(n), k + 1)
    edges = np.column_stack([sources, nearest.reshape(-1)])
    return edge_graph(n, edges, lengths.reshape(-1))


CLUMP_FRACTION = 0.1
"""Two mutual nearest points of a cloud closer than this × its median distance to the 8th
nearest point are twins for its k-NN graphs (about a third of a typical spacing)."""
CLUMPY_SHARE = 0.25
"""The k-NN graphs merge twins only in a cloud where at least this share of its points
have a neighbour that close: a scan merged with a slightly moved copy of itself has nearly all
(its graph's neighbour lists would fill with twins: TOSCA fused ~1 → ~5 on cats), the real dev
clouds (2000 or 300 points, noisy, cut, uneven) 1–10 %, left as they are."""


def graph_nodes(
    points: NDArray, reach: int
) -> tuple[tuple[NDArray, NDArray], tuple[NDArray, NDArray]]:
    """The points of a cloud its k-NN graphs are built on, and their neighbour lists.

    A position sent more than once counts once (:func:`~litege_core.sampling.first_copies`),
    and in a cloud of twins (:data:`CLUMPY_SHARE`) two mutual nearest neighbours closer than
    :data:`CLUMP_FRACTION` × its median 8th-neighbour distance count as one (the first of the
    two): twins would fill each other's neighbour lists, and the graph would be sparser than
    the one of the cloud without them. The others join their node by a straight edge
    (:func:`with_copies`).

    Args:
        points: ``(N, 3)`` float64.
        reach: neighbours per node to list.

    Returns:
        ``((first (N,), index (D,)), neighbours)``: the node each point joins (its own index
        for a node) and the nodes' indices, increasing; the nodes' :func:`knn_neighbours`
        (node positions ``0..D-1``).
    """
    n = points.shape[0]
    first = first_copies(np.asarray(points, dtype=np.float64))
    index = np.flatnonzero(first == np.arange(n))
    lengths, nearest = knn_neighbours(points[index], max(reach, OUTLIER_NEIGHBOURS))
    clumps = _clump_heads(lengths, nearest)
    if clumps is None:
        return (first, index), (lengths[:, : reach + 1], nearest[:, : reach + 1])
    first = index[clumps[np.searchsorted(index, first)]]  # each twin joins its node
    index = index[clumps == np.arange(clumps.size)]
    return (first, index), knn_neighbours(points[index], reach)


def _clump_heads(lengths: NDArray, nearest: NDArray) -> NDArray | None:
    """``(D,)`` the node each point joins, from the points' neighbour lists ``(D, k + 1)``
    (itself first): the smaller index of each pair of mutual nearest neighbours closer than
    the clump limit, else itself; ``None`` where the cloud is not clumpy (see
    :func:`graph_nodes`)."""
    if lengths.shape[1] <= OUTLIER_NEIGHBOURS:
        return None
    limit = CLUMP_FRACTION * float(np.median(lengths[:, OUTLIER_NEIGHBOURS]))
    close = lengths[:, 1] < limit
    if not limit > 0.0 or close.mean() < CLUMPY_SHARE:
        return None
    points = np.arange(lengths.shape[0])
    twin = nearest[:, 1]
    paired = close & (nearest[twin, 1] == points)  # mutual: no chains through a cloud
    return np.where(paired, np.minimum(points, twin), points)


def with_copies(
    graph: sp.csr_array, points: NDArray, distinct: NDArray, first: NDArray
) -> sp.csr_array:
    """A graph of some of a point set's points, on all its points: each other point joins the
    point it stands for by a straight edge (length 0 for an exact copy).

    Args:
        graph: ``(D, D)`` upper-triangular CSR on the points ``distinct`` names.
        points: ``(N, 3)`` float64.
        distinct: ``(D,)`` int64 indices of the graph's points, increasing.
        first: ``(N,)`` int64 the point of ``distinct`` each point joins (itself there), e.g.
            its first copy (:func:`~litege_core.sampling.first_copies`).

    Returns:
        ``(N, N)`` upper-triangular CSR (see :func:`edge_graph`).
    """
    n = first.shape[0]
    inner = graph.tocoo()
    copies = np.flatnonzero(first != np.arange(n))
    edges = np.concatenate(
        [
            np.column_stack([distinct[inner.row], distinct[inner.col]]),
            np.column_stack([first[copies], copies]),
        ]
    )
    joins = np.linalg.norm(points[copies] - points[first[copies]], axis=1)
    return edge_graph(n, edges, np.concatenate([inner.data, joins]))


MUTUAL_BLOCK = 65_536
"""Edges per block of :func:`mutual_knn_graph`'s back-link test."""


def mutual_knn_graph(
    points: NDArray, k: int, neighbours: tuple[NDArray, NDArray] | None = None
) -> sp.csr_array:
    """Mutual k-NN graph: ``i ~ j`` when each is among the other's ``k`` nearest.

    Sparser than :func:`knn_graph` where the density changes: a point on a thin part whose
    nearest include points across a gap is not among *their* nearest (they have closer ones on
    their own side), so fewer chords bridge thin parts and gaps; a point none of whose
    neighbours return the favour is isolated.

    ``i`` is among ``j``'s nearest exactly when ``|i − j|`` is below ``j``'s ``k``-th neighbour
    distance; at that distance (a tie) ``j``'s list is read (blocks of :data:`MUTUAL_BLOCK`
    edges bound the ``(E, k + 1)`` comparison). The kept edges come out row by row, each row
    then sorted by index.

    Args:
        points: ``(N, 3)`` float64.
        k: neighbours per point (clamped to ``N - 1``).
        neighbours: :func:`knn_neighbours` of ``points`` for ``k`` or more, if already known.

    Returns:
        ``(N, N)`` upper-triangular CSR of Euclidean edge lengths, as :func:`edge_graph` builds
        them (indices sorted within rows, explicit zeros for coincident points).
    """
    n = points.shape[0]
    k = min(k, n - 1)
    lengths, nearest = knn_neighbours(points, k) if neighbours is None else neighbours
    lengths, nearest = lengths[:, : k + 1], nearest[:, : k + 1]
    starts = np.repeat(np.arange(n, dtype=np.int64), k + 1)
    ends, chords = nearest.reshape(-1), lengths.reshape(-1)
    reach = lengths[:, k][ends]  # the k-th neighbour distance of each edge's far end
    keep = (starts < ends) & (chords <= reach)  # each pair once, from its smaller end
    ties = np.flatnonzero(keep & (chords == reach))
    for block in range(0, ties.size, MUTUAL_BLOCK):
        part = ties[block : block + MUTUAL_BLOCK]
        keep[part] = (nearest[ends[part]] == starts[part, None]).any(axis=1)
    indptr = np.concatenate([[0], np.cumsum(np.count_nonzero(keep.reshape(n, -1), axis=1))])
    graph = sp.csr_array((chords[keep], ends[keep], indptr), shape=(n, n))
    graph.sort_indices()
    return graph


def mutual_knn_graph_reference(points: NDArray, k: int) -> sp.csr_array:
    """:func:`mutual_knn_graph` from brute-force distance ranks (the slow reference; ties
    broken by index, as a stable sort of each row gives them)."""
    n = points.shape[0]
    k = min(k, n - 1)
    distances = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    np.fill_diagonal(distances, np.inf)
    nearest = [set(np.argsort(row, kind="stable")[:k].tolist()) for row in distances]
    edges = [(i, j) for i in range(n) for j in nearest[i] if i < j and i in nearest[j]]
    pairs = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    return edge_graph(n, pairs, distances[pairs[:, 0], pairs[:, 1]])


def arc_normals(points: NDArray, faces: NDArray) -> NDArray | None:
    """``(N, 3)`` vertex normals of a mesh with its seams welded, for the arcs of
    :func:`mesh_ring_graph`. Faces wound against their neighbours (a mesh with flipped
    triangles, or non-manifold edges) are turned over first
    (:func:`~litege_core.seams.oriented_faces`), so that summed normals do not cancel;
    ``None`` where no turning does (a non-orientable surface: plain chords). A seam copy's
    normal is zero (its arcs are chords)."""
    faces = seam_welds(points, faces)[np.asarray(faces, dtype=np.int64)]
    if not consistently_wound(faces):
        oriented = oriented_faces(faces)
        if oriented is None:
            return None
        faces = oriented
    return vertex_normals(points, faces)


def mesh_ring_graph(
    points: NDArray, faces: NDArray, rings: int = 2, *, normals: NDArray | None = None
) -> sp.csr_array:
    """Chords between the vertices of a triangle mesh that are at most ``rings`` edges apart.

    Its Dijkstra follows the mesh's connectivity, so parts that touch in space without sharing
    faces stay apart, while the chords across each vertex's neighbourhood straighten the
    zig-zag of edge-only paths (``rings = 1``: the mesh's own edges). Seam copies
    (:func:`~litege_core.seams.seam_welds`: boundary vertices stored more than
    once at one position) count as one: the rings run over the welded faces, between each
    position's first copies, and every other copy joins its first copy by a chord of length 0,
    so a mesh split along seams (a triangle soup, an OBJ cut along its UV seams) is connected
    across them. Coincident vertices inside a closed surface stay apart: they are where two
    parts touch.

    With ``normals`` (:func:`arc_normals`), a chord that is not a mesh edge is lengthened to the
    arc it spans (:func:`arc_factors`: the circle whose tangents at its ends are perpendicular
    to the normals there), so it no longer cuts through a curved part: on a coarse mesh, where
    two rings span a good part of a leg, plain chords make every path short.

    Args:
        points: ``(N, 3)`` float64 vertices.
        faces: ``(F, 3)`` int triangles into ``points``.
        rings: largest number of mesh edges between two joined vertices (≥ 1).
        normals: ``(N, 3)`` vertex normals to lengthen the chords that are not edges to their
            arcs with, or ``None``: plain chords.

    Returns:
        ``(N, N)`` upper-triangular CSR of chord (or arc) lengths, one entry per joined pair
        (explicit zeros: coincident vertices), as :func:`edge_graph` builds it.
    """
    n = points.shape[0]
    faces = np.asarray(faces, dtype=np.int64)
    first = seam_welds(points, faces)
    copies = np.flatnonzero(first != np.arange(n))
    faces = first[faces]  # welded: a position's first copy
    half = np.concatenate([half_edges(faces), np.stack([first[copies], copies], 1)])
    own = np.arange(n)  # one ring, the vertex itself included, both directions of every edge
    starts, ends = (
        np.concatenate([half[:, 0], half[:, 1], own]),
        np.concatenate([half[:, 1], half[:, 0], own]),
    )
    step = sp.coo_array((np.ones(starts.size), (starts, ends)), shape=(n, n)).tocsr()
    step.data[:] = 1.0  # membership only (repeated pairs added up)
    reach = step
    for _ in range(rings - 1):
        reach = reach @ step
        reach.data[:] = 1.0  # membership only: keeps the counts from growing
    arcs = normals is not None and rings > 1
    if arcs:
        reach = reach + step  # an edge counts 2, a longer chord 1
    reach.sort_indices()
    rows = np.repeat(np.arange(n), np.diff(reach.indptr))
    above = reach.indices > rows  # the upper triangle, each row's columns still sorted
    rows, cols, marks = rows[above], reach.indices[above].astype(np.int64), reach.data[above]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))])
    axes = np.ascontiguousarray(points.T)  # (3, N): np.take along rows beats fancy indexing
    chord = np.take(axes, rows, axis=1)
    chord -= np.take(axes, cols, axis=1)
    lengths = np.sqrt(np.einsum("ie,ie->e", chord, chord))  # zeros stay entries
    if arcs:
        assert normals is not None  # arcs says so
        chords = np.flatnonzero(marks < 1.5)
        normal_axes = np.ascontiguousarray(normals.T)
        ends_a = np.take(normal_axes, rows[chords], axis=1)
        ends_b = np.take(normal_axes, cols[chords], axis=1)
        cos = np.einsum("ie,ie->e", ends_a, ends_b)
        known = np.einsum("ie,ie->e", ends_a, ends_a) * np.einsum("ie,ie->e", ends_b, ends_b)
        lengths[chords] *= _arc_factors(cos, known)
    return sp.csr_array((lengths, cols, indptr), shape=(n, n))


def arc_factors(normals_a: NDArray, normals_b: NDArray) -> NDArray:
    """Arc length over chord length of circle arcs between two points, from their unit normals
    ``(M, 3)``: ``(θ/2) / sin(θ/2)`` with ``θ`` the angle between the normals (1 for
    parallel normals, π/2 for opposite ones, as across a thin part; 1 where either normal is
    zero: an unreferenced vertex)."""
    cos = np.einsum("ij,ij->i", normals_a, normals_b)
    known = np.einsum("ij,ij->i", normals_a, normals_a) * np.einsum(
        "ij,ij->i", normals_b, normals_b
    )
    return _arc_factors(cos, known)


def _arc_factors(cos: NDArray, known: NDArray) -> NDArray:
    """:func:`arc_factors` from the normals' ``(M,)`` dot products and the products of their
    squared lengths (0: a zero normal)."""
    half_sine = np.sqrt(np.clip(0.5 * (1.0 - cos), 0.0, 1.0))  # sin(θ/2)
    bent = (half_sine > 1e-8) & (known > 0)
    return np.where(bent, np.arcsin(half_sine) / np.where(bent, half_sine, 1.0), 1.0)


class KnnGraphEngine(GeodesicEngine):
    """Dijkstra distances on the symmetric k-NN graph of a point cloud (or a mesh's vertices).

    Args:
        shape: any :class:`~litege_core.shape.Shape`.
        k: nearest neighbours per point (default 8; clamped to ``N - 1``).

    The graph (a KD-tree query) is built on the first query or :meth:`prepare`.
    """

    method: ClassVar[str] = "knn_graph"

    def __init__(self, shape: Shape, k: int = DEFAULT_K) -> None:
        super().__init__(shape)
        if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 1:
            raise InputError(f"k must be a positive integer, got {k!r}")
        self._k = int(k)
        self._graph: sp.csr_array | None = None

    @property
    def params(self) -> Mapping[str, ParamValue]:
        return {"k": self._k}

    @property
    def graph(self) -> sp.csr_array:
        """The ``(N, N)`` upper-triangular CSR graph (built on first use)."""
        if self._graph is None:
            self._graph = knn_graph(self._shape.vertices, self._k)
        return self._graph

    def prepare(self) -> KnnGraphEngine:
        """Build the k-NN graph now."""
        _ = self.graph
        return self

    def _rows(self, sources: NDArray) -> NDArray:
        return dijkstra_rows(self.graph, sources)


__all__ = [
    "DEFAULT_K",
    "KnnGraphEngine",
    "arc_factors",
    "arc_normals",
    "dijkstra_path",
    "dijkstra_rows",
    "dijkstra_tree",
    "edge_graph",
    "edge_rows",
    "edge_subgraph",
    "graph_nodes",
    "knn_graph",
    "knn_neighbours",
    "mesh_ring_graph",
    "mutual_knn_graph",
    "mutual_knn_graph_reference",
    "run_minima",
    "with_copies",
]
