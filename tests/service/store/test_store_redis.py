"""RedisStore against real Redis servers: the shared one, and private ones for outages.

Outage tests kill (SIGKILL), freeze (SIGSTOP) and restart a private ``redis-server``; the
store must keep answering misses/``False`` without raising, pay at most one socket timeout,
then answer without I/O until its backoff deadline, and reconnect after it.
"""

from __future__ import annotations

import logging
import threading
import time

import pytest
import redis

from service.store import ArtifactStore, RedisStore
from service.store.redis_store import redact_url

SOCKET_TIMEOUT_S = 0.3
IMMEDIATE_S = 0.05  # "no network": far below any timeout


@pytest.fixture
def store(shared_redis_url: str):
    store = RedisStore(shared_redis_url, default_ttl_s=60.0, socket_timeout_s=SOCKET_TIMEOUT_S)
    yield store
    store.close()


def _timed(fn, *args):
    start = time.perf_counter()
    result = fn(*args)
    return result, time.perf_counter() - start


# -- the shared Redis ---------------------------------------------------------------------------


def test_is_an_artifact_store(store: RedisStore) -> None:
    assert isinstance(store, ArtifactStore)


def test_round_trip_get_many_and_delete(store: RedisStore, key_prefix: str) -> None:
    a, b, missing = (f"{key_prefix}{name}" for name in ("a", "b", "missing"))
    assert store.get(a) is None
    assert store.put_many({a: b"\x00\x01binary", b: b"", f"{key_prefix}c": bytearray(b"c")})
    assert store.get(a) == b"\x00\x01binary"
    assert store.get(b) == b""
    assert store.get_many([b, missing, a, a]) == [b"", None, b"\x00\x01binary", b"\x00\x01binary"]
    assert store.get_many([]) == []
    assert store.put_many({}) is True
    assert store.delete([a, missing, a]) == 1
    assert store.delete([]) == 0
    assert store.get(a) is None
    stats = store.stats()
    assert stats["hits"] == 5 and stats["misses"] == 3 and stats["writes"] == 3
    assert stats["errors"] == 0 and stats["available"] == 1.0


def test_writes_set_the_ttl_and_reads_slide_it(
    store: RedisStore, key_prefix: str, raw_redis: redis.Redis
) -> None:
    key, other = f"{key_prefix}k", f"{key_prefix}other"
    store.put_many({key: b"v", other: b"w"})
    assert 55_000 < raw_redis.pttl(key) <= 60_000
    store.put_many({f"{key_prefix}short": b"v"}, ttl_s=0.25)
    assert 0 < raw_redis.pttl(f"{key_prefix}short") <= 250
    raw_redis.pexpire(key, 5_000)
    raw_redis.pexpire(other, 5_000)
    assert store.get(key) == b"v"
    assert raw_redis.pttl(key) > 55_000  # GETEX slid it back to the full TTL
    raw_redis.pexpire(key, 5_000)
    assert store.get_many([key, other]) == [b"v", b"w"]
    assert raw_redis.pttl(key) > 55_000 and raw_redis.pttl(other) > 55_000


def test_without_ttl_keys_do_not_expire(shared_redis_url: str, key_prefix: str, raw_redis) -> None:
    store = RedisStore(shared_redis_url, default_ttl_s=None)
    try:
        store.put_many({f"{key_prefix}a": b"1", f"{key_prefix}b": b"2"})
        assert raw_redis.pttl(f"{key_prefix}a") == -1
        assert store.get(f"{key_prefix}a") == b"1"
        assert store.get_many([f"{key_prefix}b", f"{key_prefix}x"]) == [b"2", None]  # MGET
        assert raw_redis.pttl(f"{key_prefix}a") == -1
    finally:
        store.close()


def test_entries_expire_after_their_ttl(shared_redis_url: str, key_prefix: str) -> None:
    store = RedisStore(shared_redis_url, default_ttl_s=1.0)
    key, read = f"{key_prefix}expiring", f"{key_prefix}read"
    try:
        assert store.put_many({key: b"v", read: b"r"})
        time.sleep(0.6)
        assert store.get(read) == b"r"  # slides its TTL to 1 s from now
        time.sleep(0.6)
        assert store.get(key) is None
        assert store.get_many([key, read]) == [None, b"r"]
    finally:
        store.close()


def test_a_read_slides_a_per_call_ttl_to_the_default(
    store: RedisStore, key_prefix: str, raw_redis: redis.Redis
) -> None:
    key = f"{key_prefix}k"
    store.put_many({key: b"v"}, ttl_s=2.0)
    assert 0 < raw_redis.pttl(key) <= 2_000
    store.get(key)
    assert raw_redis.pttl(key) > 55_000  # documented: reads slide to default_ttl_s


def test_memory_usage(store: RedisStore, key_prefix: str) -> None:
    store.put_many({f"{key_prefix}big": b"x" * 10_000})
    usage = store.memory_usage(f"{key_prefix}big")
    assert usage is not None and usage >= 10_000
    assert store.memory_usage(f"{key_prefix}absent") is None


def test_wrong_type_keys_are_misses_and_counted_errors(
    store: RedisStore, key_prefix: str, raw_redis: redis.Redis, caplog
) -> None:
    listed, good = f"{key_prefix}list", f"{key_prefix}good"
    raw_redis.rpush(listed, b"x")
    store.put_many({good: b"g"})
    with caplog.at_level(logging.DEBUG, logger="litege.store"):
        assert store.get(listed) is None
        assert store.get_many([good, listed, good]) == [b"g", None, b"g"]
    assert "WRONGTYPE" in caplog.text
    stats = store.stats()
    assert stats["errors"] == 2 and stats["connection_errors"] == 0
    assert store.health().available  # a refused command is not an outage


def test_health_when_connected(store: RedisStore, shared_redis_url: str) -> None:
    health = store.health()
    assert (health.backend, health.available, health.degraded) == ("redis", True, False)
    assert health.detail.startswith("connected to redis://")


def test_urls_are_reported_without_passwords() -> None:
    assert redact_url("redis://:s3cret@host:6380/2") == "redis://:***@host:6380/2"
    assert redact_url("rediss://user:s3cret@host/0") == "rediss://user:***@host/0"
    assert redact_url("redis://host:6379/0") == "redis://host:6379/0"
    store = RedisStore("redis://user:s3cret@127.0.0.1:1/0", default_ttl_s=None)
    assert "s3cret" not in store.health().detail
    store.close()


def test_bad_arguments_are_rejected(shared_redis_url: str) -> None:
    with pytest.raises(ValueError, match="backoff"):
        RedisStore(shared_redis_url, default_ttl_s=None, backoff_initial_s=0)
    with pytest.raises(ValueError, match="backoff"):
        RedisStore(shared_redis_url, default_ttl_s=None, backoff_initial_s=5, backoff_max_s=1)
    with pytest.raises(ValueError, match="ttl_s"):
        RedisStore(shared_redis_url, default_ttl_s=0)


def test_concurrent_use_from_threads(store: RedisStore, key_prefix: str) -> None:
    errors: list[BaseException] = []

    def worker(t: int) -> None:
        try:
            for i in range(40):
                key = f"{key_prefix}t{t}-{i % 5}"
                assert store.put_many({key: f"{t}:{i}".encode()})
                assert store.get(key) == f"{t}:{i}".encode()
                assert store.get_many([key, f"{key_prefix}none"])[1] is None
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(t,)) for t in range(6)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors, errors[0]
    assert store.stats()["errors"] == 0


# -- private servers: refused writes and outages ------------------------------------------------


def test_put_many_is_all_or_nothing_when_redis_refuses(private_redis, caplog) -> None:
    store = RedisStore(private_redis.url, default_ttl_s=60.0)
    admin = private_redis.client()
    admin.config_set("maxmemory", 1)  # every write is now refused with OOM
    admin.config_set("maxmemory-policy", "noeviction")
    keys = [f"k{i}" for i in range(4)]
    with caplog.at_level(logging.WARNING, logger="litege.store"):
        assert store.put_many({key: b"v" * 100 for key in keys}) is False
    assert "OutOfMemoryError" in caplog.text or "OOM" in caplog.text
    assert admin.exists(*keys) == 0
    stats = store.stats()
    assert stats["write_failures"] == 4 and stats["errors"] == 1 and stats["available"] == 1.0
    admin.config_set("maxmemory", 0)
    assert store.put_many({key: b"v" for key in keys}) is True
    assert admin.exists(*keys) == 4
    admin.close()
    store.close()


def test_killed_server_degrades_then_recovers_after_backoff(private_redis, fake_clock) -> None:
    store = RedisStore(
        private_redis.url,
        default_ttl_s=60.0,
        socket_timeout_s=SOCKET_TIMEOUT_S,
        backoff_initial_s=0.5,
        backoff_max_s=4.0,
        clock=fake_clock,
    )
    assert store.put_many({"a": b"1"}) and store.get("a") == b"1"

    private_redis.kill()
    value, elapsed = _timed(store.get, "a")  # connection refused: fails fast
    assert value is None and elapsed < SOCKET_TIMEOUT_S + 0.2
    assert store.stats()["connection_errors"] == 1
    for call in (
        lambda: store.get("a"),
        lambda: store.get_many(["a", "b"]),
        lambda: store.put_many({"b": b"2"}),
        lambda: store.delete(["a"]),
        lambda: store.memory_usage("a"),
    ):
        result, elapsed = _timed(call)
        assert result in (None, [None, None], False, 0)
        assert elapsed < IMMEDIATE_S
    stats = store.stats()
    assert stats["connection_errors"] == 1 and stats["skipped"] == 5
    assert stats["available"] == 0.0 and stats["backoff_s"] == 0.5
    health = store.health()
    assert (health.backend, health.available, health.degraded) == ("redis", False, True)
    assert "unreachable since" in health.detail and "next retry in 0.5 s" in health.detail

    private_redis.start()  # back on the same port, but the store waits for its deadline
    assert store.get("a") is None
    assert store.stats()["connection_errors"] == 1  # it did not even try

    fake_clock.advance(0.5)
    assert store.put_many({"b": b"2"}) is True  # the probe succeeds: reconnected
    assert store.get("b") == b"2"
    assert store.get("a") is None  # the restarted server lost its data, as it should
    stats = store.stats()
    assert stats["available"] == 1.0 and stats["reconnects"] == 1 and stats["backoff_s"] == 0
    assert store.health().available
    store.close()


def test_backoff_doubles_up_to_the_cap_and_resets_on_success(private_redis, fake_clock) -> None:
    store = RedisStore(
        private_redis.url,
        default_ttl_s=None,
        socket_timeout_s=SOCKET_TIMEOUT_S,
        backoff_initial_s=0.5,
        backoff_max_s=3.0,
        clock=fake_clock,
    )
    private_redis.kill()
    backoffs = []
    for _ in range(5):
        assert store.get("k") is None
        backoffs.append(store.stats()["backoff_s"])
        fake_clock.advance(backoffs[-1] - 0.01)
        assert store.get("k") is None  # still inside the window: skipped
        fake_clock.advance(0.01)
    assert backoffs == [0.5, 1.0, 2.0, 3.0, 3.0]
    assert store.stats()["connection_errors"] == 5

    private_redis.start()
    assert store.health().available  # health probes too once the deadline has passed
    private_redis.kill()
    assert store.get("k") is None
    assert store.stats()["backoff_s"] == 0.5  # a new outage starts from the initial backoff
    store.close()


def test_hung_server_costs_one_socket_timeout_then_nothing(private_redis, fake_clock) -> None:
    store = RedisStore(
        private_redis.url,
        default_ttl_s=60.0,
        socket_timeout_s=SOCKET_TIMEOUT_S,
        backoff_initial_s=1.0,
        clock=fake_clock,
    )
    assert store.put_many({"a": b"1"})
    private_redis.freeze()
    try:
        value, elapsed = _timed(store.get, "a")
        assert value is None
        assert SOCKET_TIMEOUT_S * 0.8 < elapsed < SOCKET_TIMEOUT_S + 0.5
        for _ in range(20):
            (value, ok), elapsed = _timed(lambda: (store.get("a"), store.put_many({"b": b"2"})))
            assert value is None and ok is False and elapsed < IMMEDIATE_S
        health, elapsed = _timed(store.health)
        assert not health.available and health.degraded and elapsed < IMMEDIATE_S
        assert "Timeout" in health.detail
    finally:
        private_redis.thaw()
    fake_clock.advance(1.0)
    assert store.get("a") == b"1"
    store.close()


def test_concurrent_failures_of_one_outage_count_as_one(private_redis, fake_clock) -> None:
    store = RedisStore(
        private_redis.url, default_ttl_s=None, backoff_initial_s=0.5, clock=fake_clock
    )
    assert store.get("warm") is None  # open a connection first
    private_redis.kill()
    barrier = threading.Barrier(8)
    results: list[object] = []

    def worker() -> None:
        barrier.wait()
        results.extend([store.get("k"), store.put_many({"k": b"v"})])

    threads = [threading.Thread(target=worker) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sorted(results, key=repr) == [False] * 8 + [None] * 8
    stats = store.stats()
    assert 1 <= stats["connection_errors"] <= 16
    assert stats["backoff_s"] == 0.5  # racing failures did not double the backoff
    store.close()


def test_redis_down_at_start_up_is_a_degraded_store(private_redis) -> None:
    url = private_redis.url
    private_redis.kill()
    store = RedisStore(url, default_ttl_s=1.0, backoff_initial_s=0.2, backoff_max_s=0.2)
    assert store.get("a") is None
    health = store.health()  # within the backoff: reported without I/O
    assert not health.available and health.degraded and "Connection refused" in health.detail
    private_redis.start()
    time.sleep(0.25)  # real clock this time
    assert store.put_many({"a": b"1"}) is True
    assert store.get("a") == b"1" and store.health().available
    store.close()
