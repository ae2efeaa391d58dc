"""ByteLRU (the one in-process cache class) and deep_nbytes (what a live object weighs)."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from service.store import ByteLRU, CacheUsage, deep_nbytes, footprint


def test_evicts_least_recently_used_to_the_budget() -> None:
    lru: ByteLRU[str, str] = ByteLRU(100)
    assert lru.put("a", "A", 40) == []
    lru.put("b", "B", 40)
    assert lru.get("a") == "A"  # a is now more recent than b
    assert lru.put("c", "C", 40) == [("b", "B")]
    assert lru.keys() == ["a", "c"] and lru.nbytes == 80
    assert lru.usage() == CacheUsage(entries=2, bytes=80, max_bytes=100, evictions=1)
    assert lru.peek("a") == "A" and lru.keys() == ["a", "c"]  # peek keeps the order
    assert lru.put("a", "A2", 10) == []  # replacing re-accounts the size
    assert lru.nbytes == 50 and lru.get("a") == "A2"
    assert lru.pop("a") == "A2" and lru.pop("a") is None
    assert "a" not in lru and "c" in lru and len(lru) == 1


def test_an_entry_larger_than_the_budget_is_not_kept() -> None:
    lru: ByteLRU[str, str] = ByteLRU(100)
    lru.put("k", "old", 10)
    assert lru.put("k", "huge", 101) == [("k", "huge")]
    assert lru.get("k") is None and lru.nbytes == 0  # the old value went too
    assert lru.usage().evictions == 1


def test_put_many_is_all_or_nothing_unless_partial() -> None:
    lru: ByteLRU[str, int] = ByteLRU(100)
    lru.put("keep", 0, 50)
    assert lru.put_many([("x", 1, 60), ("y", 2, 60)]) is None
    assert lru.keys() == ["keep"]
    assert lru.put_many([("x", 1, 60), ("y", 2, 200)], partial=True) == [("y", 2), ("keep", 0)]
    assert lru.items() == [("x", 1)]


@dataclass(eq=False)
class _Live:
    """A live object that grows after it is handed out, like a state's lazy projector."""

    base: np.ndarray
    lazy: dict = field(default_factory=dict)


def test_live_entries_are_remeasured_when_they_grow_and_the_budget_holds() -> None:
    lru: ByteLRU[str, _Live] = ByteLRU(1000, sizeof=footprint)
    live = {key: _Live(np.zeros(30, np.uint8)) for key in "abc"}
    for key in "abc":
        lru.put(key, live[key])
    assert lru.nbytes == 90
    live["c"].lazy["projector"] = np.zeros(600, np.uint8)  # built after it was handed out
    assert lru.get("c") is live["c"]  # the hit measures it again
    assert lru.nbytes == 690
    live["b"].lazy["projector"] = np.zeros(600, np.uint8)  # grew without being touched again
    lru.put("d", _Live(np.zeros(30, np.uint8)))  # an insertion notices and evicts to budget
    assert lru.keys() == ["c", "d"] and lru.nbytes == 660
    live["d"] = lru.peek("d")
    live["d"].lazy["x"] = np.zeros(500, np.uint8)
    usage = lru.usage()  # and so does a report (a /metrics scrape)
    assert usage.bytes <= 1000 and usage.entries == 1 and lru.keys() == ["d"]
    assert usage.evictions == 3
    with pytest.raises(ValueError, match="nbytes"):
        ByteLRU(10).put("k", "v")


def test_a_footprint_notices_growth_cheaply() -> None:
    holder = _Holder({"a": np.zeros(10)})
    measured = footprint(holder)
    assert measured.nbytes == 80 and not measured.changed()
    holder.derived  # noqa: B018 - a cached property fills the instance dict
    assert measured.changed() and footprint(holder).nbytes == 80 + 8000
    holder.arrays["b"] = np.zeros(1)
    assert footprint(holder).changed() is False


def test_thread_safety_keeps_the_accounting_exact() -> None:
    lru: ByteLRU[int, int] = ByteLRU(5000)

    def worker(seed: int) -> None:
        rng = np.random.default_rng(seed)
        for _ in range(2000):
            key = int(rng.integers(200))
            if rng.random() < 0.6:
                lru.put(key, key, int(rng.integers(1, 100)))
            elif rng.random() < 0.5:
                lru.get(key)
            else:
                lru.pop(key)

    threads = [threading.Thread(target=worker, args=(s,)) for s in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert lru.nbytes <= 5000
    assert lru.nbytes == sum(size for _, (_, size, _) in lru._entries.items())


@dataclass(eq=False)
class _Holder:
    arrays: dict = field(default_factory=dict)

    @cached_property
    def derived(self) -> np.ndarray:
        return np.ones(1000)  # 8000 bytes, in the instance __dict__ once computed


def test_deep_nbytes_counts_each_buffer_once() -> None:
    base = np.zeros((100, 3))  # 2400 bytes
    tensor = torch.zeros(50, 4)  # 800 bytes
    holder = _Holder({"a": base, "view": base[10:20], "ro": base.view(), "t": tensor[:10]})
    assert deep_nbytes(holder) == 2400 + 800  # views and slices share their buffer
    assert deep_nbytes(holder, base, tensor) == 3200  # shared across objects too
    holder.derived  # noqa: B018 - a cached property is memory the object holds
    assert deep_nbytes(holder) == 3200 + 8000
    tree = cKDTree(np.zeros((64, 3)))
    assert deep_nbytes({"tree": tree}) == tree.data.nbytes + tree.indices.nbytes
    frombuffer = np.frombuffer(b"x" * 64, dtype=np.uint8)
    assert deep_nbytes([frombuffer, frombuffer[:8]]) == 64
    assert deep_nbytes(np, torch.nn.Linear(100, 100), "text", 3) == 0  # not a cache's own


def test_deep_nbytes_of_a_live_state_includes_its_projector_once_built(toy_predictor, blob):
    state = toy_predictor.register(blob(0, subdivisions=2))
    before = deep_nbytes(state)
    assert before >= state.nbytes + state.vertices.nbytes  # ShapeState.nbytes leaves them out
    state.projector  # noqa: B018 - built on the first xyz query
    assert deep_nbytes(state) > before + state.faces.shape[0] * 9 * 8  # triangle corners
