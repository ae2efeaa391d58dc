"""The micro-batcher and the runtime's batch handlers: abandoned jobs are skipped, Retry-After
follows the queue, shutdown is bounded, and one job's failure (a device out of memory
included) is its own: the rest of its batch is answered normally."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from typing import Any

import grpc
import httpx
import numpy as np
import pytest
import torch

from litege_core.query import parse_query
from service import grpc_stubs
from service.batcher import CancelToken, MicroBatcher
from service.errors import DeadlineExceededError, NotReadyError, OutOfMemoryError
from service.metrics import ServiceMetrics

POISON = 13
"""The source index the fake device cannot hold in memory."""


class Gate:
    """A handler that blocks the compute thread until opened, recording what it ran."""

    def __init__(self) -> None:
        self.entered = threading.Event()
        self.opened = threading.Event()
        self.ran: list[Any] = []

    def __call__(self, payloads: list[Any]) -> list[Any]:
        self.entered.set()
        self.opened.wait(30)
        self.ran.extend(payloads)
        return payloads


def _batcher(gate: Gate, **options: Any) -> MicroBatcher:
    values = {"max_batch": 4, "max_wait_s": 0.0, "queue_size": 64} | options
    return MicroBatcher({"work": gate}, metrics=ServiceMetrics(), **values)


async def _until(condition: Any) -> None:
    while not condition():
        await asyncio.sleep(0.005)


def test_a_job_abandoned_by_its_caller_is_not_run():
    async def scenario() -> list[Any]:
        gate = Gate()
        batcher = _batcher(gate)
        batcher.start()
        running = asyncio.ensure_future(batcher.submit("work", "first"))
        await _until(gate.entered.is_set)  # the first job occupies the worker
        token = CancelToken()
        with pytest.raises(DeadlineExceededError):
            await batcher.submit("work", "abandoned", timeout_s=0.05, token=token)
        assert token.cancelled
        cancelled = CancelToken()
        cancelled.cancel()
        gone = asyncio.ensure_future(batcher.submit("work", "cancelled", token=cancelled))
        kept = asyncio.ensure_future(batcher.submit("work", "kept"))
        await _until(lambda: batcher.depth == 3)
        assert batcher.waiting == 3  # the first, the cancelled and the kept job's callers
        gate.opened.set()
        assert await running == "first" and await kept == "kept"
        with pytest.raises(DeadlineExceededError):
            await gone  # answered, not left waiting
        assert batcher.waiting == 0
        await batcher.close()
        return gate.ran

    assert asyncio.run(scenario()) == ["first", "kept"]


def test_retry_after_follows_the_queue():
    async def scenario() -> tuple[float, float]:
        gate = Gate()
        batcher = _batcher(gate, max_batch=4)
        batcher._batch_seconds = 2.0  # measured mean batch time (as after slow batches)
        batcher.start()
        first = asyncio.ensure_future(batcher.submit("work", 0))
        await _until(gate.entered.is_set)
        idle = batcher.retry_after_s()
        queued = [asyncio.ensure_future(batcher.submit("work", i)) for i in range(1, 17)]
        await _until(lambda: batcher.depth == 16)
        busy = batcher.retry_after_s()
        gate.opened.set()
        await asyncio.gather(first, *queued)
        await batcher.close()
        return idle, busy

    idle, busy = asyncio.run(scenario())
    assert idle == 2.0  # the running batch
    assert busy == 10.0  # 16 queued jobs = 4 batches of 4, plus the running one
    assert float(int(busy)) == busy  # whole seconds, as Retry-After carries them


def test_close_drops_what_is_still_queued_after_its_timeout():
    async def scenario() -> list[Any]:
        gate = Gate()
        batcher = _batcher(gate, max_batch=1)
        batcher.start()
        running = asyncio.ensure_future(batcher.submit("work", "running"))
        await _until(gate.entered.is_set)
        queued = [asyncio.ensure_future(batcher.submit("work", i)) for i in range(3)]
        await _until(lambda: batcher.depth == 3)
        closing = asyncio.ensure_future(batcher.close(timeout_s=0.05))
        await _until(lambda: all(f.done() for f in queued))
        gate.opened.set()
        await closing
        assert await running == "running"
        return [f.exception() for f in queued]

    errors = asyncio.run(scenario())
    assert all(isinstance(e, NotReadyError) for e in errors)


# --------------------------------------------------------------------------- out of memory


def _poisoned(query: Any) -> bool:
    indices = parse_query(query).indices
    return indices is not None and POISON in indices.tolist()


@pytest.fixture(scope="module")
def service(live_service_factory):
    return live_service_factory(grpc=True)


@pytest.fixture(scope="module")
def shape_id(service, test_shape) -> str:
    shape = test_shape(1)
    response = httpx.post(
        f"{service.base_url}/shapes",
        json={"vertices": shape.vertices.tolist(), "faces": shape.faces.tolist()},
    )
    assert response.status_code in (200, 201), response.text
    return response.json()["shape_id"]


@pytest.fixture
def oom_device(service) -> Iterator[list[int]]:
    """The service's predictor on a fake device that runs out of memory for any query
    holding :data:`POISON` (CUDA's error in batches, a bare ``RuntimeError`` alone); yields
    the sizes of the batched calls."""
    predictor = service.runtime.repository.predictors["quadrupeds"]
    real_many, real_one = predictor.distances_many, predictor.distances
    batches: list[int] = []

    def many(states: Any, sources: Any, targets: Any = None) -> Any:
        batches.append(len(states))
        if any(_poisoned(s) for s in sources):
            raise torch.cuda.OutOfMemoryError("CUDA out of memory. Tried to allocate 8.00 GiB")
        return real_many(states, sources, targets)

    def one(state: Any, sources: Any, targets: Any = None) -> Any:
        if _poisoned(sources):
            raise RuntimeError("CUDA error: out of memory")
        return real_one(state, sources, targets)

    predictor.distances_many, predictor.distances = many, one
    try:
        yield batches
    finally:
        del predictor.distances_many, predictor.distances


def test_out_of_memory_fails_only_its_own_job_in_a_batch(service, shape_id, oom_device):
    runtime = service.runtime
    gate = Gate()
    runtime.batcher.handlers["block"] = gate

    async def scenario() -> list[Any]:
        blocker = asyncio.ensure_future(runtime.batcher.submit("block", None))
        await _until(gate.entered.is_set)
        requests = [
            asyncio.ensure_future(runtime.geodesic(shape_id, sources, [1, 2, 3]))
            for sources in ([0], [POISON, 1], [5])
        ]
        await _until(lambda: runtime.batcher.depth == 3)  # queued together: one batch
        gate.opened.set()
        await blocker
        return await asyncio.gather(*requests, return_exceptions=True)

    try:
        first, poisoned, third = service.call(scenario())
    finally:
        del runtime.batcher.handlers["block"]
    assert oom_device[0] == 3, "the three requests were one batched call"
    assert isinstance(poisoned, OutOfMemoryError) and poisoned.retry_after_s >= 1
    predictor = runtime.repository.predictors["quadrupeds"]
    state = runtime.repository.get(shape_id).state
    np.testing.assert_array_equal(first[1], predictor.distances(state, [0], [1, 2, 3]))
    np.testing.assert_array_equal(third[1], predictor.distances(state, [5], [1, 2, 3]))


def test_out_of_memory_is_503_and_resource_exhausted(
    service, shape_id, oom_device, caplog: pytest.LogCaptureFixture
):
    body = {"shape_id": shape_id, "sources": [POISON], "targets": [1]}
    response = httpx.post(f"{service.base_url}/geodesic", json=body)
    assert response.status_code == 503, response.text
    assert response.json()["code"] == "out-of-memory"
    assert int(response.headers["retry-after"]) >= 1
    assert not [r for r in caplog.records if r.exc_info and r.name.startswith("litege")]
    pb2, pb2_grpc = grpc_stubs.load_stubs()
    with grpc.insecure_channel(service.grpc_target) as channel:
        stub = pb2_grpc.LiteGEStub(channel)
        request = pb2.GeodesicRequest(
            shape_id=shape_id,
            source_indices=pb2.Indices(values=[POISON]),
            target_indices=pb2.Indices(values=[1]),
        )
        with pytest.raises(grpc.RpcError) as caught:
            stub.Geodesic(request, timeout=30)
        assert caught.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        trailing = dict(caught.value.trailing_metadata())
        assert trailing["litege-problem-type"].endswith("/out-of-memory")
        assert int(trailing["retry-after-ms"]) >= 1000
        ok = stub.Geodesic(
            pb2.GeodesicRequest(shape_id=shape_id, source_indices=pb2.Indices(values=[0])),
            timeout=30,
        )
        assert ok.rows == 1
