"""k-NN graph and edge-graph Dijkstra engines."""

import numpy as np
import pytest
import scipy.sparse as sp

from litege_core.engines import EdgeDijkstraEngine, KnnGraphEngine, compute_distances
from litege_core.engines import graph as graph_module
from litege_core.engines.graph import (
    CLUMPY_SHARE,
    arc_factors,
    arc_normals,
    edge_graph,
    graph_nodes,
    knn_graph,
    knn_neighbours,
    mesh_ring_graph,
    mutual_knn_graph,
    mutual_knn_graph_reference,
    run_minima,
)
from litege_core.errors import InputError
from litege_core.shape import Shape


def test_knn_close_to_great_circle_and_above_euclidean(sphere_cloud):
    # 2000 uniform points on the unit sphere, k=8: measured mean relative error 6.1 %
    # (chord zig-zags over-estimate), k=16: 1.8 %.
    sources = np.arange(0, sphere_cloud.n_points, 100)
    points = sphere_cloud.vertices
    analytic = np.arccos(np.clip(points[sources] @ points.T, -1.0, 1.0))
    euclidean = compute_distances(sphere_cloud, sources, "euclidean").distances
    for k, bound in [(8, 0.08), (16, 0.025)]:
        result = KnnGraphEngine(sphere_cloud, k=k).distances(sources)
        assert result.params["k"] == k
        d = result.distances
        assert np.isfinite(d).all()
        assert np.all(d >= euclidean * (1 - 1e-12))
        mask = analytic > 1e-6
        assert (np.abs(d - analytic)[mask] / analytic[mask]).mean() < bound


def test_knn_disconnected_cloud_gives_inf():
    rng = np.random.default_rng(3)
    blob = rng.standard_normal((50, 3))
    cloud = Shape.from_arrays(np.vstack([blob, blob + 100.0]))
    rows = compute_distances(cloud, [0, 60], "knn_graph", k=5).distances
    assert np.isfinite(rows[0, :50]).all() and np.isinf(rows[0, 50:]).all()
    assert np.isinf(rows[1, :50]).all() and np.isfinite(rows[1, 50:]).all()


def test_knn_coincident_points_are_zero_apart():
    points = np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    rows = compute_distances(Shape.from_arrays(points), [0], "knn_graph", k=1).distances
    np.testing.assert_allclose(rows[0], [0.0, 0.0, 1.0, 2.0])


def test_knn_k_is_clamped_on_tiny_clouds():
    points = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    rows = compute_distances(Shape.from_arrays(points), [0], "knn_graph", k=50).distances
    np.testing.assert_allclose(rows[0], [0.0, 1.0, 1.0])


@pytest.mark.parametrize("k", [0, -3, 2.5, True, "8"])
def test_bad_k(sphere_cloud, k):
    with pytest.raises(InputError, match="k must be"):
        KnnGraphEngine(sphere_cloud, k=k)


def test_knn_graph_is_symmetric_union():
    points = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0], [10, 0, 0]], float)
    graph = knn_graph(points, k=1)
    dense = graph.toarray()
    assert np.all(np.tril(dense) == 0)  # stored once, upper triangle
    # 0-1 (mutual), 2 -> 1, 3 -> 2
    assert {tuple(e) for e in np.argwhere(dense > 0)} == {(0, 1), (1, 2), (2, 3)}


@pytest.mark.parametrize("k", [1, 4, 9])
def test_mutual_knn_graph_equals_the_brute_force_reference(k):
    rng = np.random.default_rng(k)
    points = rng.normal(size=(120, 3)) * [1.0, 0.3, 2.0]
    points[7] = points[3]  # coincident points: a zero-length edge, kept
    fast, slow = mutual_knn_graph(points, k), mutual_knn_graph_reference(points, k)
    assert (fast != slow).nnz == 0 and fast.nnz > 0
    np.testing.assert_allclose(fast.data, slow.data, rtol=1e-12)
    # a subgraph of the symmetric k-NN graph of the same lists, with the same edge lengths
    union = knn_graph(points, k, knn_neighbours(points, k))
    assert (fast.astype(bool) > union.astype(bool)).nnz == 0
    np.testing.assert_allclose(union[fast.astype(bool)], fast[fast.astype(bool)])
    # known neighbours give the same graph
    assert (mutual_knn_graph(points, k, knn_neighbours(points, k + 3)) != fast).nnz == 0


@pytest.mark.parametrize("k", [4, 6, 8])
def test_mutual_knn_graph_reads_the_lists_at_ties(k, monkeypatch):
    """On a lattice many neighbours sit at the k-th distance: an edge is kept exactly when
    each end is in the other's list (the lists the graph was given), also with small blocks."""
    from litege_core.engines import graph as graph_module

    monkeypatch.setattr(graph_module, "MUTUAL_BLOCK", 7)
    axis = np.arange(6.0)
    points = np.stack(np.meshgrid(axis, axis, axis[:3]), axis=-1).reshape(-1, 3)
    lengths, nearest = knn_neighbours(points, k)
    lists = [set(row.tolist()) for row in nearest]
    expected = {(i, j) for i in range(len(points)) for j in lists[i] if i < j and i in lists[j]}
    graph = mutual_knn_graph(points, k, (lengths, nearest)).tocoo()
    assert {(int(i), int(j)) for i, j in zip(graph.row, graph.col, strict=True)} == expected
    assert np.all(np.diff(graph.tocsr().indices[: graph.tocsr().indptr[1]]) > 0)  # rows sorted
    np.testing.assert_allclose(
        graph.data, np.linalg.norm(points[graph.row] - points[graph.col], axis=1)
    )


def test_mutual_knn_graph_leaves_a_thin_part_alone():
    # a dense sheet and, above it, a sparse row of points: each row point's nearest are sheet
    # points, which have nearer sheet neighbours, so no chord joins the row to the sheet
    xs, ys = np.meshgrid(np.linspace(0, 1, 20), np.linspace(0, 1, 20))
    sheet = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(400)])
    row = np.column_stack([np.linspace(0.2, 0.8, 4), np.full(4, 0.5), np.full(4, 0.1)])
    points = np.vstack([sheet, row])

    def across(graph) -> int:
        coo = graph.tocoo()
        return int(np.count_nonzero((coo.row < 400) != (coo.col < 400)))

    assert across(knn_graph(points, 6)) > 0 and across(mutual_knn_graph(points, 6)) == 0


def test_edge_graph_keeps_shortest_repeat_and_drops_loops():
    edges = np.array([[1, 0], [0, 1], [2, 2], [1, 2]])
    graph = edge_graph(3, edges, np.array([3.0, 2.0, 1.0, 0.0]))
    assert isinstance(graph, sp.csr_array)
    assert graph.nnz == 2
    assert graph[0, 1] == 2.0 and graph[1, 2] == 0.0


@pytest.mark.parametrize("longest", [1, 2, 5, graph_module.RUN_LOOP_MAX + 3])
def test_run_minima_equal_reduceat(longest):
    rng = np.random.default_rng(longest)
    sizes = rng.integers(1, longest + 1, 300)
    sizes[7] = longest
    values = rng.normal(size=int(sizes.sum()))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    np.testing.assert_array_equal(run_minima(values, starts), np.minimum.reduceat(values, starts))


def test_edge_graph_equals_a_pairwise_reference():
    rng = np.random.default_rng(5)
    n = 40
    edges = rng.integers(0, n, (600, 2))  # repeats in both orders, self-loops
    weights = rng.integers(0, 5, 600).astype(float)  # ties and zero lengths
    lightest: dict[tuple[int, int], float] = {}
    for (i, j), w in zip(edges.tolist(), weights.tolist(), strict=True):
        if i != j:
            key = (min(i, j), max(i, j))
            lightest[key] = min(w, lightest.get(key, np.inf))
    graph = edge_graph(n, edges, weights)
    assert graph.has_sorted_indices
    coo = graph.tocoo()
    pairs = zip(coo.row.tolist(), coo.col.tolist(), strict=True)
    found = dict(zip(pairs, coo.data.tolist(), strict=True))
    assert found == lightest  # explicit zeros kept


def test_edge_dijkstra_on_a_square_and_components(two_spheres):
    square = Shape.from_arrays(
        np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float), [[0, 1, 3], [0, 3, 2]]
    )
    rows = EdgeDijkstraEngine(square).distances([1]).distances
    np.testing.assert_allclose(rows[0], [1.0, 0.0, 2.0, 1.0])
    rows = compute_distances(two_spheres, [0], "edge_dijkstra").distances
    assert np.isinf(rows[0, 162:]).all() and np.isfinite(rows[0, :162]).all()


def test_a_cloud_sent_twice_gets_the_clouds_distances(sphere_cloud):
    """Repeated positions count once: copies do not fill each other's neighbour lists."""
    points = np.asarray(sphere_cloud.vertices)[:400]
    twice = Shape.from_arrays(np.concatenate([points, points]))
    once = compute_distances(Shape.from_arrays(points), [0, 7], "knn_graph", k=6).distances
    rows = compute_distances(twice, [0, 407], "knn_graph", k=6).distances
    np.testing.assert_allclose(rows, np.tile(once, 2), rtol=1e-12)
    assert np.isfinite(rows).all()


def test_graph_nodes_merge_twins_only_in_a_cloud_of_twins(blob) -> None:
    points = np.asarray(blob(3).vertices)
    n = points.shape[0]
    (first, index), _ = graph_nodes(points, 24)  # an even cloud: every point a node
    np.testing.assert_array_equal(first, np.arange(n))
    np.testing.assert_array_equal(index, np.arange(n))
    shift = 1e-5 * np.random.default_rng(1).standard_normal(points.shape)
    both = np.concatenate([points, points + shift, points[:5]])  # twins and 5 exact copies
    (first, index), (lengths, _) = graph_nodes(both, 24)
    np.testing.assert_array_equal(index, np.arange(n))
    np.testing.assert_array_equal(first, np.r_[np.arange(n), np.arange(n), np.arange(5)])
    assert lengths.shape == (n, 25)
    some = n // 10  # a tenth twinned: a sixth of the cloud has a twin, not a cloud of twins
    few = np.concatenate([points, points[:some] + shift[:some]])
    assert 2 * some < CLUMPY_SHARE * few.shape[0]
    (first, index), _ = graph_nodes(few, 24)
    assert index.size == few.shape[0]


def test_a_cloud_with_moved_twins_gets_the_clouds_knn_distances(sphere_cloud):
    """The k-NN graph engine reads twins as the fusion does: each joins its first by a
    straight edge, the graph is the first copies'."""
    points = np.asarray(sphere_cloud.vertices)[:400]
    shift = 1e-6 * np.random.default_rng(2).standard_normal(points.shape)
    twins = Shape.from_arrays(np.concatenate([points, points + shift]))
    once = compute_distances(Shape.from_arrays(points), [0, 7], "knn_graph", k=6).distances
    rows = compute_distances(twins, [0, 7], "knn_graph", k=6).distances
    np.testing.assert_allclose(rows[:, :400], once, rtol=1e-12)
    joins = np.linalg.norm(shift, axis=1)
    np.testing.assert_allclose(rows[:, 400:], once + joins, rtol=1e-12, atol=1e-15)


def test_arc_factors_follow_the_circle_through_both_ends():
    up, side = np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]])
    np.testing.assert_allclose(arc_factors(up, up), 1.0)
    np.testing.assert_allclose(arc_factors(up, side), (np.pi / 4) / np.sin(np.pi / 4))
    np.testing.assert_allclose(arc_factors(up, -up), np.pi / 2)  # across a thin part
    np.testing.assert_allclose(arc_factors(up, np.zeros((1, 3))), 1.0)  # no normal: a chord


def _slow_arc_graph(points: np.ndarray, faces: np.ndarray, plain: sp.csr_array) -> np.ndarray:
    """The reference: each chord of ``plain`` that is not a mesh edge times its arc factor,
    the vertex normals summed face by face."""
    normals = np.zeros_like(points)
    edges = set()
    for a, b, c in faces.tolist():
        normal = np.cross(points[b] - points[a], points[c] - points[a])
        for vertex in (a, b, c):
            normals[vertex] += normal
        edges |= {(min(a, b), max(a, b)), (min(b, c), max(b, c)), (min(a, c), max(a, c))}
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    dense = plain.toarray()
    for i, j in zip(*np.nonzero(dense), strict=True):
        if (i, j) not in edges:
            angle = np.arccos(np.clip(normals[i] @ normals[j], -1.0, 1.0))
            dense[i, j] *= (angle / 2) / np.sin(angle / 2)
    return dense


def test_ring_graph_arcs_lengthen_the_chords_of_a_wound_mesh_only():
    """With ``arcs``, the chords that are not edges span their arcs (a slow reference), the
    edges keep their lengths, and the distance across a sphere comes nearer the great circle's;
    a face wound the other way gets the same normals (turned over first)."""
    import trimesh
    from scipy.sparse.csgraph import dijkstra

    sphere = trimesh.creation.icosphere(subdivisions=2)
    points, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces, dtype=np.int64)
    normals = arc_normals(points, faces)
    assert normals is not None
    plain = mesh_ring_graph(points, faces, 2)
    arcs = mesh_ring_graph(points, faces, 2, normals=normals)
    np.testing.assert_array_equal(arcs.indices, plain.indices)
    np.testing.assert_allclose(arcs.toarray(), _slow_arc_graph(points, faces, plain), rtol=1e-12)
    assert (arcs.data > plain.data * (1 + 1e-6)).any()
    far = int(np.argmin(points @ points[0]))  # the antipode of vertex 0, π away on the sphere
    along = [dijkstra(g, directed=False, indices=0)[far] for g in (plain, arcs)]
    assert abs(along[1] - np.pi) < 0.5 * abs(along[0] - np.pi)
    flipped = faces.copy()
    flipped[3] = flipped[3, ::-1]
    # a face wound against its neighbours is turned over first: the same normals
    np.testing.assert_allclose(arc_normals(points, flipped), normals, atol=1e-12)
