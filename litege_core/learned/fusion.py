"""Graph fusion: the network's distances blended with a calibrated graph Dijkstra.

On real shapes the network's error is dominated by shapes far from its training families (the
error follows the out-of-distribution score), while a graph Dijkstra on a dense cloud is nearly
unbiased wherever its graph has no shortcuts, and on a sparse one is poor everywhere. The fused
estimate takes the better of the two per shape, with weights fitted on data we generate
(procedural shapes, posed rigged animals, MakeHuman bodies; never the real dev set)::

    G_graph  = for a mesh input, Dijkstra on chords between vertices at most ``MESH_RINGS``
               mesh edges apart (the mesh's connectivity: no shortcut between parts that
               touch), where the calibration says so (``mesh_arcs``) lengthened to the arcs
               they span (from the vertex normals: a chord across two rings of a coarse mesh
               cuts through a curved part), on a mesh noisier than the calibration's
               ``mesh_smooth_noise`` after smoothing it down to that noise (a raw scan's
               paths would zig-zag with its vertices:
               :func:`~litege_core.learned.mesh_noise.denoised_mesh`); for a point cloud, on
               the symmetric k-NN graph of the points (canonical frame) after cutting every
               edge whose predicted geodesic exceeds ``prune_ratio`` × its chord (the network
               vetoes shortcuts between touching parts; the veto is the bundle's small head
               where the calibration says so: it costs one head evaluation per edge, ~8 N for
               N points) and, where the calibration has normal limits, every edge whose chord
               runs along the surface normal at either end, ``|n · ĉ| > c(N)`` (a chord
               across a thin part or a gap between parts; ``n`` from the points' k-NN
               covariance, ``c(N)`` interpolated in log10 N from calibration knots: looser on
               sparse clouds, whose chords bend with the surface); where the calibration
               says so (``mutual_k``), the graph is the *mutual* k-NN graph of that many
               neighbours instead (fewer chords across thin parts:
               :func:`~litege_core.engines.graph.mutual_knn_graph`); no network veto on a
               cloud whose OOD z-score exceeds ``veto_max_z`` (where the calibration has one:
               the network's edge predictions on a shape it does not know cut true surface
               edges, e.g. a torus at 300 points: 3.4 → 12.2)
    b        = the graph's median over-estimate (zig-zag paths): on a mesh ``mesh_bias``,
               or where the calibration has noise knots b(ν) at the mesh's vertex noise ν
               (:func:`mesh_noise`: a raw scan's noisy vertices lengthen every path, less
               so once smoothed),
               interpolated from them (extrapolated beyond the noisiest); b(N) at N cloud
               points, interpolated in log10 N from calibration knots
    w        = 0 on a mesh (its ring graph alone); for a cloud
               sigmoid(a + c_z · z + c_n · (log10 N − 3) + c_r · r)
               (z: the shape's OOD z-score; r: its surface roughness, high on noisy scans:
               :func:`~litege_core.learned.cloud_surface.surface_roughness`)
    G        = w · G_network + (1 − w) · G_graph / b

so a shape the network knows (low z), a sparse or a noisy cloud leans on the network, and an
unusual shape sampled densely leans on the graph. A mesh is answered by its ring graph alone: a
fitted weight was below 2 % on our generated meshes and dropping it lowered the real dev meshes'
error (BENCHMARKS "mesh-graph-alone"), so a mesh query evaluates no network unless its graph
cannot join a pair. Pairs the graph cannot join (another component) keep the network's value.
A fused predictor's paths follow the same graphs (``route="auto"`` of
:func:`~litege_core.learned.paths.trace_paths`: an edge-flip geodesic on a mesh, the fully vetoed
k-NN graph's shortest path on a cloud).

The calibration is a sidecar of the bundle, like the small head: ``fusion.json`` beside the
bundle files, naming the content hash of the bundle it was fitted for (a mismatch is refused),
written by :func:`~litege_core.learned.fusion_calibration.save_fusion`
(``scripts/calibrate_fusion.py``), read by
:func:`~litege_core.learned.fusion_calibration.load_fusion` (``Predictor(bundle,
fusion="graph")``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from litege_core.arrays import distinct_indices
from litege_core.errors import InputError
from litege_core.learned.cloud_surface import ROUGHNESS_NEIGHBOURS, local_surface, normal_cosines
from litege_core.learned.fusion_calibration import FusionCalibration
from litege_core.learned.mesh_noise import MeshEdges, denoised_mesh, mesh_edges, mesh_noise
from litege_core.learned.veto_graph import (
    LAZY_SOURCES,
    MAX_ROUNDS,
    EdgeGeodesics,
    LazyVetoGraph,
    path_edges,
    reads_trees,
)

if TYPE_CHECKING:  # scipy loads on first use: a plain CLI query never imports it
    import scipy.sparse as sp

MESH_RINGS = 2
"""Mesh edges between two vertices the graph of a mesh input joins by a chord
(:func:`~litege_core.engines.graph.mesh_ring_graph`): on the real dev meshes and the calibration
meshes two rings gave the lowest error of 1–3 (the own edges zig-zag, three admit shortcuts)."""


class ShapeGraph(NamedTuple):
    """What the fusion reads on one shape (:func:`shape_graph`)."""

    graph: sp.csr_array | LazyVetoGraph
    """``(N, N)`` over every point (a cloud's copies and twins join their node)."""
    roughness: float
    """How rough the surface is: a cloud's
    :func:`~litege_core.learned.cloud_surface.surface_roughness` (an input of the gate), a
    mesh's vertex noise (:func:`mesh_noise`, the input of its bias; 0 where the calibration
    reads none: :func:`kept_mesh_noise`)."""
    n_nodes: int
    """Distinct nodes: the mesh's vertices, or the cloud's points without its copies and twins
    (:func:`~litege_core.engines.graph.graph_nodes`): the ``N`` of the gate and the bias."""
    normals: NDArray | None = None
    """``(N, 3)`` vertex normals a mesh graph's arcs were measured with (free query points join
    it by arcs too), or ``None``: plain chords."""


def shape_graph(
    points: NDArray,
    faces: NDArray | None,
    calibration: FusionCalibration,
    kept: dict[str, Any],
    veto_key: str,
    z_score: float,
) -> ShapeGraph:
    """The graph the fusion reads on one shape, its surface roughness and its node count, kept
    in ``kept``.

    A mesh: its ring graph (:data:`MESH_RINGS`; no shortcut between parts that touch; arcs
    where the calibration's ``mesh_arcs`` says so), its vertex noise
    (:func:`kept_mesh_noise`). A cloud: its k-NN graph,
    normal-pruned where the calibration has normal limits, as a
    :class:`~litege_core.learned.veto_graph.LazyVetoGraph` whose network veto
    :func:`graph_rows` runs on the edges that paths use (the rows equal those of
    :func:`pruned_knn_graph`), or as it is where the calibration keeps the veto off at this
    OOD ``z_score`` (:meth:`~litege_core.learned.fusion_calibration.FusionCalibration.vetoes`);
    its roughness from the same 16-NN covariance.

    Args:
        points: ``(N, 3)`` float64 canonical points.
        faces: ``(F, 3)`` of a mesh, or ``None``.
        calibration: the fusion's constants.
        kept: the shape's memo (a state's ``_lazy``): keys ``fusion.mesh_graph.ARCS``,
            ``fusion.mesh_normals`` (:func:`~litege_core.engines.graph.arc_normals`),
            ``fusion.mesh_noise`` (:func:`mesh_noise`),
            ``fusion.surface``, ``fusion.nodes``
            (:func:`~litege_core.engines.graph.graph_nodes`) and
            :func:`cloud_graph_key`.
        veto_key: names the veto head (its verdicts are kept in the graph).
        z_score: the shape's OOD z-score.
    """
    if faces is not None:
        vertices, smoothed = kept_graph_mesh(points, faces, calibration, kept)
        arcs, suffix = calibration.mesh_arcs, f".{smoothed}" if smoothed else ""
        normals = kept_arc_normals(vertices, faces, kept, suffix) if arcs else None
        key = f"fusion.mesh_graph.{arcs}{suffix}"
        if key not in kept:
            from litege_core.engines.graph import mesh_ring_graph  # scipy: on use

            kept[key] = mesh_ring_graph(vertices, faces, MESH_RINGS, normals=normals)
        noise = kept_mesh_noise(points, faces, calibration, kept)
        return ShapeGraph(kept[key], noise, points.shape[0], normals)
    k, ratio, mutual = calibration.k, calibration.prune_ratio, calibration.mutual_k
    vetoed = calibration.vetoes(z_score)
    key = cloud_graph_key(calibration, veto_key, points.shape[0], vetoed)
    graph, surface, nodes = kept.get(key), kept.get("fusion.surface"), kept.get("fusion.nodes")
    if graph is None or surface is None or nodes is None:  # one search serves all (k = 16)
        from litege_core.engines.graph import (  # scipy: on first use
            graph_nodes,
            knn_neighbours,
            with_copies,
        )

        if nodes is None:
            nodes, neighbours = graph_nodes(points, calibration.reach)
            kept["fusion.nodes"] = nodes
        else:
            neighbours = knn_neighbours(points[nodes[1]], calibration.reach)
        first, index = nodes
        merged = index.size < points.shape[0]
        base = points[index] if merged else points
        if surface is None:
            shared = calibration.reach >= ROUGHNESS_NEIGHBOURS  # the shipped calibrations
            flatness, normals = local_surface(base, nearest=neighbours[1] if shared else None)
            surface = kept["fusion.surface"] = (float(np.median(flatness)), normals, flatness)
        if graph is None:
            normal_cos = calibration.normal_limit(index.size)
            unvetoed = pruned_knn_graph(
                base, k, ratio, None, neighbours, surface[1], normal_cos, mutual
            )
            cut = calibration.shortcut_limit(index.size, surface[0])
            if cut < 1.0:
                from litege_core.learned.shortcuts import cut_shortcuts, load_shortcut_scorer

                scorer = load_shortcut_scorer(sha256=calibration.shortcut_scorer)
                unvetoed = cut_shortcuts(
                    unvetoed, base, neighbours, surface[1], surface[2], cut, scorer
                )
            if merged:
                unvetoed = with_copies(unvetoed, points, index, first)
            graph = kept[key] = LazyVetoGraph(unvetoed, ratio) if vetoed else unvetoed
    return ShapeGraph(graph, surface[0], int(nodes[1].size))


def kept_arc_normals(
    points: NDArray, faces: NDArray, kept: dict[str, Any], suffix: str = ""
) -> NDArray | None:
    """A mesh's :func:`~litege_core.engines.graph.arc_normals`, kept in ``kept`` as
    ``fusion.mesh_normals`` + ``suffix`` (its arcs and its vertex noise read the same normals;
    ``suffix`` names smoothed vertices, :func:`kept_graph_mesh`)."""
    key = f"fusion.mesh_normals{suffix}"
    if key not in kept:
        from litege_core.engines.graph import arc_normals  # scipy: on use

        kept[key] = arc_normals(points, faces)
    return kept[key]


def kept_mesh_noise(
    points: NDArray, faces: NDArray, calibration: FusionCalibration, kept: dict[str, Any]
) -> float:
    """A mesh's vertex noise (:func:`mesh_noise`, kept in ``kept`` as ``fusion.mesh_noise``)
    where the calibration reads it (noise knots, a cloud or a smoothing limit), else 0."""
    reads = calibration.mesh_noise_knots or calibration.mesh_cloud_noise is not None
    if not (reads or calibration.mesh_smooth_noise is not None):
        return 0.0
    if "fusion.mesh_noise" not in kept:
        normals = kept_arc_normals(points, faces, kept)
        edges = kept_mesh_edges(points, faces, kept)
        kept["fusion.mesh_noise"] = mesh_noise(points, faces, normals, edges)
    return float(kept["fusion.mesh_noise"])


def kept_mesh_edges(points: NDArray, faces: NDArray, kept: dict[str, Any]) -> MeshEdges:
    """A mesh's :func:`~litege_core.learned.mesh_noise.mesh_edges` (its vertex noise and its
    smoothing read the same edges), kept in ``kept`` as ``fusion.mesh_edges``."""
    if "fusion.mesh_edges" not in kept:
        kept["fusion.mesh_edges"] = mesh_edges(points, faces)
    return kept["fusion.mesh_edges"]


def kept_graph_mesh(
    points: NDArray, faces: NDArray, calibration: FusionCalibration, kept: dict[str, Any]
) -> tuple[NDArray, float | None]:
    """The ``(N, 3)`` vertices a mesh's ring graph is built on and the smoothing limit they
    were taken to, or the mesh's own ``points`` and ``None``. A mesh noisier than the
    calibration's ``mesh_smooth_noise`` (:func:`kept_mesh_noise`) is smoothed down to it
    (:func:`~litege_core.learned.mesh_noise.denoised_mesh`, kept in ``kept`` as
    ``fusion.mesh_denoised.LIMIT``)."""
    limit = calibration.mesh_smooth_noise
    if limit is None:
        return points, None
    noise = kept_mesh_noise(points, faces, calibration, kept)
    if noise <= limit:
        return points, None
    key = f"fusion.mesh_denoised.{limit}"
    if key not in kept:
        edges = kept_mesh_edges(points, faces, kept)
        kept[key] = denoised_mesh(points, faces, limit, noise, edges)
    return kept[key].points, limit


def graph_faces(
    points: NDArray, faces: NDArray | None, calibration: FusionCalibration, kept: dict[str, Any]
) -> NDArray | None:
    """The faces the fusion's graph follows: a mesh's own, or ``None`` (the cloud of its
    vertices) where its vertex noise is above the calibration's cloud limit
    (:meth:`~litege_core.learned.fusion_calibration.FusionCalibration.answers_as_cloud`);
    ``None`` for a cloud."""
    if faces is None or calibration.mesh_cloud_noise is None:
        return faces
    noise = kept_mesh_noise(points, faces, calibration, kept)
    return None if calibration.answers_as_cloud(noise) else faces


def cloud_graph_key(
    calibration: FusionCalibration, veto_key: str, n_points: int, vetoed: bool
) -> str:
    """The memo key of a cloud's fusion graph (:func:`shape_graph`): everything that shapes
    it (the veto head and threshold, or no veto; ``k``, the normal limit at ``n_points`` and
    the neighbour rule), so predictors with other calibrations sharing a state keep apart."""
    c = calibration
    veto = f"{veto_key}.{c.prune_ratio}" if vetoed else "unvetoed"
    key = f"fusion.graph.{veto}.{c.k}.{c.normal_limit(n_points)}.{c.mutual_k}"
    if c.shortcut_cut:  # the cut at this size (the roughness is the shape's own)
        cut = c.shortcut_limit(n_points, 0.0)
        key += f".cut.{c.shortcut_scorer[:16]}.{cut}.{c.shortcut_max_roughness}"
    return key


def fused_distances(
    network: Callable[[], NDArray],
    calibration: FusionCalibration,
    points: NDArray,
    faces: NDArray | None,
    src: tuple[NDArray | None, NDArray],
    dst: tuple[NDArray | None, NDArray],
    ood_score: float,
    kept: dict[str, Any],
    edge_geodesics: EdgeGeodesics,
    veto_key: str,
) -> NDArray:
    """The network's distances ``(S, T)`` (canonical units) blended with the graph distances of
    the query points: :func:`shape_graph`, :func:`graph_rows`, then :func:`fuse`; float64
    ``(S, T)``. ``network`` computes them when the answer needs them: on a cloud, and on a mesh
    only where its graph joins no path (a mesh is answered by its graph alone).

    ``src``, ``dst``: ``(indices, canonical)`` as :func:`graph_rows`; ``points``, ``faces``,
    ``kept``, ``edge_geodesics``, ``veto_key``: as :func:`shape_graph` (``kept`` also keeps a
    KD-tree of ``points``, ``fusion.tree``, when free points join). A mesh noisier than the
    calibration's cloud limit is answered as the cloud of its vertices (:func:`graph_faces`)."""
    faces = graph_faces(points, faces, calibration, kept)
    graph, roughness, n_nodes, normals = shape_graph(
        points, faces, calibration, kept, veto_key, ood_score
    )
    tree = None
    if src[0] is None or dst[0] is None:  # free points join through a KD-tree
        tree = kept.get("fusion.tree")
        if tree is None:
            from scipy.spatial import cKDTree

            tree = kept["fusion.tree"] = cKDTree(points)
    rows = graph_rows(graph, points, src, dst, calibration.k, tree, edge_geodesics, normals)
    mesh = faces is not None
    if mesh and np.isfinite(rows).all():  # the network's weight on a mesh is 0
        return rows / calibration.graph_bias(points.shape[0], mesh=True, noise=roughness)
    return fuse(network(), rows, calibration, ood_score, n_nodes, roughness, mesh)


def route_trees(
    graph: LazyVetoGraph, roots: NDArray, far: NDArray, edge_geodesics: EdgeGeodesics
) -> NDArray:
    """Dijkstra predecessors ``(R, N)`` from ``roots`` on the fully vetoed cloud graph, read
    towards the ``far`` nodes: rounds of Dijkstra on ``graph`` judging only the edges of the
    routes from every root to every far node (their trees beyond
    :data:`~litege_core.learned.veto_graph.PATH_PAIRS` pairs), until no route crosses a cut
    edge, as :func:`graph_rows` does (module doc of :mod:`~litege_core.learned.veto_graph`):
    the routes of the fully vetoed graph. ``-9999``: no predecessor (a root, or cut off)."""
    from litege_core.engines.graph import dijkstra_tree  # scipy: on first use

    roots = np.asarray(roots, dtype=np.int64)
    far = np.asarray(far, dtype=np.int64)
    n = graph.graph.shape[0]
    for _ in range(MAX_ROUNDS):
        predecessors = dijkstra_tree(graph.graph, roots)[1]
        if not graph.judge(graph.positions(*path_edges(predecessors, far, n)), edge_geodesics):
            return predecessors
    return dijkstra_tree(graph.vetoed(edge_geodesics), roots)[1]


def pruned_knn_graph(
    points: NDArray,
    k: int,
    prune_ratio: float,
    edge_geodesics: EdgeGeodesics | None,
    neighbours: tuple[NDArray, NDArray] | None = None,
    normals: NDArray | None = None,
    normal_cos: float = 1.0,
    mutual_k: int = 0,
) -> sp.csr_array:
    """The symmetric k-NN graph of ``points`` (with ``mutual_k``: the mutual k-NN graph of that
    many neighbours) without the edges the network calls shortcuts and, with ``normals``,
    without the chords that run along the surface normal. With
    ``edge_geodesics`` it is the eager reference of the lazy veto of :func:`graph_rows` (which
    the fusion runs); without, the graph that veto starts from.

    Args:
        points: ``(N, 3)`` float64 (canonical frame).
        k: neighbours per point (clamped to ``N - 1``).
        prune_ratio: cut an edge whose predicted geodesic exceeds ``prune_ratio`` × its chord.
        edge_geodesics: predicted geodesics of ``(i, j)`` pairs, or ``None`` (no pruning).
        neighbours: :func:`~litege_core.engines.graph.knn_neighbours` of ``points`` for
            ``k`` or more, if already known.
        normals: ``(N, 3)`` unit normals (any sign,
            :func:`~litege_core.learned.cloud_surface.local_surface`), or ``None``.
        normal_cos: cut an edge whose unit chord ``ĉ`` has ``|n · ĉ| > normal_cos`` at either
            end (1: keep every edge).
        mutual_k: 0: the symmetric k-NN graph; else the mutual k-NN graph of ``mutual_k``
            neighbours (``neighbours`` then covers ``mutual_k`` or more).

    Returns:
        ``(N, N)`` upper-triangular CSR of chord lengths (:func:`~litege_core.engines.graph.
        edge_graph`).
    """
    from litege_core.engines.graph import (
        edge_rows,
        edge_subgraph,
        knn_graph,
        knn_neighbours,
        mutual_knn_graph,
    )

    if neighbours is None:  # the plain lists (the fusion passes its nodes': shape_graph)
        neighbours = knn_neighbours(points, max(k, mutual_k))
    if mutual_k:
        graph = mutual_knn_graph(points, mutual_k, neighbours)
    else:
        graph = knn_graph(points, k, neighbours)
    cut_normals = normals is not None and normal_cos < 1.0
    if (edge_geodesics is None and not cut_normals) or graph.nnz == 0:
        return graph
    rows = edge_rows(graph)
    keep = np.ones(graph.nnz, dtype=bool)
    if cut_normals:
        assert normals is not None
        keep &= normal_cosines(points, normals, rows, graph.indices, graph.data) <= normal_cos
    if edge_geodesics is not None:  # the network only on the edges the normals leave
        left = np.flatnonzero(keep)
        keep[left] = edge_geodesics(rows[left], graph.indices[left]) <= (
            prune_ratio * graph.data[left]
        )
    return edge_subgraph(graph, rows, keep)


def graph_rows(
    graph: sp.csr_array | LazyVetoGraph,
    points: NDArray,
    src: tuple[NDArray | None, NDArray],
    dst: tuple[NDArray | None, NDArray],
    k: int,
    tree: Any = None,
    edge_geodesics: EdgeGeodesics | None = None,
    normals: NDArray | None = None,
) -> NDArray:
    """``(S, T)`` graph distances between query points (``inf`` where no path joins them).

    A query is ``(indices, canonical)``: its node indices, or ``None`` with its ``(Q, 3)``
    canonical coordinates for points that are not nodes. Such a free point joins the graph
    through chords to its ``k`` nearest points, and only as an end of its own paths: no path
    passes through another query point, so a row does not depend on what else a request asks
    (a request split into blocks gets the same answers). With a mesh graph's arc ``normals``
    (:class:`ShapeGraph`), those chords are arcs too, measured with the normal of the free
    point's nearest vertex: a point on a vertex is answered as that vertex. Dijkstra runs from
    the smaller side.
    ``tree``: a ``scipy.spatial.cKDTree`` of ``points`` if the caller keeps one (built here
    otherwise). The cached ``graph`` is never changed.

    A :class:`~litege_core.learned.veto_graph.LazyVetoGraph` is judged by ``edge_geodesics``
    on the edges of the paths the query reads, round after round, until no path crosses a
    cut edge (its module docstring): the rows of the fully vetoed graph, exactly.
    """
    if not isinstance(graph, LazyVetoGraph):
        return _graph_rows(graph, points, src, dst, k, tree, paths=False, normals=normals)[0]
    if edge_geodesics is None:
        raise InputError("a lazily vetoed graph needs the veto's edge geodesics")
    n = points.shape[0]
    sizes = [q[1].shape[0] if q[0] is None else distinct_indices(q[0], n).size for q in (src, dst)]
    if min(sizes) <= LAZY_SOURCES:  # the Dijkstra runs of a round are few: judge lazily
        for _ in range(MAX_ROUNDS):
            rows, read = _graph_rows(graph.graph, points, src, dst, k, tree, paths=True)
            assert read is not None
            predecessors, far = read
            positions = graph.positions(*path_edges(predecessors, far, n))
            if not graph.judge(positions, edge_geodesics):
                return rows
            if reads_trees(predecessors.shape[0], far.size):  # where the trees re-route
                graph.judge_below_cuts(predecessors, positions, edge_geodesics)
    final = graph.vetoed(edge_geodesics)
    return _graph_rows(final, points, src, dst, k, tree, paths=False)[0]


def _graph_rows(
    graph: sp.csr_array,
    points: NDArray,
    src: tuple[NDArray | None, NDArray],
    dst: tuple[NDArray | None, NDArray],
    k: int,
    tree: Any,
    paths: bool,
    normals: NDArray | None = None,
) -> tuple[NDArray, tuple[NDArray, NDArray] | None]:
    """:func:`graph_rows` on a plain graph; with ``paths``, also what its shortest paths
    are read from: the ``(U, M)`` Dijkstra predecessors and the ``(F,)`` far node ids
    (:func:`~litege_core.learned.veto_graph.path_edges`)."""
    from litege_core.engines.graph import dijkstra_rows, dijkstra_tree

    count = [q[1].shape[0] if q[0] is None else np.asarray(q[0]).size for q in (src, dst)]
    flip = count[0] > count[1]  # Dijkstra from the smaller side
    near, far = (dst, src) if flip else (src, dst)
    directed = not (near[0] is not None and far[0] is not None)
    if directed:  # free points: the directed graph of _with_free_points
        graph, near_ids, far_ids = _with_free_points(graph, points, near, far, k, tree, normals)
    else:  # nodes only: the graph as it is
        near_ids, far_ids = (np.asarray(q[0], dtype=np.int64) for q in (near, far))
    unique, order = np.unique(near_ids, return_inverse=True)
    read = None
    if paths:
        full, predecessors = dijkstra_tree(graph, unique, directed=directed)
        read = predecessors, far_ids
    else:
        full = dijkstra_rows(graph, unique, directed=directed)
    rows = full[order.reshape(-1)][:, far_ids]
    return (rows.T if flip else rows), read


def _with_free_points(
    graph: sp.csr_array,
    points: NDArray,
    near: tuple[NDArray | None, NDArray],
    far: tuple[NDArray | None, NDArray],
    k: int,
    tree: Any,
    normals: NDArray | None = None,
) -> tuple[sp.csr_array, NDArray, NDArray]:
    """The directed graph of :func:`graph_rows` with free query points, and the node ids of the
    ``near`` and ``far`` queries in it (chords lengthened to arcs with ``normals``, each free
    point taking its nearest point's).

    ``graph`` (upper-triangular ``(n, n)`` CSR, as :func:`~litege_core.engines.graph.edge_graph`
    builds it) becomes both directions of every edge; each free ``near`` point a new node with
    chords *out* to its ``k`` nearest points, each free ``far`` point one with chords *in* from
    them. Paths from near nodes then end at far nodes and never pass through a query point.
    Explicit zero lengths stay edges."""
    import scipy.sparse as sp

    n = points.shape[0]
    coo = graph.tocoo()
    rows, cols, lengths = [coo.row, coo.col], [coo.col, coo.row], [coo.data, coo.data]
    ids: list[NDArray] = []
    n_free = 0
    for side, (indices, canonical) in (("near", near), ("far", far)):
        if indices is not None:
            ids.append(np.asarray(indices, dtype=np.int64))
            continue
        if tree is None:
            from scipy.spatial import cKDTree

            tree = cKDTree(points)
        neighbours = min(k, n)
        chords, nearest = tree.query(canonical, k=neighbours)
        chords = chords.reshape(len(canonical), neighbours).reshape(-1)
        nearest = nearest.reshape(len(canonical), neighbours).reshape(-1)
        if normals is not None:
            from litege_core.engines.graph import arc_factors

            own = np.repeat(nearest.reshape(len(canonical), neighbours)[:, 0], neighbours)
            chords = chords * arc_factors(normals[own], normals[nearest])
        nodes = n + n_free + np.arange(len(canonical))
        n_free += len(canonical)
        free = np.repeat(nodes, neighbours)
        rows.append(free if side == "near" else nearest)
        cols.append(nearest if side == "near" else free)
        lengths.append(chords)
        ids.append(nodes)
    size = n + n_free
    augmented = sp.csr_array(
        (np.concatenate(lengths), (np.concatenate(rows), np.concatenate(cols))), shape=(size, size)
    )
    return augmented, ids[0], ids[1]


def fuse(
    network: NDArray,
    graph: NDArray,
    calibration: FusionCalibration,
    z_score: float,
    n: int,
    roughness: float,
    mesh: bool = False,
) -> NDArray:
    """``w · network + (1 − w) · graph / b`` (same units; ``mesh``: the graph is the mesh's
    ring graph); the network alone where the graph is ``inf``. ``network``, ``graph``: ``(S, T)``;
    ``roughness``: as :class:`ShapeGraph`'s; returns float64 ``(S, T)``."""
    weight = calibration.network_weight(z_score, n, roughness, mesh)
    network = np.asarray(network, np.float64)
    corrected = corrected_graph(network, graph, calibration, n, mesh, roughness)
    return weight * network + (1.0 - weight) * corrected


def corrected_graph(
    network: NDArray,
    graph: NDArray,
    calibration: FusionCalibration,
    n: int,
    mesh: bool = False,
    roughness: float = 0.0,
) -> NDArray:
    """``graph / b`` as :func:`fuse` blends it: the network's value where the graph is ``inf``.
    ``network``, ``graph``: ``(S, T)`` (same units); ``roughness``: a mesh's vertex noise
    (:func:`mesh_noise`; a cloud's bias ignores it); returns float64 ``(S, T)``."""
    corrected = np.asarray(graph, np.float64) / calibration.graph_bias(n, mesh, roughness)
    return np.where(np.isfinite(corrected), corrected, np.asarray(network, np.float64))


__all__ = [
    "MESH_RINGS",
    "ShapeGraph",
    "cloud_graph_key",
    "corrected_graph",
    "fuse",
    "fused_distances",
    "graph_faces",
    "graph_rows",
    "kept_arc_normals",
    "kept_graph_mesh",
    "kept_mesh_edges",
    "kept_mesh_noise",
    "pruned_knn_graph",
    "route_trees",
    "shape_graph",
]
