"""TieredStore write-behind against a private redis-server that is killed and restarted (never
the shared one): writes and deletes Redis missed are queued (bounded, counted) and replayed
when it returns, reads see the queue, and a Redis that came back empty is refilled from the
local tier, also when it restarted between two requests."""

from __future__ import annotations

import time

import pytest

from service.store import InMemoryStore, RedisStore, TieredStore


def _tiered(url: str, clock, *, write_behind_bytes: int = 10_000, **kwargs) -> TieredStore:
    remote = RedisStore(url, default_ttl_s=60.0, backoff_initial_s=1.0, clock=clock)
    return TieredStore(
        InMemoryStore(10_000, clock=clock),
        remote,
        write_behind_bytes=write_behind_bytes,
        **kwargs,
    )


def _wait_for(condition, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def test_writes_and_deletes_during_an_outage_reach_redis_when_it_returns(
    private_redis, fake_clock
) -> None:
    store = _tiered(private_redis.url, fake_clock, flush_interval_s=None)
    assert store.put_many({"gone": b"g", "kept": b"k"}) is True
    private_redis.kill()

    assert store.put_many({"new": b"n", "other": b"o"}, ttl_s=30.0) is False
    assert store.delete(["gone"]) == 1
    store.local.clear()  # the hot tier evicted them: the queue still answers
    assert store.get_many(["new", "gone", "other"]) == [b"n", None, b"o"]
    stats = store.stats()
    assert stats["pending_writes"] == 3 and stats["write_behind_queued"] == 3
    assert stats["pending_bytes"] == 2 + len("gone")
    assert store.flush() is False  # still down: nothing lost, nothing raised
    assert store.stats()["pending_writes"] == 3

    private_redis.start()  # empty: no persistence
    fake_clock.advance(1.0)
    assert store.flush() is True
    raw = private_redis.client()
    assert raw.get("new") == b"n" and raw.get("other") == b"o"
    assert 0 < raw.pttl("new") <= 30_000  # with the TTL the write asked for
    assert raw.exists("gone") == 0
    stats = store.stats()
    assert stats["pending_writes"] == 0 and stats["write_behind_flushed"] == 3
    store.close()


def test_a_newer_write_or_delete_replaces_the_queued_one(private_redis, fake_clock) -> None:
    store = _tiered(private_redis.url, fake_clock, flush_interval_s=None)
    private_redis.kill()
    store.put_many({"k": b"v1"})
    store.delete(["k"])  # the queued write becomes a queued delete
    assert store.get("k") is None
    store.put_many({"k": b"v2"})
    assert store.stats()["pending_writes"] == 1
    private_redis.start()
    fake_clock.advance(1.0)
    assert store.put_many({"now": b"direct"}) is True  # a direct write clears its own key only
    assert store.flush() is True
    assert private_redis.client().get("k") == b"v2"
    store.close()


def test_the_queue_is_bounded_and_drops_the_oldest(private_redis, fake_clock, caplog) -> None:
    store = _tiered(private_redis.url, fake_clock, write_behind_bytes=250, flush_interval_s=None)
    private_redis.kill()
    for i in range(5):
        store.put_many({f"k{i}": bytes([i]) * 100})
    usage = store.usage()["write_behind"]
    assert usage.bytes <= 250 and usage.entries == 2 and usage.max_bytes == 250
    stats = store.stats()
    assert stats["write_behind_dropped"] == 3 and stats["write_behind_queued"] == 5
    assert "write-behind queue full" in caplog.text
    assert store.put_many({"huge": b"x" * 300}) is False  # larger than the queue: dropped
    assert store.stats()["write_behind_dropped"] == 4

    store.local.delete(["k0", "huge"])  # the hot tier evicted these meanwhile

    private_redis.start()
    fake_clock.advance(1.0)
    assert store.flush() is True
    raw = private_redis.client()
    # k3, k4 replayed from the queue; k1, k2 refilled from the hot tier; k0 and huge lost
    assert [raw.exists(k) for k in ("k0", "k1", "k2", "k3", "k4", "huge")] == [0, 1, 1, 1, 1, 0]
    assert store.stats()["write_behind_flushed"] == 2 and store.stats()["refilled"] == 2
    store.close()


def test_an_emptied_redis_is_refilled_from_the_local_tier_after_an_outage(
    private_redis, fake_clock
) -> None:
    store = _tiered(private_redis.url, fake_clock, flush_interval_s=None, refill_batch_keys=2)
    assert store.put_many({f"k{i}": b"v" for i in range(5)})
    store.delete(["k0"])
    private_redis.kill()
    assert store.get("k1") == b"v"  # served locally; the remote read fails: an outage
    private_redis.start()  # empty
    fake_clock.advance(1.0)
    assert store.get("nothing") is None  # the next remote call reconnects
    assert store.flush() is True
    raw = private_redis.client()
    assert sorted(k.decode() for k in raw.keys("*")) == ["k1", "k2", "k3", "k4"]
    assert raw.pttl("k1") > 0
    stats = store.stats()
    assert stats["refilled"] == 4
    raw.delete("k1")
    assert store.flush() is True  # no new outage: no new refill
    assert raw.exists("k1") == 0 and store.stats()["refilled"] == 4
    store.close()


def test_a_restart_between_requests_is_noticed_and_refilled(private_redis) -> None:
    """redis-py reconnects silently: the server's new run_id gives the restart away."""
    store = TieredStore(
        InMemoryStore(10_000),
        RedisStore(private_redis.url, default_ttl_s=60.0),
        flush_interval_s=0.05,
    )
    assert store.put_many({"a": b"1", "b": b"2"}) is True
    private_redis.kill()
    private_redis.start()  # no request saw it go
    raw = private_redis.client()
    # the next request gets a fresh connection (new run_id), or, when the dead one is used
    # first, an outage whose end the flusher probes for; refilled either way
    assert store.get("absent") is None
    _wait_for(lambda: store.stats()["refilled"] == 2)  # counted once the batch is written
    assert raw.exists("a", "b") == 2 and store.stats()["remote_restarts"] == 1
    store.close()


def test_the_background_flusher_replays_without_traffic(private_redis) -> None:
    store = TieredStore(
        InMemoryStore(10_000),
        RedisStore(private_redis.url, default_ttl_s=60.0, backoff_initial_s=0.05),
        flush_interval_s=0.05,
    )
    private_redis.kill()
    assert store.put_many({"queued": b"q"}) is False
    assert "1 writes queued" in store.health().detail
    private_redis.start()
    raw = private_redis.client()
    _wait_for(lambda: store.stats()["write_behind_flushed"] == 1)  # no request drives it
    assert raw.get("queued") == b"q" and store.stats()["pending_writes"] == 0
    store.close()


def test_a_redis_back_from_an_outage_is_refilled_without_traffic(private_redis) -> None:
    store = TieredStore(
        InMemoryStore(10_000),
        RedisStore(private_redis.url, default_ttl_s=60.0, backoff_initial_s=0.05),
        flush_interval_s=0.05,
    )
    assert store.put_many({"kept": b"k"}) is True
    private_redis.kill()
    assert store.get("other") is None  # the outage is seen; nothing is queued
    private_redis.start()  # empty; from now on nobody calls the store
    raw = private_redis.client()
    _wait_for(lambda: store.stats()["refilled"] == 1)
    assert raw.get("kept") == b"k" and not store.health().degraded
    store.close()


def test_close_replays_once_more_and_counts_what_it_must_drop(
    private_redis, fake_clock, caplog
) -> None:
    url = private_redis.url
    store = _tiered(url, fake_clock, flush_interval_s=None)
    private_redis.kill()
    store.put_many({"a": b"1"})
    private_redis.start()
    fake_clock.advance(1.0)
    store.close()
    assert private_redis.client().get("a") == b"1"

    store = _tiered(url, fake_clock, flush_interval_s=None)
    private_redis.kill()
    store.put_many({"b": b"2"})
    store.close()
    assert "closing with 1 writes the shared store never got" in caplog.text
    assert store.stats()["write_behind_dropped"] == 1


def test_bad_arguments_are_rejected(shared_redis_url: str) -> None:
    with pytest.raises(ValueError, match="flush_interval_s"):
        TieredStore(
            InMemoryStore(10), RedisStore(shared_redis_url, default_ttl_s=None), flush_interval_s=0
        )
