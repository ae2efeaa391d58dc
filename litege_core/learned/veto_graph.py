"""A cloud's fusion graph whose network veto runs only on the edges that shortest paths use.

The fusion cuts every k-NN edge whose predicted geodesic exceeds ``prune_ratio`` × its chord
(:func:`~litege_core.learned.fusion.pruned_knn_graph`). Evaluating the veto head on every edge
(~8 N for N points) costs more than everything else in a single-pair query on a cloud. Yet a
query only reads the lengths of shortest paths, and a shortest path that crosses no cut edge of
the full veto is also a shortest path of the fully vetoed graph (it is a path there, and that
graph has fewer edges). So :func:`vetoed_rows` repeats:

1. Dijkstra on the graph without the cuts found so far, keeping the predecessors;
2. the veto on the not yet judged edges of the paths the query reads (each source's path to each
   target for a few pairs, else each source's whole shortest-path tree);
3. stop when none of them is cut,

which gives the rows of the fully vetoed graph exactly, judging a few dozen edges for one pair
and about N for a distance field. Each round repeats the Dijkstra runs, so a query that needs
more than :data:`LAZY_SOURCES` of them judges every edge first instead (one run each, as
before). Verdicts are kept with the shape, so later queries start from them. After
:data:`MAX_ROUNDS` rounds every remaining edge is judged at once (a bounded cost: at most the
full veto and that many Dijkstra runs).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    import scipy.sparse as sp

EdgeGeodesics = Callable[[NDArray, NDArray], NDArray]
"""``(i (E,), j (E,)) → (E,)`` predicted geodesics between point pairs (canonical units)."""

MAX_ROUNDS = 8
"""Dijkstra rounds of :func:`vetoed_rows` before every remaining edge is judged at once."""
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
        keys = np.minimum(a, b).astype(np.int64) * n + np.maximum(a, b)
        if edges.size == 0:
            return np.zeros(0, dtype=np.int64)
        found = np.minimum(np.searchsorted(edges, keys), edges.size - 1)
        return np.unique(found[edges[found] == keys])

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
        indptr = np.concatenate([[0], np.cumsum(np.bincount(starts[keep], minlength=n))])
        self._graph = sp.csr_array(
            (self._base.data[keep], self._base.indices[keep], indptr), shape=self._base.shape
        )

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
    missing = np.unique(points[rows[points] < 0])
    if missing.size:
        start = 0 if table is None else table.shape[0]
        rows = rows.copy()
        rows[missing] = np.arange(start, start + missing.size)
        new = compute(missing)
        table = new if table is None else concatenate([table, new])
    return table, rows


def path_edges(predecessors: NDArray, far: NDArray, n_nodes: int) -> tuple[NDArray, NDArray]:
    """The edges ``(a, b)`` (both ends below ``n_nodes``) of the shortest paths from each
    Dijkstra source to each ``far`` node, read from scipy's ``(U, M)`` predecessors
    (``-9999``: none): the paths themselves for up to :data:`PATH_PAIRS` pairs, else each
    source's whole tree."""
    sources, width = predecessors.shape
    if sources * far.size <= PATH_PAIRS:
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
]
