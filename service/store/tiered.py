"""Two tiers: a small in-process LRU in front of a shared (Redis) store.

Reads try the local tier first and fill it from remote hits; writes go to both. When the
remote tier is down the local tier keeps serving what it holds and the store reports itself
*degraded* (still available).

Artifacts are content-addressed (bundle hash + shape id), so a stale local copy cannot be
wrong, only kept alive after a delete issued on *another* replica, until its local TTL or LRU
eviction drops it.
"""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence

from service.store.base import ArtifactStore, StoreHealth
from service.store.memory import InMemoryStore


class TieredStore:
    """``local`` (hot, per process) over ``remote`` (shared).

    Args:
        local: the hot tier; entries filled from remote hits get its default TTL.
        remote: the shared tier, e.g. a :class:`~service.store.redis_store.RedisStore`.
    """

    def __init__(self, local: InMemoryStore, remote: ArtifactStore) -> None:
        self.local = local
        self.remote = remote
        self._lock = threading.Lock()
        self._counts = dict.fromkeys(("hits", "misses", "writes", "write_failures"), 0)

    def _count_reads(self, hits: int, misses: int) -> None:
        with self._lock:
            self._counts["hits"] += hits
            self._counts["misses"] += misses

    def get(self, key: str) -> bytes | None:
        """Local value, else remote value (then copied into the local tier), else ``None``."""
        value = self.local.get(key)
        if value is None:
            value = self.remote.get(key)
            if value is not None:
                self.local.put_many({key: value})
        self._count_reads(int(value is not None), int(value is None))
        return value

    def get_many(self, keys: Sequence[str]) -> list[bytes | None]:
        """Values in order: local hits, then one remote batch for the rest (filling local)."""
        keys = list(keys)
        values = self.local.get_many(keys)
        missing = [i for i, v in enumerate(values) if v is None]
        if missing:
            remote_values = self.remote.get_many([keys[i] for i in missing])
            fill: dict[str, bytes] = {}
            for i, value in zip(missing, remote_values, strict=True):
                if value is not None:
                    values[i] = value
                    fill[keys[i]] = value
            if fill:
                self.local.put_many(fill)
        hits = sum(v is not None for v in values)
        self._count_reads(hits, len(values) - hits)
        return values

    def put_many(self, items: Mapping[str, bytes], ttl_s: float | None = None) -> bool:
        """Write to both tiers; ``True`` iff the remote write succeeded.

        The local write is always attempted (it only fails for a batch larger than the
        local bound, which is then simply not cached locally).
        """
        self.local.put_many(items, ttl_s)
        ok = self.remote.put_many(items, ttl_s)
        with self._lock:
            self._counts["writes" if ok else "write_failures"] += len(items)
        return ok

    def delete(self, keys: Sequence[str]) -> int:
        """Delete from both tiers; the larger of the two counts (a key counts once)."""
        keys = list(keys)
        return max(self.local.delete(keys), self.remote.delete(keys))

    def health(self) -> StoreHealth:
        """Available always (the local tier serves); degraded while remote is unreachable."""
        remote = self.remote.health()
        return StoreHealth(
            backend=f"tiered({self.local.health().backend}+{remote.backend})",
            available=True,
            degraded=not remote.available,
            detail=remote.detail,
        )

    def stats(self) -> dict[str, float]:
        """``local_*`` and ``remote_*`` counters of the tiers, plus this store's own hits,
        misses (a miss in both tiers), writes and write_failures (remote outcome, keys)."""
        out: dict[str, float] = {}
        out.update({f"local_{k}": v for k, v in self.local.stats().items()})
        out.update({f"remote_{k}": v for k, v in self.remote.stats().items()})
        with self._lock:
            out.update({k: float(v) for k, v in self._counts.items()})
        return out

    def close(self) -> None:
        """Close both tiers."""
        try:
            self.remote.close()
        finally:
            self.local.close()


__all__ = ["TieredStore"]
