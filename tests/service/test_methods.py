"""``method`` on ``/geodesic``, ``/paths`` and the gRPC calls (issue 16, "pick the engine"):
``learned`` (default), ``heat``, ``exact`` and ``graph`` over real REST and gRPC on loopback,
each equal to the library's :class:`~litege_core.engines.ClassicalSolver` on the same
geometry; the answer names the method and the engine; solvers are cached per shape and method
within their own budget; large requests run in row blocks; the limits answer 422 /
INVALID_ARGUMENT."""

from __future__ import annotations

from typing import Any

import grpc
import httpx
import msgpack
import numpy as np
import pytest

from litege_core.engines import ClassicalSolver
from litege_core.shape import Shape
from service import grpc_stubs
from service.client import LiteGEClient, ProblemError
from service.grpc_client import GrpcCallError, GrpcClient
from service.problems import PROBLEM_BASE_URI

MAX_EXACT_VERTICES = 1000
MAX_EXACT_SOURCES = 6
ENGINES = {"heat": "heat", "exact": "exact-mmp", "graph": "knn-graph"}


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory(
        grpc=True,
        max_exact_vertices=MAX_EXACT_VERTICES,
        max_exact_sources=MAX_EXACT_SOURCES,
    )


@pytest.fixture(scope="module")
def http(service):
    with httpx.Client(base_url=service.base_url, timeout=60) as client:
        yield client


@pytest.fixture(scope="module")
def client(service):
    with LiteGEClient(service.base_url, binary=False) as c:
        yield c


@pytest.fixture(scope="module")
def grpc_client(service):
    with GrpcClient(service.grpc_target, timeout_s=60) as c:
        yield c


@pytest.fixture(scope="module")
def shapes(client, test_shape, blob) -> dict[str, Any]:
    """A 642-vertex mesh, a point cloud, and a mesh above the exact limit, registered."""
    mesh = test_shape(1)
    cloud = Shape.from_arrays(test_shape(3).vertices)
    large = blob(2, subdivisions=4)
    assert mesh.n_points <= MAX_EXACT_VERTICES < large.n_points
    return {
        "mesh": (mesh, client.register_arrays(mesh.vertices, mesh.faces)["shape_id"]),
        "cloud": (cloud, client.register_arrays(cloud.vertices)["shape_id"]),
        "large": (large, client.register_arrays(large.vertices, large.faces)["shape_id"]),
    }


def _solver(shape: Shape, method: str) -> ClassicalSolver:
    return ClassicalSolver(shape, method, max_exact_vertices=MAX_EXACT_VERTICES)


def _problem(response: httpx.Response, status: int, code: str) -> dict[str, Any]:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/problem+json")
    problem = response.json()
    assert problem["code"] == code and problem["type"] == PROBLEM_BASE_URI + code
    return problem


# --------------------------------------------------------------------------- REST: distances


@pytest.mark.parametrize("method", ["heat", "exact", "graph"])
def test_rest_geodesic_by_each_method_equals_the_library(http, shapes, method):
    shape, shape_id = shapes["mesh"]
    sources, targets = [0, 17, 200], [1, 2, 300, 641]
    response = http.post(
        "/geodesic",
        json={"shape_id": shape_id, "sources": sources, "targets": targets, "method": method},
    )
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["method"] == method and body["engine"] == ENGINES[method]
    assert body["model"] is None and body["units"] == "input"
    expected = _solver(shape, method).distances(sources, targets)
    np.testing.assert_array_equal(np.asarray(body["distances"], dtype=np.float32), expected)


@pytest.mark.parametrize("method", ["heat", "exact", "graph"])
def test_xyz_queries_and_all_targets_equal_the_library(client, shapes, method):
    shape, shape_id = shapes["mesh"]
    points = shape.vertices[[3, 50, 400]] * 1.01  # near, not on, the surface
    got = client.geodesic(shape_id, points, "all", method=method)
    expected = _solver(shape, method).distances(points, None)
    assert got.shape == (3, shape.n_points)
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-7)


def test_learned_is_the_default_and_says_so(http, shapes):
    _, shape_id = shapes["mesh"]
    plain = http.post("/geodesic", json={"shape_id": shape_id, "sources": [0], "targets": [5]})
    named = http.post(
        "/geodesic",
        json={"shape_id": shape_id, "sources": [0], "targets": [5], "method": "learned"},
    )
    assert plain.status_code == named.status_code == 200
    for body in (plain.json(), named.json()):
        assert body["method"] == "learned" and body["engine"] == "learned"
        assert body["model"] == "quadrupeds"
    assert plain.json()["distances"] == named.json()["distances"]


def test_point_cloud_heat_and_graph(http, shapes):
    shape, shape_id = shapes["cloud"]
    for method, engine in (("heat", "pointcloud-heat"), ("graph", "knn-graph")):
        response = http.post(
            "/geodesic",
            json={"shape_id": shape_id, "sources": [0, 9], "method": method},
        )
        assert response.status_code == 200, response.text
        assert response.json()["engine"] == engine
        expected = _solver(shape, method).distances([0, 9], None)
        np.testing.assert_array_equal(
            np.asarray(response.json()["distances"], dtype=np.float32), expected
        )


def test_binary_formats_name_the_engine(http, shapes):
    shape, shape_id = shapes["mesh"]
    body = {"shape_id": shape_id, "sources": [4, 8], "method": "exact"}
    expected = _solver(shape, "exact").distances([4, 8], None)
    raw = http.post("/geodesic", json=body, headers={"Accept": "application/octet-stream"})
    assert raw.headers["X-Method"] == "exact" and raw.headers["X-Engine"] == "exact-mmp"
    assert "X-Model" not in raw.headers
    got = np.frombuffer(raw.content, dtype="<f4").reshape(2, shape.n_points)
    np.testing.assert_array_equal(got, expected)
    packed = http.post("/geodesic", json=body, headers={"Accept": "application/msgpack"})
    payload = msgpack.unpackb(packed.content)
    assert (payload["method"], payload["engine"], payload["model"]) == ("exact", "exact-mmp", None)
    learned = http.post(
        "/geodesic",
        json={"shape_id": shape_id, "sources": [0]},
        headers={"Accept": "application/octet-stream"},
    )
    assert learned.headers["X-Engine"] == "learned" and learned.headers["X-Model"] == "quadrupeds"


def test_no_surface_path_is_null_in_json_and_inf_in_binary(client, http, blob):
    """Two far-apart components: a classical engine answers +inf between them (JSON null)."""
    one, two = blob(5), blob(6)
    vertices = np.vstack([one.vertices, two.vertices + np.array([100.0, 0.0, 0.0])])
    faces = np.vstack([one.faces, two.faces + one.n_points])
    shape_id = client.register_arrays(vertices, faces)["shape_id"]
    far = one.n_points + 3
    body = {"shape_id": shape_id, "sources": [0], "targets": [1, far], "method": "graph"}
    answer = http.post("/geodesic", json=body).json()
    assert answer["distances"][0][0] > 0 and answer["distances"][0][1] is None
    raw = http.post("/geodesic", json=body, headers={"Accept": "application/octet-stream"})
    assert np.isinf(np.frombuffer(raw.content, dtype="<f4")[1])
    np.testing.assert_array_equal(client.geodesic(shape_id, [0], [far], method="graph"), [[np.inf]])


# --------------------------------------------------------------------------- REST: paths


def test_exact_path_comes_from_the_exact_engine(client, shapes):
    shape, shape_id = shapes["mesh"]
    got = client.path(shape_id, 5, 300, method="exact")
    expected = _solver(shape, "exact").path(5, 300)
    assert got["method"] == "exact" and got["engine"] == "exact-mmp" and got["model"] is None
    assert got["segments"] == [{"start": 0, "method": "exact-mmp"}]
    np.testing.assert_allclose(got["points"], expected.points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["points"][0], shape.vertices[5], atol=1e-12)
    np.testing.assert_allclose(got["points"][-1], shape.vertices[300], atol=1e-12)
    assert got["length"] == pytest.approx(expected.length)
    assert got["distance"] == pytest.approx(got["length"], rel=1e-6)
    assert got["converged"] is None and got["n_steps"] is None
    assert got["predicted_distance"] is None
    exact_distance = client.geodesic(shape_id, [5], [300], method="exact")[0, 0]
    assert got["distance"] == pytest.approx(float(exact_distance), rel=1e-5)


@pytest.mark.parametrize("method", ["heat", "graph"])
def test_heat_and_graph_paths(client, shapes, method):
    for name in ("mesh", "cloud"):
        shape, shape_id = shapes[name]
        got = client.path(shape_id, 0, 100, method=method)
        expected = _solver(shape, method).path(0, 100)
        assert got["engine"] == expected.engine
        assert [(s["start"], s["method"]) for s in got["segments"]] == [
            tuple(s) for s in expected.segments
        ]
        np.testing.assert_allclose(got["points"], expected.points, rtol=0, atol=1e-12)


def test_learned_path_keeps_converged_and_has_segments(client, shapes):
    _, shape_id = shapes["mesh"]
    got = client.path(shape_id, 5, 300)
    assert got["method"] == "learned" and got["engine"] == "learned"
    assert got["model"] == "quadrupeds" and isinstance(got["converged"], bool)
    assert got["segments"][0]["start"] == 0 and got["segments"]
    assert {s["method"] for s in got["segments"]} <= {
        "learned",
        "edge-flip",
        "mesh-edges",
        "knn-graph",
        "straight",
    }
    # the model's distance as /geodesic answers it (fused), beside the network's own
    answer = client.geodesic(shape_id, [5], [300])
    assert got["distance"] == pytest.approx(float(np.asarray(answer)[0, 0]), rel=1e-5)
    assert isinstance(got["predicted_distance"], float)


def test_path_xyz_points_by_exact(client, shapes):
    shape, shape_id = shapes["mesh"]
    source, target = shape.vertices[10] * 1.02, shape.vertices[500] * 0.99
    got = client.path(shape_id, source, target, method="exact")
    expected = _solver(shape, "exact").path(source, target)
    np.testing.assert_allclose(got["points"], expected.points, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- limits (REST)


def test_limits_are_422_problems(http, shapes):
    _, mesh_id = shapes["mesh"]
    _, cloud_id = shapes["cloud"]
    _, large_id = shapes["large"]
    geodesic = "/geodesic"

    def g(shape_id: str, method: str, sources: Any = (0,), **extra: Any) -> dict[str, Any]:
        return {"shape_id": shape_id, "sources": list(sources), "method": method, **extra}

    def p(shape_id: str, method: str) -> dict[str, Any]:
        return {"shape_id": shape_id, "source": 0, "target": 1, "method": method}

    too_many = range(MAX_EXACT_SOURCES + 1)
    cases = [
        (geodesic, g(cloud_id, "exact"), "method-not-applicable"),
        ("/paths", p(cloud_id, "exact"), "method-not-applicable"),
        (geodesic, g(large_id, "exact"), "method-size-limit"),
        ("/paths", p(large_id, "exact"), "method-size-limit"),
        (geodesic, g(mesh_id, "exact", too_many), "too-many-queries"),
        (geodesic, g(mesh_id, "mmp"), "invalid-request"),
        ("/paths", p(mesh_id, ""), "invalid-request"),
        (geodesic, g(mesh_id, "heat", model="cats"), "unknown-model"),
    ]
    for path, body, code in cases:
        problem = _problem(http.post(path, json=body), 422, code)
        assert problem["detail"]
    detail = _problem(http.post(geodesic, json=cases[2][1]), 422, "method-size-limit")["detail"]
    assert str(MAX_EXACT_VERTICES) in detail
    detail = _problem(http.post(geodesic, json=cases[4][1]), 422, "too-many-queries")["detail"]
    assert "LITEGE_MAX_EXACT_SOURCES" in detail and str(MAX_EXACT_SOURCES) in detail
    # the other methods serve the large mesh
    ok = http.post(geodesic, json={"shape_id": large_id, "sources": [0], "method": "heat"})
    assert ok.status_code == 200 and ok.json()["engine"] == "heat"


def test_unknown_shape_is_404_for_classical_methods(http):
    response = http.post("/geodesic", json={"shape_id": "0" * 64, "sources": [0], "method": "heat"})
    _problem(response, 404, "shape-not-found")


# --------------------------------------------------------------------------- runtime


def test_a_large_classical_request_runs_in_row_blocks(service, client, shapes):
    shape, shape_id = shapes["mesh"]
    runtime = service.runtime
    real = runtime.batcher.handlers["classical_geodesic"]
    jobs: list[int] = []

    def counting(batch: list[Any]) -> list[Any]:
        jobs.extend(job.sources.count(0) for job in batch)
        return real(batch)

    runtime.batcher.handlers["classical_geodesic"] = counting
    runtime.classical_chunk_sources["graph"] = 3
    try:
        sources = [0, 1, 2, 3, 4, 5, 6, 7]
        got = client.geodesic(shape_id, sources, "all", method="graph")
    finally:
        runtime.classical_chunk_sources["graph"] = 256
        runtime.batcher.handlers["classical_geodesic"] = real
    assert jobs == [8, 3, 3, 2]  # the first job only learns the size
    np.testing.assert_array_equal(got, _solver(shape, "graph").distances(sources, None))


def test_solvers_are_cached_per_shape_and_method_and_dropped_on_delete(service, client, test_shape):
    shape = test_shape(7)
    shape_id = client.register_arrays(shape.vertices, shape.faces)["shape_id"]
    solvers = service.runtime.solvers
    before = len(solvers)
    for _ in range(2):
        client.geodesic(shape_id, [0], [1], method="heat")
        client.path(shape_id, 0, 1, method="heat")
    client.geodesic(shape_id, [0], [1], method="graph")
    assert len(solvers) == before + 2
    metrics = client.metrics()
    assert 'litege_cache_budget_bytes{cache="solver"}' in metrics
    client.delete_shape(shape_id)
    assert len(solvers) == before
    with pytest.raises(ProblemError) as gone:
        client.geodesic(shape_id, [0], [1], method="heat")
    assert gone.value.status == 404


def test_solver_budget_setting_bounds_the_cache(live_service_factory, test_shape):
    service = live_service_factory(solver_cache_bytes=1024 * 1024)
    shape = test_shape(8)  # ~642 vertices: one heat solver ≈ 5 MiB with its native estimate
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_arrays(shape.vertices, shape.faces)["shape_id"]
        got = client.geodesic(shape_id, [0], [1, 2], method="heat")
        np.testing.assert_array_equal(got, _solver(shape, "heat").distances([0], [1, 2]))
    usage = service.runtime.solvers._lru.usage()
    assert usage.bytes <= usage.max_bytes == 1024 * 1024


# --------------------------------------------------------------------------- gRPC


@pytest.mark.parametrize("method", ["heat", "exact", "graph"])
def test_grpc_geodesic_and_path_by_each_method(grpc_client, shapes, method):
    shape, shape_id = shapes["mesh"]
    got = grpc_client.geodesic(shape_id, [0, 17], [5, 9, 600], method=method)
    np.testing.assert_array_equal(got, _solver(shape, method).distances([0, 17], [5, 9, 600]))
    path = grpc_client.path(shape_id, 5, 300, method=method)
    expected = _solver(shape, method).path(5, 300)
    assert path["method"] == method and path["engine"] == expected.engine
    assert path["segments"] == list(expected.segments)
    assert path["converged"] is None and path["n_steps"] is None and path["model"] is None
    np.testing.assert_allclose(path["points"], expected.points, rtol=0, atol=1e-12)
    assert path["distance"] == pytest.approx(expected.distance)


def test_grpc_responses_say_the_engine(service, shapes):
    pb2, pb2_grpc = grpc_stubs.load_stubs()
    _, shape_id = shapes["mesh"]
    with grpc.insecure_channel(service.grpc_target) as channel:
        stub = pb2_grpc.LiteGEStub(channel)
        request = pb2.GeodesicRequest(
            shape_id=shape_id, source_indices=pb2.Indices(values=[0]), method="exact"
        )
        answer = stub.Geodesic(request, timeout=60)
        assert (answer.method, answer.engine, answer.shape_id) == ("exact", "exact-mmp", shape_id)
        assert not answer.HasField("shape")
        learned = stub.Geodesic(
            pb2.GeodesicRequest(shape_id=shape_id, source_indices=pb2.Indices(values=[0])),
            timeout=60,
        )
        assert (learned.method, learned.engine) == ("learned", "learned")
        assert learned.shape.model == "quadrupeds" and learned.shape_id == shape_id
        path = stub.Path(
            pb2.PathRequest(
                shape_id=shape_id,
                source=pb2.QueryPoint(index=5),
                target=pb2.QueryPoint(index=300),
            ),
            timeout=60,
        )
        assert path.method == "learned" and path.HasField("converged")
        assert path.model == "quadrupeds" and path.segments[0].start == 0


def test_grpc_limits_are_invalid_argument(grpc_client, shapes):
    _, mesh_id = shapes["mesh"]
    _, cloud_id = shapes["cloud"]
    _, large_id = shapes["large"]
    calls = {
        "method-not-applicable": lambda: grpc_client.geodesic(cloud_id, [0], method="exact"),
        "method-size-limit": lambda: grpc_client.path(large_id, 0, 1, method="exact"),
        "too-many-queries": lambda: grpc_client.geodesic(
            mesh_id, list(range(MAX_EXACT_SOURCES + 1)), method="exact"
        ),
        "invalid-request": lambda: grpc_client.geodesic(mesh_id, [0], method="fast"),
    }
    for code, call in calls.items():
        with pytest.raises(GrpcCallError) as caught:
            call()
        assert caught.value.code == grpc.StatusCode.INVALID_ARGUMENT, caught.value
        assert caught.value.problem_type == PROBLEM_BASE_URI + code


def test_solvers_are_built_from_the_stored_geometry(service, client, shapes):
    """After a restart (no live state, no solver) a classical query reads the shape's stored
    geometry: no model state is built for it."""
    shape, shape_id = shapes["mesh"]
    runtime = service.runtime
    runtime.repository.forget_live()
    runtime.solvers.clear()
    got = client.geodesic(shape_id, [3], [4, 5], method="exact")
    np.testing.assert_array_equal(got, _solver(shape, "exact").distances([3], [4, 5]))
    assert len(runtime.repository._live) == 0  # the learned model was not involved


@pytest.mark.parametrize("method", ["learned", "heat", "graph"])
def test_a_triangle_soup_is_answered_as_its_welded_mesh(client, shapes, method):
    """A mesh sent with its seams split (every corner its own vertex, as a soup or an OBJ cut
    along its UV seams) gets the welded mesh's distances at every copy, not ``inf`` beyond
    each triangle."""
    shape, shape_id = shapes["mesh"]
    corner = np.asarray(shape.faces).reshape(-1)  # soup vertex → welded vertex
    soup_id = client.register_arrays(shape.vertices[corner], np.arange(corner.size).reshape(-1, 3))[
        "shape_id"
    ]
    got = client.geodesic(soup_id, [0, 40], [5, 900, 3000], method=method)
    expected = client.geodesic(shape_id, corner[[0, 40]], corner[[5, 900, 3000]], method=method)
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, expected, rtol=1e-5)
