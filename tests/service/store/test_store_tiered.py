"""TieredStore (local LRU over Redis) and make_store, against real Redis servers."""

from __future__ import annotations

import pytest
import redis

from service.store import (
    ArtifactStore,
    InMemoryStore,
    RedisStore,
    TieredStore,
    make_store,
)


@pytest.fixture
def tiered(shared_redis_url: str):
    store = TieredStore(
        InMemoryStore(1000, default_ttl_s=60.0), RedisStore(shared_redis_url, default_ttl_s=60.0)
    )
    yield store
    store.close()


def test_is_an_artifact_store(tiered: TieredStore) -> None:
    assert isinstance(tiered, ArtifactStore)


def test_writes_go_to_both_tiers(tiered: TieredStore, key_prefix: str, raw_redis) -> None:
    key = f"{key_prefix}a"
    assert tiered.put_many({key: b"1"}) is True
    assert tiered.local.get(key) == b"1"
    assert raw_redis.get(key) == b"1"


def test_a_remote_hit_fills_the_local_tier(
    tiered: TieredStore, key_prefix: str, raw_redis: redis.Redis
) -> None:
    key = f"{key_prefix}a"
    raw_redis.set(key, b"remote")  # e.g. written by another replica
    assert tiered.local.get(key) is None
    assert tiered.get(key) == b"remote"
    assert tiered.local.get(key) == b"remote"
    raw_redis.delete(key)
    assert tiered.get(key) == b"remote"  # now served by the local tier


def test_get_many_mixes_local_remote_and_misses(
    tiered: TieredStore, key_prefix: str, raw_redis: redis.Redis
) -> None:
    local, remote, none = (f"{key_prefix}{n}" for n in ("local", "remote", "none"))
    tiered.local.put_many({local: b"L"})
    raw_redis.set(remote, b"R")
    assert tiered.get_many([remote, none, local, remote]) == [b"R", None, b"L", b"R"]
    assert tiered.local.get(remote) == b"R"
    stats = tiered.stats()
    assert stats["hits"] == 3 and stats["misses"] == 1
    assert stats["remote_misses"] == 1  # only the keys the local tier missed went remote
    assert tiered.get_many([]) == []


def test_delete_removes_from_both(tiered: TieredStore, key_prefix: str, raw_redis) -> None:
    a, b = f"{key_prefix}a", f"{key_prefix}b"
    tiered.put_many({a: b"1", b: b"2"})
    assert tiered.delete([a, b, f"{key_prefix}c"]) == 2
    assert tiered.get_many([a, b]) == [None, None]
    assert raw_redis.exists(a, b) == 0


def test_a_value_too_large_for_the_local_tier_still_goes_remote(
    tiered: TieredStore, key_prefix: str
) -> None:
    key = f"{key_prefix}big"
    assert tiered.put_many({key: b"x" * 5000}) is True
    assert tiered.local.get(key) is None
    assert tiered.get(key) == b"x" * 5000


def test_health_and_stats_when_connected(tiered: TieredStore, key_prefix: str) -> None:
    health = tiered.health()
    assert health.backend == "tiered(memory+redis)"
    assert health.available and not health.degraded and "connected" in health.detail
    tiered.put_many({f"{key_prefix}a": b"123"})
    stats = tiered.stats()
    assert stats["local_bytes"] == 3 and stats["local_items"] == 1
    assert stats["remote_writes"] == 1 and stats["writes"] == 1
    assert {"local_evictions", "remote_connection_errors", "remote_available"} <= set(stats)


def test_remote_outage_degrades_but_keeps_serving_the_local_tier(private_redis, fake_clock) -> None:
    remote = RedisStore(
        private_redis.url, default_ttl_s=60.0, backoff_initial_s=1.0, clock=fake_clock
    )
    store = TieredStore(InMemoryStore(1000, clock=fake_clock), remote, flush_interval_s=None)
    assert store.put_many({"hot": b"h"}) is True
    private_redis.kill()

    assert store.get("hot") == b"h"
    assert store.put_many({"new": b"n"}) is False  # not shared ...
    assert store.get("new") == b"n"  # ... but cached locally
    assert store.get_many(["hot", "cold"]) == [b"h", None]
    assert store.delete(["hot"]) == 1
    health = store.health()
    assert health.available and health.degraded and "unreachable" in health.detail
    stats = store.stats()
    assert stats["remote_available"] == 0.0 and stats["write_failures"] == 1
    assert stats["pending_writes"] == 2  # "new", and the delete of "hot"

    private_redis.start()
    fake_clock.advance(1.0)
    assert store.put_many({"again": b"a"}) is True
    assert not store.health().degraded
    store.close()


def test_make_store_without_redis_is_one_memory_store() -> None:
    for url in (None, ""):
        store = make_store(url, memory_bytes=1234, hot_bytes=10, ttl_s=5.0, write_behind_bytes=9)
        assert isinstance(store, InMemoryStore) and set(store.usage()) == {"memory"}
        assert store.max_bytes == 1234 and store.default_ttl_s == 5.0
        assert store.health().backend == "memory"


def test_make_store_with_redis_is_tiered(shared_redis_url: str, key_prefix: str) -> None:
    store = make_store(
        shared_redis_url, memory_bytes=1234, hot_bytes=100, ttl_s=30.0, write_behind_bytes=50
    )
    assert isinstance(store, TieredStore)
    assert store.local.max_bytes == 100 and store.local.default_ttl_s == 30.0
    usage = store.usage()
    assert set(usage) == {"hot", "write_behind"}
    assert usage["hot"].max_bytes == 100 and usage["write_behind"].max_bytes == 50
    assert isinstance(store.remote, RedisStore) and store.remote.default_ttl_s == 30.0
    assert store.put_many({f"{key_prefix}k": b"v"})
    assert store.get(f"{key_prefix}k") == b"v"
    assert store.health().backend == "tiered(memory+redis)"
    store.close()


def test_make_store_does_not_connect(private_redis) -> None:
    url = private_redis.url
    private_redis.kill()
    store = make_store(url, memory_bytes=10, hot_bytes=10, ttl_s=None, write_behind_bytes=10)
    assert store.get("k") is None
    assert store.health().degraded
    store.close()
