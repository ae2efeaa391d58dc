"""The gRPC API end to end: a real :class:`service.runtime.Runtime` and ``grpc.aio`` server on
loopback (own event loop in a background thread), driven by :class:`GrpcClient` and raw stubs.

Also the stub generator (``service.grpc_stubs``): staleness, read-only installs, concurrent
generation.
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import threading
from collections.abc import Callable, Coroutine, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import grpc
import numpy as np
import pytest
import trimesh

from litege_core.errors import MissingDependencyError
from litege_core.io import load_shape
from litege_core.learned import Predictor, load_shipped
from service import grpc_stubs
from service.errors import OverloadedError
from service.grpc_client import GrpcCallError, GrpcClient
from service.grpc_server import (
    PROBLEM_TYPE_KEY,
    RETRY_AFTER_KEY,
    LiteGEServicer,
    start_grpc_server,
    stop_grpc_server,
)
from service.problems import PROBLEM_BASE_URI
from service.runtime import Runtime
from service.settings import Settings

MODEL = "quadrupeds"
API_KEY = "test-key-0123456789abcdef"
STRICT_UPLOAD_BYTES = 64 << 10
STRICT_MAX_QUERIES = 1000
STRICT_BATCH_WAIT_MS = 400.0
"""The strict server's batcher waits this long for company: every computed call is slower."""
REPO = Path(__file__).resolve().parents[2]
SC = grpc.StatusCode


# --------------------------------------------------------------------------- fixtures


class LoopThread:
    """An asyncio event loop running forever in a daemon thread."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coro: Coroutine[Any, Any, Any], timeout: float = 120) -> Any:
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(30)
        self.loop.close()


@dataclass
class Served:
    runtime: Runtime
    server: grpc.aio.Server
    target: str


def _settings(**overrides: Any) -> Settings:
    base: dict[str, Any] = {
        "models": (MODEL,),
        "default_model": MODEL,
        "device": "cpu",
        "api_key": None,
        "redis_url": None,
    }
    return Settings(**(base | overrides))


def _serve(loop_thread: LoopThread, settings: Settings) -> Iterator[Served]:
    async def start() -> Served:
        runtime = await Runtime.start(settings)
        server, port = await start_grpc_server(runtime, "127.0.0.1", 0)
        return Served(runtime, server, f"127.0.0.1:{port}")

    async def stop(served: Served) -> None:
        await stop_grpc_server(served.server, 0)
        await served.runtime.close()

    served = loop_thread.run(start())
    try:
        yield served
    finally:
        loop_thread.run(stop(served))


@pytest.fixture(scope="module")
def loop_thread() -> Iterator[LoopThread]:
    thread = LoopThread()
    yield thread
    thread.stop()


@pytest.fixture(scope="module")
def served(loop_thread: LoopThread) -> Iterator[Served]:
    """The default server: no API key, default limits."""
    yield from _serve(loop_thread, _settings())


@pytest.fixture(scope="module")
def strict(loop_thread: LoopThread) -> Iterator[Served]:
    """API key, 64 KiB upload limit, 1000 pairs per query, and a slow batcher (deterministic
    deadline test)."""
    yield from _serve(
        loop_thread,
        _settings(
            api_key=API_KEY,
            max_upload_bytes=STRICT_UPLOAD_BYTES,
            batch_max_wait_ms=STRICT_BATCH_WAIT_MS,
            max_queries=STRICT_MAX_QUERIES,
        ),
    )


@pytest.fixture(scope="module")
def client(served: Served) -> Iterator[GrpcClient]:
    with GrpcClient(served.target, timeout_s=60) as c:
        yield c


@pytest.fixture(scope="module")
def stub(client: GrpcClient) -> Any:
    """The raw ``LiteGEStub`` on the client's channel (for malformed requests)."""
    _, pb2_grpc = grpc_stubs.load_stubs()
    return pb2_grpc.LiteGEStub(client._channel)


@pytest.fixture(scope="module")
def pb2() -> Any:
    return grpc_stubs.load_stubs()[0]


@pytest.fixture(scope="module")
def predictor() -> Predictor:
    """The library on the same shipped bundle, for reference numbers."""
    return Predictor(load_shipped(MODEL))


@dataclass(frozen=True)
class MeshFiles:
    vertices: np.ndarray  # (N, 3) float64 on a 1/256 grid: exact in float32 PLY and 8-digit OBJ
    faces: np.ndarray  # (F, 3) int64
    obj: bytes
    ply: bytes


def _mesh_files(blob: Callable[..., Any], seed: int) -> MeshFiles:
    shape = blob(seed)
    vertices = np.round(np.asarray(shape.vertices) * 256) / 256
    faces = np.asarray(shape.faces)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    obj = mesh.export(file_type="obj", include_normals=False, include_texture=False).encode()
    ply = mesh.export(file_type="ply")
    return MeshFiles(vertices, faces, obj, ply)


@pytest.fixture(scope="module")
def mesh(blob: Callable[..., Any]) -> MeshFiles:
    return _mesh_files(blob, 11)


@pytest.fixture(scope="module")
def registered(client: GrpcClient, mesh: MeshFiles, predictor: Predictor) -> dict[str, Any]:
    """A shape registered once for the query tests, with reference distances."""
    info = client.register_file(mesh.ply, "ply")
    state = predictor.register(load_shape(mesh.ply, file_format="ply"))
    return {
        "info": info,
        "state": state,
        "probe": np.array([0, 5, 9, 300]),
        "reference": predictor.distances(state, np.array([0, 5, 9, 300]), np.array([1, 2, 641])),
    }


def _assert_cache_intact(client: GrpcClient, registered: dict[str, Any]) -> None:
    sid = registered["info"]["shape_id"]
    got = client.geodesic(sid, registered["probe"], np.array([1, 2, 641]))
    np.testing.assert_allclose(got, registered["reference"], atol=1e-5, rtol=0)


def _raises(code: grpc.StatusCode, problem: str | None, call: Callable[[], Any]) -> GrpcCallError:
    with pytest.raises(GrpcCallError) as caught:
        call()
    assert caught.value.code == code, caught.value
    if problem is not None:
        assert caught.value.problem_type == PROBLEM_BASE_URI + problem
    return caught.value


def _raw_error(call: Callable[[], Any]) -> GrpcCallError:
    with pytest.raises(grpc.RpcError) as caught:
        call()
    return GrpcCallError.of(caught.value)


# --------------------------------------------------------------------------- health, reflection


def test_health_serving(client: GrpcClient) -> None:
    assert client.health() == "SERVING"
    assert client.health("litege.v1.LiteGE") == "SERVING"


def test_reflection_lists_the_service(served: Served) -> None:
    from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc

    with grpc.insecure_channel(served.target) as channel:
        stub = reflection_pb2_grpc.ServerReflectionStub(channel)
        requests = [
            reflection_pb2.ServerReflectionRequest(list_services=""),
            reflection_pb2.ServerReflectionRequest(file_containing_symbol="litege.v1.LiteGE"),
        ]
        listed, described = list(stub.ServerReflectionInfo(iter(requests), timeout=10))
    names = {s.name for s in listed.list_services_response.service}
    assert {"litege.v1.LiteGE", "grpc.health.v1.Health"} <= names
    assert described.file_descriptor_response.file_descriptor_proto


# --------------------------------------------------------------------------- registration


def test_register_streamed_chunks_then_idempotent(
    client: GrpcClient, blob: Callable[..., Any]
) -> None:
    files = _mesh_files(blob, 21)
    chunk = 1024
    assert len(files.obj) // chunk > 20  # really many messages
    info = client.register_file(files.obj, "obj", chunk_bytes=chunk)
    assert info["created"] is True
    assert info["kind"] == "mesh"
    assert (info["n_points"], info["n_faces"]) == (len(files.vertices), len(files.faces))
    assert info["model"] == MODEL
    assert info["bundle_hash"] == load_shipped(MODEL).content_hash
    assert info["shape_id"] == load_shape(files.obj, file_format="obj").content_hash
    assert isinstance(info["ood_score"], float)
    if info["ood_calibrated"]:
        assert isinstance(info["out_of_distribution"], bool)
    else:
        assert info["out_of_distribution"] is None

    again = client.register_file(files.obj, "obj", chunk_bytes=4096)
    assert again == info | {"created": False}
    as_ply = client.register_file(files.ply, "ply", chunk_bytes=777)
    assert as_ply["shape_id"] == info["shape_id"]
    assert as_ply["created"] is False
    as_arrays = client.register_arrays(files.vertices, files.faces, chunk_bytes=1000)
    assert as_arrays["shape_id"] == info["shape_id"]


def test_register_from_path(client: GrpcClient, mesh: MeshFiles, tmp_path: Path) -> None:
    path = tmp_path / "blob.ply"
    path.write_bytes(mesh.ply)
    info = client.register_file(path)
    assert info["shape_id"] == load_shape(mesh.ply, file_format="ply").content_hash


def test_register_arrays_inline_and_point_cloud(
    client: GrpcClient, stub: Any, pb2: Any, blob: Callable[..., Any]
) -> None:
    files = _mesh_files(blob, 22)
    header = pb2.ShapeHeader(
        file_format="arrays",
        vertices=files.vertices.ravel().tolist(),
        faces=files.faces.ravel().tolist(),
    )
    inline = stub.RegisterShape(iter([pb2.RegisterShapeRequest(header=header)]), timeout=60)
    raw = client.register_arrays(files.vertices, files.faces)
    assert inline.shape_id == raw["shape_id"]
    assert inline.kind == "mesh" and inline.n_faces == len(files.faces)

    cloud = client.register_arrays(files.vertices, kind="point_cloud")
    assert cloud["kind"] == "point_cloud"
    assert cloud["n_faces"] == 0
    assert cloud["shape_id"] != raw["shape_id"]
    distances = client.geodesic(cloud["shape_id"], [0, 1])
    assert distances.shape == (2, len(files.vertices))


# --------------------------------------------------------------------------- queries


def test_geodesic_indices_match_library(
    client: GrpcClient, registered: dict[str, Any], predictor: Predictor
) -> None:
    sid = registered["info"]["shape_id"]
    sources, targets = np.array([0, 17, 42]), np.array([3, 100, 641, 0])
    got = client.geodesic(sid, sources, targets)
    assert got.dtype == np.float32 and got.shape == (3, 4)
    expected = predictor.distances(registered["state"], sources, targets)
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0)
    assert got[0, 3] == 0.0


def test_geodesic_all_targets(
    client: GrpcClient, registered: dict[str, Any], predictor: Predictor
) -> None:
    sid = registered["info"]["shape_id"]
    n = registered["info"]["n_points"]
    for targets in ("all", None):
        got = client.geodesic(sid, [5, 6], targets)
        assert got.shape == (2, n)
        expected = predictor.distances(registered["state"], np.array([5, 6]), None)
        np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0)


def test_geodesic_points_match_library(
    client: GrpcClient, registered: dict[str, Any], mesh: MeshFiles, predictor: Predictor
) -> None:
    sid = registered["info"]["shape_id"]
    sources = mesh.vertices[[3, 50]] * 1.01  # near, not on, the surface
    targets = mesh.vertices[[7, 8, 9]]
    got = client.geodesic(sid, sources, targets)
    expected = predictor.distances(registered["state"], sources, targets)
    assert got.shape == (2, 3)
    np.testing.assert_allclose(got, expected, atol=1e-5, rtol=0)
    mixed = client.geodesic(sid, sources, [7, 8, 9])  # points to indices
    np.testing.assert_allclose(mixed, expected, atol=1e-5, rtol=0)


def test_path_runs_from_source_to_target(
    client: GrpcClient, registered: dict[str, Any], mesh: MeshFiles, predictor: Predictor
) -> None:
    sid = registered["info"]["shape_id"]
    path = client.path(sid, 0, 300)
    points = path["points"]
    assert points.ndim == 2 and points.shape[1] == 3 and len(points) >= 2
    assert path["converged"] is True
    np.testing.assert_allclose(points[0], mesh.vertices[0], atol=1e-6)
    np.testing.assert_allclose(points[-1], mesh.vertices[300], atol=1e-6)
    library = predictor.path(registered["state"], 0, 300)  # also source → target
    np.testing.assert_allclose(points, np.asarray(library.points), atol=1e-5)
    assert path["predicted_distance"] == pytest.approx(library.predicted_distance, abs=1e-5)
    assert path["length"] > 0 and path["predicted_distance"] > 0 and path["n_steps"] >= 0
    assert isinstance(path["converged"], bool)

    by_point = client.path(sid, mesh.vertices[0], mesh.vertices[300])
    np.testing.assert_allclose(by_point["points"][0], mesh.vertices[0], atol=1e-6)
    assert by_point["predicted_distance"] == pytest.approx(path["predicted_distance"], abs=1e-5)


def test_get_then_delete_then_not_found(client: GrpcClient, blob: Callable[..., Any]) -> None:
    files = _mesh_files(blob, 23)
    sid = client.register_file(files.ply, "ply")["shape_id"]
    info = client.get_shape(sid)
    assert info["shape_id"] == sid and info["created"] is False
    assert client.get_shape(sid, model=MODEL)["model"] == MODEL
    assert client.delete_shape(sid) == {"shape_id": sid, "deleted": True}
    _raises(SC.NOT_FOUND, "shape-not-found", lambda: client.get_shape(sid))
    _raises(SC.NOT_FOUND, "shape-not-found", lambda: client.delete_shape(sid))
    _raises(SC.NOT_FOUND, "shape-not-found", lambda: client.geodesic(sid, [0]))


@pytest.mark.parametrize("method", ["get", "delete", "geodesic", "path"])
def test_unknown_shape_is_not_found(
    client: GrpcClient, registered: dict[str, Any], method: str
) -> None:
    unknown = "0" * 64
    calls = {
        "get": lambda: client.get_shape(unknown),
        "delete": lambda: client.delete_shape(unknown),
        "geodesic": lambda: client.geodesic(unknown, [0]),
        "path": lambda: client.path(unknown, 0, 1),
    }
    _raises(SC.NOT_FOUND, "shape-not-found", calls[method])
    _assert_cache_intact(client, registered)


# --------------------------------------------------------------------------- bad inputs


def _header(pb2: Any, **fields: Any) -> Any:
    return pb2.RegisterShapeRequest(header=pb2.ShapeHeader(**fields))


def _chunk(pb2: Any, data: bytes) -> Any:
    return pb2.RegisterShapeRequest(chunk=data)


BAD_INPUTS: dict[str, tuple[str, Callable[[GrpcClient, Any, Any, str, MeshFiles], Any]]] = {
    "malformed file": (
        "malformed-file",
        lambda c, s, p, sid, m: c.register_file(b"not a mesh at all", "ply"),
    ),
    "garbage GLB": ("malformed-file", lambda c, s, p, sid, m: c.register_file(b"hello", "glb")),
    "truncated file": (
        "malformed-file",
        lambda c, s, p, sid, m: c.register_file(m.ply[: len(m.ply) // 2], "ply"),
    ),
    "unsupported format": (
        "unsupported-format",
        lambda c, s, p, sid, m: c.register_file(m.obj, "docx"),
    ),
    "NaN vertices": (
        "non-finite-coordinates",
        lambda c, s, p, sid, m: c.register_arrays(
            np.where(np.arange(len(m.vertices))[:, None] == 3, np.nan, m.vertices), m.faces
        ),
    ),
    "face index out of range": (
        "face-index-out-of-range",
        lambda c, s, p, sid, m: c.register_arrays(m.vertices, m.faces + 10_000),
    ),
    "bad kind": ("bad-array-shape", lambda c, s, p, sid, m: c.register_file(m.ply, "ply", "x")),
    "unknown model on register": (
        "unknown-model",
        lambda c, s, p, sid, m: c.register_file(m.ply, "ply", model="giraffes"),
    ),
    "missing header": (
        "invalid-request",
        lambda c, s, p, sid, m: s.RegisterShape(iter([_chunk(p, m.ply)]), timeout=30),
    ),
    "empty stream": ("invalid-request", lambda c, s, p, sid, m: s.RegisterShape(iter([]))),
    "second header": (
        "invalid-request",
        lambda c, s, p, sid, m: s.RegisterShape(
            iter([_header(p, file_format="ply"), _header(p, file_format="ply")]), timeout=30
        ),
    ),
    "no file format": (
        "invalid-request",
        lambda c, s, p, sid, m: s.RegisterShape(iter([_header(p), _chunk(p, m.ply)]), timeout=30),
    ),
    "raw arrays of the wrong size": (
        "bad-array-shape",
        lambda c, s, p, sid, m: s.RegisterShape(
            iter([_header(p, file_format="arrays", n_vertices=10), _chunk(p, b"\0" * 200)]),
            timeout=30,
        ),
    ),
    "inline vertices not triples": (
        "bad-array-shape",
        lambda c, s, p, sid, m: s.RegisterShape(
            iter([_header(p, file_format="arrays", vertices=[1.0, 2.0])]), timeout=30
        ),
    ),
    "index out of range": (
        "index-out-of-range",
        lambda c, s, p, sid, m: c.geodesic(sid, [0, 10**6]),
    ),
    "negative target index": (
        "index-out-of-range",
        lambda c, s, p, sid, m: c.geodesic(sid, [0], [-5]),
    ),
    "unknown model on query": (
        "unknown-model",
        lambda c, s, p, sid, m: c.geodesic(sid, [0], model="giraffes"),
    ),
    "no sources": (
        "invalid-request",
        lambda c, s, p, sid, m: s.Geodesic(p.GeodesicRequest(shape_id=sid), timeout=30),
    ),
    "empty sources": (
        "bad-array-shape",
        lambda c, s, p, sid, m: s.Geodesic(
            p.GeodesicRequest(shape_id=sid, source_indices=p.Indices()), timeout=30
        ),
    ),
    "points not triples": (
        "bad-array-shape",
        lambda c, s, p, sid, m: s.Geodesic(
            p.GeodesicRequest(shape_id=sid, source_points=p.Points(xyz=[1.0, 2.0])), timeout=30
        ),
    ),
    "NaN query point": (
        "non-finite-coordinates",
        lambda c, s, p, sid, m: c.geodesic(sid, np.array([[np.nan, 0.0, 0.0]])),
    ),
    "no shape id": (
        "invalid-request",
        lambda c, s, p, sid, m: s.GetShape(p.ShapeRef(shape_id=" "), timeout=30),
    ),
    "path without target": (
        "invalid-request",
        lambda c, s, p, sid, m: s.Path(
            p.PathRequest(shape_id=sid, source=p.QueryPoint(index=0)), timeout=30
        ),
    ),
    "path index out of range": (
        "index-out-of-range",
        lambda c, s, p, sid, m: c.path(sid, 0, 10**6),
    ),
    "shape id of 20,000 characters": (
        "invalid-request",
        lambda c, s, p, sid, m: s.GetShape(p.ShapeRef(shape_id="a" * 20_000), timeout=30),
    ),
    "model of 30,000 characters": (
        "unknown-model",
        lambda c, s, p, sid, m: c.geodesic(sid, [0], model="m" * 30_000),
    ),
    "method of 30,000 characters": (
        "invalid-request",
        lambda c, s, p, sid, m: c.geodesic(sid, [0], method="m" * 30_000),
    ),
    "file format of 30,000 characters": (
        "unsupported-format",
        lambda c, s, p, sid, m: s.RegisterShape(
            iter([_header(p, file_format="f" * 30_000), _chunk(p, b"x")]), timeout=30
        ),
    ),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_input_is_invalid_argument_and_cache_survives(
    case: str,
    client: GrpcClient,
    stub: Any,
    pb2: Any,
    registered: dict[str, Any],
    mesh: MeshFiles,
) -> None:
    problem, call = BAD_INPUTS[case]
    sid = registered["info"]["shape_id"]

    def attempt() -> None:
        try:
            call(client, stub, pb2, sid, mesh)
        except grpc.RpcError as exc:  # raw stub calls
            raise GrpcCallError.of(exc) from None

    error = _raises(SC.INVALID_ARGUMENT, None, attempt)
    assert error.problem_type is not None
    # a more specific subclass may answer; the reported type must still be a LiteGE problem
    assert error.problem_type == PROBLEM_BASE_URI + problem, error
    assert error.message and len(error.message) < 1000  # request strings are cut, not echoed
    _assert_cache_intact(client, registered)


# --------------------------------------------------------------------------- limits and auth


def test_upload_over_the_limit_is_resource_exhausted(strict: Served, mesh: MeshFiles) -> None:
    data = (mesh.obj * (STRICT_UPLOAD_BYTES // len(mesh.obj) + 2))[: STRICT_UPLOAD_BYTES + 10]
    with GrpcClient(strict.target, api_key=API_KEY) as client:
        _raises(
            SC.RESOURCE_EXHAUSTED,
            "payload-too-large",
            lambda: client.register_file(data, "obj", chunk_bytes=4096),
        )
        # inline arrays count too
        big = np.zeros((STRICT_UPLOAD_BYTES // 24 + 10, 3))
        _raises(
            SC.RESOURCE_EXHAUSTED,
            "payload-too-large",
            lambda: client.register_arrays(big, chunk_bytes=4096),
        )
        assert client.health() == "SERVING"
        info = client.register_file(mesh.ply, "ply")  # below the limit: fine
        assert info["n_points"] == len(mesh.vertices)


@pytest.mark.parametrize("key", [None, "wrong-key-0123456789"])
def test_api_key_required(strict: Served, mesh: MeshFiles, key: str | None) -> None:
    with GrpcClient(strict.target, api_key=key) as client:
        _raises(SC.UNAUTHENTICATED, "unauthorized", lambda: client.get_shape("0" * 64))
        _raises(SC.UNAUTHENTICATED, "unauthorized", lambda: client.register_file(mesh.ply, "ply"))
        _raises(SC.UNAUTHENTICATED, "unauthorized", lambda: client.geodesic("0" * 64, [0]))
        assert client.health() == "SERVING"  # health stays open
        assert client.health("litege.v1.LiteGE") == "SERVING"


def test_api_key_accepted(strict: Served) -> None:
    with GrpcClient(strict.target, api_key=API_KEY) as client:
        _raises(SC.NOT_FOUND, "shape-not-found", lambda: client.get_shape("0" * 64))


def test_too_many_queries_is_invalid_argument(strict: Served, mesh: MeshFiles) -> None:
    with GrpcClient(strict.target, api_key=API_KEY) as client:
        sid = client.register_file(mesh.ply, "ply")["shape_id"]
        error = _raises(
            SC.INVALID_ARGUMENT, "too-many-queries", lambda: client.geodesic(sid, [0, 1])
        )
        assert "×" in error.message  # non-ASCII details arrive intact
        assert client.geodesic(sid, [0], np.arange(10)).shape == (1, 10)


def test_client_deadline_is_deadline_exceeded(strict: Served, mesh: MeshFiles) -> None:
    """The strict server's batcher waits 400 ms before computing: a 100 ms deadline cannot be
    met, whichever side notices first."""
    with GrpcClient(strict.target, api_key=API_KEY) as client:
        sid = client.register_file(mesh.ply, "ply")["shape_id"]
        _raises(SC.DEADLINE_EXCEEDED, None, lambda: client.geodesic(sid, [0, 1], timeout_s=0.1))
        _raises(SC.DEADLINE_EXCEEDED, None, lambda: client.path(sid, 0, 300, timeout_s=0.1))
        assert client.geodesic(sid, [0, 1], [2]).shape == (2, 1)  # still serving


# --------------------------------------------------------------------------- servicer unit tests


class _AbortedError(Exception):
    pass


class FakeContext:
    """The parts of ``grpc.aio.ServicerContext`` the servicer uses."""

    def __init__(self, remaining: float | None = None, metadata: tuple = ()) -> None:
        self.remaining = remaining
        self.metadata = metadata
        self.code: grpc.StatusCode | None = None
        self.details = ""
        self.trailing: dict[str, str] = {}

    def time_remaining(self) -> float | None:
        return self.remaining

    def invocation_metadata(self) -> tuple:
        return self.metadata

    async def abort(
        self, code: grpc.StatusCode, details: str = "", trailing_metadata: tuple = ()
    ) -> None:
        self.code, self.details, self.trailing = code, details, dict(trailing_metadata)
        raise _AbortedError(details)


def test_expired_deadline_reaches_the_runtime(
    loop_thread: LoopThread, served: Served, registered: dict[str, Any], pb2: Any
) -> None:
    """No time left: the runtime gets timeout 0 and the call ends DEADLINE_EXCEEDED (server
    side, with the problem type) instead of computing."""
    servicer = LiteGEServicer(served.runtime)
    request = pb2.GeodesicRequest(
        shape_id=registered["info"]["shape_id"], source_indices=pb2.Indices(values=[0])
    )
    context = FakeContext(remaining=0.0)
    with pytest.raises(_AbortedError):
        loop_thread.run(servicer.Geodesic(request, context))
    assert context.code == SC.DEADLINE_EXCEEDED
    assert context.trailing[PROBLEM_TYPE_KEY] == PROBLEM_BASE_URI + "deadline-exceeded"
    ok = loop_thread.run(servicer.Geodesic(request, FakeContext(remaining=30.0)))
    assert (ok.rows, ok.cols) == (1, registered["info"]["n_points"])


class _FailingRuntime:
    """A runtime whose geodesic raises (error mapping only); everything else is the real
    runtime's (settings, metrics, the shared concurrency limit)."""

    def __init__(self, runtime: Runtime, exc: Exception) -> None:
        self._runtime = runtime
        self.exc = exc

    def __getattr__(self, name: str) -> Any:
        return getattr(self._runtime, name)

    async def geodesic(self, *args: Any, **kwargs: Any) -> Any:
        raise self.exc


def test_overloaded_sends_retry_after(loop_thread: LoopThread, served: Served, pb2: Any) -> None:
    failing = _FailingRuntime(served.runtime, OverloadedError("queue full", retry_after_s=2.5))
    servicer = LiteGEServicer(failing)
    request = pb2.GeodesicRequest(shape_id="x", source_indices=pb2.Indices(values=[0]))
    context = FakeContext()
    with pytest.raises(_AbortedError):
        loop_thread.run(servicer.Geodesic(request, context))
    assert context.code == SC.RESOURCE_EXHAUSTED
    assert context.trailing[RETRY_AFTER_KEY] == "2500"
    assert context.trailing[PROBLEM_TYPE_KEY] == PROBLEM_BASE_URI + "overloaded"


def test_unexpected_error_is_internal_without_details(
    loop_thread: LoopThread, served: Served, pb2: Any, caplog: pytest.LogCaptureFixture
) -> None:
    failing = _FailingRuntime(served.runtime, RuntimeError("secret /path/to/weights"))
    servicer = LiteGEServicer(failing)
    request = pb2.GeodesicRequest(shape_id="x", source_indices=pb2.Indices(values=[0]))
    context = FakeContext()
    with pytest.raises(_AbortedError):
        loop_thread.run(servicer.Geodesic(request, context))
    assert context.code == SC.INTERNAL
    assert "secret" not in context.details
    assert any("secret" in r.exc_text for r in caplog.records if r.exc_text)


# --------------------------------------------------------------------------- stub generation


def test_generated_stubs_are_package_relative() -> None:
    pb2, pb2_grpc = grpc_stubs.load_stubs()
    assert pb2.__name__ == "service._generated.litege_pb2"
    assert pb2_grpc.litege__pb2 is pb2
    assert pb2.DESCRIPTOR.package == "litege.v1"
    assert not grpc_stubs.is_stale()
    assert (grpc_stubs.GENERATED_DIR / "litege_pb2.pyi").is_file()
    correspond = pb2.DESCRIPTOR.services_by_name["LiteGE"].methods_by_name["Correspond"]
    assert correspond.client_streaming and correspond.server_streaming


def test_generate_records_hash_and_detects_staleness(tmp_path: Path) -> None:
    proto = tmp_path / "litege.proto"
    proto.write_bytes(grpc_stubs.PROTO_PATH.read_bytes())
    out = tmp_path / "gen"
    assert grpc_stubs.is_stale(proto, out)  # missing
    grpc_stubs.generate(proto, out)
    assert (out / grpc_stubs.HASH_FILE).read_text().strip() == grpc_stubs.proto_sha256(proto)
    assert "from . import litege_pb2 as" in (out / "litege_pb2_grpc.py").read_text()
    assert not [p for p in out.iterdir() if p.name.startswith(".tmp-")]
    assert not grpc_stubs.is_stale(proto, out)
    proto.write_text(proto.read_text() + "\n// changed\n")
    assert grpc_stubs.is_stale(proto, out)
    (out / "litege_pb2.py").unlink()
    assert grpc_stubs.recorded_sha256(out) is None


def test_read_only_stale_stubs_raise_missing_dependency(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(grpc_stubs, "_writable", lambda out_dir: False)
    with pytest.raises(MissingDependencyError, match=r"python -m service\.grpc_stubs"):
        grpc_stubs.generate(grpc_stubs.PROTO_PATH, tmp_path / "gen")
    # load_stubs in a fresh process: stale stubs, read-only directory
    code = (
        "import service.grpc_stubs as g\n"
        "g._writable = lambda out_dir: False\n"
        "g.is_stale = lambda *a: True\n"
        "from litege_core.errors import MissingDependencyError\n"
        "try:\n    g.load_stubs()\nexcept MissingDependencyError as e:\n"
        "    print('MissingDependencyError:', e)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert "MissingDependencyError:" in result.stdout, result.stderr
    assert "python -m service.grpc_stubs" in result.stdout


def test_concurrent_generation_does_not_corrupt(tmp_path: Path) -> None:
    out = tmp_path / "genpkg"
    code = (
        "import sys; from pathlib import Path\n"
        "from service.grpc_stubs import generate, PROTO_PATH\n"
        "for _ in range(3): generate(PROTO_PATH, Path(sys.argv[1]))\n"
    )
    env = os.environ | {"OMP_NUM_THREADS": "1"}
    procs = [
        subprocess.Popen([sys.executable, "-c", code, str(out)], cwd=REPO, env=env)
        for _ in range(3)
    ]
    assert all(p.wait(timeout=120) == 0 for p in procs)
    assert not grpc_stubs.is_stale(grpc_stubs.PROTO_PATH, out)
    check = (
        "import genpkg.litege_pb2_grpc as g, genpkg.litege_pb2 as p\n"
        "assert g.litege__pb2 is p and p.ShapeInfo(shape_id='x').shape_id == 'x'\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", check], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stderr
