"""Graph fusion (issue 14): the network-pruned kNN graph of a cloud and the edge graph of a mesh,
graph rows for indexed and free points, the blend, and ``Predictor(bundle, fusion=...)`` checked
against a graph built independently (the calibration itself: ``test_fusion_calibration.py``)."""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from litege_core.engines.graph import arc_normals, knn_graph, mesh_ring_graph
from litege_core.errors import ArtifactError, InputError
from litege_core.learned import Predictor, load_bundle
from litege_core.learned.fusion import MESH_RINGS, fuse, graph_rows, pruned_knn_graph
from litege_core.learned.fusion_calibration import (
    DEFAULT_FUSION,
    FusionCalibration,
    resolve_fusion,
    save_fusion,
)
from litege_core.learned.paths import EDGE_FLIP, KNN_GRAPH, MESH_EDGES, SurfaceRouter
from litege_core.shape import Shape
from tests.litege_core.learned.conftest import toy_calibration as _calibration

# ------------------------------------------------------------------ graph and blend


def _hairpin(n_per_arm: int = 60, gap: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Points along two parallel arms ``gap`` apart joined at one end (a hairpin) and their
    arc-length coordinate: the arms touch in space but are 2 apart along the curve."""
    t = np.linspace(0.0, 1.0, n_per_arm)
    arm_a = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    arm_b = np.column_stack([t, np.full_like(t, gap), np.zeros_like(t)])
    points = np.concatenate([arm_a, arm_b])
    arc = np.concatenate([1.0 - t, 1.0 + gap + t])  # both arms meet through the bend at x = 0
    return points, arc


def test_pruning_cuts_the_shortcut_between_touching_parts() -> None:
    points, arc = _hairpin()
    n = points.shape[0]

    def truth(i, j):
        return np.abs(arc[i] - arc[j])

    plain = pruned_knn_graph(points, 4, 1.6, None)
    pruned = pruned_knn_graph(points, 4, 1.6, truth)
    assert pruned.nnz < plain.nnz
    tips = (n // 2 - 1, n - 1)  # the free ends of both arms, 0.05 apart in space
    assert dijkstra(plain, directed=False, indices=tips[0])[tips[1]] < 0.1
    # without the shortcut the path runs around the bend (the bend itself is one kNN edge)
    assert dijkstra(pruned, directed=False, indices=tips[0])[tips[1]] > 1.9
    # no pruning equals the plain symmetric kNN graph
    assert (plain != knn_graph(points, 4)).nnz == 0


def test_route_trees_are_the_fully_vetoed_graphs_routes() -> None:
    from litege_core.engines.graph import dijkstra_tree
    from litege_core.learned.fusion import route_trees
    from litege_core.learned.veto_graph import LazyVetoGraph

    points, arc = _hairpin()
    n = points.shape[0]

    def truth(i, j):
        return np.abs(arc[i] - arc[j])

    def chain(predecessors, row, node):
        out = [int(node)]
        while predecessors[row, out[-1]] >= 0:
            out.append(int(predecessors[row, out[-1]]))
        return out

    base = pruned_knn_graph(points, 4, 1.6, None)
    lazy = LazyVetoGraph(base, 1.6)
    roots, far = np.array([n // 2 - 1]), np.array([n - 1, n - 10])  # one tip to the other arm
    lazy_trees = route_trees(lazy, roots, far, truth)
    eager = dijkstra_tree(pruned_knn_graph(points, 4, 1.6, truth), roots)[1]
    for node in far:
        route = chain(lazy_trees, 0, node)
        assert route == chain(eager, 0, node) and route[-1] == roots[0]
        assert len(route) > n // 2  # around the bend, not across the 0.05 gap
    assert 0 < lazy.judged < base.nnz  # the routes' edges, not every edge


def _sheets(gap: float = 0.04, spacing: float = 0.05) -> np.ndarray:
    """Two parallel square grids ``gap`` apart (closer than their own spacing): kNN joins each
    point to the one across and to the diagonal ones across (chords 51° off the sheets)."""
    t = np.arange(0.0, 1.0 + 1e-9, spacing)
    x, y = (a.reshape(-1) for a in np.meshgrid(t, t))
    sheet = np.column_stack([x, y, np.zeros_like(x)])
    return np.concatenate([sheet, sheet + np.array([0.0, 0.0, gap])])


def test_the_normal_limit_cuts_the_chords_between_two_sheets() -> None:
    from litege_core.learned.cloud_surface import local_surface

    points = _sheets()
    n = points.shape[0] // 2
    _, normals = local_surface(points)

    def across(graph) -> np.ndarray:
        coo = graph.tocoo()
        return (coo.row < n) != (coo.col < n)

    plain = pruned_knn_graph(points, 8, 1.6, None)
    cut = pruned_knn_graph(points, 8, 1.6, None, normals=normals, normal_cos=0.5)
    assert across(plain).sum() > n  # each point joins the one across and diagonal ones
    # a few diagonal chords at the grid's corners, whose normals tilt, survive; no straight one
    assert across(cut).sum() < 0.02 * across(plain).sum()
    coo = cut.tocoo()
    assert not np.any(np.abs(coo.row - coo.col) == n)
    # every edge within a sheet is kept (its chord is perpendicular to the normal)
    assert cut.nnz - across(cut).sum() == plain.nnz - across(plain).sum()
    # without normals, or with the limit 1, the graph is the plain one
    same = pruned_knn_graph(points, 8, 1.6, None, normals=normals, normal_cos=1.0)
    assert (same != plain).nnz == 0


def test_graph_rows_of_free_points_on_nodes_equal_the_indexed_rows() -> None:
    rng = np.random.default_rng(0)
    points = rng.normal(size=(300, 3))
    graph = pruned_knn_graph(points, 8, 1.6, None)
    src, dst = np.array([3, 40, 3]), np.arange(0, 300, 7)
    indexed = graph_rows(graph, points, (src, points[src]), (dst, points[dst]), 8)
    free = graph_rows(graph, points, (None, points[src]), (None, points[dst]), 8)
    np.testing.assert_allclose(free, indexed, atol=1e-9)
    reference = dijkstra(graph, directed=False, indices=src)[:, dst]
    np.testing.assert_allclose(indexed, reference)
    # Dijkstra runs from the smaller side: the transpose is the same table
    np.testing.assert_allclose(
        graph_rows(graph, points, (dst, points[dst]), (src, points[src]), 8), reference.T
    )


def test_a_free_point_joins_through_its_nearest_chords() -> None:
    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    graph = pruned_knn_graph(points, 1, 1.6, None)
    query = np.array([[0.5, 0.5, 0.0]])
    rows = graph_rows(graph, points, (None, query), (np.array([2]), points[[2]]), 2)
    assert rows[0, 0] == pytest.approx(np.sqrt(0.5) + 1.0)


def _reference_free_rows(graph, points, src_points, dst_points, k):
    """Slow reference, one pair at a time: the shortest chord from the source to one of its k
    nearest points, graph path, chord from one of the target's k nearest points."""
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    src_chords, src_nearest = tree.query(src_points, k=k)
    dst_chords, dst_nearest = tree.query(dst_points, k=k)
    out = np.empty((len(src_points), len(dst_points)))
    for i in range(len(src_points)):
        inner = dijkstra(graph, directed=False, indices=src_nearest[i])  # (k, n)
        for j in range(len(dst_points)):
            through = inner[:, dst_nearest[j]] + dst_chords[j][None, :]
            out[i, j] = np.min(src_chords[i][:, None] + through)
    return out


def test_free_points_join_the_cached_graph_as_the_pairwise_reference_does() -> None:
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(3)
    points = rng.normal(size=(400, 3))
    graph = pruned_knn_graph(points, 8, 1.6, None)
    src_points = np.vstack([rng.normal(size=(3, 3)), points[[7]]])  # one exactly on a node
    dst_points = rng.normal(size=(25, 3))
    reference = _reference_free_rows(graph, points, src_points, dst_points, 8)
    rows = graph_rows(graph, points, (None, src_points), (None, dst_points), 8)
    np.testing.assert_allclose(rows, reference, rtol=1e-12)
    kept_tree = graph_rows(
        graph, points, (None, src_points), (None, dst_points), 8, tree=cKDTree(points)
    )
    np.testing.assert_array_equal(kept_tree, rows)
    assert graph.shape == (400, 400)  # the cached graph itself is left as it was
    # free sources against indexed targets (and the transpose): the same reference
    dst = np.arange(0, 400, 9)
    indexed = graph_rows(graph, points, (None, src_points), (dst, points[dst]), 8)
    np.testing.assert_allclose(
        indexed, _reference_free_rows(graph, points, src_points, points[dst], 8)
    )
    np.testing.assert_allclose(
        graph_rows(graph, points, (dst, points[dst]), (None, src_points), 8), indexed.T
    )


def test_a_row_does_not_depend_on_the_other_query_points() -> None:
    """A free query point is never a step of another point's path: a request split into blocks
    gets the answers of the whole request."""
    from litege_core.engines.graph import edge_graph

    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0]])
    graph = edge_graph(3, np.array([[0, 1]]), np.array([1.0]))  # 0 — 1 only: 2 is cut off
    bridge = np.array([[2.0, 0.0, 0.0]])  # a free point between nodes 1 and 2
    sources = np.vstack([points[[0]] + [0.0, 1e-3, 0.0], bridge])
    whole = graph_rows(graph, points, (None, sources), (np.array([2]), points[[2]]), 2)
    alone = graph_rows(graph, points, (None, sources[:1]), (np.array([2]), points[[2]]), 2)
    assert np.isinf(alone[0, 0]) and np.isinf(whole[0, 0])  # not through the bridge point
    assert whole[1, 0] == pytest.approx(1.0)  # the bridge's own chord to node 2

    rng = np.random.default_rng(5)
    cloud = rng.normal(size=(300, 3))
    cloud_graph = pruned_knn_graph(cloud, 6, 1.6, None)
    free_src, free_dst = rng.normal(size=(10, 3)), rng.normal(size=(40, 3))
    full = graph_rows(cloud_graph, cloud, (None, free_src), (None, free_dst), 6)
    blocks = [
        graph_rows(cloud_graph, cloud, (None, free_src[i : i + 3]), (None, free_dst), 6)
        for i in range(0, 10, 3)
    ]
    np.testing.assert_array_equal(np.vstack(blocks), full)


def test_fuse_blends_with_the_gate_and_keeps_the_network_where_the_graph_fails() -> None:
    network = np.array([[0.0, 10.0, 20.0]])
    graph = np.array([[0.0, 12.0, np.inf]])
    only_graph = _calibration(gate=(-60.0, 0.0, 0.0, 0.0), bias=(1.2, 1.2, 1.2))
    only_network = _calibration(gate=(60.0, 0.0, 0.0, 0.0))
    np.testing.assert_allclose(fuse(network, graph, only_graph, 0.0, 1000, 0.1), [[0, 10, 20]])
    np.testing.assert_allclose(fuse(network, graph, only_network, 5.0, 300, 0.1), network)
    half = _calibration(gate=(0.0, 0.0, 0.0, 0.0), bias=(1.0, 1.0, 1.0))
    np.testing.assert_allclose(fuse(network, graph, half, 1.0, 1000, 0.1), [[0, 11, 20]])
    # a mesh: the graph alone (the cloud gate trusts only the network here), the network only
    # where the graph fails
    mesh = _calibration(gate=(60.0, 0.0, 0.0, 0.0), mesh_bias=1.2)
    np.testing.assert_allclose(fuse(network, graph, mesh, 0.0, 1000, 0.1, mesh=True), [[0, 10, 20]])


# ------------------------------------------------------------------ through the predictor


@pytest.fixture(scope="module")
def bundle_dir(toy_bundle_dir_with_ood):
    return toy_bundle_dir_with_ood


def _graph_only(bundle_hash: str, prune_ratio: float = 1e9) -> FusionCalibration:
    return _calibration(bundle_hash, gate=(-60.0, 0.0, 0.0, 0.0), prune_ratio=prune_ratio)


def _graph_only_predictor(bundle_dir) -> tuple[Predictor, FusionCalibration]:
    """A predictor of the toy bundle whose answers are its graph's rows, and its calibration."""
    bundle = load_bundle(bundle_dir)
    calibration = _graph_only(bundle.content_hash)
    return Predictor(bundle, fusion=calibration), calibration


def _cloud(shape: Shape) -> Shape:
    """The vertices of a mesh as a point cloud (its fusion graph is the pruned kNN graph)."""
    return Shape.from_arrays(np.asarray(shape.vertices))


def test_graph_only_fusion_equals_an_independent_dijkstra(bundle_dir, blob) -> None:
    predictor, calibration = _graph_only_predictor(bundle_dir)
    assert "fusion='graph'" in repr(predictor)
    state = predictor.register(_cloud(blob(3)))
    before = state.nbytes
    sources = np.array([0, 17, 200])
    rows = predictor.distances(state, sources)
    assert state.nbytes > before  # the cached graph counts
    points = state.canonical_points
    expected = dijkstra(knn_graph(points, 8), directed=False, indices=sources)
    expected /= calibration.graph_bias(state.n_points) * state.transform.scale
    np.testing.assert_allclose(rows, expected, rtol=1e-5, atol=1e-5)
    assert np.all(rows[np.arange(3), sources] == 0.0)


def test_graph_only_fusion_reads_the_mutual_knn_graph(bundle_dir, blob) -> None:
    from litege_core.engines.graph import mutual_knn_graph

    bundle = load_bundle(bundle_dir)
    calibration = dataclasses.replace(_graph_only(bundle.content_hash), mutual_k=12)
    predictor = Predictor(bundle, fusion=calibration)
    state = predictor.register(_cloud(blob(3)))
    sources = np.array([0, 17, 200])
    rows = predictor.distances(state, sources)
    points = state.canonical_points
    graph = mutual_knn_graph(points, 12)
    assert graph.nnz != knn_graph(points, 8).nnz
    expected = dijkstra(graph, directed=False, indices=sources)
    expected /= calibration.graph_bias(state.n_points) * state.transform.scale
    finite = np.isfinite(expected)
    np.testing.assert_allclose(rows[finite], expected[finite], rtol=1e-5, atol=1e-5)
    assert np.isfinite(rows).all()  # pairs the graph cannot join keep the network's value


def test_graph_only_fusion_applies_the_normal_limit(bundle_dir, blob) -> None:
    from litege_core.learned.cloud_surface import local_surface

    bundle = load_bundle(bundle_dir)
    calibration = _graph_only(bundle.content_hash, prune_ratio=1e9)
    calibration = dataclasses.replace(calibration, normal_cos=(0.3, 0.3, 0.3))
    predictor = Predictor(bundle, fusion=calibration)
    state = predictor.register(_cloud(blob(3)))
    sources = np.array([0, 17, 200])
    rows = predictor.distances(state, sources)
    points = state.canonical_points
    graph = pruned_knn_graph(points, 8, 1e9, None, normals=local_surface(points)[1], normal_cos=0.3)
    assert graph.nnz < knn_graph(points, 8).nnz  # the limit cuts some chords of the blob
    expected = dijkstra(graph, directed=False, indices=sources)
    expected /= calibration.graph_bias(state.n_points) * state.transform.scale
    finite = np.isfinite(expected)
    np.testing.assert_allclose(rows[finite], expected[finite], rtol=1e-5, atol=1e-5)


def test_graph_only_fusion_applies_the_learned_shortcut_cut(
    bundle_dir, blob, shipped_toy_scorer
) -> None:
    from litege_core.engines.graph import knn_neighbours
    from litege_core.learned.cloud_surface import local_surface
    from litege_core.learned.shortcuts import cut_shortcuts, load_shortcut_scorer

    bundle = load_bundle(bundle_dir)
    plain = _graph_only(bundle.content_hash)
    cutting = dataclasses.replace(
        plain, shortcut_cut=(0.5, 0.5, 0.5), shortcut_scorer=shipped_toy_scorer
    )
    shape, sources = _cloud(blob(3)), np.array([0, 17, 200])
    state = Predictor(bundle, fusion=cutting).register(shape)
    rows = Predictor(bundle, fusion=cutting).distances(state, sources)
    points = state.canonical_points
    neighbours = knn_neighbours(points, 8)
    flatness, normals = local_surface(points)
    whole = knn_graph(points, 8, neighbours)
    graph = cut_shortcuts(whole, points, neighbours, normals, flatness, 0.5, load_shortcut_scorer())
    assert 0 < graph.nnz < whole.nnz  # the toy scorer cuts the longest chords
    expected = dijkstra(graph, directed=False, indices=sources)
    expected /= cutting.graph_bias(state.n_points) * state.transform.scale
    finite = np.isfinite(expected)
    np.testing.assert_allclose(rows[finite], expected[finite], rtol=1e-5, atol=1e-5)
    uncut = Predictor(bundle, fusion=plain).distances(state, sources)
    assert np.all(rows[finite] >= uncut[finite] - 1e-6) and np.any(rows > uncut + 1e-4)
    # above its roughness limit a cloud is not cut; a cut fitted with another scorer is refused
    smooth_only = dataclasses.replace(cutting, shortcut_max_roughness=1e-6)
    np.testing.assert_array_equal(
        Predictor(bundle, fusion=smooth_only).distances(state, sources), uncut
    )
    foreign = dataclasses.replace(cutting, shortcut_scorer="0" * 64)
    with pytest.raises(InputError, match="fit the fusion again"):
        Predictor(bundle, fusion=foreign).distances(state, sources)


def test_fusion_sits_between_the_network_and_the_graph(bundle_dir, blob) -> None:
    bundle = load_bundle(bundle_dir)
    half = _calibration(
        bundle.content_hash, gate=(0.0, 0.0, 0.0, 0.0), bias=(1.0, 1.0, 1.0), prune_ratio=1e9
    )
    network, graph, fused = (
        Predictor(bundle, fusion=fusion)
        for fusion in ("none", _graph_only(bundle.content_hash), half)
    )
    shape = _cloud(blob(4))
    sources = np.array([5, 60])
    n_points = network.register(shape).n_points
    rows = {
        name: p.distances(p.register(shape), sources)
        for name, p in (("network", network), ("graph", graph), ("fused", fused))
    }
    # bias 1 and w = 1/2 for every shape: the plain average of network and graph
    assert np.all(np.isfinite(rows["graph"]))
    assert np.abs(rows["graph"] - rows["network"]).max() > 0.1 * rows["network"].max()
    mean = 0.5 * (rows["network"] + rows["graph"] * graph.fusion.graph_bias(n_points))
    np.testing.assert_allclose(rows["fused"], mean, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("mutual_k", [0, 12])
def test_a_cloud_sent_twice_gets_the_clouds_fused_distances(bundle_dir, blob, mutual_k) -> None:
    """Repeated positions count once in the fusion: its graph (copies joined to their first
    copy by zero edges, not filling each other's neighbour lists), its roughness and the point
    count of its gate and bias. Before, a TOSCA cloud sent twice went from 0.9 to 4.7 error."""
    bundle = load_bundle(bundle_dir)
    calibration = _calibration(  # no veto: the toy network would cut every edge
        bundle.content_hash, prune_ratio=1e9, gate=(0.0, 0.0, -2.0, 0.0), mutual_k=mutual_k
    )
    predictor = Predictor(bundle, fusion=calibration)
    points = np.asarray(blob(3).vertices)
    n = points.shape[0]
    once = predictor.distances(predictor.register(Shape.from_arrays(points)), [0, 17, 200])
    state = predictor.register(Shape.from_arrays(np.concatenate([points, points])))
    twice = predictor.distances(state, [0, n + 17, 200])
    np.testing.assert_allclose(twice, np.tile(once, 2), rtol=1e-5, atol=1e-6)


def test_a_cloud_merged_with_a_moved_copy_keeps_the_clouds_graph(bundle_dir, blob) -> None:
    """Twins (a scan merged with a slightly moved copy of itself) count once in the graph: the
    graph is the first copies' k-NN graph, and each twin joins its first by a straight edge.
    Before, twins filled each other's neighbour lists (a TOSCA cat at 2000 points: fused 0.9 →
    4.1 with twins 0.001 apart at unit area)."""
    predictor, calibration = _graph_only_predictor(bundle_dir)
    points = np.asarray(blob(3).vertices)
    n = points.shape[0]
    shift = 1e-4 * np.random.default_rng(0).standard_normal(points.shape)
    state = predictor.register(Shape.from_arrays(np.concatenate([points, points + shift])))
    sources = np.array([0, 17, 200])
    rows = predictor.distances(state, sources)
    canonical = state.canonical_points
    expected = dijkstra(knn_graph(canonical[:n], 8), directed=False, indices=sources)
    expected /= calibration.graph_bias(n) * state.transform.scale  # n nodes: the bias of n
    np.testing.assert_allclose(rows[:, :n], expected, rtol=1e-5, atol=1e-6)
    joins = np.linalg.norm(canonical[n:] - canonical[:n], axis=1)
    joins /= calibration.graph_bias(n) * state.transform.scale
    np.testing.assert_allclose(rows[:, n:], expected + joins, rtol=1e-5, atol=1e-6)


def _reference_ring_graph(points: np.ndarray, faces: np.ndarray, rings: int):
    """Slow reference of :func:`mesh_ring_graph`: a breadth-first search from every vertex."""
    from litege_core.engines.graph import edge_graph

    neighbours: dict[int, set[int]] = {i: set() for i in range(len(points))}
    for a, b, c in faces.tolist():
        neighbours[a] |= {b, c}
        neighbours[b] |= {a, c}
        neighbours[c] |= {a, b}
    pairs = []
    for start in range(len(points)):
        seen, frontier = {start}, {start}
        for _ in range(rings):
            frontier = {j for i in frontier for j in neighbours[i]} - seen
            seen |= frontier
        pairs += [(start, j) for j in seen if j > start]
    pairs = np.asarray(pairs)
    lengths = np.linalg.norm(points[pairs[:, 0]] - points[pairs[:, 1]], axis=1)
    return edge_graph(len(points), pairs, lengths)


@pytest.mark.parametrize("rings", [1, 2, 3])
def test_the_mesh_ring_graph_equals_a_breadth_first_reference(blob, rings) -> None:
    shape = blob(2, 2)
    points, faces = np.asarray(shape.vertices, np.float64), np.asarray(shape.faces)
    fast, slow = mesh_ring_graph(points, faces, rings), _reference_ring_graph(points, faces, rings)
    assert fast.nnz == slow.nnz
    np.testing.assert_allclose(fast.toarray(), slow.toarray(), rtol=1e-12)


def test_a_mesh_stored_as_a_triangle_soup_gets_the_welded_mesh_distances(blob) -> None:
    """Every corner its own vertex (a soup, or an OBJ split along seams): the ring graph joins
    the copies of a position by chords of length 0, so its Dijkstra equals the welded mesh's
    at every copy; the reference's BFS on the soup's own faces reaches one triangle only."""
    from scipy.sparse.csgraph import dijkstra

    from litege_core.sampling import first_copies

    shape = blob(2, 2)
    points, faces = np.asarray(shape.vertices, np.float64), np.asarray(shape.faces)
    soup_points = points[faces.reshape(-1)]
    soup_faces = np.arange(soup_points.shape[0]).reshape(-1, 3)
    np.testing.assert_array_equal(
        soup_points[first_copies(soup_points)], soup_points
    )  # a copy is at its first copy's position
    assert np.unique(first_copies(soup_points)).size == points.shape[0]
    corner = faces.reshape(-1)  # soup vertex → welded vertex
    welded = dijkstra(mesh_ring_graph(points, faces, 2), directed=False, indices=corner[[0, 9]])
    soup = dijkstra(mesh_ring_graph(soup_points, soup_faces, 2), directed=False, indices=[0, 9])
    np.testing.assert_allclose(soup, welded[:, corner], atol=1e-12)
    lonely = dijkstra(_reference_ring_graph(soup_points, soup_faces, 2), directed=False, indices=0)
    assert np.isinf(lonely).sum() == soup_points.shape[0] - 3
    # two closed surfaces touching at one vertex (a coincident pair on no boundary): not welded
    other = points - points[5] + points[0]  # its vertex 5 lies on the first one's vertex 0
    touching = mesh_ring_graph(
        np.concatenate([points, other]), np.concatenate([faces, faces + len(points)]), 2
    )
    apart = dijkstra(touching, directed=False, indices=0)
    assert np.isinf(apart[len(points) :]).all() and np.isfinite(apart[: len(points)]).all()


def test_a_mesh_fuses_with_dijkstra_on_its_ring_graph(bundle_dir, blob) -> None:
    predictor, calibration = _graph_only_predictor(bundle_dir)
    shape = blob(3)
    state = predictor.register(shape)
    sources = np.array([0, 17, 200])
    before = state.nbytes
    rows = predictor.distances(state, sources)
    ring = state._lazy[f"fusion.mesh_graph.{calibration.mesh_arcs}"]
    graph_bytes = ring.data.nbytes + ring.indices.nbytes + ring.indptr.nbytes
    assert state.nbytes >= before + graph_bytes  # the mesh's ring graph counts for the cache
    counted = state.nbytes
    inside = np.asarray(shape.vertices)[np.asarray(shape.faces)[:2]].mean(axis=1)
    predictor.distances(state, inside)  # points inside triangles join through a k-d tree
    tree = state._lazy["fusion.tree"]
    assert state.nbytes >= counted + tree.data.nbytes + tree.indices.nbytes
    points, faces = state.canonical_points, np.asarray(shape.faces)
    reference = _reference_ring_graph(points, faces, MESH_RINGS)
    expected = dijkstra(reference, directed=False, indices=sources)
    expected /= calibration.mesh_bias * state.transform.scale
    np.testing.assert_allclose(rows, expected, rtol=1e-5, atol=1e-5)
    # the cloud of the same vertices fuses with its kNN graph instead: other distances
    cloud_rows = predictor.distances(predictor.register(_cloud(shape)), sources)
    assert np.abs(cloud_rows - rows).max() > 1e-3 * rows.max()


def test_a_mesh_fuses_with_the_arcs_its_calibration_chooses(bundle_dir, blob) -> None:
    """``mesh_arcs``: the mesh is answered by Dijkstra on its ring graph with the chords
    lengthened to their arcs; a predictor with plain chords sharing the state keeps its own
    graph (other answers)."""
    predictor, calibration = _graph_only_predictor(bundle_dir)
    arcs = Predictor(predictor.bundle, fusion=dataclasses.replace(calibration, mesh_arcs=True))
    shape = blob(3)
    state = arcs.register(shape)
    sources = np.array([0, 17, 200])
    plain_rows = predictor.distances(state, sources)
    rows = arcs.distances(state, sources)
    points, faces = state.canonical_points, np.asarray(shape.faces)
    graph = mesh_ring_graph(points, faces, MESH_RINGS, normals=arc_normals(points, faces))
    expected = dijkstra(graph, directed=False, indices=sources)
    expected /= calibration.mesh_bias * state.transform.scale
    np.testing.assert_allclose(rows, expected, rtol=1e-5, atol=1e-5)
    assert (rows >= plain_rows - 1e-6).all() and (rows > plain_rows * (1 + 1e-4)).any()
    np.testing.assert_allclose(predictor.distances(state, sources), plain_rows)
    # points given by their positions, on vertices, are answered as those vertices
    on_vertices = np.asarray(shape.vertices)[sources]
    np.testing.assert_allclose(arcs.distances(state, on_vertices), rows, rtol=1e-5, atol=1e-6)
    targets = np.array([5, 90, 400])
    by_index = arcs.distances(state, sources, targets)
    by_point = arcs.distances(state, sources, np.asarray(shape.vertices)[targets])
    np.testing.assert_allclose(by_point, by_index, rtol=1e-5, atol=1e-6)


def _noisy_blob(blob, fraction: float) -> tuple[Shape, Shape]:
    """The toy blob mesh and a copy with vertex noise of ``fraction`` of its edge length."""
    shape = blob(3)
    points, faces = np.asarray(shape.vertices), np.asarray(shape.faces)
    edge = float(np.median(np.linalg.norm(points[faces[:, 0]] - points[faces[:, 1]], axis=1)))
    noise = np.random.default_rng(2).normal(0.0, fraction * edge, points.shape)
    return shape, Shape.from_arrays(points + noise, faces)


def test_a_noisy_mesh_takes_the_bias_of_its_noise(bundle_dir, blob) -> None:
    """With noise knots a mesh's rows are divided by the bias at its vertex noise (measured
    once per shape, on its canonical vertices); the clean mesh keeps the first knot's."""
    from litege_core.learned.mesh_noise import mesh_noise

    predictor, calibration = _graph_only_predictor(bundle_dir)
    knotted = dataclasses.replace(
        calibration, mesh_noise_knots=(0.0, 0.2), mesh_noise_bias=(1.0, 1.5)
    )
    noisy_predictor = Predictor(predictor.bundle, fusion=knotted)
    shape, noisy = _noisy_blob(blob, 0.1)
    points, faces = np.asarray(shape.vertices), np.asarray(shape.faces)
    sources = np.array([0, 17, 200])
    biases = []
    for mesh in (shape, noisy):
        state = noisy_predictor.register(mesh)
        rows = noisy_predictor.distances(state, sources)
        noise = mesh_noise(state.canonical_points, faces)
        assert state._lazy["fusion.mesh_noise"] == noise
        plain = predictor.distances(predictor.register(mesh), sources)
        bias = knotted.graph_bias(len(points), mesh=True, noise=noise)
        np.testing.assert_allclose(rows, plain * calibration.mesh_bias / bias, rtol=1e-6)
        biases.append(bias)
    assert biases[0] < 1.05 < 1.1 < biases[1] < 1.5  # the noisy mesh's well above the clean


def test_a_noisy_mesh_is_smoothed_before_its_graph(bundle_dir, blob, monkeypatch) -> None:
    """With ``mesh_smooth_noise`` a mesh noisier than the limit is answered by the ring graph of
    its denoised vertices (kept with the state); its rows come closer to the clean mesh's than
    the unsmoothed graph's do (one constant bias here: the noise knots are fitted on smoothed
    graphs, their bias read at the noise of the mesh as given). A mesh no noisier than the
    limit is answered exactly as without it. Its noise and its smoothing read one
    :func:`mesh_edges`."""
    from litege_core.learned import fusion, mesh_noise
    from litege_core.learned.mesh_noise import denoised_mesh, mesh_edges

    built: list[int] = []

    def counted(points: np.ndarray, faces: np.ndarray):
        built.append(points.shape[0])
        return mesh_edges(points, faces)

    for module in (fusion, mesh_noise):
        monkeypatch.setattr(module, "mesh_edges", counted)

    predictor, calibration = _graph_only_predictor(bundle_dir)
    plain = predictor
    smoothing = Predictor(
        predictor.bundle, fusion=dataclasses.replace(calibration, mesh_smooth_noise=0.08)
    )
    shape, noisy = _noisy_blob(blob, 0.3)
    sources = np.array([0, 17, 200])
    clean = plain.distances(plain.register(shape), sources)
    np.testing.assert_array_equal(smoothing.distances(smoothing.register(shape), sources), clean)
    built.clear()
    state = smoothing.register(noisy)
    rows = smoothing.distances(state, sources)
    assert len(built) == 1
    denoised = state._lazy["fusion.mesh_denoised.0.08"]
    expected = denoised_mesh(state.canonical_points, np.asarray(noisy.faces), 0.08)
    np.testing.assert_array_equal(denoised.points, expected.points)
    assert denoised.steps > 0 and denoised.noise <= 0.08 < state._lazy["fusion.mesh_noise"]
    graph = mesh_ring_graph(denoised.points, np.asarray(noisy.faces), MESH_RINGS)
    scale = state.transform.scale
    expected_rows = dijkstra(graph, directed=False, indices=sources) / scale / calibration.mesh_bias
    np.testing.assert_allclose(rows, expected_rows, rtol=1e-6)
    unsmoothed = plain.distances(plain.register(noisy), sources)

    def error(answer: np.ndarray) -> float:
        return float(np.mean(np.abs(answer - clean)) / np.mean(clean))

    assert error(rows) < 0.5 * error(unsmoothed)


def test_a_mesh_noisier_than_the_cloud_limit_is_answered_as_its_vertices(bundle_dir, blob) -> None:
    """Above ``mesh_cloud_noise`` a mesh's fusion reads the cloud graph of its vertices (its
    ring graph is never built) and blends the network as on a cloud; below, its ring graph."""
    from litege_core.learned.fusion import graph_faces

    bundle = load_bundle(bundle_dir)
    calibration = _calibration(bundle.content_hash, mesh_cloud_noise=1e-3)
    _, noisy = _noisy_blob(blob, 0.2)
    faces = np.asarray(noisy.faces)
    sources = np.array([0, 17, 200])
    as_cloud = Predictor(bundle, fusion=calibration)
    state = as_cloud.register(noisy)
    rows = as_cloud.distances(state, sources)
    assert not any(key.startswith("fusion.mesh_graph") for key in state._lazy)
    assert any(key.startswith("fusion.graph.") for key in state._lazy)
    assert graph_faces(state.canonical_points, faces, calibration, state._lazy) is None
    by_ring = Predictor(bundle, fusion=dataclasses.replace(calibration, mesh_cloud_noise=None))
    ring_state = by_ring.register(noisy)
    ring_rows = by_ring.distances(ring_state, sources)
    assert any(key.startswith("fusion.mesh_graph") for key in ring_state._lazy)
    assert np.abs(rows - ring_rows).max() > 1e-3 * ring_rows.max()
    # a mesh below the limit keeps its ring graph
    smooth = dataclasses.replace(calibration, mesh_cloud_noise=10.0)
    assert graph_faces(ring_state.canonical_points, faces, smooth, ring_state._lazy) is faces
    assert graph_faces(ring_state.canonical_points, None, smooth, ring_state._lazy) is None


def test_a_mesh_its_graph_spans_evaluates_no_network(bundle_dir, blob, monkeypatch) -> None:
    bundle = load_bundle(bundle_dir)
    # a cloud gate that trusts only the network: a mesh is still answered by its graph alone
    calibration = _calibration(bundle.content_hash, gate=(60.0, 0.0, 0.0, 0.0))
    predictor = Predictor(bundle, fusion=calibration)
    shape = blob(3)
    state = predictor.register(shape)

    def refuse(*args, **kwargs):
        raise AssertionError("the network was evaluated")

    monkeypatch.setattr(predictor, "evaluate_blocks", refuse)
    monkeypatch.setattr(predictor, "_resolve_many", refuse)
    sources = np.array([0, 17, 200])
    rows = predictor.distances(state, sources)
    ring = _reference_ring_graph(state.canonical_points, np.asarray(shape.faces), MESH_RINGS)
    expected = dijkstra(ring, directed=False, indices=sources)
    expected /= calibration.mesh_bias * state.transform.scale
    np.testing.assert_allclose(rows, expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(predictor.distance_field(state, 17), rows[1], rtol=1e-6)
    inside = np.asarray(shape.vertices)[np.asarray(shape.faces)[:2]].mean(axis=1)
    assert np.all(np.isfinite(predictor.distances(state, inside)))  # xyz points: no network


def test_paths_of_a_fused_shape_follow_its_surface(bundle_dir, blob) -> None:
    bundle = load_bundle(bundle_dir)
    fused = Predictor(bundle, fusion=_calibration(bundle.content_hash))
    plain = Predictor(bundle, fusion="none")
    mesh, sources, targets = blob(3), np.array([0, 5, 9]), np.array([200, 100, 50])
    # auto: a fused shape takes the surface route, as its distances take (mostly) the graph's
    paths = fused.paths(fused.register(mesh), sources, targets)  # a mesh: edge-flip
    assert all(p.n_steps == 0 and p.segments[0][1] in (EDGE_FLIP, MESH_EDGES) for p in paths)
    expected = plain.paths(plain.register(mesh), sources, targets, route="surface")
    for a, b in zip(paths, expected, strict=True):
        np.testing.assert_allclose(a.points, b.points)
    cloud = _cloud(mesh)  # a cloud: the fusion's vetoed k-NN graph, the one its distances read
    state = fused.register(cloud)
    paths = fused.paths(state, sources, targets)
    (lazy,) = [v for key, v in state._lazy.items() if key.startswith("fusion.graph.")]
    assert 0 < lazy.judged < lazy.graph.nnz  # vetoed lazily: the routes' edges only
    vetoed = pruned_knn_graph(state.canonical_points, 8, 1.6, fused._edge_geodesics(state))
    assert vetoed.nnz < knn_graph(state.canonical_points, 8).nnz  # the veto cut some edges
    routes = SurfaceRouter(cloud.vertices, None, vetoed).routes(targets, sources)
    for path, (route, method) in zip(paths, routes, strict=True):
        assert path.n_steps == 0 and path.segments == ((0, method),) and method == KNN_GRAPH
        np.testing.assert_allclose(path.points, route[::-1])
    # the learned walk without a fusion, or when asked
    walks = [
        plain.paths(plain.register(mesh), sources, targets),
        fused.paths(fused.register(mesh), sources, targets, route="learned"),
        fused.paths(fused.register(_cloud(mesh)), sources, targets, route="learned"),
    ]
    for paths in walks:
        assert any(path.n_steps > 0 for path in paths)


def test_predictors_with_other_cloud_graphs_keep_their_routers_apart(bundle_dir, blob) -> None:
    """A state shared by two fused predictors of one bundle whose calibrations differ only in
    the neighbour rule: each routes on its own graph (the memo keys name all of it)."""
    bundle = load_bundle(bundle_dir)
    symmetric = Predictor(bundle, fusion=_graph_only(bundle.content_hash))
    mutual = Predictor(bundle, fusion=dataclasses.replace(symmetric.fusion, mutual_k=12))
    state = symmetric.register(_cloud(blob(3)))
    first, second = symmetric.surface_router(state), mutual.surface_router(state)
    assert first is not second and first.graph.nnz != second.graph.nnz
    assert symmetric.surface_router(state) is first  # kept with the state


def test_a_mesh_of_two_parts_takes_the_network_between_them(bundle_dir, blob) -> None:
    bundle = load_bundle(bundle_dir)
    first, second = blob(3), blob(4)
    n_first = first.n_points
    two = Shape.from_arrays(
        np.concatenate([first.vertices, np.asarray(second.vertices) + np.array([4.0, 0.0, 0.0])]),
        np.concatenate([first.faces, np.asarray(second.faces) + n_first]),
    )
    calibration = _calibration(bundle.content_hash, mesh_bias=1.1)
    fused, network = Predictor(bundle, fusion=calibration), Predictor(bundle, fusion="none")
    sources = np.array([0, n_first + 5])
    state = fused.register(two)
    rows = fused.distances(state, sources)
    alone = network.distances(network.register(two), sources)
    across = np.zeros_like(rows, dtype=bool)
    across[0, n_first:] = across[1, :n_first] = True
    np.testing.assert_allclose(rows[across], alone[across], rtol=1e-6)  # the network's values
    ring = mesh_ring_graph(state.canonical_points, np.asarray(two.faces), MESH_RINGS)
    expected = dijkstra(ring, directed=False, indices=sources)
    expected /= calibration.mesh_bias * state.transform.scale
    np.testing.assert_allclose(rows[~across], expected[~across], rtol=1e-5, atol=1e-5)


def test_a_batch_of_meshes_and_clouds_equals_each_alone(bundle_dir, blob) -> None:
    bundle = load_bundle(bundle_dir)
    predictor = Predictor(bundle, fusion=_calibration(bundle.content_hash))
    states = [predictor.register(s) for s in (blob(3), _cloud(blob(4)), blob(5), _cloud(blob(3)))]
    sources = [np.array([0, 9]), np.array([3]), np.array([1, 2, 40]), np.array([7])]
    batch = predictor.distances_many(states, sources)
    for state, query, got in zip(states, sources, batch, strict=True):
        np.testing.assert_allclose(got, predictor.distances(state, query), rtol=1e-6)


def test_the_mesh_ring_graph_keeps_touching_parts_apart() -> None:
    # two parallel strips 0.01 apart (closer than their own edges), joined at one end by faces
    t = np.linspace(0.0, 1.0, 11)
    rows = [np.column_stack([t, np.full_like(t, y), np.zeros_like(t)]) for y in (0.0, 0.1)]
    top = [np.column_stack([t, np.full_like(t, y), np.full_like(t, 0.01)]) for y in (0.0, 0.1)]
    points = np.concatenate(rows + top)  # 44 points: strip A (0-21), strip B (22-43)
    faces = []
    for base in (0, 22):
        for i in range(10):
            a, b, c, d = base + i, base + i + 1, base + 11 + i, base + 12 + i
            faces += [(a, b, c), (b, d, c)]
    faces += [(0, 11, 22), (11, 33, 22)]  # the strips meet only along x = 0
    far_a, far_b = 10, 32  # the x = 1 ends, 0.01 apart in space
    for rings in (1, 2, 3):
        graph = mesh_ring_graph(points, np.asarray(faces), rings)
        through = dijkstra(graph, directed=False, indices=far_a)[far_b]
        assert through > 1.5  # along strip A to x = 0 and back along strip B (chords cut
        # the corner at x = 0 with more rings), never across the 0.01 gap
    assert dijkstra(knn_graph(points, 4), directed=False, indices=far_a)[far_b] < 0.05


def test_free_query_points_join_the_graph_through_their_nearest_points(bundle_dir, blob) -> None:
    from scipy.spatial import cKDTree

    predictor, calibration = _graph_only_predictor(bundle_dir)
    shape = blob(5)
    state = predictor.register(shape)
    centroid = np.asarray(shape.vertices)[np.asarray(shape.faces)[30]].mean(axis=0)
    rows = predictor.distances(state, centroid[None], np.arange(50))
    # independently: the projected point with chords to its 8 nearest vertices, then Dijkstra
    # over the mesh's ring graph
    canonical = state.transform.apply(np.asarray(centroid[None], np.float64))
    points = state.canonical_points
    chords, nearest = cKDTree(points).query(canonical[0], k=8)
    mesh = mesh_ring_graph(points, np.asarray(shape.faces), MESH_RINGS)
    through = dijkstra(mesh, directed=False, indices=nearest)[:, :50]
    expected = (chords[:, None] + through).min(axis=0)
    expected /= calibration.mesh_bias * state.transform.scale
    # the query is projected onto the surface first: within a small fraction of an edge
    np.testing.assert_allclose(rows[0], expected, rtol=0.02, atol=0.02 * state.spacing)


def test_fusion_options_are_checked(bundle_dir, toy_predictor, tmp_path) -> None:
    bundle = load_bundle(bundle_dir)
    with pytest.raises(InputError, match="fusion must be one of"):
        Predictor(bundle, fusion="average")
    with pytest.raises(InputError, match="no graph-fusion"):
        Predictor(bundle, fusion="graph")
    with pytest.raises(InputError, match="not for bundle"):
        Predictor(bundle, fusion=_calibration("0" * 64))
    # a bundle without residual statistics has no z-score for the gate
    plain = toy_predictor.bundle
    with pytest.raises(ArtifactError, match="residual statistics"):
        Predictor(plain, fusion=_calibration(plain.content_hash))
    copy = tmp_path / "toy"
    shutil.copytree(bundle_dir, copy)
    save_fusion(copy, _calibration(bundle.content_hash))
    assert Predictor(load_bundle(copy), fusion="graph").fusion == _calibration(bundle.content_hash)


def test_auto_fuses_exactly_where_the_bundle_ships_a_calibration(bundle_dir, tmp_path) -> None:
    bundle = load_bundle(bundle_dir)
    assert DEFAULT_FUSION == "auto"
    assert Predictor(bundle).fusion is None  # no fusion.json: the network alone
    assert resolve_fusion("auto", None, bundle.content_hash, "toy") is None
    copy = tmp_path / "toy"
    shutil.copytree(bundle_dir, copy)
    save_fusion(copy, _calibration(bundle.content_hash))
    calibrated = load_bundle(copy)
    assert Predictor(calibrated).fusion == _calibration(bundle.content_hash)
    assert Predictor(calibrated, fusion="none").fusion is None
    # a stale calibration beside a bundle is an error under auto too, not a silent fallback
    save_fusion(copy, _calibration("0" * 64))
    with pytest.raises(InputError, match="fitted for bundle"):
        Predictor(load_bundle(copy))
    with pytest.raises(InputError, match="fusion must be one of"):
        resolve_fusion("always", copy, bundle.content_hash, "toy")


def test_the_small_head_vetoes_edges_when_the_calibration_says_so(bundle_dir, blob, tmp_path):
    import torch

    from litege_core.learned.small_head import save_small_head
    from litege_core.nets.small_head import SmallHead

    directory = tmp_path / "toy"
    shutil.copytree(bundle_dir, directory)
    bundle = load_bundle(directory)
    torch.manual_seed(3)
    save_small_head(directory, SmallHead(bundle.network.width, 12, 8).eval(), bundle.content_hash)
    bundle = load_bundle(directory)
    small = Predictor(bundle, head="small")
    shape = _cloud(blob(6))
    state = small.register(shape)
    # the small head's own predictions (canonical units) decide which kNN edges survive
    predicted = small.distances(state, "all", "all").astype(np.float64) * state.transform.scale
    chords = knn_graph(state.canonical_points, 8).tocoo()
    ratio = predicted[chords.row, chords.col] / chords.data
    # cut 20-40 % of the edges, at the widest gap between ratios (no edge near the threshold)
    ordered = np.sort(ratio)
    low, high = int(0.6 * ordered.size), int(0.8 * ordered.size)
    widest = low + int(np.argmax(np.diff(ordered[low : high + 1])))
    prune_ratio = float(ordered[widest : widest + 2].mean())
    assert prune_ratio > 1.0
    expected_graph = pruned_knn_graph(
        state.canonical_points, 8, prune_ratio, lambda i, j: predicted[i, j]
    )
    calibration = _graph_only(bundle.content_hash, prune_ratio)
    for head in ("full", "small"):
        fused = Predictor(
            bundle, head=head, fusion=dataclasses.replace(calibration, veto_head="small")
        )
        rows = fused.distances(fused.register(shape), np.array([0, 9]))
        expected = dijkstra(expected_graph, directed=False, indices=[0, 9])
        expected /= calibration.graph_bias(state.n_points) * state.transform.scale
        finite = np.isfinite(expected)
        np.testing.assert_allclose(rows[finite], expected[finite], rtol=1e-4, atol=1e-5)
    with pytest.raises(InputError, match="no small head"):
        Predictor(
            load_bundle(bundle_dir), fusion=dataclasses.replace(calibration, veto_head="small")
        )


def test_a_cloud_beyond_the_veto_limit_reads_the_unvetoed_graph(bundle_dir, blob) -> None:
    """Above ``veto_max_z`` a cloud's rows and paths come from its k-NN graph with no edge
    cut by the network; at or below it, from the vetoed graph (a veto that cuts edges here)."""
    bundle = load_bundle(bundle_dir)
    shape = _cloud(blob(6))
    probe = Predictor(bundle, fusion=_graph_only(bundle.content_hash))
    z = probe.register(shape).ood_score
    sources = np.array([0, 9])
    rows, graphs = {}, {}
    for name, limit in (("vetoed", z + 0.5), ("unvetoed", z - 0.5)):
        calibration = dataclasses.replace(
            _graph_only(bundle.content_hash, prune_ratio=1.05), veto_max_z=limit
        )
        predictor = Predictor(bundle, fusion=calibration)
        state = predictor.register(shape)
        rows[name] = predictor.distances(state, sources)
        graphs[name] = predictor.surface_router(state).graph
        predictor.paths(state, [0], [9])  # routes on that graph
    points = state.canonical_points
    unvetoed = knn_graph(points, 8)
    assert graphs["unvetoed"].nnz == unvetoed.nnz
    assert graphs["vetoed"].nnz < unvetoed.nnz  # the network cut edges below the limit
    expected = dijkstra(unvetoed, directed=False, indices=sources)
    expected /= calibration.graph_bias(state.n_points) * state.transform.scale
    np.testing.assert_allclose(rows["unvetoed"], expected, rtol=1e-5, atol=1e-5)
    assert not np.allclose(rows["vetoed"], rows["unvetoed"])


def test_agreement_is_the_network_against_its_own_graph(bundle_dir, blob, tmp_path) -> None:
    from litege_core.sampling import farthest_point_sampling

    bundle = load_bundle(bundle_dir)
    shape = blob(4)
    assert np.isnan(Predictor(bundle, fusion="none").agreement(Predictor(bundle).register(shape)))
    calibration = _calibration(bundle.content_hash, mesh_bias=1.05)
    fused = Predictor(bundle, fusion=calibration)
    state = fused.register(shape)
    score = fused.agreement(state, n_sources=3)
    # the reference: network rows and the graph-only answer (graph / bias) from three FPS sources
    sources = farthest_point_sampling(state.canonical_points, 3)
    network = Predictor(bundle, fusion="none")
    net = network.distances(network.register(shape), sources).astype(np.float64)
    graph = fused.distances(state, sources).astype(np.float64)  # a mesh: its graph alone
    assert score == pytest.approx(np.abs(net - graph).mean() / graph.mean(), rel=1e-4)
    assert score > 0.0
    assert f"fusion.mesh_graph.{calibration.mesh_arcs}" in state._lazy  # kept for the fused queries


def test_choose_model_weighs_the_agreement_beside_the_z_score() -> None:
    from litege_core.learned.routing import choose_model

    scores = {"quadrupeds": 0.5, "humans": 0.9}
    assert choose_model(scores) == "quadrupeds"
    assert choose_model(scores, {"quadrupeds": 0.10, "humans": 0.03}, weight=40.0) == "humans"
    assert choose_model(scores, {"quadrupeds": 0.10, "humans": 0.03}, weight=1.0) == "quadrupeds"
    # an agreement missing or nan anywhere: the z-score alone
    assert choose_model(scores, {"quadrupeds": 0.10, "humans": float("nan")}) == "quadrupeds"
    assert choose_model(scores, {"humans": 0.03}) == "quadrupeds"
    assert choose_model({"a": float("nan"), "b": 3.0}) == "b"  # a non-finite score ranks last
    assert choose_model({"a": 1.0, "b": 1.0}) == "a"  # ties: the first loaded
    with pytest.raises(InputError):
        choose_model({})
