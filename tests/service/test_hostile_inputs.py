"""Hostile inputs over real REST and gRPC on loopback: every one is a 4xx problem (REST:
``application/problem+json``) or a non-INTERNAL gRPC status with a problem type, never a 5xx,
and the service answers a normal request right after each.

Includes the cases of issue 13: absurd but finite numbers (an ``.npy`` header declaring
``(10^12, 3)``, query points at 1e154 on ``/geodesic`` and ``/paths``, a correspondence query
at 1e40 with ``return_distance``), ``sources: "all"``, a body that never arrives, and a large
body sent without the API key; and of issue 16's ``method``: an unknown method, ``exact`` on a
point cloud, above the vertex limit, or with too many sources; and of correspondence's
``refine``: an unknown value, and a refinement with a point cloud.
"""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import grpc
import httpx
import numpy as np
import pytest

from litege_core.matching.model import MatchingModel
from service import grpc_stubs
from service.problems import PROBLEM_BASE_URI

API_KEY = "hostile-test-key-0123456789"
MAX_QUERIES = 5000
UPLOAD_BYTES = 1 << 20
BODY_TIMEOUT_S = 1.0
MAX_EXACT_VERTICES = 100  # below the test meshes' 642 vertices
MAX_EXACT_SOURCES = 3
PROBLEM_JSON = "application/problem+json"
HUGE = 1e154


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory(
        grpc=True,
        matching=MatchingModel.tiny_random(3),
        api_key=API_KEY,
        max_queries=MAX_QUERIES,
        max_upload_bytes=UPLOAD_BYTES,
        body_read_timeout_s=BODY_TIMEOUT_S,
        max_exact_vertices=MAX_EXACT_VERTICES,
        max_exact_sources=MAX_EXACT_SOURCES,
    )


@pytest.fixture(scope="module")
def http(service):
    with httpx.Client(
        base_url=service.base_url, headers={"X-API-Key": API_KEY}, timeout=30
    ) as client:
        yield client


@pytest.fixture(scope="module")
def shape_ids(http, test_shape) -> list[str]:
    """Two meshes and a point cloud."""
    ids = []
    for seed, faces in ((1, True), (2, True), (3, False)):
        shape = test_shape(seed)
        body: dict[str, Any] = {"vertices": shape.vertices.tolist()}
        if faces:
            body["faces"] = shape.faces.tolist()
        response = http.post("/shapes", json=body)
        assert response.status_code in (200, 201), response.text
        ids.append(response.json()["shape_id"])
    return ids


@pytest.fixture(scope="module")
def channel(service):
    with grpc.insecure_channel(service.grpc_target) as ch:
        yield ch


@pytest.fixture(scope="module")
def stub(channel):
    _, pb2_grpc = grpc_stubs.load_stubs()
    return pb2_grpc.LiteGEStub(channel)


@pytest.fixture(scope="module")
def pb2():
    return grpc_stubs.load_stubs()[0]


def _assert_still_answers(http: httpx.Client, shape_id: str) -> None:
    response = http.post("/geodesic", json={"shape_id": shape_id, "sources": [0], "targets": [1]})
    assert response.status_code == 200, response.text
    assert response.json()["rows"] == 1


# --------------------------------------------------------------------------- REST


@dataclass(frozen=True)
class Raw:
    """A response read off a raw socket (for requests httpx will not send)."""

    status_code: int
    text: str

    @property
    def headers(self) -> dict[str, str]:
        head = self.text.split("\r\n\r\n", 1)[0].split("\r\n")[1:]
        return {k.strip().lower(): v.strip() for k, _, v in (h.partition(":") for h in head)}

    def json(self) -> Any:
        return json.loads(self.text.split("\r\n\r\n", 1)[1])


def _raw(service, head: bytes, body: bytes = b"", wait_s: float = 20.0) -> Raw:
    """Send ``head`` (and ``body``) and read the response, leaving the request unfinished."""
    host, port = service.base_url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=wait_s) as sock:
        sock.sendall(head + body)
        data = b""
        while b"\r\n\r\n" not in data or not _complete(data):
            chunk = sock.recv(65536)
            if not chunk:
                break
            data += chunk
    text = data.decode("utf-8", "replace")
    return Raw(int(text.split(" ", 2)[1]), text)


def _complete(data: bytes) -> bool:
    head, _, rest = data.partition(b"\r\n\r\n")
    for line in head.split(b"\r\n"):
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return len(rest) >= int(value)
    return True


def _post_head(path: str, length: int, key: str | None = API_KEY) -> bytes:
    lines = [f"POST {path} HTTP/1.1", "Host: test", "Content-Type: application/json"]
    lines.append(f"Content-Length: {length}")
    if key is not None:
        lines.append(f"X-API-Key: {key}")
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def _npy(shape: tuple[int, ...], payload: bytes = b"\0" * 240) -> bytes:
    header = f"{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}".encode()
    header += b" " * (118 - len(header)) + b"\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header + payload


def _json(http: httpx.Client, path: str, text: str) -> httpx.Response:
    return http.post(path, content=text, headers={"content-type": "application/json"})


RestCase = Callable[[httpx.Client, Any, list[str]], Any]


def _geodesic(**fields: Any) -> RestCase:
    return lambda h, s, ids: h.post("/geodesic", json={"shape_id": ids[0], **fields})


def _geodesic_text(sources: str) -> RestCase:
    return lambda h, s, ids: _json(
        h, "/geodesic", f'{{"shape_id": "{ids[0]}", "sources": {sources}}}'
    )


def _path(source: Any, target: Any = 1, **fields: Any) -> RestCase:
    return lambda h, s, ids: h.post(
        "/paths", json={"shape_id": ids[0], "source": source, "target": target, **fields}
    )


def _on_cloud(path: str, **fields: Any) -> RestCase:
    return lambda h, s, ids: h.post(path, json={"shape_id": ids[2], **fields})


def _match(**fields: Any) -> RestCase:
    return lambda h, s, ids: h.post(
        "/correspondences",
        json={"source_shape_id": ids[0], "target_shape_id": ids[1], **fields},
    )


def _upload(name: str, data: bytes) -> RestCase:
    return lambda h, s, ids: h.post("/shapes", files={"file": (name, data)})


REST_CASES: dict[str, tuple[RestCase, int]] = {
    # issue 13: finite but absurd numbers
    "geodesic source at 1e154": (_geodesic(sources=[[HUGE, 0.0, 0.0]]), 422),
    "geodesic targets at 1e154": (_geodesic(sources=[0], targets=[[HUGE, HUGE, HUGE]]), 422),
    "path source at 1e154": (_path([HUGE, 0.0, 0.0]), 422),
    "path target at 1e300": (_path(0, [1e300, 1e300, 1e300]), 422),
    "correspondence at 1e40 with distances": (
        _match(queries=[[1e40, 0.0, 0.0]], return_distance=True),
        422,
    ),
    ".npy declaring (10^12, 3)": (_upload("big.npy", _npy((10**12, 3))), 413),
    "sources 'all'": (_geodesic(sources="all"), 422),
    # query values
    "sources null": (_geodesic(sources=None), 422),
    "sources a string": (_geodesic(sources="0,1"), 422),
    "sources an object": (_geodesic(sources={"a": 1}), 422),
    "sources booleans": (_geodesic(sources=[True, False]), 422),
    "sources ragged": (_geodesic(sources=[[1.0, 2.0, 3.0], [4.0, 5.0]]), 422),
    "sources 3-D": (_geodesic(sources=[[[0]]]), 422),
    "sources empty": (_geodesic(sources=[]), 422),
    "sources integral floats": (_geodesic(sources=[1.0, 2.0]), 422),
    "source index 10^30": (_geodesic(sources=[10**30]), 422),
    "source index 2^63": (_geodesic(sources=[2**63]), 422),
    "source index -2^63": (_geodesic(sources=[-(2**63)]), 422),
    "source index -1": (_geodesic(sources=[-1]), 422),
    "sources NaN literal": (_geodesic_text("[[NaN, 0, 0]]"), 422),
    "sources Infinity literal": (_geodesic_text("[[Infinity, 0, 0]]"), 422),
    "sources 1e999999": (_geodesic_text("[[1e999999, 0, 0]]"), 422),
    "sources nested 10000 deep": (_geodesic_text("[" * 10000 + "]" * 10000), 422),
    "targets 'ALL'": (_geodesic(sources=[0], targets="ALL"), 422),
    "targets empty": (_geodesic(sources=[0], targets=[]), 422),
    "too many pairs": (_geodesic(sources=list(range(100)), targets="all"), 422),
    "path two sources": (_path([0, 1]), 422),
    "path source an object": (_path({"x": 1}), 422),
    "path source -1": (_path(-1), 422),
    # issue 16: method
    "unknown method": (_geodesic(sources=[0], method="dijkstra"), 422),
    "method in capitals": (_geodesic(sources=[0], method="EXACT"), 422),
    "method null": (_geodesic(sources=[0], method=None), 422),
    "method a number": (_geodesic(sources=[0], method=3), 422),
    "path unknown method": (_path(0, 1, method="fast-marching"), 422),
    "exact on a point cloud": (_on_cloud("/geodesic", sources=[0], method="exact"), 422),
    "exact path on a point cloud": (
        _on_cloud("/paths", source=0, target=1, method="exact"),
        422,
    ),
    "exact above the vertex limit": (_geodesic(sources=[0], method="exact"), 422),
    "exact path above the vertex limit": (_path(0, 1, method="exact"), 422),
    "too many exact sources": (
        _geodesic(sources=list(range(MAX_EXACT_SOURCES + 1)), method="exact"),
        422,
    ),
    "classical method, unknown model": (_geodesic(sources=[0], method="heat", model="x"), 422),
    "classical method, source at 1e154": (
        _geodesic(sources=[[HUGE, 0.0, 0.0]], method="graph"),
        422,
    ),
    "classical method, index -1": (_geodesic(sources=[-1], method="heat"), 422),
    "classical method, index out of range": (_geodesic(sources=[10**6], method="graph"), 422),
    "classical method, too many pairs": (
        _geodesic(sources=list(range(100)), targets="all", method="graph"),
        422,
    ),
    "classical path, target at 1e300": (_path(0, [1e300, 1e300, 1e300], method="heat"), 422),
    "unknown model 'Auto'": (_geodesic(sources=[0], model="Auto"), 422),
    "correspondence points not triples": (_match(queries=[[0.0, 0.0]]), 422),
    "correspondence too many queries": (_match(queries=list(range(MAX_QUERIES + 1))), 422),
    "correspondence id a number": (
        lambda h, s, ids: h.post(
            "/correspondences", json={"source_shape_id": 5, "target_shape_id": ids[1]}
        ),
        422,
    ),
    "correspondence unknown refine": (_match(queries=[0], refine="zoomout++"), 422),
    "correspondence refine a list": (_match(queries=[0], refine=["zoomout"]), 422),
    "correspondence refine, point cloud target": (
        lambda h, s, ids: h.post(
            "/correspondences",
            json={
                "source_shape_id": ids[0],
                "target_shape_id": ids[2],
                "queries": [0],
                "refine": "zoomout",
            },
        ),
        422,
    ),
    # request bodies
    "shape id empty": (
        lambda h, s, ids: h.post("/geodesic", json={"shape_id": "", "sources": [0]}),
        422,
    ),
    "shape id 10k chars": (
        lambda h, s, ids: h.post("/geodesic", json={"shape_id": "a" * 10_000, "sources": [0]}),
        422,
    ),
    "extra field": (_geodesic(sources=[0], beams=4), 422),
    "body a list": (lambda h, s, ids: h.post("/geodesic", json=[1, 2]), 422),
    "body truncated": (lambda h, s, ids: _json(h, "/geodesic", '{"shape_id": "'), 422),
    "body empty": (lambda h, s, ids: _json(h, "/geodesic", ""), 422),
    "body not JSON": (
        lambda h, s, ids: h.post(
            "/geodesic", content=b"\xff\xfe", headers={"content-type": "text/plain"}
        ),
        415,
    ),
    "unknown shape, long id": (lambda h, s, ids: h.get("/shapes/" + "f" * 1000), 404),
    # uploads
    ".npy declaring a negative shape": (_upload("neg.npy", _npy((-1, 3))), 400),
    ".npy pickled object array": (
        _upload("obj.npy", _npy((1,)).replace(b"<f8", b"|O1")),
        400,
    ),
    "OBJ with 1e400 vertex": (
        _upload("inf.obj", b"v 1e400 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
        422,
    ),
    "OBJ with 1e300 vertices": (
        _upload("huge.obj", b"v 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nf 1 2 3\n"),
        422,
    ),
    "OBJ face index 1e30": (
        _upload("face.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1000000000000000000000000000000\n"),
        422,
    ),
    "JSON vertices at 1e308": (
        lambda h, s, ids: h.post(
            "/shapes",
            json={"vertices": [[1e308, 0, 0], [0, 1e308, 0], [0, 0, 1e308], [1, 1, 1]]},
        ),
        422,
    ),
    "unknown format": (_upload("a.dwg", b"abc"), 415),
    "declared body over the limit": (
        lambda h, s, ids: _raw(s, _post_head("/shapes", 10 * UPLOAD_BYTES)),
        413,
    ),
    # slow and unauthenticated clients
    "body never arrives": (lambda h, s, ids: _raw(s, _post_head("/geodesic", 100), b"{"), 408),
    "no API key, large body unsent": (
        lambda h, s, ids: _raw(s, _post_head("/geodesic", UPLOAD_BYTES // 2, key=None)),
        401,
    ),
    "wrong API key": (
        lambda h, s, ids: h.post(
            "/geodesic", json={"shape_id": ids[0], "sources": [0]}, headers={"X-API-Key": "x"}
        ),
        401,
    ),
}


@pytest.mark.parametrize("case", list(REST_CASES))
def test_rest_hostile_input_is_a_4xx_problem(service, http, shape_ids, case):
    call, status = REST_CASES[case]
    response = call(http, service, shape_ids)
    assert 400 <= response.status_code < 500, response.text
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM_JSON)
    problem = response.json()
    assert problem["status"] == status and problem["type"].startswith(PROBLEM_BASE_URI)
    assert problem["detail"]
    _assert_still_answers(http, shape_ids[0])


def test_a_refused_small_body_is_read_first_and_the_connection_kept(service, shape_ids):
    """A wrong key with a small body: the body is drained before the 401, so the connection
    closes cleanly (no reset racing the answer) and stays open for the next request; an
    unsent large body is refused unread and its connection closed."""
    body = json.dumps({"shape_id": shape_ids[0], "sources": [0]}).encode()
    with httpx.Client(base_url=service.base_url, timeout=30) as client:
        for _ in range(20):  # one connection, reused each time
            refused = client.post("/geodesic", content=body, headers={"X-API-Key": "x"})
            assert refused.status_code == 401
            assert refused.headers.get("connection") != "close"
        answered = client.post(
            "/geodesic",
            content=body,
            headers={"X-API-Key": API_KEY, "Content-Type": "application/json"},
        )
        assert answered.status_code == 200
    unsent = _raw(service, _post_head("/geodesic", UPLOAD_BYTES // 2, key="x"))
    assert unsent.status_code == 401 and unsent.headers.get("connection") == "close"


def test_sources_all_says_why(http, shape_ids):
    response = http.post("/geodesic", json={"shape_id": shape_ids[0], "sources": "all"})
    assert response.status_code == 422
    assert "'all' is not allowed" in response.json()["detail"]


@pytest.mark.parametrize(
    ("fields", "code", "says"),
    [
        ({"method": "dijkstra"}, "invalid-request", "'learned', 'heat', 'exact' or 'graph'"),
        ({"method": "exact"}, "method-size-limit", f"at most {MAX_EXACT_VERTICES} vertices"),
        (
            {"method": "exact", "sources": list(range(MAX_EXACT_SOURCES + 1))},
            "too-many-queries",
            "LITEGE_MAX_EXACT_SOURCES",
        ),
    ],
)
def test_method_refusals_say_why(http, shape_ids, fields, code, says):
    body = {"shape_id": shape_ids[0], "sources": [0], **fields}
    problem = http.post("/geodesic", json=body).json()
    assert problem["status"] == 422 and problem["code"] == code, problem
    assert says in problem["detail"], problem["detail"]


def test_exact_on_a_point_cloud_says_why(http, shape_ids):
    body = {"shape_id": shape_ids[2], "sources": [0], "method": "exact"}
    problem = http.post("/geodesic", json=body).json()
    assert problem["code"] == "method-not-applicable" and "point cloud" in problem["detail"]


def test_heat_on_a_cloud_of_few_distinct_points_says_why(http):
    """Point-cloud heat joins each point to 30 neighbours: a cloud of 20 points (sent
    twice, so 40 rows) is a 422 that names the fix, not the solver's failure as a 500."""
    points = np.random.default_rng(4).normal(size=(20, 3))
    response = http.post("/shapes", json={"vertices": np.vstack([points, points]).tolist()})
    assert response.status_code in (200, 201), response.text
    body = {"shape_id": response.json()["shape_id"], "sources": [0], "method": "heat"}
    problem = http.post("/geodesic", json=body).json()
    assert problem["status"] == 422 and problem["code"] == "method-not-applicable", problem
    assert "20" in problem["detail"] and "method='graph'" in problem["detail"]
    graph = http.post("/geodesic", json={**body, "method": "graph"})
    assert graph.status_code == 200, graph.text


# --------------------------------------------------------------------------- gRPC

GrpcCase = Callable[[Any, Any, list[str]], Any]
META = (("x-api-key", API_KEY),)


def _call(method: str, message: Callable[[Any, list[str]], Any]) -> GrpcCase:
    return lambda stub, pb2, ids: getattr(stub, method)(
        message(pb2, ids), metadata=META, timeout=30
    )


def _stream(method: str, messages: Callable[[Any, list[str]], list[Any]]) -> GrpcCase:
    def call(stub: Any, pb2: Any, ids: list[str]) -> Any:
        result = getattr(stub, method)(iter(messages(pb2, ids)), metadata=META, timeout=30)
        return list(result) if method == "Correspond" else result

    return call


def _header(pb2: Any, **fields: Any) -> Any:
    return pb2.RegisterShapeRequest(header=pb2.ShapeHeader(**fields))


def _file(pb2: Any, file_format: str, data: bytes) -> list[Any]:
    return [_header(pb2, file_format=file_format), pb2.RegisterShapeRequest(chunk=data)]


def _grpc_geodesic(**fields: Any) -> GrpcCase:
    def message(pb2: Any, ids: list[str]) -> Any:
        values = dict(fields)
        for name in ("source_points", "target_points"):
            if name in values:
                values[name] = pb2.Points(xyz=values[name])
        for name in ("source_indices", "target_indices"):
            if name in values:
                values[name] = pb2.Indices(values=values[name])
        shape = ids[_shape_of(values)]
        return pb2.GeodesicRequest(shape_id=shape, **_without_shape(values))

    return _call("Geodesic", message)


def _grpc_path(source: dict[str, Any], target: dict[str, Any], **fields: Any) -> GrpcCase:
    def point(pb2: Any, spec: dict[str, Any]) -> Any:
        if "xyz" in spec:
            return pb2.QueryPoint(
                xyz=pb2.Point(x=spec["xyz"][0], y=spec["xyz"][1], z=spec["xyz"][2])
            )
        return pb2.QueryPoint(**spec)

    return _call(
        "Path",
        lambda pb2, ids: pb2.PathRequest(
            shape_id=ids[_shape_of(fields)],
            source=point(pb2, source),
            target=point(pb2, target),
            **_without_shape(fields),
        ),
    )


def _shape_of(fields: dict[str, Any]) -> int:
    return int(fields.get("shape", 0))


def _without_shape(fields: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in fields.items() if k != "shape"}


def _grpc_match(**fields: Any) -> GrpcCase:
    def messages(pb2: Any, ids: list[str]) -> list[Any]:
        values = {"source_shape_id": ids[0], "target_shape_id": ids[1], **fields}
        if "query_points" in values:
            values["query_points"] = pb2.Points(xyz=values["query_points"])
        if "query_indices" in values:
            values["query_indices"] = pb2.Indices(values=values["query_indices"])
        return [pb2.CorrespondRequest(**values)]

    return _stream("Correspond", messages)


GRPC_CASES: dict[str, GrpcCase] = {
    "geodesic source at 1e154": _grpc_geodesic(source_points=[HUGE, 0.0, 0.0]),
    "geodesic targets at 1e300": _grpc_geodesic(
        source_indices=[0], target_points=[1e300, 1e300, 1e300]
    ),
    "geodesic source NaN": _grpc_geodesic(source_points=[float("nan"), 0.0, 0.0]),
    "geodesic source inf": _grpc_geodesic(source_points=[float("inf"), 0.0, 0.0]),
    "geodesic points not triples": _grpc_geodesic(source_points=[1.0, 2.0, 3.0, 4.0]),
    "geodesic source index -1": _grpc_geodesic(source_indices=[-1]),
    "geodesic source index 2^62": _grpc_geodesic(source_indices=[2**62]),
    "geodesic sources empty": _grpc_geodesic(source_indices=[]),
    "geodesic no sources": _grpc_geodesic(),
    "geodesic too many pairs": _grpc_geodesic(source_indices=list(range(100))),
    "unknown method": _grpc_geodesic(source_indices=[0], method="dijkstra"),
    "path unknown method": _grpc_path({"index": 0}, {"index": 1}, method="fast-marching"),
    "exact on a point cloud": _grpc_geodesic(source_indices=[0], method="exact", shape=2),
    "exact path on a point cloud": _grpc_path({"index": 0}, {"index": 1}, method="exact", shape=2),
    "exact above the vertex limit": _grpc_geodesic(source_indices=[0], method="exact"),
    "exact path above the vertex limit": _grpc_path({"index": 0}, {"index": 1}, method="exact"),
    "too many exact sources": _grpc_geodesic(
        source_indices=list(range(MAX_EXACT_SOURCES + 1)), method="exact"
    ),
    "classical method, unknown model": _grpc_geodesic(source_indices=[0], method="heat", model="x"),
    "classical method, source at 1e154": _grpc_geodesic(
        source_points=[HUGE, 0.0, 0.0], method="graph"
    ),
    "classical path, index -5": _grpc_path({"index": 0}, {"index": -5}, method="heat"),
    "path source at 1e154": _grpc_path({"xyz": (HUGE, 0.0, 0.0)}, {"index": 1}),
    "path target index -5": _grpc_path({"index": 0}, {"index": -5}),
    "path no source": _call(
        "Path", lambda pb2, ids: pb2.PathRequest(shape_id=ids[0], target=pb2.QueryPoint(index=1))
    ),
    "correspondence at 1e40 with distances": _grpc_match(
        query_points=[1e40, 0.0, 0.0], return_distance=True
    ),
    "correspondence queries empty": _grpc_match(query_indices=[]),
    "correspondence index -1": _grpc_match(query_indices=[-1]),
    "correspondence no pair": _stream(
        "Correspond",
        lambda pb2, ids: [pb2.CorrespondRequest(query_indices=pb2.Indices(values=[0]))],
    ),
    "correspondence too many queries": _grpc_match(query_indices=list(range(MAX_QUERIES + 1))),
    "correspondence unknown refine": _grpc_match(query_indices=[0], refine="zoomout++"),
    "correspondence refine, point cloud source": _stream(
        "Correspond",
        lambda pb2, ids: [
            pb2.CorrespondRequest(
                source_shape_id=ids[2],
                target_shape_id=ids[0],
                query_indices=pb2.Indices(values=[0]),
                refine="zoomout-hybrid",
            )
        ],
    ),
    ".npy declaring (10^12, 3)": _stream(
        "RegisterShape", lambda pb2, ids: _file(pb2, "npy", _npy((10**12, 3)))
    ),
    ".npy declaring a negative shape": _stream(
        "RegisterShape", lambda pb2, ids: _file(pb2, "npy", _npy((-1, 3)))
    ),
    "raw arrays declaring 2^63 vertices": _stream(
        "RegisterShape",
        lambda pb2, ids: [
            _header(pb2, file_format="arrays", n_vertices=2**63, n_faces=0),
            pb2.RegisterShapeRequest(chunk=b"\0" * 72),
        ],
    ),
    "inline vertices at 1e308": _stream(
        "RegisterShape",
        lambda pb2, ids: [
            _header(
                pb2,
                file_format="arrays",
                vertices=[1e308, 0, 0, 0, 1e308, 0, 0, 0, 1e308],
                faces=[0, 1, 2],
            )
        ],
    ),
    "inline vertices not triples": _stream(
        "RegisterShape",
        lambda pb2, ids: [_header(pb2, file_format="arrays", vertices=[1.0, 2.0, 3.0, 4.0])],
    ),
    "unknown format": _stream("RegisterShape", lambda pb2, ids: _file(pb2, "dwg", b"abc")),
    "empty upload stream": _stream("RegisterShape", lambda pb2, ids: []),
    "shape id blank": _call("GetShape", lambda pb2, ids: pb2.ShapeRef(shape_id=" ")),
    "unknown shape, long id": _call(
        "GetShape", lambda pb2, ids: pb2.ShapeRef(shape_id="f" * 10_000)
    ),
    "delete unknown shape": _call("DeleteShape", lambda pb2, ids: pb2.ShapeRef(shape_id="0" * 64)),
    "no API key": lambda stub, pb2, ids: stub.GetShape(pb2.ShapeRef(shape_id=ids[0]), timeout=30),
}
CLIENT_CODES = {
    grpc.StatusCode.INVALID_ARGUMENT,
    grpc.StatusCode.NOT_FOUND,
    grpc.StatusCode.RESOURCE_EXHAUSTED,
    grpc.StatusCode.UNAUTHENTICATED,
}


@pytest.mark.parametrize("case", list(GRPC_CASES))
def test_grpc_hostile_input_is_a_client_status(http, stub, pb2, shape_ids, case):
    with pytest.raises(grpc.RpcError) as caught:
        GRPC_CASES[case](stub, pb2, shape_ids)
    error = caught.value
    assert error.code() in CLIENT_CODES, (error.code(), error.details())
    trailing = dict(error.trailing_metadata() or ())
    assert trailing.get("litege-problem-type", "").startswith(PROBLEM_BASE_URI), trailing
    assert error.details()
    answer = stub.Geodesic(
        pb2.GeodesicRequest(
            shape_id=shape_ids[0],
            source_indices=pb2.Indices(values=[0]),
            target_indices=pb2.Indices(values=[1]),
        ),
        metadata=META,
        timeout=30,
    )
    assert (answer.rows, answer.cols) == (1, 1)
    _assert_still_answers(http, shape_ids[0])


def test_the_suite_is_large_enough():
    assert len(REST_CASES) + len(GRPC_CASES) >= 40
    assert np.isfinite(HUGE)  # the absurd numbers are finite: a unit error, not a NaN


def test_grpc_upload_that_stalls_is_refused(http, stub, pb2, shape_ids):
    """An upload stream that stops sending is ended after the body-read timeout (it held no
    concurrency slot meanwhile) and the service goes on answering."""
    release = threading.Event()

    def stalling() -> Iterator[Any]:
        yield _header(pb2, file_format="obj")
        release.wait(30)  # the client sends nothing more

    try:
        with pytest.raises(grpc.RpcError) as caught:
            stub.RegisterShape(stalling(), metadata=META, timeout=30)
    finally:
        release.set()
    assert caught.value.code() == grpc.StatusCode.DEADLINE_EXCEEDED, caught.value.details()
    trailing = dict(caught.value.trailing_metadata() or ())
    assert trailing["litege-problem-type"] == PROBLEM_BASE_URI + "request-timeout"
    _assert_still_answers(http, shape_ids[0])
