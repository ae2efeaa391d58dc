"""A Redis outage over real servers (a private redis-server that is killed and restarted
empty, never the shared one): what the API accepted meanwhile reaches Redis once it is back,
what it held before is refilled from the API's hot tier, and a restarted API finds it all."""

from __future__ import annotations

import time
from dataclasses import astuple

import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from service.client import LiteGEClient, ProblemError
from service.repository import record_artifact
from service.store import artifact_key, geometry_key


def sample(text: str, name: str, **labels: str) -> float:
    """One sample of a Prometheus exposition (0 when absent)."""
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if s.name == name and all(s.labels.get(k) == v for k, v in labels.items()):
                return s.value
    return 0.0


def wait_for(condition, timeout_s: float = 40.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.1)


def test_registrations_during_an_outage_survive_it_and_an_api_restart(
    live_service_factory, private_redis, mesh_bytes
):
    service = live_service_factory(redis_url=private_redis.url)
    record = record_artifact(service.runtime.repository.predictors["quadrupeds"])
    with LiteGEClient(service.base_url) as client:
        before = client.register_file(mesh_bytes(1, "obj"), file_format="obj")["shape_id"]
        doomed = client.register_file(mesh_bytes(2, "obj"), file_format="obj")["shape_id"]
        private_redis.kill()

        during = client.register_file(mesh_bytes(3, "obj"), file_format="obj")
        assert during["created"] is True  # 201, while nothing reaches Redis
        shape_id = during["shape_id"]
        distances = client.geodesic(shape_id, [0], [1, 2, 3])
        client.delete_shape(doomed)  # a delete Redis missed must not be undone
        text = client.metrics()
        assert sample(text, "litege_store_write_behind_total", result="queued") >= 3
        assert sample(text, "litege_cache_entries", cache="write_behind") >= 3
        assert (
            0
            < sample(text, "litege_cache_bytes", cache="write_behind")
            <= sample(text, "litege_cache_budget_bytes", cache="write_behind")
        )

        private_redis.start()  # empty: no persistence
        redis_client = private_redis.client()
        wanted = [
            geometry_key(shape_id),
            artifact_key(shape_id, *astuple(record)),
            geometry_key(before),  # not written during the outage: refilled
            artifact_key(before, *astuple(record)),
        ]
        # no traffic needed: the write-behind flusher reconnects and replays by itself
        wait_for(lambda: redis_client.exists(*wanted) == len(wanted))
        assert redis_client.exists(geometry_key(doomed)) == 0
        wait_for(lambda: not client.ready()["degraded"])

        def settled() -> bool:  # the counters move once a batch is written
            text = client.metrics()
            return (
                sample(text, "litege_store_write_behind_total", result="flushed") >= 3
                and sample(text, "litege_store_refilled_total") >= 2
                and sample(text, "litege_cache_entries", cache="write_behind") == 0
            )

        wait_for(settled)
    service.stop()

    restarted = live_service_factory(redis_url=private_redis.url)
    with LiteGEClient(restarted.base_url) as client:
        info = client.get_shape(shape_id)
        assert info["shape_id"] == shape_id and info["created"] is False
        np.testing.assert_allclose(client.geodesic(shape_id, [0], [1, 2, 3]), distances, rtol=1e-5)
        assert client.get_shape(before)["shape_id"] == before
        with pytest.raises(ProblemError) as gone:
            client.get_shape(doomed)
        assert gone.value.status == 404
        text = client.metrics()
    assert sample(text, "litege_cache_requests_total", tier="store", result="recompute") == 0
    assert sample(text, "litege_shapes_registered_total", created="true") == 0


def test_a_shape_registered_under_one_model_is_queried_under_another(
    live_service_factory, mesh_bytes
):
    service = live_service_factory(models=("quadrupeds", "humans"))
    with LiteGEClient(service.base_url) as client:
        shape_id = client.register_file(mesh_bytes(5, "obj"), file_format="obj")["shape_id"]
        info = client.get_shape(shape_id, model="humans")  # no upload under "humans"
        assert info["model"] == "humans" and info["created"] is False
        assert client.geodesic(shape_id, [0], [1], model="humans").shape == (1, 1)
        assert client.get_shape(shape_id)["model"] == "quadrupeds"


def test_a_delete_during_an_outage_is_not_undone_when_redis_returns_with_its_data(
    live_service_factory, private_redis, mesh_bytes
):
    service = live_service_factory(redis_url=private_redis.url)
    with LiteGEClient(service.base_url) as client:
        doomed = client.register_file(mesh_bytes(6, "obj"), file_format="obj")["shape_id"]
        private_redis.freeze()  # hung: Redis keeps what it holds
        try:
            client.delete_shape(doomed)
            with pytest.raises(ProblemError):
                client.get_shape(doomed)
        finally:
            private_redis.thaw()
        redis_client = private_redis.client()
        wait_for(lambda: redis_client.exists(geometry_key(doomed)) == 0)
        wait_for(lambda: not client.ready()["degraded"])
    service.stop()
    restarted = live_service_factory(redis_url=private_redis.url)
    with LiteGEClient(restarted.base_url) as client, pytest.raises(ProblemError) as gone:
        client.get_shape(doomed)
    assert gone.value.status == 404
