"""Exact (MMP) engine: analytic sphere, bounds, symmetry, backends, robustness."""

import numpy as np
import pytest

from litege_core.engines import (
    EdgeDijkstraEngine,
    EuclideanEngine,
    ExactGeodesicEngine,
    compute_distances,
)
from litege_core.engines._topology import MeshTopology
from litege_core.errors import ComputationError, InputError
from litege_core.shape import Shape


def great_circle(vertices: np.ndarray, sources: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(vertices[sources] @ vertices.T, -1.0, 1.0))


def max_face_depth(shape: Shape) -> float:
    """Largest gap between the unit sphere and a face plane: 1 - sqrt(1 - R_circ^2)."""
    corners = shape.vertices[shape.faces]
    a = np.linalg.norm(corners[:, 1] - corners[:, 2], axis=1)
    b = np.linalg.norm(corners[:, 0] - corners[:, 2], axis=1)
    c = np.linalg.norm(corners[:, 0] - corners[:, 1], axis=1)
    circumradius = a * b * c / (4.0 * shape.face_areas)
    return float((1.0 - np.sqrt(1.0 - circumradius**2)).max())


def test_exact_matches_great_circle_on_unit_icosphere(sphere4):
    # The icosphere is inscribed in the unit sphere; radially projecting a polyhedral path
    # onto the sphere stretches it by at most 1 / (1 - depth), so the polyhedral geodesic is
    # within a relative `depth` (max face-to-sphere gap, 1.14e-3 here) of the great circle.
    # Measured: max relative deficit 7.1e-4, and exact <= great circle everywhere.
    sources = np.arange(0, sphere4.n_points, 211)
    exact = compute_distances(sphere4, sources, "exact").distances
    analytic = great_circle(sphere4.vertices, sources)
    depth = max_face_depth(sphere4)
    assert 1e-3 < depth < 1.2e-3
    atol = 1e-7  # arccos(x) near x = 1 is only accurate to ~1.5e-8
    assert np.all(exact >= analytic * (1.0 - depth) - atol)
    assert np.all(exact <= analytic * (1.0 + depth) + atol)


def test_euclidean_le_exact_le_edge_dijkstra(bumpy_torus):
    sources = np.arange(0, bumpy_torus.n_points, 173)
    exact = ExactGeodesicEngine(bumpy_torus).distances(sources).distances
    lower = EuclideanEngine(bumpy_torus).distances(sources).distances
    upper = EdgeDijkstraEngine(bumpy_torus).distances(sources).distances
    assert np.all(lower <= exact * (1 + 1e-9) + 1e-12)
    assert np.all(exact <= upper * (1 + 1e-9) + 1e-12)
    # the bound is not trivial: edge paths are clearly longer somewhere
    assert (upper - exact).max() > 0.05


def test_exact_is_symmetric(sphere3):
    sources = np.arange(0, sphere3.n_points, 29)
    d = ExactGeodesicEngine(sphere3).distances(sources).distances[:, sources]
    np.testing.assert_allclose(d, d.T, rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(np.diag(d), 0.0)


def test_backends_agree(bumpy_torus):
    sources = np.array([0, 500, 1999])
    a = ExactGeodesicEngine(bumpy_torus, backend="pygeodesic").distances(sources)
    b = ExactGeodesicEngine(bumpy_torus, backend="gdist").distances(sources)
    np.testing.assert_allclose(a.distances, b.distances, rtol=1e-6, atol=0)
    assert a.params["backend"] == "pygeodesic" and b.params["backend"] == "gdist"


@pytest.fixture(scope="module")
def sphere2_rows(two_spheres):
    """Exact rows from vertices 0 and 38 (= 200 - 162) of one 162-vertex sphere alone."""
    one = Shape.from_arrays(two_spheres.vertices[:162], two_spheres.faces[:320])
    return ExactGeodesicEngine(one).distances([0, 38]).distances


@pytest.mark.parametrize("backend", ["pygeodesic", "gdist"])
def test_disconnected_components_give_inf(two_spheres, sphere2_rows, backend):
    # Raw pygeodesic fails at random here (OverflowError on a garbage source index for the
    # unreachable sphere); the engine solves each component on its own.
    for _ in range(5):
        rows = compute_distances(two_spheres, [0, 200], "exact", backend=backend).distances
        np.testing.assert_array_equal(rows[0, :162], sphere2_rows[0])
        np.testing.assert_allclose(rows[1, 162:], sphere2_rows[1], rtol=1e-12)  # shifted copy
    assert np.isfinite(rows[0, :162]).all() and np.isinf(rows[0, 162:]).all()
    assert np.isinf(rows[1, :162]).all() and np.isfinite(rows[1, 162:]).all()
    assert rows[0, 0] == 0.0 and rows[1, 200] == 0.0


@pytest.mark.parametrize("backend", ["pygeodesic", "gdist"])
def test_unreferenced_vertex_is_unreachable(sphere3, backend):
    # pygeodesic refuses a mesh whose last vertex is unused; the engine compacts the mesh.
    vertices = np.vstack([sphere3.vertices, [[3.0, 0.0, 0.0]]])
    shape = Shape.from_arrays(vertices, sphere3.faces)
    engine = ExactGeodesicEngine(shape, backend=backend)
    rows = engine.distances([0, 642]).distances
    reference = ExactGeodesicEngine(sphere3, backend=backend).distances([0]).distances[0]
    np.testing.assert_array_equal(rows[0, :642], reference)
    assert rows[0, 642] == np.inf
    assert rows[1, 642] == 0.0 and np.isinf(rows[1, :642]).all()


def test_degenerate_and_duplicate_faces_are_dropped(sphere3):
    # Both would segfault the C++ solver next to a neighbour face.
    faces = np.vstack([sphere3.faces, sphere3.faces[:3], [[0, 0, 5]], [[7, 8, 7]]])
    shape = Shape.from_arrays(sphere3.vertices, faces)
    engine = ExactGeodesicEngine(shape)
    assert engine.topology.n_dropped_faces == 5
    expected = ExactGeodesicEngine(sphere3).distances([3]).distances
    np.testing.assert_array_equal(engine.distances([3]).distances, expected)


def test_nonmanifold_edge_is_refused_before_the_solver_runs():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    shape = Shape.from_arrays(vertices, faces)
    with pytest.raises(InputError, match="needs a manifold mesh"):
        ExactGeodesicEngine(shape)
    # the edge graph and the heat method still work on it
    assert np.isfinite(compute_distances(shape, [2], "edge_dijkstra").distances).all()
    assert np.isfinite(compute_distances(shape, [2], "heat").distances).all()


def test_point_cloud_is_refused(sphere_cloud):
    with pytest.raises(InputError, match="needs a triangle mesh"):
        ExactGeodesicEngine(sphere_cloud)
    with pytest.raises(InputError, match="needs a triangle mesh"):
        EdgeDijkstraEngine(sphere_cloud)


@pytest.mark.parametrize(
    "options", [{"backend": "libigl"}, {"n_workers": 0}, {"n_workers": 1.5}, {"n_workers": True}]
)
def test_bad_options(sphere3, options):
    with pytest.raises(InputError):
        ExactGeodesicEngine(sphere3, **options)


def test_solver_is_built_lazily(sphere3):
    engine = ExactGeodesicEngine(sphere3)
    assert engine._solver is None
    engine.distances([1])
    assert engine._solver is not None
    assert engine.prepare() is engine


def test_process_pool_matches_in_process(sphere3):
    sources = np.arange(0, sphere3.n_points, 64)
    serial = ExactGeodesicEngine(sphere3).distances(sources).distances
    pooled = ExactGeodesicEngine(sphere3, n_workers=2).distances(sources).distances
    np.testing.assert_array_equal(serial, pooled)


def test_foreign_failures_become_computation_error(sphere3, monkeypatch):
    engine = ExactGeodesicEngine(sphere3).prepare()

    class Failing:
        def geodesicDistances(self, *args):  # noqa: N802 - pygeodesic's name
            return None, None  # what pygeodesic returns on error

    _, solver = engine._solver.solver(0)
    monkeypatch.setattr(solver, "_algorithm", Failing())
    with pytest.raises(ComputationError, match="pygeodesic"):
        engine.distances([0])

    gdist_engine = ExactGeodesicEngine(sphere3, backend="gdist").prepare()

    def overflow(*args, **kwargs):
        raise OverflowError("Python integer 2748550400 out of bounds for int32")

    _, gdist_solver = gdist_engine._solver.solver(0)
    monkeypatch.setattr(gdist_solver, "_compute", overflow)
    with pytest.raises(ComputationError, match="OverflowError"):
        gdist_engine.distances([0])


def test_worker_crash_becomes_computation_error(sphere3):
    # A non-manifold edge segfaults the C++ solver; force it past the guard into a worker.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 1]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    engine = ExactGeodesicEngine(sphere3, n_workers=2)
    engine._topology = MeshTopology.from_arrays(vertices, faces)
    with pytest.raises(ComputationError, match="worker process died"):
        engine.distances([0, 1])
