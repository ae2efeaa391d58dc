"""Paths stay on the surface every time (issue 13, item 6): walks that stall or run out of
steps are finished by an on-surface route, and :attr:`GeodesicPath.segments` names the method
of each part. The learned distance here is the untrained toy network of ``conftest.py``
(roughly Euclidean plus noise), so walks stall where the surface bends away; ``max_steps``
forces the rest."""

import importlib.util
import itertools

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from litege_core.engines import ExactGeodesicEngine
from litege_core.engines.graph import knn_graph
from litege_core.errors import InputError
from litege_core.learned import shape_samples
from litege_core.learned.paths import (
    CLOUD_CANDIDATES,
    CLOUD_STEP_FRACTION,
    EDGE_FLIP,
    KNN_GRAPH,
    LEARNED,
    MESH_EDGES,
    PATH_METHODS,
    STRAIGHT,
    SurfaceRouter,
)
from litege_core.shape import Shape
from litege_core.synth import generate_shape

MESH_ROUTE = EDGE_FLIP if importlib.util.find_spec("potpourri3d") else MESH_EDGES
"""The route that finishes stalled walks on a manifold mesh (the 'engines' extra gives
potpourri3d's edge-flip geodesics; without it, shortest edge paths)."""


@pytest.fixture(scope="module")
def animal() -> Shape:
    """A procedural cat (y-up), 3900 vertices."""
    return generate_shape("quadruped", "cat", 7, rest_pose=True).to_shape()


@pytest.fixture(scope="module")
def torus() -> Shape:
    mesh = trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=48)
    return Shape.from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))


def _max_edge(shape: Shape) -> float:
    faces = np.asarray(shape.faces)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return float(np.linalg.norm(np.diff(shape.vertices[edges], axis=1), axis=2).max())


def _check_parts(path) -> list[tuple[int, int, str]]:
    """``(start, stop, method)`` of every part; checks the ``segments`` contract."""
    starts = [start for start, _ in path.segments]
    assert starts[0] == 0 and all(a < b for a, b in itertools.pairwise(starts))
    assert starts[-1] < path.points.shape[0] - 1 or path.length == 0.0
    assert {method for _, method in path.segments} <= set(PATH_METHODS)
    stops = [*starts[1:], path.points.shape[0] - 1]
    return [(a, b, m) for (a, m), b in zip(path.segments, stops, strict=True)]


def _assert_on_mesh(shape: Shape, path, source: np.ndarray, target: np.ndarray) -> None:
    mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
    diagonal = float(np.linalg.norm(np.ptp(shape.vertices, axis=0)))
    points = np.asarray(path.points)
    np.testing.assert_allclose(points[0], source, atol=1e-12 * diagonal)
    np.testing.assert_allclose(points[-1], target, atol=1e-12 * diagonal)
    assert trimesh.proximity.closest_point(mesh, points)[1].max() <= 1e-6 * diagonal
    hops = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert hops.max(initial=0.0) <= _max_edge(shape) * (1 + 1e-9)  # no jump through the air
    assert path.length == pytest.approx(hops.sum())
    parts = _check_parts(path)
    assert path.converged == (path.segments == ((0, LEARNED),))  # default tolerance
    for start, stop, method in parts:
        assert method != STRAIGHT  # connected meshes
        if method == LEARNED:
            # the walk: target, then one point per accepted step (+ the source if it got there)
            assert stop - start == path.n_steps + (1 if path.converged else 0)
        else:  # a route: straight inside triangles, so its midpoints are on the mesh too
            part = points[start : stop + 1]
            middle = 0.5 * (part[1:] + part[:-1])
            assert trimesh.proximity.closest_point(mesh, middle)[1].max() <= 1e-6 * diagonal


@pytest.mark.parametrize("max_steps", [0, 1, 4, None])
def test_mesh_paths_stay_on_the_surface(toy_predictor, animal, max_steps):
    state = toy_predictor.register(animal)
    rng = np.random.default_rng(0)
    sources, targets = rng.integers(0, animal.n_points, (2, 12))
    paths = toy_predictor.paths(state, sources, targets, max_steps=max_steps)
    methods = set()
    for path, s, t in zip(paths, sources, targets, strict=True):
        _assert_on_mesh(animal, path, animal.vertices[s], animal.vertices[t])
        methods |= {method for _, method in path.segments}
    if max_steps is not None:
        assert MESH_ROUTE in methods  # forced stalls were finished by routes
        assert not any(p.converged for p in paths if p.n_steps < max_steps)


def test_xyz_ends_and_a_torus(toy_predictor, torus):
    state = toy_predictor.register(torus)
    rng = np.random.default_rng(1)
    ends = torus.vertices[rng.integers(0, torus.n_points, (2, 6))]
    sources = ends[0] * 1.03 + 0.01  # off the surface: projected
    targets = ends[1]
    mesh = trimesh.Trimesh(torus.vertices, torus.faces, process=False)
    snapped = trimesh.proximity.closest_point(mesh, sources)[0]
    for max_steps in (1, None):
        paths = toy_predictor.paths(state, sources, targets, max_steps=max_steps)
        for path, s, t in zip(paths, snapped, targets, strict=True):
            _assert_on_mesh(torus, path, s, t)


def test_point_cloud_walks_are_finished_on_the_knn_graph(toy_predictor, animal):
    points = shape_samples(animal, 3000, seed=2)
    cloud = Shape.from_arrays(points)
    state = toy_predictor.register(cloud)
    tree = cKDTree(points)
    spacing = float(tree.query(points, k=2)[0][:, 1].mean())
    step = CLOUD_STEP_FRACTION * spacing
    walker_reach = 2 * step + float(tree.query(points, k=CLOUD_CANDIDATES)[0][:, -1].max())
    graph = knn_graph(points, 8)
    graph = graph + graph.T
    rng = np.random.default_rng(3)
    sources, targets = rng.integers(0, cloud.n_points, (2, 10))
    for max_steps in (1, None):
        paths = toy_predictor.paths(state, sources, targets, max_steps=max_steps)
        for path, s, t in zip(paths, sources, targets, strict=True):
            np.testing.assert_array_equal(path.points[[0, -1]], points[[s, t]])
            distance, index = tree.query(path.points)
            assert distance.max() == 0.0  # every vertex is a cloud point
            for start, stop, method in _check_parts(path):
                if method == LEARNED:
                    hops = np.linalg.norm(np.diff(path.points[start : stop + 1], axis=0), axis=1)
                    assert hops.max(initial=0.0) <= walker_reach
                else:
                    assert method == KNN_GRAPH
                    chain = index[start : stop + 1]
                    assert all(graph[a, b] > 0 for a, b in itertools.pairwise(chain))
            if max_steps == 1:
                assert path.segments[0][1] == KNN_GRAPH and not path.converged


def test_surface_routes_skip_the_walk(toy_predictor, animal, torus):
    state = toy_predictor.register(animal)
    rng = np.random.default_rng(5)
    sources, targets = rng.integers(0, animal.n_points, (2, 8))
    targets[0] = sources[0]  # a point to itself: a one-point route
    router = SurfaceRouter(animal.vertices, animal.faces)
    paths = toy_predictor.paths(state, sources, targets, route="surface")
    for path, (route, method) in zip(paths, router.routes(targets, sources), strict=True):
        assert path.n_steps == 0 and path.converged and path.segments == ((0, method),)
        assert method == (MESH_ROUTE if route.shape[0] > 1 else MESH_EDGES)
        expected = route[::-1] if route.shape[0] > 1 else route[[0, 0]]
        np.testing.assert_allclose(path.points, expected, atol=1e-12)  # read from the source
        assert path.length == pytest.approx(np.linalg.norm(np.diff(expected, axis=0), axis=1).sum())
    # xyz ends: straight inside their triangles, the route between their nearest corners
    torus_state = toy_predictor.register(torus)
    ends = torus.vertices[rng.integers(0, torus.n_points, (2, 4))]
    sources = ends[0] * 1.03 + 0.01  # off the surface: projected
    mesh = trimesh.Trimesh(torus.vertices, torus.faces, process=False)
    diagonal = float(np.linalg.norm(np.ptp(torus.vertices, axis=0)))
    for path in toy_predictor.paths(torus_state, sources, ends[1], route="surface"):
        assert path.n_steps == 0 and path.segments == ((0, MESH_ROUTE),)
        points = np.asarray(path.points)
        middle = 0.5 * (points[1:] + points[:-1])
        assert trimesh.proximity.closest_point(mesh, middle)[1].max() <= 1e-6 * diagonal
    # a cloud: its k-NN graph's route; an unknown route is refused
    cloud = Shape.from_arrays(shape_samples(animal, 2000, seed=2))
    cloud_state = toy_predictor.register(cloud)
    path = toy_predictor.path(cloud_state, 3, 400, route="surface")
    assert path.segments == ((0, KNN_GRAPH),) and path.n_steps == 0
    with pytest.raises(InputError, match="route"):
        toy_predictor.path(cloud_state, 3, 400, route="shortest")


# ------------------------------------------------------------------------ the router


def test_edge_flip_routes_are_geodesics(animal):
    pytest.importorskip("potpourri3d")
    pytest.importorskip("pygeodesic")
    router = SurfaceRouter(animal.vertices, animal.faces)
    rng = np.random.default_rng(4)
    starts, ends = rng.integers(0, animal.n_points, (2, 6))
    exact = ExactGeodesicEngine(animal).distances(starts).distances[np.arange(6), ends]
    edges = SurfaceRouter(animal.vertices, animal.faces)
    edges._flip_refused = True  # the fallback: shortest edge path
    for (route, method), (fallback, other), a, b, d in zip(
        router.routes(starts, ends), edges.routes(starts, ends), starts, ends, exact, strict=True
    ):
        assert (method, other) == (EDGE_FLIP, MESH_EDGES)
        np.testing.assert_array_equal(route[[0, -1]], animal.vertices[[a, b]])
        np.testing.assert_array_equal(fallback[[0, -1]], animal.vertices[[a, b]])
        length = np.linalg.norm(np.diff(route, axis=0), axis=1).sum()
        edge_length = np.linalg.norm(np.diff(fallback, axis=0), axis=1).sum()
        assert d * (1 - 1e-9) <= length <= edge_length * (1 + 1e-9)
        assert length <= 1.05 * d  # locally shortest from the edge path: at most a few % off


def test_a_given_cloud_graph_routes_and_its_gaps_fall_back_on_the_knn_graph():
    import scipy.sparse as sp

    points = np.column_stack([np.linspace(0.0, 1.0, 40), np.zeros(40), np.zeros(40)])
    full = knn_graph(points, 4)
    rows, cols = full.nonzero()
    split = (rows < 20) == (cols < 20)  # the given graph: two halves, no edge between them
    given = sp.csr_array((full.data[split], (rows[split], cols[split])), shape=full.shape)
    router = SurfaceRouter(points, None, given)
    (inside, how_inside), (across, how_across) = router.routes(np.array([0, 0]), [10, 30])
    assert how_inside == how_across == KNN_GRAPH  # never a straight jump where k-NN joins them
    np.testing.assert_allclose(np.linalg.norm(np.diff(across, axis=0), axis=1).sum(), 30 / 39)
    np.testing.assert_allclose(np.linalg.norm(np.diff(inside, axis=0), axis=1).sum(), 10 / 39)
    assert inside[:, 0].max() <= points[19, 0]  # the given graph's route, inside its half


def test_router_falls_back_on_meshes_geometry_central_refuses(sphere_mesh):
    vertices, faces = sphere_mesh
    extra = np.array([[faces[0, 0], faces[0, 1], faces[40, 2]]])  # a third face on one edge
    router = SurfaceRouter(vertices, np.concatenate([faces, extra]))
    ((route, method),) = router.routes([0], [300])
    assert method == MESH_EDGES
    edges = {tuple(sorted(e)) for f in faces for e in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0]))}
    _, chain = cKDTree(vertices).query(route)
    assert all(tuple(sorted((a, b))) in edges for a, b in itertools.pairwise(chain))


def test_straight_only_between_components(sphere_mesh):
    vertices, faces = sphere_mesh
    n = vertices.shape[0]
    two = SurfaceRouter(
        np.concatenate([vertices, vertices + 3.0]), np.concatenate([faces, faces + n])
    )
    (across, method), (within, other), (same, third) = two.routes([0, 0, 5], [n + 7, 9, 5])
    assert method == STRAIGHT and across.shape == (2, 3)
    assert other == MESH_ROUTE and within.shape[0] > 2
    assert same.shape == (1, 3) and third == MESH_EDGES


def test_routes_on_a_triangle_soup_cross_its_seams(sphere_mesh):
    """A soup (every corner its own vertex) routes as the welded mesh, not straight between
    triangles: each copy of a position is routed from its first copy."""
    vertices, faces = sphere_mesh
    corner = faces.reshape(-1)  # soup vertex → welded vertex
    soup = SurfaceRouter(vertices[corner], np.arange(corner.size).reshape(-1, 3))
    welded = SurfaceRouter(vertices, faces)
    starts, ends = np.array([0, 5, 99]), np.array([700, 301, 2])
    for (route, method), (expected, how) in zip(
        soup.routes(starts, ends), welded.routes(corner[starts], corner[ends]), strict=True
    ):
        assert method == how != STRAIGHT
        np.testing.assert_allclose(route, expected, atol=1e-12)
