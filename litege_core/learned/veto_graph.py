"""A cloud's fusion graph whose network veto runs only on the edges that shortest paths use.

The fusion cuts every k-NN edge whose predicted geodesic exceeds ``prune_ratio`` × its chord
(:func:`~litege_core.learned.fusion.pruned_knn_graph`). Evaluating the veto head on every edge
(~8 N for N points) costs more than everything else in a single-pair query on a cloud. Yet a
query only reads the lengths of shortest paths, and a shortest path that crosses no cut edge of
the full veto is also a shortest path of the fully vetoed graph (it is a path there, and that
graph has fewer edges). So :func:`~litege_core.learned.fusion.graph_rows` repeats:

1. Dijkstra on the graph without the cuts found so far, keeping the predecessors;
2. the veto on the not yet judged edges of the paths the query reads (each source's path to each
   target for a few pairs, else each source's whole shortest-path tree);
3. stop when none of them is cut; else, for whole trees, also the veto on the edges around the
   subtrees below the cut edges (:meth:`LazyVetoGraph.judge_below_cuts`), where the next
   round's trees re-route,

which gives the rows of the fully vetoed graph exactly, judging a few dozen edges for one pair
and about N for a distance field, in two rounds where a tree crosses cut edges (without step 3's
second veto: one more round per edge cut on the new paths, up to eight). Each round repeats the
Dijkstra runs, so a query that needs more than :data:`LAZY_SOURCES` of them judges every edge
first instead (one run each, as before). Verdicts are kept with the shape, so later queries
start from them. After :data:`MAX_ROUNDS` rounds every remaining edge is judged at once (a
bounded cost: at most the full veto and that many Dijkstra runs).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from litege_core.arrays import distinct_indices

if TYPE_CHECKING:
    import scipy.sparse as sp

EdgeGeodesics = Callable[[NDArray, NDArray], NDArray]
"""``(i (E,), j (E,)) → (E,)`` predicted geodesics between point pairs (canonical units)."""

MAX_ROUNDS = 8
"""Dijkstra rounds of :func:`~litege_core.learned.fusion.graph_rows` before every remaining
edge is judged at once."""
LAZY_SOURCES = 2
"""Most Dijkstra sources of a lazily vetoed query: on a 2K cloud a round of Dijkstra costs
~0.8 ms a source and the full veto ~5 ms, so beyond two sources judging every edge first is
cheaper."""
PATH_PAIRS = 256
"""Up to this many (source, target) pairs the veto judges the edges of their paths only, beyond
it each source's whole shortest-path tree."""

_UNKNOWN, _KEEP, _CUT = 0, 1, -1


class LazyVetoGraph:
    """A cloud's graph before the veto (k-NN, normal limit) and the verdicts found so far.

    Args:
        graph: ``(n, n)`` upper-triangular CSR of chord lengths, indices sorted within rows
            (as :func:`~litege_core.engines.graph.edge_graph` builds them).
        prune_ratio: an edge is cut when its predicted geodesic exceeds this × its chord.
    """

    def __init__(self, graph: sp.csr_array, prune_ratio: float) -> None:
        self.prune_ratio = float(prune_ratio)
        self._base = graph
        self._verdicts = np.zeros(graph.nnz, dtype=np.int8)
        self._graph = graph  # the base without the cut edges (the base itself until a cut)
        self._lock = threading.Lock()

    @property
    def graph(self) -> sp.csr_array:
        """The graph without the edges cut so far (what Dijkstra runs on)."""
        return self._graph

    @property
    def judged(self) -> int:
        """Edges the veto has judged so far."""
        return int(np.count_nonzero(self._verdicts))

    @property
    def nbytes(self) -> int:
        total = self._verdicts.nbytes
        for graph in {id(self._base): self._base, id(self._graph): self._graph}.values():
            total += graph.data.nbytes + graph.indices.nbytes + graph.indptr.nbytes
        return int(total)

    def _starts(self) -> NDArray:
        """``(E,)`` the first end of each base edge (its CSR row)."""
        n = self._base.shape[0]
        return np.repeat(np.arange(n, dtype=np.int64), np.diff(self._base.indptr))

    def positions(self, a: NDArray, b: NDArray) -> NDArray:
        """Positions in the base graph of the edges ``(a, b)`` (node pairs in either order;
        pairs that are not edges are dropped)."""
        n = max(self._base.shape[0], 1)
        edges = self._starts() * n + self._base.indices  # ascending (rows, then columns)
        if edges.size == 0:
            return np.zeros(0, dtype=np.int64)
        keys = np.minimum(a, b).astype(np.int64) * n + np.maximum(a, b)
        keys.sort()  # sorted needles: searchsorted reuses each answer as the next one's start
        found = np.minimum(np.searchsorted(edges, keys), edges.size - 1)
        return distinct_indices(found[edges[found] == keys], edges.size)

    def judge(self, positions: NDArray | None, edge_geodesics: EdgeGeodesics) -> bool:
        """Runs the veto on the not yet judged edges among ``positions`` (``None``: every
        edge); ``True`` if any of them is cut, now or before (a path read from a snapshot that
        another thread has cut since must be read again). Thread-safe: verdicts and the graph
        change together under a lock, and a verdict never changes once given."""
        if positions is None:
            positions = np.arange(self._verdicts.size)
        with self._lock:
            unknown = positions[self._verdicts[positions] == _UNKNOWN]
            if unknown.size:
                starts = self._starts()
                predicted = edge_geodesics(starts[unknown], self._base.indices[unknown])
                cut = predicted > self.prune_ratio * self._base.data[unknown]
                self._verdicts[unknown] = np.where(cut, _CUT, _KEEP)
                if cut.any():
                    self._rebuild(starts)
            return bool(np.any(self._verdicts[positions] == _CUT))

    def _rebuild(self, starts: NDArray) -> None:
        """The graph without every edge cut so far (replaced whole: readers keep a snapshot;
        called under the lock)."""
        import scipy.sparse as sp

        keep = self._verdicts != _CUT
        n = self._base.shape[0]
        cut = np.bincount(starts[~keep], minlength=n)  # few: cheaper than counting kept
        indptr = self._base.indptr - np.concatenate([[0], np.cumsum(cut)])
        self._graph = sp.csr_array(
            (self._base.data[keep], self._base.indices[keep], indptr), shape=self._base.shape
        )

    def judge_below_cuts(
        self, predecessors: NDArray, positions: NDArray, edge_geodesics: EdgeGeodesics
    ) -> None:
        """After a round whose shortest-path trees crossed cut edges: runs the veto on the not
        yet judged edges with an end in a subtree below a cut edge among ``positions`` (the
        trees' edges), where the next round's trees re-route. Their new paths then cross
        judged edges only, so the next round is usually the last, instead of one round per
        edge cut on the way (a heuristic: what it judges never changes an answer).

        ``predecessors``: ``(U, M)`` of the round's Dijkstra (``M >= n``: free points last).
        """
        cut = positions[self._verdicts[positions] == _CUT]
        if cut.size == 0:
            return
        starts, ends = self._starts(), self._base.indices
        below = subtrees_below(predecessors, starts[cut], ends[cut])[: self._base.shape[0]]
        self.judge(np.flatnonzero(below[starts] | below[ends]), edge_geodesics)

    def vetoed(self, edge_geodesics: EdgeGeodesics) -> sp.csr_array:
        """The fully vetoed graph (judges every remaining edge)."""
        self.judge(None, edge_geodesics)
        with self._lock:
            return self._graph


def grown_features(
    kept: tuple[Any, NDArray] | None,
    n_points: int,
    points: NDArray,
    compute: Callable[[NDArray], Any],
    concatenate: Callable[[list[Any]], Any],
) -> tuple[Any, NDArray]:
    """The veto head's features of the points a veto has reached, grown to cover ``points``:
    ``(table (R, F), rows (n_points,))`` with ``rows[p]`` the table row of point ``p`` (``-1``:
    not computed). ``kept``: the pair from the previous call, or ``None``; ``compute``: the
    features of ``(M,)`` point indices, ``(M, F)``; ``concatenate``: joins tables (numpy's or
    torch's). A new pair is returned whenever rows are added, never the old one changed, so a
    caller that stores it keeps ``(table, rows)`` consistent for concurrent readers."""
    table, rows = kept if kept is not None else (None, np.full(n_points, -1, dtype=np.int64))
    missing = distinct_indices(points[rows[points] < 0], n_points)
    if missing.size:
        start = 0 if table is None else table.shape[0]
        rows = rows.copy()
        rows[missing] = np.arange(start, start + missing.size)
        new = compute(missing)
        table = new if table is None else concatenate([table, new])
    return table, rows


def subtrees_below(predecessors: NDArray, a: NDArray, b: NDArray) -> NDArray:
    """``(M,)`` whether a node lies, in the shortest-path tree of any Dijkstra source, below
    one of the edges ``(a, b)`` (``(C,)`` node pairs in either order; an edge that is not a
    tree edge marks nothing). ``predecessors``: scipy's ``(U, M)`` (``-9999``: none).

    By pointer jumping: each node learns whether an ancestor twice as far up is marked, so
    ``log2`` of the trees' depth vectorized steps (:func:`subtrees_below_reference` walks
    each node's path)."""
    sources, width = predecessors.shape
    marked = np.zeros((sources, width), dtype=bool)  # the child end of each tree edge (a, b)
    for parent, child in ((a, b), (b, a)):
        row, edge = np.nonzero(predecessors[:, child] == parent)
        marked[row, child[edge]] = True
    inside = marked.reshape(-1)  # flat (U·M,): one tree after the other
    up = np.asarray(predecessors, dtype=np.int64).reshape(-1)
    up = np.where(up >= 0, up + np.repeat(np.arange(sources) * width, width), -1)
    node = np.flatnonzero(up >= 0)
    while node.size:  # invariant: inside[v] covers v and its ancestors below up[v]
        ancestor = up[node]
        inside[node] |= inside[ancestor]
        up[node] = up[ancestor]
        node = node[up[node] >= 0]
    return np.asarray(marked.any(axis=0))


def subtrees_below_reference(predecessors: NDArray, a: NDArray, b: NDArray) -> NDArray:
    """:func:`subtrees_below` by walking every node's path to its source (the slow
    reference)."""
    sources, width = predecessors.shape
    tree_edges = {(int(x), int(y)) for x, y in zip(a, b, strict=True)}
    tree_edges |= {(y, x) for x, y in tree_edges}
    inside = np.zeros(width, dtype=bool)
    for row in range(sources):
        for node in range(width):
            walk = node
            while predecessors[row, walk] >= 0 and not inside[node]:
                parent = int(predecessors[row, walk])
                inside[node] = (parent, walk) in tree_edges
                walk = parent
    return inside


def reads_trees(n_sources: int, n_far: int) -> bool:
    """Whether :func:`path_edges` reads each source's whole shortest-path tree (more than
    :data:`PATH_PAIRS` pairs) rather than the pairs' paths."""
    return n_sources * n_far > PATH_PAIRS


def path_edges(predecessors: NDArray, far: NDArray, n_nodes: int) -> tuple[NDArray, NDArray]:
    """The edges ``(a, b)`` (both ends below ``n_nodes``) of the shortest paths from each
    Dijkstra source to each ``far`` node, read from scipy's ``(U, M)`` predecessors
    (``-9999``: none): the paths themselves for up to :data:`PATH_PAIRS` pairs, else each
    source's whole tree."""
    sources, width = predecessors.shape
    if not reads_trees(sources, far.size):
        row = np.repeat(np.arange(sources), far.size)
        node = np.tile(np.asarray(far, dtype=np.int64), sources)
        starts, ends = [], []
        while node.size:
            previous = predecessors[row, node]
            step = previous >= 0
            starts.append(previous[step])
            ends.append(node[step])
            row, node = row[step], previous[step]
        a, b = np.concatenate(starts), np.concatenate(ends)
    else:
        step = predecessors >= 0
        a = predecessors[step]
        b = np.broadcast_to(np.arange(width), predecessors.shape)[step]
    inside = (a < n_nodes) & (b < n_nodes)
    return a[inside], b[inside]


__all__ = [
    "LAZY_SOURCES",
    "MAX_ROUNDS",
    "PATH_PAIRS",
    "EdgeGeodesics",
    "LazyVetoGraph",
    "grown_features",
    "path_edges",
    "reads_trees",
    "subtrees_below",
    "subtrees_below_reference",
]
