"""The ``Correspond`` bidirectional stream over a real gRPC server on loopback, on the untrained
``MatchingModel.tiny_random`` (plumbing, not accuracy): batches answered in order and equal to
the library, one preparation per shape, errors ending the stream with the failing batch's
status, cancellation stopping the work, per-batch deadlines."""

from __future__ import annotations

import importlib.util
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import grpc
import numpy as np
import pytest

from litege_core.matching.model import MatchingModel
from service import grpc_stubs
from service.grpc_client import GrpcCallError, GrpcClient
from service.problems import PROBLEM_BASE_URI

SEED = 5
MODEL = "tiny"
SLOW_WAIT_MS = 150.0
"""The slow server's batcher waits this long before computing: every batch takes longer."""
SC = grpc.StatusCode
HAS_PYFM = importlib.util.find_spec("pyFM") is not None
NEEDS_PYFM = pytest.mark.skipif(
    not HAS_PYFM, reason="refine='zoomout' needs pyFM (PyPI pyfmaps, the 'eval' extra)"
)


def counter(service, name: str, **labels: str) -> float:
    value = service.runtime.metrics.registry.get_sample_value(name, labels)
    return 0.0 if value is None else value


def computed(service) -> float:
    return counter(service, "litege_correspond_batches_total", model=MODEL)


@pytest.fixture(scope="module")
def reference() -> MatchingModel:
    return MatchingModel.tiny_random(SEED)


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory(grpc=True, matching=MatchingModel.tiny_random(SEED))


@pytest.fixture(scope="module")
def slow(live_service_factory):
    """A slow batcher (deterministic cancellation and deadlines) and a 100-query limit."""
    return live_service_factory(
        grpc=True,
        matching=MatchingModel.tiny_random(SEED),
        batch_max_wait_ms=SLOW_WAIT_MS,
        max_queries=100,
    )


@pytest.fixture(scope="module")
def client(service) -> Iterator[GrpcClient]:
    with GrpcClient(service.grpc_target, timeout_s=60) as c:
        yield c


@pytest.fixture(scope="module")
def pb2() -> Any:
    return grpc_stubs.load_stubs()[0]


@pytest.fixture(scope="module")
def stub(client: GrpcClient) -> Any:
    _, pb2_grpc = grpc_stubs.load_stubs()
    return pb2_grpc.LiteGEStub(client._channel)


@pytest.fixture(scope="module")
def pair(client, test_shape, reference) -> dict[str, Any]:
    source, target = test_shape(1), test_shape(2)
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in (source, target)]
    return {
        "ids": ids,
        "shapes": (source, target),
        "prepared": [reference.prepare(s, seed=0) for s in (source, target)],
    }


def _register_pair(client: GrpcClient, test_shape: Callable[..., Any]) -> list[str]:
    return [
        client.register_arrays(s.vertices, s.faces)["shape_id"]
        for s in (test_shape(1), test_shape(2))
    ]


def _request(pb2: Any, batch_id: int, queries: Any = None, **fields: Any) -> Any:
    request = pb2.CorrespondRequest(batch_id=batch_id, **fields)
    if queries == "all":
        request.all_queries = True
    elif queries is not None:
        request.query_indices.values.extend(queries)
    return request


def _raises(call: Callable[[], Any]) -> GrpcCallError:
    with pytest.raises((GrpcCallError, grpc.RpcError)) as caught:
        call()
    error = caught.value
    return error if isinstance(error, GrpcCallError) else GrpcCallError.of(error)


def _assert_serving(client: GrpcClient, pair: dict[str, Any], reference: MatchingModel) -> None:
    (answer,) = client.correspond(*pair["ids"], [[0, 1, 2]])
    expected = reference.match(*pair["prepared"], np.array([0, 1, 2]))
    np.testing.assert_array_equal(answer["matches"], expected.indices)


# --------------------------------------------------------------------------- answers


def test_batches_answered_in_order_equal_the_library(client, pair, reference):
    points = pair["shapes"][0].vertices[[3, 50]] * 1.01
    batches = [np.array([0, 1, 2]), "all", points, np.array([641, 5])]
    answers = list(client.correspond(*pair["ids"], batches, return_distance=True))
    assert [a["batch_id"] for a in answers] == [0, 1, 2, 3]
    expected = [
        reference.match(*pair["prepared"], np.array([0, 1, 2])),
        reference.match(*pair["prepared"]),
        reference.match(*pair["prepared"], query_points=points),
        reference.match(*pair["prepared"], np.array([641, 5])),
    ]
    for answer, want in zip(answers, expected, strict=True):
        assert answer["model"] == MODEL and answer["n_queries"] == len(want.indices)
        assert answer["refinement"] == "none"
        assert (answer["source_shape_id"], answer["target_shape_id"]) == tuple(pair["ids"])
        for role, prepared in zip(("source_frame", "target_frame"), pair["prepared"], strict=True):
            assert answer[role] == {"frame": prepared.frame, "check": prepared.frame_check}
        np.testing.assert_array_equal(answer["matches"], want.indices)
        unit_area = answer["distances_unit_area"]
        np.testing.assert_allclose(unit_area, want.distance, atol=1e-5, rtol=0)
        in_target_units = want.distance / pair["prepared"][1].transform.scale
        np.testing.assert_allclose(answer["distances"], in_target_units, rtol=1e-5, atol=1e-6)


def test_distances_only_when_asked(client, pair, stub, pb2):
    (answer,) = client.correspond(*pair["ids"], [[4, 5]])
    assert answer["distances"] is None and answer["matches"].shape == (2,)
    src, tgt = pair["ids"]
    request = _request(pb2, 9, [4, 5], source_shape_id=src, target_shape_id=tgt)
    raw = list(stub.Correspond(iter([request]), timeout=30))
    assert len(raw) == 1 and raw[0].batch_id == 9 and len(raw[0].distances) == 0
    assert len(raw[0].distances_unit_area) == 0


def test_later_messages_inherit_or_replace_the_pair(stub, pb2, pair, reference):
    src, tgt = pair["ids"]
    requests = [
        _request(pb2, 10, [0, 1], source_shape_id=src, target_shape_id=tgt, model=MODEL),
        _request(pb2, 11, [2]),  # inherits the pair
        _request(pb2, 12, [0, 1], source_shape_id=tgt, target_shape_id=src),  # reversed
    ]
    answers = list(stub.Correspond(iter(requests), timeout=30))
    assert [a.batch_id for a in answers] == [10, 11, 12]
    forward, backward = pair["prepared"], pair["prepared"][::-1]
    assert list(answers[1].matches) == list(reference.match(*forward, np.array([2])).indices)
    assert answers[2].source_shape_id == tgt
    assert list(answers[2].matches) == list(reference.match(*backward, np.array([0, 1])).indices)


def test_shapes_are_prepared_once_across_streams(service, client, test_shape):
    ids = [
        client.register_arrays(s.vertices, s.faces)["shape_id"]
        for s in (test_shape(11), test_shape(12))
    ]
    before = counter(service, "litege_matching_prepared_total", model=MODEL)
    list(client.correspond(*ids, [[0], [1], "all"]))
    assert counter(service, "litege_matching_prepared_total", model=MODEL) == before + 2
    list(client.correspond(ids[1], ids[0], [[0], [1]]))
    assert counter(service, "litege_matching_prepared_total", model=MODEL) == before + 2


# --------------------------------------------------------------------------- refinement


@pytest.fixture(scope="module")
def small_pair(client, blob, reference) -> dict[str, Any]:
    """Two small meshes (162 vertices: ZoomOut in about a second), their library preparations
    and a registered point cloud."""
    shapes = (blob(21, subdivisions=2), blob(22, subdivisions=2))
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in shapes]
    cloud = client.register_arrays(blob(23, subdivisions=2).vertices, kind="point_cloud")
    return {
        "ids": ids,
        "shapes": shapes,
        "prepared": [reference.prepare(s, seed=0) for s in shapes],
        "cloud": cloud["shape_id"],
    }


@NEEDS_PYFM
def test_refine_zoomout_on_two_meshes(client, small_pair, reference):
    answers = list(
        client.correspond(
            *small_pair["ids"], ["all", [0, 7, 100]], refine="zoomout", return_distance=True
        )
    )
    assert [a["refinement"] for a in answers] == ["zoomout", "zoomout"]
    expected = reference.match(*small_pair["prepared"], refine="zoomout")
    n_target = small_pair["shapes"][1].n_points
    full, some = answers
    assert full["n_queries"] == small_pair["shapes"][0].n_points
    assert full["matches"].min() >= 0 and full["matches"].max() < n_target
    assert np.isfinite(full["distances"]).all()
    np.testing.assert_array_equal(full["matches"], expected.indices)
    np.testing.assert_array_equal(some["matches"], expected.indices[[0, 7, 100]])


@NEEDS_PYFM
def test_refine_is_inherited_and_replaced_like_the_model(stub, pb2, small_pair, reference):
    src, tgt = small_pair["ids"]
    requests = [
        _request(pb2, 0, [0, 1], source_shape_id=src, target_shape_id=tgt, refine="zoomout"),
        _request(pb2, 1, [2]),  # inherits refine
        _request(pb2, 2, [0, 1], refine="none"),
        _request(pb2, 3, [0, 1], refine=""),  # empty: the default, "none"
    ]
    answers = list(stub.Correspond(iter(requests), timeout=60))
    assert [a.refinement for a in answers] == ["zoomout", "zoomout", "none", "none"]
    refined = reference.match(*small_pair["prepared"], refine="zoomout").indices
    plain = reference.match(*small_pair["prepared"], np.array([0, 1])).indices
    assert list(answers[0].matches) == list(refined[[0, 1]])
    assert list(answers[1].matches) == [refined[2]]
    assert list(answers[2].matches) == list(plain) == list(answers[3].matches)


@pytest.mark.parametrize("cloud_is", ["source", "target"])
def test_refine_with_a_point_cloud_is_invalid_argument(client, small_pair, reference, cloud_is):
    mesh, cloud = small_pair["ids"][0], small_pair["cloud"]
    src, tgt = (cloud, mesh) if cloud_is == "source" else (mesh, cloud)
    error = _raises(lambda: list(client.correspond(src, tgt, [[0, 1]], refine="zoomout")))
    assert error.code == SC.INVALID_ARGUMENT and error.batch_id == 0
    assert error.problem_type == PROBLEM_BASE_URI + "method-not-applicable"
    assert "point cloud" in error.message and cloud_is in error.message
    (answer,) = client.correspond(src, tgt, [[0, 1]])  # unrefined: fine
    assert answer["refinement"] == "none"


def test_refine_without_pyfm_is_unimplemented(client, blob, monkeypatch):
    """pyFM not importable on the server: UNIMPLEMENTED missing-dependency, never INTERNAL.
    Fresh shapes: a pair refined before keeps its map (smoothed matches need no pyFM)."""
    monkeypatch.setitem(sys.modules, "pyFM", None)  # `import pyFM` now raises ImportError
    shapes = (blob(43, subdivisions=2), blob(44, subdivisions=2))
    ids = [client.register_arrays(s.vertices, s.faces)["shape_id"] for s in shapes]
    error = _raises(lambda: list(client.correspond(*ids, [[0]], refine="zoomout")))
    assert error.code == SC.UNIMPLEMENTED and error.batch_id == 0
    assert error.problem_type == PROBLEM_BASE_URI + "missing-dependency"
    assert "pyFM" in error.message
    assert len(list(client.correspond(*ids, [[0]]))) == 1  # unrefined still works


# --------------------------------------------------------------------------- errors


def test_error_in_batch_k_after_good_batches(service, client, pair, reference):
    answers: list[dict[str, Any]] = []
    before = computed(service)

    def consume() -> None:
        for answer in client.correspond(*pair["ids"], [[0], [1], [10**6], [2]]):
            answers.append(answer)

    error = _raises(consume)
    assert [a["batch_id"] for a in answers] == [0, 1]
    assert error.code == SC.INVALID_ARGUMENT
    assert error.problem_type == PROBLEM_BASE_URI + "index-out-of-range"
    assert error.batch_id == 2 and "1000000" in error.message
    assert computed(service) == before + 2, "nothing after the failed batch is computed"
    _assert_serving(client, pair, reference)


UNKNOWN = "0" * 64

DROP = object()
BAD_STREAMS: dict[str, tuple[SC, str, dict[str, Any]]] = {
    # case: (code, problem, fields replacing those of a good first message)
    "unknown source id": (SC.NOT_FOUND, "shape-not-found", {"source_shape_id": UNKNOWN}),
    "unknown target id": (SC.NOT_FOUND, "shape-not-found", {"target_shape_id": UNKNOWN}),
    "no pair in the first message": (
        SC.INVALID_ARGUMENT,
        "invalid-request",
        {"target_shape_id": DROP},
    ),
    "no queries": (SC.INVALID_ARGUMENT, "invalid-request", {"query_indices": DROP}),
    "all_queries false": (
        SC.INVALID_ARGUMENT,
        "invalid-request",
        {"query_indices": DROP, "all_queries": False},
    ),
    "empty query list": (SC.INVALID_ARGUMENT, "bad-array-shape", {"query_indices": []}),
    "negative index": (SC.INVALID_ARGUMENT, "index-out-of-range", {"query_indices": [-3]}),
    "NaN point": (
        SC.INVALID_ARGUMENT,
        "non-finite-coordinates",
        {"query_indices": DROP, "query_points": [np.nan, 0.0, 0.0]},
    ),
    "points not triples": (
        SC.INVALID_ARGUMENT,
        "bad-array-shape",
        {"query_indices": DROP, "query_points": [1.0, 2.0]},
    ),
    "unknown model": (SC.INVALID_ARGUMENT, "unknown-model", {"model": "giraffes"}),
    "unknown refine": (SC.INVALID_ARGUMENT, "invalid-request", {"refine": "zoom-out"}),
    "refine in capitals": (SC.INVALID_ARGUMENT, "invalid-request", {"refine": "ZoomOut"}),
}


def _bad_request(pb2: Any, source: str, target: str, fields: dict[str, Any]) -> Any:
    values = {"source_shape_id": source, "target_shape_id": target, "query_indices": [0]}
    values = {k: v for k, v in (values | fields).items() if v is not DROP}
    if "query_indices" in values:
        values["query_indices"] = pb2.Indices(values=values["query_indices"])
    if "query_points" in values:
        values["query_points"] = pb2.Points(xyz=values["query_points"])
    return pb2.CorrespondRequest(**values)


@pytest.mark.parametrize("case", list(BAD_STREAMS))
def test_bad_inputs_end_the_stream_with_their_code(client, stub, pb2, pair, reference, case):
    code, problem, fields = BAD_STREAMS[case]
    request = _bad_request(pb2, *pair["ids"], fields)
    error = _raises(lambda: list(stub.Correspond(iter([request]), timeout=30)))
    assert error.code == code, error
    assert error.problem_type == PROBLEM_BASE_URI + problem
    assert error.message and error.batch_id == 0
    _assert_serving(client, pair, reference)


def test_too_many_queries_in_a_batch(slow, test_shape):
    with GrpcClient(slow.grpc_target) as client:
        ids = _register_pair(client, test_shape)
        answers: list[dict[str, Any]] = []

        def consume() -> None:
            answers.extend(client.correspond(*ids, [np.arange(100), "all"]))  # 642 points

        error = _raises(consume)
        assert error.code == SC.INVALID_ARGUMENT and error.batch_id == 1
        assert error.problem_type == PROBLEM_BASE_URI + "too-many-queries"
        assert [a["n_queries"] for a in answers] == [100]


# --------------------------------------------------------------------------- flow, deadlines


def _wait_stable(read: Callable[[], float], settle_s: float = 0.6, limit_s: float = 10) -> float:
    """``read()`` once it stopped changing for ``settle_s``."""
    deadline = time.monotonic() + limit_s
    value = read()
    while time.monotonic() < deadline:
        time.sleep(settle_s)
        again = read()
        if again == value:
            return value
        value = again
    raise AssertionError("the counter kept changing")


def _until(condition: Callable[[], bool], limit_s: float = 10) -> None:
    deadline = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("the condition did not hold in time")
        time.sleep(0.002)


def _stream_codes(service) -> dict[str, float]:
    return {
        code: counter(
            service,
            "litege_grpc_request_duration_seconds_count",
            method="Correspond",
            code=code,
        )
        for code in ("OK", "CANCELLED")
    }


def test_cancellation_stops_the_stream(slow, test_shape):
    """Cancelled while batch 2 computes (the slow batcher holds it ≥ SLOW_WAIT_MS): the
    server stops, computes nothing further and counts the stream CANCELLED."""
    n_batches = 40  # ≥ 6 s of work at SLOW_WAIT_MS per batch
    with GrpcClient(slow.grpc_target, timeout_s=60) as client:
        ids = _register_pair(client, test_shape)
        before, codes_before = computed(slow), _stream_codes(slow)
        answers = client.correspond(*ids, ([i] for i in range(n_batches)))
        received = [next(answers), next(answers)]
        _until(lambda: slow.runtime.batcher.waiting == 1)  # batch 2 submitted
        answers.close()  # cancels the call
        assert [a["batch_id"] for a in received] == [0, 1]
        done = _wait_stable(lambda: computed(slow)) - before
        assert 2 <= done <= 3, f"{done} batches computed after cancelling at 2"
        cancelled = _wait_stable(lambda: _stream_codes(slow)["CANCELLED"])
        codes = _stream_codes(slow)
        assert cancelled - codes_before["CANCELLED"] == 1, codes
        assert codes["OK"] == codes_before["OK"], codes
        (answer,) = client.correspond(*ids, [[0, 1]])  # later calls work
        assert answer["n_queries"] == 2


def test_cancellation_between_batches_ends_the_stream(slow, test_shape):
    """Cancelled while the server waits for the next batch: the stream ends, once, with no
    batch computed after it (gRPC shows the server an end of stream: OK or CANCELLED)."""
    hold = threading.Event()

    def batches() -> Iterator[list[int]]:
        yield [0]
        yield [1]
        hold.wait(30)  # the client sends nothing more until the test has cancelled
        yield [2]

    with GrpcClient(slow.grpc_target, timeout_s=60) as client:
        ids = _register_pair(client, test_shape)
        before, codes_before = computed(slow), _stream_codes(slow)
        answers = client.correspond(*ids, batches())
        received = [next(answers), next(answers)]
        assert [a["batch_id"] for a in received] == [0, 1]
        answers.close()
        hold.set()
        assert _wait_stable(lambda: computed(slow)) - before == 2
        codes = _wait_stable(lambda: sum(_stream_codes(slow).values()))
        assert codes - sum(codes_before.values()) == 1, _stream_codes(slow)
        assert slow.runtime.batcher.waiting == 0


def test_server_reads_one_batch_at_a_time(slow, test_shape):
    """Flow control: while batch 0 computes, the server has not taken batch 1 from the
    stream (its queue holds at most the stream's current batch)."""
    with GrpcClient(slow.grpc_target, timeout_s=60) as client:
        ids = _register_pair(client, test_shape)
        depths: list[int] = []

        def batches() -> Iterator[list[int]]:
            for i in range(4):
                yield [i]
                depths.append(slow.runtime.batcher.depth)

        answers = list(client.correspond(*ids, batches()))
        assert [a["batch_id"] for a in answers] == [0, 1, 2, 3]
        assert max(depths) <= 1


def test_per_batch_deadline(slow, test_shape):
    with GrpcClient(slow.grpc_target, timeout_s=60) as client:
        ids = _register_pair(client, test_shape)
        pb2, pb2_grpc = grpc_stubs.load_stubs()
        stub = pb2_grpc.LiteGEStub(client._channel)
        before = computed(slow)
        requests = [
            _request(
                pb2, 0, [0], source_shape_id=ids[0], target_shape_id=ids[1], deadline_ms=30_000
            ),
            _request(pb2, 1, [1], deadline_ms=20),  # < SLOW_WAIT_MS: cannot be met
            _request(pb2, 2, [2]),
        ]
        answers: list[Any] = []

        def consume() -> None:
            answers.extend(stub.Correspond(iter(requests), timeout=30))

        error = _raises(consume)
        assert [a.batch_id for a in answers] == [0]
        assert error.code == SC.DEADLINE_EXCEEDED and error.batch_id == 1
        assert error.problem_type == PROBLEM_BASE_URI + "deadline-exceeded"
        assert _wait_stable(lambda: computed(slow)) == before + 1, "expired batch not computed"
        answers = list(client.correspond(*ids, [[0], [1]], deadline_ms=30_000))
        assert [a["batch_id"] for a in answers] == [0, 1]


def test_call_deadline_bounds_the_stream(slow, test_shape):
    with GrpcClient(slow.grpc_target, timeout_s=60) as client:
        ids = _register_pair(client, test_shape)
        error = _raises(lambda: list(client.correspond(*ids, [[0]] * 20, timeout_s=0.5)))
        assert error.code == SC.DEADLINE_EXCEEDED
        assert len(list(client.correspond(*ids, [[0]]))) == 1


def test_api_key_is_required(live_service_factory, test_shape):
    key = "k" * 24
    served = live_service_factory(grpc=True, matching=MatchingModel.tiny_random(SEED), api_key=key)
    with GrpcClient(served.grpc_target, api_key=key) as client:
        ids = _register_pair(client, test_shape)
    with GrpcClient(served.grpc_target) as anonymous:
        error = _raises(lambda: list(anonymous.correspond(*ids, [[0]])))
    assert error.code == SC.UNAUTHENTICATED
    assert error.problem_type == PROBLEM_BASE_URI + "unauthorized"
