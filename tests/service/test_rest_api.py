"""The REST API end to end over real HTTP: upload → geodesic → path, idempotency, binary
responses, and every bad input giving its RFC 9457 problem while the cache stays intact."""

from __future__ import annotations

import asyncio
import json
import math
import threading
import time

import grpc
import httpx
import msgpack
import numpy as np
import pytest

from litege_core.io import load_shape, save_shape
from litege_core.learned import Predictor, load_shipped
from service import grpc_stubs
from service.client import LiteGEClient, ProblemError
from service.errors import OverloadedError
from service.problems import PROBLEM_BASE_URI

PROBLEM_JSON = "application/problem+json"


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory(max_upload_bytes=2 * 1024 * 1024)


@pytest.fixture(scope="module")
def client(service):
    with LiteGEClient(service.base_url) as c:
        yield c


@pytest.fixture(scope="module")
def registered(client, mesh_bytes):
    """A shape registered once for the whole module, and its id."""
    info = client.register_file(mesh_bytes(1, "obj"), file_format="obj")
    return info["shape_id"]


@pytest.fixture(scope="module")
def reference(test_shape):
    """The library's own answer on the same shipped model (the service must match it)."""
    predictor = Predictor(load_shipped("quadrupeds"))
    return predictor, predictor.register(test_shape(1))


def assert_problem(response: httpx.Response, status: int, code: str) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM_JSON)
    problem = response.json()
    assert problem["status"] == status and problem["code"] == code
    assert problem["type"] == PROBLEM_BASE_URI + code
    assert problem["detail"]
    return problem


def test_upload_is_idempotent_across_formats(service, mesh_bytes, test_shape):
    with httpx.Client(base_url=service.base_url) as http:
        first = http.post("/shapes", files={"file": ("a.obj", mesh_bytes(2, "obj"))})
        again = http.post("/shapes", files={"file": ("a.ply", mesh_bytes(2, "ply"))})
        shape = test_shape(2)
        as_json = http.post(
            "/shapes",
            json={"vertices": shape.vertices.tolist(), "faces": shape.faces.tolist()},
        )
    assert first.status_code == 201 and first.json()["created"] is True
    assert first.headers["location"] == f"/shapes/{first.json()['shape_id']}"
    assert again.status_code == 200 and again.json()["created"] is False
    assert as_json.status_code == 200
    ids = {r.json()["shape_id"] for r in (first, again, as_json)}
    assert ids == {shape.content_hash}
    body = first.json()
    assert body["kind"] == "mesh" and body["n_points"] == shape.n_points
    assert body["n_faces"] == shape.n_faces and body["model"] == "quadrupeds"
    assert math.isfinite(body["ood_score"])


def test_gltf_and_glb_uploads_are_the_same_shape(service, test_shape, tmp_path):
    for file_format in ("gltf", "glb"):
        save_shape(test_shape(4), tmp_path / f"a.{file_format}")
    with httpx.Client(base_url=service.base_url) as http:
        ids = {
            http.post("/shapes", files={"file": (name, (tmp_path / name).read_bytes())}).json()[
                "shape_id"
            ]
            for name in ("a.gltf", "a.glb")
        }
    assert ids == {load_shape(tmp_path / "a.glb").content_hash}


def test_geodesic_matches_the_library(client, registered, reference):
    predictor, state = reference
    expected = predictor.distances(state, [0, 17, 200])
    got = client.geodesic(registered, [0, 17, 200], "all")
    assert got.dtype == np.float32 and got.shape == (3, state.n_points)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert got[1, 17] == 0.0


def test_geodesic_json_binary_and_msgpack_agree(service, registered):
    body = {"shape_id": registered, "sources": [3, 4], "targets": [5, 6, 7]}
    with httpx.Client(base_url=service.base_url) as http:
        as_json = http.post("/geodesic", json=body).json()
        raw = http.post("/geodesic", json=body, headers={"Accept": "application/octet-stream"})
        packed = http.post("/geodesic", json=body, headers={"Accept": "application/msgpack"})
    matrix = np.asarray(as_json["distances"], dtype=np.float32)
    assert (as_json["rows"], as_json["cols"]) == (2, 3) and as_json["units"] == "input"
    assert raw.headers["x-array-shape"] == "2,3" and raw.headers["x-array-dtype"] == "<f4"
    np.testing.assert_array_equal(np.frombuffer(raw.content, "<f4").reshape(2, 3), matrix)
    payload = msgpack.unpackb(packed.content)
    assert payload["shape"] == [2, 3]
    np.testing.assert_array_equal(
        np.frombuffer(payload["data"], payload["dtype"]).reshape(2, 3), matrix
    )


def test_geodesic_with_xyz_points(client, registered, reference):
    predictor, state = reference
    points = state.vertices[[10, 20]] + 1e-4
    got = client.geodesic(registered, points, [30, 40])
    np.testing.assert_allclose(got, predictor.distances(state, points, [30, 40]), rtol=1e-5)


def test_path_goes_from_source_to_target(client, registered, reference):
    predictor, state = reference
    expected = predictor.path(state, 5, 300)  # the library's path on the same model
    path = client.path(registered, 5, 300)
    points = path["points"]
    assert points.shape[1] == 3 and len(points) >= 2
    np.testing.assert_allclose(points[0], state.vertices[5], atol=0.05)
    np.testing.assert_allclose(points[-1], state.vertices[300], atol=1e-9)
    # whether the walk converged is the model's business on this blob (OOD z ~3 under the
    # quadrupeds model); the service must answer exactly what the library answers
    assert path["converged"] is expected.converged
    assert path["length"] == pytest.approx(expected.length, rel=1e-5) and path["length"] > 0
    np.testing.assert_allclose(points, expected.points, atol=1e-5)


def test_a_cloud_of_repeated_points_has_paths(client, test_shape):
    """Every point sent twice (a client that concatenates a scan with itself): the default
    step is the cloud's spacing between distinct points, so the walk answers instead of
    failing on a zero step."""
    points = np.asarray(test_shape(3).vertices)
    shape_id = client.register_arrays(np.vstack([points, points]))["shape_id"]
    path = client.path(shape_id, 0, 200)
    assert len(path["points"]) >= 2 and path["length"] > 0
    np.testing.assert_allclose(path["points"][-1], points[200], atol=1e-9)


def test_get_and_delete(client, mesh_bytes):
    info = client.register_file(mesh_bytes(3, "off"), file_format="off")
    assert client.get_shape(info["shape_id"])["shape_id"] == info["shape_id"]
    client.delete_shape(info["shape_id"])
    with pytest.raises(ProblemError) as missing:
        client.get_shape(info["shape_id"])
    assert missing.value.status == 404 and missing.value.code == "shape-not-found"
    with pytest.raises(ProblemError) as again:
        client.delete_shape(info["shape_id"])
    assert again.value.status == 404


GLTF_WITH_BUFFER_FILE = {
    "asset": {"version": "2.0"},
    "buffers": [{"uri": "model.bin", "byteLength": 36}],
}
"""A ``.gltf`` whose buffer is a separate file, which an upload cannot bring."""


def _bad_requests(shape_id: str) -> list[tuple[str, dict, int, str]]:
    nan_json = '{"vertices": [[0, 0, 0], [1, 0, 0], [0, NaN, 0]], "faces": [[0, 1, 2]]}'
    return [
        (
            "malformed OBJ",
            {"files": {"file": ("x.obj", b"v 1 2\nf 1 2 3 4 5\x00\xff")}},
            400,
            "malformed-file",
        ),
        ("unknown extension", {"files": {"file": ("x.dwg", b"abc")}}, 415, "unsupported-format"),
        (
            "glTF naming a buffer file",
            {"files": {"file": ("x.gltf", json.dumps(GLTF_WITH_BUFFER_FILE).encode())}},
            400,
            "malformed-file",
        ),
        (
            "no file part",
            {"data": {"kind": "mesh"}, "files": {"other": ("a", b"")}},
            400,
            "malformed-file",
        ),
        (
            "NaN vertex",
            {"content": nan_json, "headers": {"content-type": "application/json"}},
            422,
            "non-finite-coordinates",
        ),
        (
            "face index out of range",
            {"json": {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0]], "faces": [[0, 1, 7]]}},
            422,
            "face-index-out-of-range",
        ),
        (
            "degenerate mesh",
            {"json": {"vertices": [[0, 0, 0]] * 4, "faces": [[0, 1, 2], [1, 2, 3]]}},
            422,
            "degenerate-shape",
        ),
        ("empty vertices", {"json": {"vertices": []}}, 422, "invalid-request"),
        (
            "unknown model",
            {"json": {"vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], "model": "fish"}},
            422,
            "unknown-model",
        ),
        (
            "wrong content type",
            {"content": b"v 0 0 0", "headers": {"content-type": "text/plain"}},
            415,
            "unsupported-media-type",
        ),
        (
            "broken JSON",
            {"content": b"{", "headers": {"content-type": "application/json"}},
            422,
            "invalid-request",
        ),
    ]


BAD_UPLOADS = [case[0] for case in _bad_requests("")]


@pytest.mark.parametrize("name", BAD_UPLOADS)
def test_bad_uploads_give_problems_and_keep_the_cache(service, client, registered, name):
    before = client.geodesic(registered, [0], [1, 2, 3])
    case = {c[0]: c for c in _bad_requests(registered)}[name]
    _, kwargs, status, code = case
    with httpx.Client(base_url=service.base_url) as http:
        assert_problem(http.post("/shapes", **kwargs), status, code)
    np.testing.assert_array_equal(client.geodesic(registered, [0], [1, 2, 3]), before)


def test_oversized_upload_is_refused_before_parsing(service, client, registered):
    big = b"v 0 0 0\n" * (300 * 1024)  # 2.4 MB > the module's 2 MiB limit
    with httpx.Client(base_url=service.base_url) as http:
        assert_problem(
            http.post("/shapes", files={"file": ("big.obj", big)}), 413, "payload-too-large"
        )
    assert client.get_shape(registered)["shape_id"] == registered


@pytest.mark.parametrize(
    ("body", "status", "code"),
    [
        ({"sources": [10**7]}, 422, "index-out-of-range"),
        ({"sources": [-1]}, 422, "index-out-of-range"),
        ({"sources": [[0.0, 1.0]]}, 422, "bad-array-shape"),
        ({"sources": []}, 422, "bad-array-shape"),
        ({"sources": [0], "targets": "some"}, 422, "bad-array-shape"),
        ({"sources": "all"}, 422, "invalid-input"),
        ({"sources": [1.0]}, 422, "bad-array-shape"),
        ({"sources": [[1e154, 0, 0]]}, 422, "coordinate-out-of-range"),
        ({"sources": [[float("nan"), 0, 0]]}, 422, "non-finite-coordinates"),
        ({"sources": [0], "model": "fish"}, 422, "unknown-model"),
        ({"sources": [0], "extra": 1}, 422, "invalid-request"),
    ],
)
def test_bad_geodesic_queries(service, client, registered, body, status, code):
    before = client.geodesic(registered, [0], [1])
    with httpx.Client(base_url=service.base_url) as http:
        content = json.dumps({"shape_id": registered, **body})
        response = http.post(
            "/geodesic", content=content, headers={"content-type": "application/json"}
        )
    assert_problem(response, status, code)
    np.testing.assert_array_equal(client.geodesic(registered, [0], [1]), before)


def test_unknown_shape_id_is_404(service):
    with httpx.Client(base_url=service.base_url) as http:
        problem = assert_problem(
            http.post("/geodesic", json={"shape_id": "f" * 64, "sources": [0]}),
            404,
            "shape-not-found",
        )
        assert "upload it again" in problem["detail"]
        assert_problem(http.get("/shapes/abc"), 404, "shape-not-found")
        assert_problem(
            http.post("/paths", json={"shape_id": "abc", "source": 0, "target": 1}),
            404,
            "shape-not-found",
        )
        assert_problem(http.get("/no-such-route"), 404, "not-found")


def test_problem_details_do_not_echo_long_request_strings(service, registered):
    """A 30,000-character model name or id is cut in the problem detail."""
    with httpx.Client(base_url=service.base_url) as http:
        body = {"shape_id": registered, "sources": [0], "model": "m" * 30_000}
        problem = assert_problem(http.post("/geodesic", json=body), 422, "unknown-model")
        assert len(problem["detail"]) < 1000 and "more characters" in problem["detail"]
        problem = assert_problem(http.get("/shapes/" + "a" * 5000), 404, "shape-not-found")
        assert len(problem["detail"]) < 1000


def test_too_many_queries(live_service_factory, mesh_bytes):
    service = live_service_factory(max_queries=100)
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        assert client.geodesic(shape_id, [0], list(range(100))).shape == (1, 100)
        with pytest.raises(ProblemError) as error:
            client.geodesic(shape_id, [0, 1], "all")
    assert error.value.status == 422 and error.value.code == "too-many-queries"


def test_api_key(live_service_factory, mesh_bytes):
    key = "k" * 24
    service = live_service_factory(api_key=key)
    with httpx.Client(base_url=service.base_url) as http:
        upload = {"files": {"file": ("a.obj", mesh_bytes(1, "obj"))}}
        assert_problem(http.post("/shapes", **upload), 401, "unauthorized")
        assert_problem(
            http.post("/shapes", headers={"X-API-Key": "wrong" * 5}, **upload),
            401,
            "unauthorized",
        )
        assert http.get("/healthz").status_code == 200
        assert http.get("/readyz").status_code == 200
    with LiteGEClient(service.base_url, api_key=key) as client:
        assert client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]


def test_probes_and_metrics(service, client, registered):
    with httpx.Client(base_url=service.base_url) as http:
        assert http.get("/healthz").json() == {"status": "ok"}
        ready = http.get("/readyz").json()
        version = http.get("/version").json()
    assert ready["status"] == "ready" and ready["degraded"] is False
    assert ready["store"]["backend"] == "memory"
    assert "quadrupeds" in ready["models"]
    assert version["settings"]["api_key"] is None and "obj" in version["formats"]
    client.geodesic(registered, [0], [1])
    text = client.metrics()
    for name in (
        "litege_http_request_duration_seconds_bucket",
        'litege_cache_requests_total{result="hit",tier="state"}',
        "litege_batch_size_bucket",
        "litege_queue_wait_seconds_bucket",
        'litege_model_load_seconds{model="quadrupeds"}',
        "litege_requests_in_flight",
    ):
        assert name in text, name


def test_openapi_documents_both_upload_kinds(service):
    schema = httpx.get(f"{service.base_url}/openapi.json").json()
    content = schema["paths"]["/shapes"]["post"]["requestBody"]["content"]
    assert {"multipart/form-data", "application/json"} <= set(content)
    assert (
        "application/octet-stream"
        in (schema["paths"]["/geodesic"]["post"]["responses"]["200"]["content"])
    )


# --------------------------------------------------------------------------- failures and limits


def _client_port(response: httpx.Response) -> int:
    """The local port of the connection that carried ``response``."""
    return response.extensions["network_stream"].get_extra_info("client_addr")[1]


def test_an_internal_error_keeps_the_connection_open(
    service, registered, monkeypatch, caplog: pytest.LogCaptureFixture
):
    async def broken(*args, **kwargs):
        raise RuntimeError("secret /path/to/weights")

    body = {"shape_id": registered, "sources": [0], "targets": [1]}
    with httpx.Client(base_url=service.base_url) as http:
        with monkeypatch.context() as patch:
            patch.setattr(service.runtime, "geodesic", broken)
            failed = http.post("/geodesic", json=body)
            first_port = _client_port(failed)
        problem = assert_problem(failed, 500, "internal-error")
        assert "secret" not in failed.text and problem["instance"] == "/geodesic"
        again = http.post("/geodesic", json=body)
        assert again.status_code == 200
        assert _client_port(again) == first_port, "the keep-alive connection was closed"
    assert any("secret" in (r.exc_text or "") for r in caplog.records)


def test_a_503_is_logged_without_a_traceback(
    service, registered, monkeypatch, caplog: pytest.LogCaptureFixture
):
    async def overloaded(*args, **kwargs):
        raise OverloadedError("the compute queue is full", retry_after_s=2.5)

    monkeypatch.setattr(service.runtime, "geodesic", overloaded)
    with httpx.Client(base_url=service.base_url) as http:
        response = http.post("/geodesic", json={"shape_id": registered, "sources": [0]})
    assert_problem(response, 503, "overloaded")
    assert response.headers["retry-after"] == "3"  # whole seconds, rounded up
    logged = [r for r in caplog.records if r.name == "litege.http" and r.levelno >= 30]
    assert logged and not any(r.exc_info for r in logged)


class Gate:
    """A compute job that holds the service's worker until opened."""

    def __init__(self, service) -> None:
        self.service = service
        self.entered = threading.Event()
        self.opened = threading.Event()

    def __enter__(self) -> Gate:
        def hold(jobs):
            self.entered.set()
            self.opened.wait(30)
            return jobs

        self.service.runtime.batcher.handlers["hold"] = hold
        return self

    def __exit__(self, *exc: object) -> None:
        self.opened.set()
        del self.service.runtime.batcher.handlers["hold"]


def test_one_concurrency_limit_for_rest_and_grpc(live_service_factory, mesh_bytes, thread_pool):
    service = live_service_factory(grpc=True, max_concurrency=1)
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
    pb2, pb2_grpc = grpc_stubs.load_stubs()
    with grpc.insecure_channel(service.grpc_target) as channel:
        stub = pb2_grpc.LiteGEStub(channel)
        request = pb2.GeodesicRequest(shape_id=shape_id, source_indices=pb2.Indices(values=[0]))
        with Gate(service) as gate:
            service.call(_submit_in_background(service, "hold"))
            assert gate.entered.wait(30)
            held = thread_pool.submit(stub.Geodesic, request, timeout=60)  # takes the slot
            _wait_for(lambda: service.runtime.admission.in_flight == 1)
            refused = httpx.post(
                f"{service.base_url}/geodesic", json={"shape_id": shape_id, "sources": [0]}
            )
            assert_problem(refused, 429, "overloaded")
            assert int(refused.headers["retry-after"]) >= 1
        assert held.result(60).rows == 1
        with Gate(service) as gate:
            service.call(_submit_in_background(service, "hold"))
            assert gate.entered.wait(30)
            body = {"shape_id": shape_id, "sources": [0]}
            held_rest = thread_pool.submit(httpx.post, f"{service.base_url}/geodesic", json=body)
            _wait_for(lambda: service.runtime.admission.in_flight == 1)
            with pytest.raises(grpc.RpcError) as caught:
                stub.Geodesic(request, timeout=60)
            assert caught.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
            assert dict(caught.value.trailing_metadata())["retry-after-ms"]
        assert held_rest.result(60).status_code == 200


_BACKGROUND: list[asyncio.Future] = []


async def _submit_in_background(service, kind: str) -> None:
    _BACKGROUND.append(asyncio.ensure_future(service.runtime.batcher.submit(kind, None)))


def _wait_for(condition) -> None:
    for _ in range(3000):
        if condition():
            return
        time.sleep(0.01)
    raise AssertionError("condition never met")


def test_a_geodesic_larger_than_one_job_runs_in_row_blocks(
    service, client, registered, reference, monkeypatch
):
    predictor, state = reference
    runtime = service.runtime
    handler = runtime.batcher.handlers["geodesic"]
    jobs: list[int] = []

    def counting(batch):
        jobs.append(len(batch))
        return handler(batch)

    monkeypatch.setattr(runtime, "geodesic_chunk_pairs", 3 * state.n_points)
    monkeypatch.setitem(runtime.batcher.handlers, "geodesic", counting)
    sources = list(range(0, 70, 7))  # 10 sources: 4 row blocks of at most 3
    got = client.geodesic(registered, sources, "all")
    np.testing.assert_allclose(got, predictor.distances(state, sources), rtol=1e-5, atol=1e-6)
    assert len(jobs) == 1 + 4  # the whole request (answered "split"), then its blocks
    jobs.clear()
    points = state.vertices[:100:10] + 1e-4  # 10 xyz sources × 214 xyz targets: 2 blocks
    targets = state.vertices[::3] + 1e-4
    got = client.geodesic(registered, points, targets)
    expected = predictor.distances(state, points, targets)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-6)
    assert len(jobs) == 1 + 2
