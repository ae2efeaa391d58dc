"""ClassicalSolver: the heat / exact / graph methods behind the service's ``method`` switch."""

import numpy as np
import pytest

from litege_core.engines import (
    ClassicalSolver,
    ExactGeodesicEngine,
    HeatGeodesicEngine,
    KnnGraphEngine,
    PointCloudHeatEngine,
    surface_point_distances,
)
from litege_core.engines.graph import dijkstra_path
from litege_core.engines.solver import ENGINE_NAMES, MeshDescent, polyline_length
from litege_core.errors import (
    ArrayShapeError,
    IndexOutOfRangeError,
    InputError,
    MethodNotApplicableError,
    MethodSizeLimitError,
    ShapeTooLargeError,
)
from litege_core.projection import MeshProjector
from litege_core.shape import Shape

METHODS = ("heat", "exact", "graph")


def sphere_points(count: int, seed: int, radius: float = 1.0) -> np.ndarray:
    points = np.random.default_rng(seed).standard_normal((count, 3))
    return radius * points / np.linalg.norm(points, axis=1, keepdims=True)


def off_surface(shape: Shape, points: np.ndarray) -> np.ndarray:
    """Distance of each point to the mesh (exact closest point)."""
    return MeshProjector(shape.vertices, shape.faces).project(points).distance


# ----------------------------------------------------------------------- construction


def test_engine_names_and_params(sphere3, sphere_cloud):
    assert ClassicalSolver(sphere3, "exact").engine == "exact-mmp"
    assert ClassicalSolver(sphere3, "heat").engine == "heat"
    assert ClassicalSolver(sphere_cloud, "heat").engine == "pointcloud-heat"
    assert ClassicalSolver(sphere3, "graph").engine == "knn-graph"
    assert ClassicalSolver(sphere_cloud, "graph", k=6).params == {"k": 6}
    assert ClassicalSolver(sphere3, "heat").params == {"t_coef": 1.0, "use_robust": True}
    assert {ClassicalSolver(sphere3, m).engine for m in METHODS} <= set(ENGINE_NAMES)


def test_exact_on_a_point_cloud_is_refused(sphere_cloud):
    with pytest.raises(MethodNotApplicableError, match="point cloud") as caught:
        ClassicalSolver(sphere_cloud, "exact")
    assert isinstance(caught.value, InputError)
    assert caught.value.code == "method-not-applicable"


def test_exact_above_the_size_bound_is_refused(sphere3):
    with pytest.raises(MethodSizeLimitError, match="at most 641 vertices") as caught:
        ClassicalSolver(sphere3, "exact", max_exact_vertices=641)
    error = caught.value
    assert isinstance(error, MethodNotApplicableError) and isinstance(error, InputError)
    assert not isinstance(error, ShapeTooLargeError)  # a 422, not the upload bound's 413
    assert error.details["n_vertices"] == 642 and error.details["max_vertices"] == 641
    assert error.code == "method-size-limit"
    ClassicalSolver(sphere3, "exact", max_exact_vertices=642)  # at the bound: accepted
    ClassicalSolver(sphere3, "exact", max_exact_vertices=None)  # no bound
    ClassicalSolver(sphere3, "heat", max_exact_vertices=10)  # only exact is bounded


@pytest.mark.parametrize(
    ("method", "options"),
    [
        ("learned", {}),
        ("knn_graph", {}),
        ("graph", {"k": 0}),
        ("exact", {"max_exact_vertices": 0}),
        ("exact", {"max_exact_vertices": True}),
        ("exact", {"backend": "fast"}),
        ("heat", {"t_coef": -1.0}),
    ],
)
def test_bad_method_or_option(sphere3, method, options):
    with pytest.raises(InputError):
        ClassicalSolver(sphere3, method, **options)


# ----------------------------------------------------------------------- index queries


@pytest.mark.parametrize(
    ("method", "engine_class", "options"),
    [
        ("exact", ExactGeodesicEngine, {}),
        ("heat", HeatGeodesicEngine, {"use_robust": True}),
        ("graph", KnnGraphEngine, {}),
    ],
)
def test_index_distances_equal_the_engines_on_a_mesh(bumpy_torus, method, engine_class, options):
    solver = ClassicalSolver(bumpy_torus, method)
    sources = np.array([5, 1000, 5, 77])
    targets = np.array([0, 1, 2, 1999, 5, 1000])
    reference = engine_class(bumpy_torus, **options).distances(sources).distances
    got = solver.distances(sources, targets, dtype=np.float64)
    np.testing.assert_allclose(got, reference[:, targets], rtol=0, atol=1e-9)
    fields = solver.distances(sources, dtype=np.float64)  # targets=None: all vertices
    np.testing.assert_allclose(fields, reference, rtol=0, atol=1e-9)
    single = solver.distances(sources, targets)
    assert single.dtype == np.float32 and single.shape == (4, 6)
    np.testing.assert_allclose(single, reference[:, targets], rtol=1e-6)
    np.testing.assert_allclose(solver.distance_field(1000), reference[1], rtol=1e-6)


@pytest.mark.parametrize(
    ("method", "engine_class"), [("heat", PointCloudHeatEngine), ("graph", KnnGraphEngine)]
)
def test_index_distances_equal_the_engines_on_a_cloud(sphere_cloud, method, engine_class):
    solver = ClassicalSolver(sphere_cloud, method)
    reference = engine_class(sphere_cloud).distances([3, 1500]).distances
    np.testing.assert_allclose(
        solver.distances([3, 1500], "all", dtype=np.float64), reference, rtol=0, atol=1e-9
    )


def test_bad_queries(sphere3):
    solver = ClassicalSolver(sphere3, "graph")
    with pytest.raises(IndexOutOfRangeError):
        solver.distances([642])
    with pytest.raises(ArrayShapeError):
        solver.distances([1.0, 2.0])  # floats are not indices
    with pytest.raises(ArrayShapeError):
        solver.path([0, 1], 2)  # one point per end
    with pytest.raises(InputError):
        solver.distances([0], dtype=np.int32)


# ----------------------------------------------------------------------- xyz queries


def test_exact_xyz_queries_equal_the_surface_point_reference(sphere3):
    solver = ClassicalSolver(sphere3, "exact")
    points = sphere_points(6, seed=3, radius=1.05)  # off the surface: snapped onto it
    projection = MeshProjector(sphere3.vertices, sphere3.faces).project(points)
    reference = surface_point_distances(
        sphere3, projection.face_index, projection.barycentric, to_vertices=True
    )
    got = solver.distances(points, points, dtype=np.float64)
    np.testing.assert_allclose(got, reference.distances, rtol=0, atol=1e-9)
    to_vertices = solver.distances(points, None, dtype=np.float64)
    np.testing.assert_allclose(to_vertices, reference.to_vertices, rtol=0, atol=1e-9)
    # index sources to xyz targets: the same numbers, transposed
    mixed = solver.distances([0, 100], points, dtype=np.float64)
    np.testing.assert_allclose(mixed, reference.to_vertices[:, [0, 100]].T, rtol=0, atol=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_xyz_at_vertices_equal_index_queries(sphere3, method):
    # an xyz point exactly at a vertex snaps onto that vertex: the same answer as its index
    solver = ClassicalSolver(sphere3, method)
    indices = np.array([0, 11, 300, 641])
    by_index = solver.distances(indices, indices[::-1], dtype=np.float64)
    by_xyz = solver.distances(
        sphere3.vertices[indices], sphere3.vertices[indices[::-1]], dtype=float
    )
    np.testing.assert_allclose(by_xyz, by_index, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("method", METHODS)
def test_identical_points_give_exactly_zero(sphere3, method):
    solver = ClassicalSolver(sphere3, method)
    points = sphere_points(3, seed=4)
    query = np.vstack([points, points[1], sphere3.vertices[7]])  # a repeat and a vertex
    distances = solver.distances(query, query)
    assert np.all(np.diag(distances) == 0.0)
    assert distances[1, 3] == 0.0 and distances[3, 1] == 0.0
    assert solver.distances([7], sphere3.vertices[7])[0, 0] == 0.0
    off_diagonal = distances[~np.eye(5, dtype=bool)]
    assert np.count_nonzero(off_diagonal == 0) == 2
    assert solver.path(points[0], points[0]).length == 0.0


@pytest.mark.parametrize("method", ("heat", "graph"))
def test_xyz_queries_on_a_cloud_snap_to_the_nearest_point(sphere_cloud, method):
    solver = ClassicalSolver(sphere_cloud, method)
    query = sphere_cloud.vertices[[10, 20, 30]] * 1.01 + 1e-4  # near, not on, three points
    np.testing.assert_array_equal(
        solver.distances(query, [10, 20, 30]), solver.distances([10, 20, 30], [10, 20, 30])
    )


def test_heat_xyz_queries_are_close_to_exact(bumpy_torus):
    points = bumpy_torus.vertices[[3, 500, 1200, 1800]] + 0.01  # snapped between vertices
    exact = ClassicalSolver(bumpy_torus, "exact").distances(points, points, dtype=float)
    heat = ClassicalSolver(bumpy_torus, "heat").distances(points, points, dtype=float)
    off = ~np.eye(4, dtype=bool)
    relative = np.abs(heat[off] - exact[off]) / exact[off]
    assert relative.max() < 0.08, relative  # measured 0.05 at most


def test_graph_xyz_queries_match_a_brute_force_reference(sphere3):
    """A surface point joins the k-NN graph through its triangle's corners; check against
    min over corner pairs of |p − a| + D_graph(a, b) + |b − q|."""
    solver = ClassicalSolver(sphere3, "graph")
    points = sphere_points(5, seed=6)
    projection = MeshProjector(sphere3.vertices, sphere3.faces).project(points)
    graph = KnnGraphEngine(sphere3).distances(np.arange(642)).distances
    corners = sphere3.faces[projection.face_index]
    expected = np.empty((5, 5))
    for i in range(5):
        for j in range(5):
            a, b = corners[i], corners[j]
            to_a = np.linalg.norm(sphere3.vertices[a] - projection.points[i], axis=1)
            to_b = np.linalg.norm(sphere3.vertices[b] - projection.points[j], axis=1)
            expected[i, j] = np.min(to_a[:, None] + graph[np.ix_(a, b)] + to_b[None, :])
    np.fill_diagonal(expected, 0.0)  # the random points lie in five different triangles
    assert np.unique(projection.face_index).size == 5
    got = solver.distances(points, points, dtype=np.float64)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    euclidean = np.linalg.norm(projection.points[:, None] - projection.points[None], axis=2)
    assert np.all(got >= euclidean - 1e-12)


def test_refined_mesh_is_kept_for_the_last_query_set_only(sphere3):
    solver = ClassicalSolver(sphere3, "exact")
    first, second = sphere_points(2, seed=7), sphere_points(2, seed=8)
    a = solver.distances(first, first)
    kept = solver._last
    assert kept is not None
    solver.path(first[1], first[0])  # the same point set: the refined mesh is reused
    assert solver._last is kept
    solver.distances(second, second)
    assert solver._last is not kept and solver._last[0] != kept[0]
    np.testing.assert_array_equal(solver.distances(first, first), a)


def test_other_components_are_unreachable(two_spheres):
    for method in METHODS:
        solver = ClassicalSolver(two_spheres, method)
        distances = solver.distances([0, 200], [1, 300])
        assert np.isfinite(distances[0, 0]) and np.isfinite(distances[1, 1])
        assert np.isinf(distances[0, 1]) and np.isinf(distances[1, 0])
        with pytest.raises(InputError, match="different connected components"):
            solver.path(0, 300)


# ----------------------------------------------------------------------- paths

# measured over these pairs: heat paths at most 1.2% (sphere) / 1.6% (torus) longer than the
# exact geodesic; graph paths (chords between vertices) within 9% either way
PATH_TOLERANCE = {"exact": 1e-6, "heat": 0.04, "graph": 0.15}


@pytest.mark.parametrize("shape_name", ["sphere3", "bumpy_torus"])
@pytest.mark.parametrize("method", METHODS)
def test_vertex_paths_lie_on_the_surface_and_are_about_geodesic(request, shape_name, method):
    shape = request.getfixturevalue(shape_name)
    solver = ClassicalSolver(shape, method)
    exact = ClassicalSolver(shape, "exact")
    pairs = np.random.default_rng(9).integers(shape.n_points, size=(6, 2))
    for source, target in pairs.tolist():
        path = solver.path(source, target)
        assert path.engine == solver.engine
        assert path.points.shape[1] == 3 and path.points.shape[0] >= 2
        assert not path.points.flags.writeable
        np.testing.assert_array_equal(path.points[0], shape.vertices[source])
        np.testing.assert_array_equal(path.points[-1], shape.vertices[target])
        assert off_surface(shape, path.points).max() < 1e-9
        assert path.length == pytest.approx(polyline_length(path.points), rel=1e-12)
        geodesic = exact.distances([source], [target], dtype=np.float64)[0, 0]
        assert abs(path.length - geodesic) <= PATH_TOLERANCE[method] * geodesic
        if method in ("exact", "heat"):  # on the surface: never shorter than the geodesic
            assert path.length >= geodesic * (1 - 1e-9)
        if method in ("exact", "graph"):
            assert path.distance == pytest.approx(path.length, rel=1e-9)


def test_heat_path_segments_run_on_the_surface(bumpy_torus):
    # every segment (not only its ends) lies on the surface: sample the segments
    path = ClassicalSolver(bumpy_torus, "heat").path(10, 1500)
    t = np.linspace(0.0, 1.0, 7)[1:-1, None, None]
    inner = (1 - t) * path.points[:-1] + t * path.points[1:]
    assert off_surface(bumpy_torus, inner.reshape(-1, 3)).max() < 1e-9
    assert path.segments == ((0, "heat-descent"),)


@pytest.mark.parametrize("method", ("exact", "heat"))
def test_xyz_paths_start_and_end_at_the_snapped_points(sphere3, method):
    source, target = sphere_points(2, seed=10, radius=0.97)
    snapped = MeshProjector(sphere3.vertices, sphere3.faces).project(np.vstack([source, target]))
    path = ClassicalSolver(sphere3, method).path(source, target)
    np.testing.assert_allclose(path.points[0], snapped.points[0], atol=1e-12)
    np.testing.assert_allclose(path.points[-1], snapped.points[1], atol=1e-12)
    assert off_surface(sphere3, path.points).max() < 1e-9
    reference = surface_point_distances(sphere3, snapped.face_index, snapped.barycentric)
    geodesic = reference.distances[0, 1]
    assert path.length >= geodesic * (1 - 1e-9)
    assert path.length <= geodesic * (1 + PATH_TOLERANCE[method])


def test_graph_xyz_path_goes_through_triangle_corners(sphere3):
    source, target = sphere_points(2, seed=11)
    solver = ClassicalSolver(sphere3, "graph")
    path = solver.path(source, target)
    snapped = MeshProjector(sphere3.vertices, sphere3.faces).project(np.vstack([source, target]))
    np.testing.assert_allclose(path.points[[0, -1]], snapped.points, atol=1e-12)
    assert path.length == pytest.approx(solver.distances(source, target, dtype=float)[0, 0])
    # the first hop stays in the source's triangle: it ends at one of its corners
    corners = sphere3.vertices[sphere3.faces[snapped.face_index[0]]]
    assert np.min(np.linalg.norm(corners - path.points[1], axis=1)) == 0.0


@pytest.mark.parametrize("method", ("heat", "graph"))
def test_cloud_paths_visit_cloud_points(sphere_cloud, method):
    solver = ClassicalSolver(sphere_cloud, method)
    exact_sphere = np.arccos(np.clip(sphere_cloud.vertices[5] @ sphere_cloud.vertices[900], -1, 1))
    path = solver.path(5, 900)
    np.testing.assert_array_equal(path.points[0], sphere_cloud.vertices[5])
    np.testing.assert_array_equal(path.points[-1], sphere_cloud.vertices[900])
    nearest = np.min(
        np.linalg.norm(path.points[:, None] - sphere_cloud.vertices[None], axis=2), axis=1
    )
    assert nearest.max() == 0.0
    assert abs(path.length - exact_sphere) < 0.1 * exact_sphere  # great-circle arc


def test_stuck_heat_descent_is_finished_along_mesh_edges(flat_grid, monkeypatch):
    solver = ClassicalSolver(flat_grid, "heat")
    engine = solver._base.engine
    true_field = engine.distance

    def pitted(source):
        field = np.array(true_field(source))
        field[112] = -1.0  # a spurious minimum in the middle of the square
        return field

    monkeypatch.setattr(engine, "distance", pitted)
    path = solver.path(0, 224)  # corner to corner, across the pit
    assert path.segments[0][1] == "mesh-edges" and path.segments[-1][1] == "heat-descent"
    split = path.segments[-1][0]
    np.testing.assert_array_equal(path.points[split], flat_grid.vertices[112])
    np.testing.assert_array_equal(path.points[0], flat_grid.vertices[0])
    np.testing.assert_array_equal(path.points[-1], flat_grid.vertices[224])
    _, nodes = dijkstra_path(solver._base._finish.graph, 0, 112)
    np.testing.assert_array_equal(path.points[: split + 1], flat_grid.vertices[nodes])
    assert np.all(path.points[:, 2] == 0.0)


def test_mesh_descent_of_an_exact_field_is_nearly_straight(flat_grid):
    # the field |x − goal| on a flat square: the descent is close to the straight segment
    goal, start = 3, 220
    field = np.linalg.norm(flat_grid.vertices - flat_grid.vertices[goal], axis=1)
    points, last, reached = MeshDescent(flat_grid.vertices, flat_grid.faces).walk(
        field, goal, start
    )
    assert reached and last == goal
    straight = field[start]
    assert straight <= polyline_length(points) <= 1.01 * straight
    assert np.all(np.diff(np.linalg.norm(points - flat_grid.vertices[goal], axis=1)) < 0)


def test_exact_paths_with_the_gdist_backend_use_pygeodesic(sphere3):
    # gdist has no path output: the path comes from pygeodesic (same algorithm)
    gdist = ClassicalSolver(sphere3, "exact", backend="gdist")
    pygeodesic = ClassicalSolver(sphere3, "exact")
    np.testing.assert_array_equal(gdist.path(0, 300).points, pygeodesic.path(0, 300).points)
    assert gdist.params == {"backend": "gdist"}
    np.testing.assert_allclose(
        gdist.distances([0], [300], dtype=float), pygeodesic.distances([0], [300], dtype=float)
    )


@pytest.mark.parametrize("method", METHODS)
def test_duplicated_vertices_are_zero_apart(sphere3, method):
    # vertex 642 is an unreferenced copy of vertex 0: the engines cannot reach it (+inf),
    # but the two are the same point
    shape = Shape.from_arrays(np.vstack([sphere3.vertices, sphere3.vertices[:1]]), sphere3.faces)
    solver = ClassicalSolver(shape, method)
    distances = solver.distances([0, 642, 5], [642, 0, 5])
    assert distances[0, 0] == 0.0 and distances[1, 1] == 0.0 and distances[2, 2] == 0.0
    assert distances[1, 2] == np.inf or method == "graph"  # the k-NN graph joins the copy


@pytest.mark.parametrize("method", ["exact", "heat", "graph"])
def test_a_triangle_soup_is_answered_as_its_welded_mesh(bumpy_torus, method):
    """Every corner its own vertex (a soup, or an OBJ split along its UV seams): index and xyz
    queries, fields and paths equal the welded mesh's at every copy."""
    if method == "exact":
        pytest.importorskip("pygeodesic")
    vertices, faces = np.asarray(bumpy_torus.vertices), np.asarray(bumpy_torus.faces)
    corner = faces.reshape(-1)  # soup vertex → welded vertex
    soup = Shape.from_arrays(vertices[corner], np.arange(corner.size).reshape(-1, 3))
    welded, split = ClassicalSolver(bumpy_torus, method), ClassicalSolver(soup, method)
    xyz = vertices[[3, 500]] * 1.01  # off the surface: projected
    np.testing.assert_allclose(
        split.distances([0, 40], [5, 900, 3000]),
        welded.distances(corner[[0, 40]], corner[[5, 900, 3000]]),
        rtol=1e-6,
    )
    np.testing.assert_allclose(
        split.distances(xyz, [5, 900]), welded.distances(xyz, corner[[5, 900]]), rtol=1e-6
    )
    np.testing.assert_allclose(
        split.distance_field(7), welded.distance_field(int(corner[7]))[corner], rtol=1e-6
    )
    path, expected = split.path(0, 3000), welded.path(int(corner[0]), int(corner[3000]))
    np.testing.assert_allclose(path.length, expected.length, rtol=1e-9)
