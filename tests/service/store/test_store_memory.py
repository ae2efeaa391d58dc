"""InMemoryStore: LRU bounded by value bytes, TTL, all-or-nothing writes, thread safety."""

from __future__ import annotations

import random
import sys
import threading

import pytest

from service.store import ArtifactStore, InMemoryStore, StoreHealth


def test_is_an_artifact_store() -> None:
    assert isinstance(InMemoryStore(10), ArtifactStore)


def test_put_get_get_many_delete() -> None:
    store = InMemoryStore(1000)
    assert store.get("a") is None
    assert store.put_many({"a": b"1", "b": b"22"}) is True
    assert store.get("a") == b"1"
    assert store.get_many(["b", "missing", "a", "b"]) == [b"22", None, b"1", b"22"]
    assert store.get_many([]) == []
    assert store.put_many({}) is True
    assert store.delete(["a", "a", "missing"]) == 1
    assert store.get("a") is None
    stats = store.stats()
    assert stats["hits"] == 4 and stats["misses"] == 3
    assert stats["writes"] == 2 and stats["items"] == 1 and stats["bytes"] == 2


def test_bytes_like_values_are_copied_and_other_values_rejected() -> None:
    store = InMemoryStore(100)
    buffer = bytearray(b"abc")
    store.put_many({"a": buffer, "m": memoryview(b"xy")})
    buffer[0] = ord("z")
    assert store.get("a") == b"abc" and store.get("m") == b"xy"
    with pytest.raises(TypeError):
        store.put_many({"s": "text"})  # type: ignore[dict-item]


def test_lru_evicts_least_recently_used_until_under_the_byte_bound() -> None:
    store = InMemoryStore(100)
    store.put_many({"a": b"a" * 40})
    store.put_many({"b": b"b" * 40})
    assert store.get("a") is not None  # a is now more recent than b
    store.put_many({"c": b"c" * 40})
    assert store.get("b") is None
    assert store.get("a") == b"a" * 40 and store.get("c") == b"c" * 40
    stats = store.stats()
    assert stats["bytes"] == 80 and stats["items"] == 2 and stats["evictions"] == 1
    store.put_many({"d": b"d" * 100})  # exactly the bound: everything else goes
    assert store.get_many(["a", "c", "d"]) == [None, None, b"d" * 100]
    assert store.stats()["evictions"] == 3


def test_overwriting_a_key_accounts_its_new_size() -> None:
    store = InMemoryStore(100)
    store.put_many({"a": b"x" * 60, "b": b"y" * 30})
    store.put_many({"a": b"x" * 10})
    assert store.stats()["bytes"] == 40
    store.put_many({"c": b"z" * 60})
    assert store.get_many(["a", "b", "c"]) == [b"x" * 10, b"y" * 30, b"z" * 60]


def test_a_value_larger_than_the_bound_is_not_stored() -> None:
    store = InMemoryStore(100)
    store.put_many({"keep": b"k" * 50})
    assert store.put_many({"small": b"s", "huge": b"h" * 101}) is False
    assert store.get_many(["small", "huge", "keep"]) == [None, None, b"k" * 50]
    assert store.stats()["write_failures"] == 2


def test_a_batch_larger_than_the_bound_is_all_or_nothing() -> None:
    store = InMemoryStore(100)
    store.put_many({"keep": b"k" * 50})
    assert store.put_many({"x": b"x" * 60, "y": b"y" * 60}) is False
    assert store.get_many(["x", "y", "keep"]) == [None, None, b"k" * 50]


def test_zero_bound_stores_nothing_but_empty_values() -> None:
    store = InMemoryStore(0)
    assert store.put_many({"a": b"1"}) is False
    assert store.put_many({"e": b""}) is True and store.get("e") == b""


def test_default_ttl_expires_entries(fake_clock) -> None:
    store = InMemoryStore(1000, default_ttl_s=10.0, clock=fake_clock)
    store.put_many({"a": b"1", "b": b"2"})
    fake_clock.advance(9.9)
    assert store.get("a") == b"1"  # a get refreshes recency, not the expiry
    fake_clock.advance(0.1)
    assert store.get_many(["a", "b"]) == [None, None]
    stats = store.stats()
    assert stats["items"] == 0 and stats["bytes"] == 0 and stats["expirations"] == 2


def test_per_call_ttl_overrides_the_default(fake_clock) -> None:
    store = InMemoryStore(1000, default_ttl_s=10.0, clock=fake_clock)
    store.put_many({"short": b"1"}, ttl_s=1.0)
    store.put_many({"long": b"2"}, ttl_s=100.0)
    store.put_many({"default": b"3"})
    fake_clock.advance(5.0)
    assert store.get_many(["short", "long", "default"]) == [None, b"2", b"3"]
    fake_clock.advance(50.0)
    assert store.get_many(["long", "default"]) == [b"2", None]


def test_no_ttl_keeps_entries(fake_clock) -> None:
    store = InMemoryStore(1000, clock=fake_clock)
    store.put_many({"a": b"1"})
    fake_clock.advance(1e9)
    assert store.get("a") == b"1"


def test_expired_entries_are_dropped_from_the_byte_count(fake_clock) -> None:
    store = InMemoryStore(100, clock=fake_clock)
    store.put_many({"old": b"o" * 60}, ttl_s=1.0)
    store.put_many({"live": b"l" * 30})
    fake_clock.advance(2.0)
    assert store.stats()["bytes"] == 30  # stats sweeps expired entries
    store.put_many({"new": b"n" * 60})
    assert store.get_many(["live", "new"]) == [b"l" * 30, b"n" * 60]


def test_delete_does_not_count_expired_entries(fake_clock) -> None:
    store = InMemoryStore(100, clock=fake_clock)
    store.put_many({"a": b"1"}, ttl_s=1.0)
    store.put_many({"b": b"2"})
    fake_clock.advance(1.0)
    assert store.delete(["a", "b"]) == 1
    assert store.stats()["items"] == 0


@pytest.mark.parametrize("ttl", [0, -1.0, float("nan")])
def test_non_positive_ttl_is_rejected(ttl: float) -> None:
    with pytest.raises(ValueError, match="ttl_s"):
        InMemoryStore(10, default_ttl_s=ttl)
    with pytest.raises(ValueError, match="ttl_s"):
        InMemoryStore(10).put_many({"a": b"1"}, ttl_s=ttl)


def test_negative_bound_is_rejected() -> None:
    with pytest.raises(ValueError, match="max_bytes"):
        InMemoryStore(-1)


def test_health_and_close() -> None:
    store = InMemoryStore(100)
    store.put_many({"a": b"12345"})
    health = store.health()
    assert isinstance(health, StoreHealth)
    assert (health.backend, health.available, health.degraded) == ("memory", True, False)
    assert "5 of 100 bytes" in health.detail
    store.close()
    assert store.get("a") is None and store.stats()["bytes"] == 0


def test_concurrent_gets_puts_and_deletes_keep_the_store_consistent() -> None:
    store = InMemoryStore(4000, default_ttl_s=60.0)
    keys = [f"k{i}" for i in range(50)]
    errors: list[BaseException] = []
    barrier = threading.Barrier(6)

    def value_of(key: str, size: int) -> bytes:
        return (key.encode() + b"|") * size

    def worker(seed: int) -> None:
        rng = random.Random(seed)
        try:
            barrier.wait()
            for _ in range(3000):
                op = rng.random()
                key = rng.choice(keys)
                if op < 0.4:
                    batch = {k: value_of(k, rng.randint(1, 40)) for k in rng.sample(keys, 3)}
                    store.put_many(batch)
                elif op < 0.8:
                    batch_keys = rng.sample(keys, 4)
                    for k, v in zip(batch_keys, store.get_many(batch_keys), strict=True):
                        assert v is None or v.startswith(k.encode() + b"|")
                elif op < 0.95:
                    v = store.get(key)
                    assert v is None or v.startswith(key.encode() + b"|")
                else:
                    store.delete([key])
        except BaseException as exc:  # re-raised in the main thread
            errors.append(exc)

    threads = [threading.Thread(target=worker, args=(seed,)) for seed in range(6)]
    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)  # switch threads often, to interleave inside operations
    try:
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        sys.setswitchinterval(old_interval)
    assert not errors, errors[0]
    stats = store.stats()
    values = [v for v in store.get_many(keys) if v is not None]
    assert stats["bytes"] == sum(len(v) for v in values) <= 4000
    assert stats["items"] == len(values)
