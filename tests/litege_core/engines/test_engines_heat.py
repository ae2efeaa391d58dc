"""Heat-method engines (potpourri3d) against exact and analytic distances."""

import numpy as np
import pytest

from litege_core.engines import (
    ExactGeodesicEngine,
    HeatGeodesicEngine,
    PointCloudHeatEngine,
    compute_distances,
)
from litege_core.errors import ComputationError, InputError
from litege_core.shape import Shape


def mean_relative_error(approx: np.ndarray, reference: np.ndarray) -> float:
    mask = reference > 1e-6  # skip the source itself
    return float((np.abs(approx - reference)[mask] / reference[mask]).mean())


@pytest.mark.parametrize(
    ("fixture", "use_robust", "bound"),
    [
        # measured mean relative errors: sphere3 1.48 % (robust and not), bumpy torus
        # 3.31 % (robust) / 3.19 % (not); bounds leave ~35 % headroom
        ("sphere3", True, 0.02),
        ("bumpy_torus", True, 0.045),
        ("bumpy_torus", False, 0.045),
    ],
)
def test_heat_close_to_exact(request, fixture, use_robust, bound):
    shape = request.getfixturevalue(fixture)
    sources = np.arange(0, shape.n_points, shape.n_points // 8)
    exact = ExactGeodesicEngine(shape).distances(sources).distances
    result = HeatGeodesicEngine(shape, use_robust=use_robust).distances(sources)
    assert result.method == "heat"
    assert dict(result.params) == {"t_coef": 1.0, "use_robust": use_robust}
    error = mean_relative_error(result.distances, exact)
    assert error < bound
    assert np.all(result.distances[np.arange(sources.size), sources] == 0.0)


def test_pointcloud_heat_close_to_great_circle(sphere_cloud):
    # 2000 uniform points on the unit sphere: measured mean relative error 2.28 %.
    sources = np.arange(0, sphere_cloud.n_points, 100)
    result = PointCloudHeatEngine(sphere_cloud).distances(sources)
    points = sphere_cloud.vertices
    analytic = np.arccos(np.clip(points[sources] @ points.T, -1.0, 1.0))
    assert mean_relative_error(result.distances, analytic) < 0.03
    assert np.all(result.distances[np.arange(sources.size), sources] == 0.0)
    assert result.params["t_coef"] == 1.0


def test_pointcloud_heat_solves_repeated_points_once(sphere_cloud):
    """Each point sent twice: the rows are the cloud's own, repeated (the solver would
    otherwise see degenerate neighbourhoods)."""
    points = np.asarray(sphere_cloud.vertices)[:600]
    once = PointCloudHeatEngine(Shape.from_arrays(points)).distances([0, 7]).distances
    twice = PointCloudHeatEngine(Shape.from_arrays(np.vstack([points, points])))
    rows = twice.distances([0, 607]).distances  # point 607 repeats point 7
    np.testing.assert_array_equal(rows[:, :600], once)  # the same solver input, in order
    np.testing.assert_array_equal(rows[:, 600:], rows[:, :600])
    assert rows[0, 600] == rows[1, 7] == 0.0


def test_pointcloud_heat_needs_more_distinct_points_than_its_neighbourhood():
    from litege_core.engines.heat import POINT_CLOUD_HEAT_NEIGHBOURS
    from litege_core.errors import MethodNotApplicableError

    rng = np.random.default_rng(0)
    few = rng.normal(size=(POINT_CLOUD_HEAT_NEIGHBOURS, 3))
    crowded = np.vstack([np.zeros((300, 3)), few])  # 331 points, 31 distinct
    with pytest.raises(MethodNotApplicableError, match=r"distinct points.*method='graph'"):
        PointCloudHeatEngine(Shape.from_arrays(few)).distances([0])
    rows = PointCloudHeatEngine(Shape.from_arrays(crowded)).distances([0, 300]).distances
    assert np.isfinite(rows).all() and np.all(rows[0, :300] == 0.0)
    with pytest.raises(MethodNotApplicableError):
        PointCloudHeatEngine(Shape.from_arrays(crowded[:-1])).distances([0])  # 30 distinct


def test_pointcloud_heat_accepts_a_mesh_through_its_vertices(sphere3):
    rows = compute_distances(sphere3, [0], "pointcloud_heat").distances
    cloud_rows = compute_distances(sphere3.as_point_cloud(), [0], "pointcloud_heat").distances
    np.testing.assert_array_equal(rows, cloud_rows)


def test_heat_disconnected_components_give_inf(two_spheres):
    # The raw solver returns finite garbage (about 1.47) on the other sphere.
    rows = compute_distances(two_spheres, [0, 200], "heat").distances
    assert np.isfinite(rows[0, :162]).all() and np.isinf(rows[0, 162:]).all()
    assert np.isinf(rows[1, :162]).all() and np.isfinite(rows[1, 162:]).all()


def test_heat_ignores_duplicate_and_degenerate_faces(sphere3):
    # Duplicated faces shift the raw solver's distances (by up to 0.022 here) and a face with
    # a repeated corner makes it raise; the engine cleans both away.
    faces = np.vstack([sphere3.faces, sphere3.faces[:20], [[0, 0, 5]]])
    dirty = Shape.from_arrays(sphere3.vertices, faces)
    expected = compute_distances(sphere3, [0], "heat").distances
    np.testing.assert_array_equal(compute_distances(dirty, [0], "heat").distances, expected)


def test_heat_refuses_point_clouds(sphere_cloud):
    with pytest.raises(InputError, match=r"needs a triangle mesh.*pointcloud_heat"):
        HeatGeodesicEngine(sphere_cloud)


@pytest.mark.parametrize("t_coef", [0.0, -1.0, float("nan"), float("inf"), "1", True])
def test_bad_t_coef(sphere3, t_coef):
    with pytest.raises(InputError, match="t_coef"):
        HeatGeodesicEngine(sphere3, t_coef=t_coef)
    with pytest.raises(InputError, match="t_coef"):
        PointCloudHeatEngine(sphere3, t_coef=t_coef)


def test_heat_builds_lazily_and_reuses_the_factorisation(sphere3):
    engine = HeatGeodesicEngine(sphere3, t_coef=2.0)
    assert engine._solver is None
    first = engine.distances([5]).distances
    solver = engine._solver
    assert solver is not None
    np.testing.assert_array_equal(engine.distances([5]).distances, first)
    assert engine._solver is solver


def test_solver_errors_become_computation_error(sphere3, monkeypatch):
    engine = HeatGeodesicEngine(sphere3).prepare()

    class Failing:
        def compute_distance(self, index):
            raise RuntimeError("factorisation failed")

    monkeypatch.setattr(engine, "_solver", Failing())
    with pytest.raises(ComputationError, match="factorisation failed"):
        engine.distances([0])


def test_nan_rows_become_computation_error(sphere3, monkeypatch):
    engine = PointCloudHeatEngine(sphere3).prepare()

    class NaNSolver:
        def compute_distance(self, index):
            return np.full(sphere3.n_points, np.nan)

    monkeypatch.setattr(engine, "_solver", NaNSolver())
    with pytest.raises(ComputationError, match="NaN"):
        engine.distances([0])
