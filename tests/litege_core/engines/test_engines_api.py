"""The shared interface: registry, one-off function, result type, index validation."""

import numpy as np
import pytest

from litege_core.engines import (
    ENGINES,
    GeodesicEngine,
    GeodesicResult,
    compute_distances,
    make_engine,
)
from litege_core.errors import ArrayShapeError, IndexOutOfRangeError, InputError
from litege_core.shape import Shape

MESH_METHODS = ["exact", "heat", "pointcloud_heat", "knn_graph", "edge_dijkstra", "euclidean"]
CLOUD_METHODS = ["pointcloud_heat", "knn_graph", "euclidean"]


def test_exported_members_exist():
    import litege_core.engines as geodesics

    assert sorted(geodesics.__all__) == geodesics.__all__
    for name in geodesics.__all__:
        assert hasattr(geodesics, name), name


def test_registry_lists_every_method():
    assert sorted(ENGINES) == sorted(MESH_METHODS)
    assert all(issubclass(engine, GeodesicEngine) for engine in ENGINES.values())


@pytest.mark.parametrize("method", MESH_METHODS)
def test_every_method_on_a_mesh(sphere3, method):
    sources = np.array([7, 0, 7])
    result = compute_distances(sphere3, sources, method)
    assert isinstance(result, GeodesicResult)
    assert result.method == method
    assert result.distances.shape == (3, sphere3.n_points)
    assert result.distances.dtype == np.float64
    np.testing.assert_array_equal(result.sources, sources)
    np.testing.assert_array_equal(result.distances[0], result.distances[2])  # repeats kept
    assert result.distances[0, 7] == 0.0 and result.distances[1, 0] == 0.0
    assert np.isfinite(result.distances).all() and (result.distances >= 0).all()
    with pytest.raises(ValueError, match="read-only"):
        result.distances[0, 0] = 1.0
    with pytest.raises(TypeError):
        result.params["x"] = 1  # type: ignore[index]


@pytest.mark.parametrize("method", CLOUD_METHODS)
def test_cloud_methods_on_a_point_cloud(sphere_cloud, method):
    result = compute_distances(sphere_cloud, [3], method)
    assert result.distances.shape == (1, sphere_cloud.n_points)


@pytest.mark.parametrize("method", sorted(set(MESH_METHODS) - set(CLOUD_METHODS)))
def test_mesh_methods_refuse_point_clouds(sphere_cloud, method):
    with pytest.raises(InputError, match="needs a triangle mesh"):
        make_engine(sphere_cloud, method)


@pytest.mark.parametrize("method", MESH_METHODS)
@pytest.mark.parametrize("bad", [[642], [-1], [0, 10_000]])
def test_out_of_range_sources(sphere3, method, bad):
    engine = make_engine(sphere3, method)
    with pytest.raises(IndexOutOfRangeError, match=r"outside \[0, 642\)"):
        engine.distances(bad)


@pytest.mark.parametrize("bad", [[], np.empty(0, dtype=np.int64)])
def test_empty_sources(sphere3, bad):
    with pytest.raises(InputError, match="source is empty"):
        compute_distances(sphere3, bad, "euclidean")


@pytest.mark.parametrize("bad", [[0.0, 1.0], [True], [[0, 1]], ["a"], [[0], [1, 2]]])
def test_malformed_sources(sphere3, bad):
    with pytest.raises(ArrayShapeError):
        compute_distances(sphere3, bad, "euclidean")


def test_scalar_source_and_single_row(sphere3):
    engine = make_engine(sphere3, "edge_dijkstra")
    np.testing.assert_array_equal(engine.distances(np.int32(4)).distances[0], engine.distance(4))
    with pytest.raises(ArrayShapeError):
        engine.distance([1, 2])  # type: ignore[arg-type]


def test_unknown_method_and_bad_option(sphere3):
    with pytest.raises(InputError, match="unknown geodesic method"):
        compute_distances(sphere3, [0], "fmm")
    with pytest.raises(InputError, match=r"bad option.*t_coeff"):
        make_engine(sphere3, "heat", t_coeff=2.0)


def test_engine_refuses_non_shapes(sphere3):
    with pytest.raises(InputError, match="Shape"):
        make_engine(sphere3.vertices, "euclidean")  # type: ignore[arg-type]


def test_repr_and_params(sphere3):
    engine = make_engine(sphere3, "knn_graph", k=12)
    assert repr(engine) == "KnnGraphEngine(n_points=642, k=12)"
    result = engine.distances([0])
    assert dict(result.params) == {"k": 12}
    assert "knn_graph" in repr(result) and "1x642" in repr(result)


@pytest.mark.parametrize("method", ["exact", "heat", "edge_dijkstra"])
def test_a_triangle_soup_gets_the_welded_mesh_distances(sphere3, method):
    """Every corner its own vertex (a soup, or an OBJ split along its UV seams): the engines
    that follow the mesh's connectivity weld the seams, so each copy gets the welded mesh's
    value at its position instead of ``inf`` beyond its own triangle."""
    pytest.importorskip("pygeodesic") if method == "exact" else None
    vertices, faces = np.asarray(sphere3.vertices), np.asarray(sphere3.faces)
    corner = faces.reshape(-1)  # soup vertex → welded vertex
    soup = Shape.from_arrays(vertices[corner], np.arange(corner.size).reshape(-1, 3))
    welded = compute_distances(sphere3, corner[[0, 40]], method).distances
    rows = compute_distances(soup, np.array([0, 40]), method).distances
    np.testing.assert_allclose(rows, welded[:, corner], rtol=1e-9, atol=1e-12)
