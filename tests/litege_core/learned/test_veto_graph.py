"""The lazily vetoed fusion graph (issue 17): its rows equal Dijkstra on the eagerly vetoed
graph for every kind of query, it judges far fewer edges than the full veto for a few pairs, and
its verdicts are kept for later queries."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from litege_core.learned import veto_graph
from litege_core.learned.fusion import graph_rows, pruned_knn_graph
from litege_core.learned.veto_graph import (
    LazyVetoGraph,
    path_edges,
    subtrees_below,
    subtrees_below_reference,
)

K, RATIO = 8, 1.3


class CountingVeto:
    """A veto that calls every edge whose ends' ids sum to a multiple of ``period`` a
    shortcut (predicted 3 × the chord) and counts the edges it is asked about."""

    def __init__(self, points: np.ndarray, period: int = 5) -> None:
        self.points, self.period, self.asked = points, period, 0

    def __call__(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        self.asked += i.size
        chord = np.linalg.norm(self.points[i] - self.points[j], axis=1)
        return np.where((i + j) % self.period == 0, 3.0, 1.0) * chord


def _cloud(n: int = 600, seed: int = 0) -> np.ndarray:
    directions = np.random.default_rng(seed).normal(size=(n, 3))
    return directions / np.linalg.norm(directions, axis=1, keepdims=True) * (1.0, 0.6, 0.4)


def _lazy(points: np.ndarray) -> LazyVetoGraph:
    return LazyVetoGraph(pruned_knn_graph(points, K, RATIO, None), RATIO)


def _eager_rows(points, veto, sources, targets) -> np.ndarray:
    graph = pruned_knn_graph(points, K, RATIO, veto)
    return dijkstra(graph, directed=False, indices=sources)[:, targets]


@pytest.mark.parametrize(
    ("n_sources", "n_targets"),
    [(1, 1), (3, 5), (1, None), (4, None), (40, None), (None, 2)],  # None: every point
)
def test_lazy_rows_equal_the_eagerly_vetoed_graph(n_sources, n_targets) -> None:
    points = _cloud()
    n = points.shape[0]
    rng = np.random.default_rng(1)
    sources = np.arange(n) if n_sources is None else rng.choice(n, n_sources, replace=False)
    targets = np.arange(n) if n_targets is None else rng.choice(n, n_targets, replace=False)
    veto = CountingVeto(points)
    lazy = _lazy(points)
    rows = graph_rows(lazy, points, (sources, None), (targets, None), K, None, veto)
    assert veto.asked == lazy.judged  # each edge judged once
    np.testing.assert_allclose(rows, _eager_rows(points, veto, sources, targets), rtol=1e-12)


def test_many_sources_judge_every_edge_before_one_dijkstra() -> None:
    points = _cloud()
    veto = CountingVeto(points)
    lazy = _lazy(points)
    sources = np.arange(veto_graph.LAZY_SOURCES + 1)
    graph_rows(lazy, points, (sources, None), (np.arange(600), None), K, None, veto)
    assert lazy.judged == lazy._verdicts.size == veto.asked


def test_one_pair_judges_a_few_edges_and_later_queries_reuse_the_verdicts() -> None:
    points = _cloud(2000)
    veto = CountingVeto(points)
    lazy = _lazy(points)
    edges = lazy.graph.nnz
    query = (np.array([3]), None), (np.array([1500]), None)
    first = graph_rows(lazy, points, *query, K, None, veto)
    assert lazy.graph.nnz < edges  # the veto cut some edges of the paths
    assert 0 < veto.asked < 0.05 * edges  # the paths' edges, not the whole graph
    asked = veto.asked
    again = graph_rows(lazy, points, *query, K, None, veto)
    assert veto.asked == asked  # nothing left to judge on that path
    np.testing.assert_array_equal(again, first)
    np.testing.assert_allclose(first, _eager_rows(points, veto, [3], [1500]), rtol=1e-12)


def test_free_query_points_are_vetoed_like_nodes() -> None:
    points = _cloud()
    rng = np.random.default_rng(2)
    free = rng.normal(size=(3, 3)) * 0.3 + points[:3]
    veto = CountingVeto(points)
    lazy = _lazy(points)
    targets = np.arange(0, points.shape[0], 7)
    rows = graph_rows(lazy, points, (None, free), (targets, None), K, None, veto)
    # the reference: the same free points on the eagerly vetoed graph
    eager = pruned_knn_graph(points, K, RATIO, veto)
    expected = graph_rows(eager, points, (None, free), (targets, None), K)
    np.testing.assert_allclose(rows, expected, rtol=1e-12)


def test_after_max_rounds_every_edge_is_judged(monkeypatch) -> None:
    points = _cloud()
    monkeypatch.setattr(veto_graph, "MAX_ROUNDS", 1)
    monkeypatch.setattr("litege_core.learned.fusion.MAX_ROUNDS", 1)
    veto = CountingVeto(points, period=3)
    lazy = _lazy(points)
    rows = graph_rows(lazy, points, (np.array([0]), None), (np.arange(600), None), K, None, veto)
    assert lazy.judged == lazy._verdicts.size  # the first round cut edges: all were judged
    np.testing.assert_allclose(rows, _eager_rows(points, veto, [0], np.arange(600)), rtol=1e-12)


def test_path_edges_walks_paths_trees_or_gives_up() -> None:
    # a path 0 - 1 - 2 - 3 from source 0, and node 4 unreachable
    predecessors = np.array([[-9999, 0, 1, 2, -9999]])
    a, b = path_edges(predecessors, np.array([3, 4]), 5)
    assert sorted(zip(a.tolist(), b.tolist(), strict=True)) == [(0, 1), (1, 2), (2, 3)]
    a, b = path_edges(predecessors, np.array([1]), 5)
    assert list(zip(a.tolist(), b.tolist(), strict=True)) == [(0, 1)]
    # free nodes (5 and up) are left out
    a, b = path_edges(np.array([[-9999, 0, 1, 2, -9999, 3]]), np.array([5]), 5)
    assert sorted(zip(a.tolist(), b.tolist(), strict=True)) == [(0, 1), (1, 2), (2, 3)]
    far = np.arange(5).repeat(veto_graph.PATH_PAIRS // 5 + 1)
    a, b = path_edges(np.tile(predecessors, (2, 1)), far, 5)  # many pairs: the trees
    assert set(zip(a.tolist(), b.tolist(), strict=True)) == {(0, 1), (1, 2), (2, 3)}


def test_subtrees_below_cut_tree_edges_equal_the_walking_reference() -> None:
    points = _cloud(300)
    graph = _lazy(points).graph
    _, predecessors = dijkstra(graph, directed=False, indices=[0, 150], return_predecessors=True)
    rng = np.random.default_rng(4)
    coo = graph.tocoo()
    picked = rng.choice(coo.nnz, 40, replace=False)  # tree edges and others, either order
    a, b = coo.row[picked], coo.col[picked]
    a[::2], b[::2] = b[::2].copy(), a[::2].copy()
    below = subtrees_below(predecessors, a, b)
    np.testing.assert_array_equal(below, subtrees_below_reference(predecessors, a, b))
    assert 0 < below.sum() < 300
    # a path 0 - 1 - 2 - 3 and 0 - 4: cutting 1 - 2 leaves 2 and 3 below it
    path = np.array([[-9999, 0, 1, 2, 0]])
    below = subtrees_below(path, np.array([2]), np.array([1]))
    np.testing.assert_array_equal(below, [False, False, True, True, False])


def test_a_distance_field_rerouted_past_cut_edges_takes_two_rounds(monkeypatch) -> None:
    """A tree whose edges the veto cuts re-routes through edges judged in the same round
    (``judge_below_cuts``): the second Dijkstra round finds nothing left to judge."""
    from litege_core.engines import graph as engines_graph

    points = _cloud()
    veto = CountingVeto(points, period=3)
    lazy = _lazy(points)
    runs = []
    tree = engines_graph.dijkstra_tree

    def counted(*args, **kwargs):
        runs.append(1)
        return tree(*args, **kwargs)

    monkeypatch.setattr(engines_graph, "dijkstra_tree", counted)
    rows = graph_rows(lazy, points, (np.array([0]), None), (np.arange(600), None), K, None, veto)
    assert len(runs) == 2 and veto.asked == lazy.judged < lazy._verdicts.size
    np.testing.assert_allclose(rows, _eager_rows(points, veto, [0], np.arange(600)), rtol=1e-12)


def test_positions_find_edges_in_either_order() -> None:
    points = _cloud(50)
    lazy = _lazy(points)
    coo = lazy.graph.tocoo()
    picked = np.array([0, 5, 17])
    found = lazy.positions(coo.col[picked], coo.row[picked])  # reversed ends
    np.testing.assert_array_equal(found, picked)
    assert lazy.positions(np.array([0]), np.array([0])).size == 0  # no self edge
    assert lazy.nbytes > 0


def test_a_path_read_before_another_thread_cut_it_is_read_again() -> None:
    """``judge`` reports a cut edge among the positions even when another caller judged it: a
    path taken from an older snapshot of the graph is not final."""
    points = _cloud(100)
    veto = CountingVeto(points, period=2)
    lazy = _lazy(points)
    snapshot = lazy.graph
    coo = snapshot.tocoo()
    positions = lazy.positions(coo.row, coo.col)
    assert lazy.judge(positions, veto)  # this caller cuts some edges
    asked = veto.asked
    assert lazy.judge(positions, veto)  # a second caller on the old snapshot: still cut
    assert veto.asked == asked  # without judging anything again
    assert lazy.graph.nnz < snapshot.nnz


def test_the_predictors_veto_nothing_when_asked_about_no_edge(toy_predictor) -> None:
    from litege_core.shape import Shape

    predictor = toy_predictor
    state = predictor.register(Shape.from_arrays(_cloud(300)))
    empty = np.zeros(0, dtype=np.int64)
    assert predictor._pair_distances(state, empty, empty).shape == (0,)
