"""Operations over real servers: state in Redis survives an API restart, evicted state is
recomputed, a Redis outage degrades but does not stop the service, and overload answers
503/429 with Retry-After or 504 instead of queueing without bound."""

from __future__ import annotations

import asyncio
import re
import threading
import time
from dataclasses import astuple

import httpx
import numpy as np
import pytest

from service.client import LiteGEClient, ProblemError
from service.repository import record_artifact
from service.store import artifact_key, geometry_key


def metric(text: str, name: str, **labels: str) -> float:
    """The value of one sample of a Prometheus text exposition (0 when absent)."""
    for line in text.splitlines():
        if not line.startswith(name + ("{" if labels else " ")) and line.split(" ")[0] != name:
            continue
        if all(f'{k}="{v}"' in line for k, v in labels.items()):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


def record_key(service, shape_id: str) -> str:
    """Where the service keeps the shape's record (its lattice names it)."""
    predictor = service.runtime.repository.predictors["quadrupeds"]
    return artifact_key(shape_id, *astuple(record_artifact(predictor)))


def test_state_survives_an_api_restart(live_service_factory, private_redis, mesh_bytes):
    first = live_service_factory(redis_url=private_redis.url)
    with LiteGEClient(first.base_url) as client:
        shape_id = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        before = client.geodesic(shape_id, [0, 9], "all")
    first.stop()
    keys = {k.decode() for k in private_redis.client().keys("litege:*")}
    assert keys == {
        geometry_key(shape_id),
        record_key(first, shape_id),
    }
    second = live_service_factory(redis_url=private_redis.url)
    with LiteGEClient(second.base_url) as client:
        assert client.get_shape(shape_id)["created"] is False
        np.testing.assert_array_equal(client.geodesic(shape_id, [0, 9], "all"), before)
        text = client.metrics()
    assert metric(text, "litege_cache_requests_total", tier="store", result="hit") >= 1
    assert metric(text, "litege_cache_requests_total", tier="store", result="recompute") == 0
    assert metric(text, "litege_shapes_registered_total", created="true") == 0


def test_evicted_record_is_recomputed_and_lost_arrays_say_upload_again(
    live_service_factory, private_redis, mesh_bytes
):
    service = live_service_factory(redis_url=private_redis.url)
    redis_client = private_redis.client()
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(2, "ply"), file_format="ply")["shape_id"]
        before = client.geodesic(shape_id, [1], [2, 3, 4])
        record = record_key(service, shape_id)
        arrays_key = geometry_key(shape_id)

        # Redis evicts the record; the process forgets its live state (restart, LRU).
        redis_client.delete(record)
        service.runtime.repository.forget_live()
        service.runtime.store.local.clear()
        np.testing.assert_allclose(client.geodesic(shape_id, [1], [2, 3, 4]), before, rtol=1e-6)
        assert redis_client.exists(record), "the recomputed record is written back"
        assert (
            metric(
                client.metrics(), "litege_cache_requests_total", tier="store", result="recompute"
            )
            == 1
        )

        # Redis evicts the arrays themselves: the shape is gone, the client must upload again.
        redis_client.delete(arrays_key)
        service.runtime.repository.forget_live()
        service.runtime.store.local.clear()
        with pytest.raises(ProblemError) as gone:
            client.geodesic(shape_id, [1], [2])
        assert gone.value.status == 404 and "upload it again" in gone.value.problem["detail"]
        again = client.register_file(mesh_bytes(2, "ply"), file_format="ply")
        assert again["shape_id"] == shape_id and again["created"] is True


def test_redis_outage_degrades_and_recovers(live_service_factory, private_redis, mesh_bytes):
    service = live_service_factory(redis_url=private_redis.url)
    with LiteGEClient(service.base_url) as client:
        kept = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        before = client.geodesic(kept, [0], "all")
        private_redis.kill()

        started = time.monotonic()
        # served from the process's own cache; equal up to float32 rounding (a state read
        # back may or may not hold its point table, whose products round differently)
        np.testing.assert_allclose(client.geodesic(kept, [0], "all"), before, rtol=1e-6)
        during = client.register_file(mesh_bytes(3, "obj"), file_format="obj")
        assert during["created"] is True
        assert client.geodesic(during["shape_id"], [0], [1]).shape == (1, 1)
        assert client.get_shape(during["shape_id"])["shape_id"] == during["shape_id"]
        assert time.monotonic() - started < 5, "an outage must not make requests hang"
        ready = client.ready()
        assert ready["status"] == "ready" and ready["degraded"] is True
        assert metric(client.metrics(), "litege_store_degraded") == 1

        private_redis.start()
        deadline = time.monotonic() + 40
        while client.ready()["degraded"]:
            assert time.monotonic() < deadline, "did not reconnect to Redis"
            client.geodesic(kept, [0], [1])  # traffic drives the reconnect attempts
            time.sleep(0.2)
        after = client.register_file(mesh_bytes(4, "obj"), file_format="obj")["shape_id"]
        key = geometry_key(after)
        assert private_redis.client().exists(key)
        assert metric(client.metrics(), "litege_store_degraded") == 0


class BlockedWorker:
    """Occupies the service's compute thread until released (deterministic overload)."""

    def __init__(self, service) -> None:
        self.service = service
        self.release = threading.Event()
        batcher = service.runtime.batcher
        batcher.handlers["block"] = lambda jobs: [self.release.wait(30) for _ in jobs]
        self.futures = []

    def occupy(self, jobs: int) -> None:
        batcher = self.service.runtime.batcher
        for _ in range(jobs):
            self.futures.append(
                asyncio.run_coroutine_threadsafe(batcher.submit("block", None), self.service.loop)
            )
            time.sleep(0.1)

    def __enter__(self) -> BlockedWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release.set()
        for future in self.futures:
            future.result(10)


def test_full_queue_answers_503_with_retry_after(live_service_factory, mesh_bytes):
    service = live_service_factory(queue_size=1, batch_max_size=1)
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        with BlockedWorker(service) as blocked:
            blocked.occupy(2)  # one running, one filling the queue
            response = httpx.post(
                f"{service.base_url}/geodesic", json={"shape_id": shape_id, "sources": [0]}
            )
            assert response.status_code == 503
            assert response.json()["code"] == "overloaded"
            assert int(response.headers["retry-after"]) >= 1
        assert client.geodesic(shape_id, [0], [1]).shape == (1, 1)
        assert metric(client.metrics(), "litege_rejected_total", reason="queue_full") == 1


def test_concurrency_limit_answers_429(live_service_factory, mesh_bytes):
    service = live_service_factory(max_concurrency=1)
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        body = {"shape_id": shape_id, "sources": [0], "targets": [1]}
        with BlockedWorker(service) as blocked:
            blocked.occupy(1)
            waiting = threading.Thread(
                target=httpx.post, args=(f"{service.base_url}/geodesic",), kwargs={"json": body}
            )
            waiting.start()
            time.sleep(0.3)
            response = httpx.post(f"{service.base_url}/geodesic", json=body)
            assert response.status_code == 429 and response.headers["retry-after"] == "1"
            assert httpx.get(f"{service.base_url}/healthz").status_code == 200
        waiting.join(10)


def test_deadline_answers_504(live_service_factory, mesh_bytes):
    service = live_service_factory(request_timeout_s=0.5)
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        with BlockedWorker(service) as blocked:
            blocked.occupy(1)
            with pytest.raises(ProblemError) as late:
                client.geodesic(shape_id, [0], [1])
        assert late.value.status == 504 and late.value.code == "deadline-exceeded"
        assert re.search(r"\d", late.value.problem["detail"])
        assert client.geodesic(shape_id, [0], [1]).shape == (1, 1)
