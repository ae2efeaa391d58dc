"""An in-process artifact store: a :class:`~service.store.lru.ByteLRU` of values, with TTL.

Used alone when no Redis is configured (budget ``LITEGE_MEMORY_CACHE_BYTES``) and as the hot
tier in front of Redis (``LITEGE_HOT_CACHE_BYTES``). Thread-safe; every operation is
O(number of keys touched) except :meth:`InMemoryStore.stats`, which sweeps expired entries
(O(entries)).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence

from service.store.base import StoreHealth, as_bytes, check_ttl
from service.store.lru import ByteLRU, CacheUsage

_Entry = tuple[bytes, float | None]  # value, expires_at (clock seconds) or None


class InMemoryStore:
    """Thread-safe LRU byte cache bounded by the total size of its values.

    Args:
        max_bytes: bound on the summed ``len(value)`` of all entries (keys are not counted).
        default_ttl_s: lifetime in seconds of entries written without ``ttl_s``; ``None``
            keeps them until evicted. The TTL is fixed at write time (a ``get`` refreshes
            recency for the LRU, not the expiry).
        clock: monotonic clock in seconds (injectable for tests).
        name: what :meth:`usage` calls this cache (``"memory"`` alone, ``"hot"`` as a tier).
    """

    backend = "memory"

    def __init__(
        self,
        max_bytes: int,
        *,
        default_ttl_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
        name: str = "memory",
    ) -> None:
        if max_bytes < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        check_ttl(default_ttl_s)
        self.max_bytes = int(max_bytes)
        self.default_ttl_s = default_ttl_s
        self.name = name
        self._clock = clock
        # the lock makes a batch (and its counters) atomic; the LRU has its own, inner one
        self._lock = threading.Lock()
        self._lru: ByteLRU[str, _Entry] = ByteLRU(self.max_bytes)
        self._counts = dict.fromkeys(
            ("hits", "misses", "writes", "write_failures", "evictions", "expirations"), 0
        )

    # -- internals (call with the lock held) -----------------------------------------------

    def _lookup(self, key: str, now: float) -> bytes | None:
        entry = self._lru.get(key)
        if entry is None:
            self._counts["misses"] += 1
            return None
        value, expires_at = entry
        if expires_at is not None and now >= expires_at:
            self._lru.pop(key)
            self._counts["expirations"] += 1
            self._counts["misses"] += 1
            return None
        self._counts["hits"] += 1
        return value

    def _sweep_expired(self, now: float) -> None:
        for key, (_, expires_at) in self._lru.items():
            if expires_at is not None and now >= expires_at:
                self._lru.pop(key)
                self._counts["expirations"] += 1

    # -- ArtifactStore -----------------------------------------------------------------------

    def get(self, key: str) -> bytes | None:
        """The value of ``key``, or ``None`` if absent or expired; refreshes its recency."""
        with self._lock:
            return self._lookup(key, self._clock())

    def get_many(self, keys: Sequence[str]) -> list[bytes | None]:
        """The values of ``keys`` in order, ``None`` for each miss (one lock acquisition)."""
        with self._lock:
            now = self._clock()
            return [self._lookup(key, now) for key in keys]

    def peek_many(self, keys: Sequence[str]) -> list[bytes | None]:
        """Like :meth:`get_many` but without touching recency or counters."""
        with self._lock:
            now = self._clock()
            out: list[bytes | None] = []
            for key in keys:
                entry = self._lru.peek(key)
                fresh = entry is not None and (entry[1] is None or now < entry[1])
                out.append(entry[0] if fresh else None)  # type: ignore[index]
            return out

    def keys(self) -> list[str]:
        """The keys held now, least recently used first (a snapshot; may include expired)."""
        return self._lru.keys()

    def put_many(self, items: Mapping[str, bytes], ttl_s: float | None = None) -> bool:
        """Store all ``items`` (expiring after ``ttl_s`` seconds, default the store's TTL).

        All or nothing: returns ``False`` and stores nothing when the batch cannot fit at
        all (one value, or the batch as a whole, is larger than ``max_bytes``). Otherwise
        evicts least recently used entries until the bound holds and returns ``True``.
        """
        check_ttl(ttl_s)
        values = {key: as_bytes(key, value) for key, value in items.items()}
        if not values:
            return True
        ttl = self.default_ttl_s if ttl_s is None else ttl_s
        with self._lock:
            now = self._clock()
            expires_at = None if ttl is None else now + ttl
            evicted = self._lru.put_many(
                [(key, (value, expires_at), len(value)) for key, value in values.items()]
            )
            if evicted is None:
                self._counts["write_failures"] += len(values)
                return False
            for _, (_, exp) in evicted:
                expired = exp is not None and now >= exp
                self._counts["expirations" if expired else "evictions"] += 1
            self._counts["writes"] += len(values)
            return True

    def delete(self, keys: Sequence[str]) -> int:
        """Delete ``keys``; return how many were present and unexpired."""
        with self._lock:
            now = self._clock()
            deleted = 0
            for key in dict.fromkeys(keys):  # a repeated key counts once, like Redis DEL
                entry = self._lru.pop(key)
                if entry is not None and (entry[1] is None or now < entry[1]):
                    deleted += 1
            return deleted

    def health(self) -> StoreHealth:
        """Always available: the process's own memory."""
        detail = f"in-process LRU, {self._lru.nbytes} of {self.max_bytes} bytes used"
        return StoreHealth(backend=self.backend, available=True, degraded=False, detail=detail)

    def stats(self) -> dict[str, float]:
        """hits, misses, writes, write_failures (keys), errors (always 0), items, bytes
        (summed value sizes), max_bytes, evictions (LRU), expirations (TTL)."""
        with self._lock:
            self._sweep_expired(self._clock())
            out: dict[str, float] = {k: float(v) for k, v in self._counts.items()}
            usage = self._lru.usage()
            out["errors"] = 0.0
            out["items"] = float(usage.entries)
            out["bytes"] = float(usage.bytes)
            out["max_bytes"] = float(self.max_bytes)
            return out

    def usage(self) -> dict[str, CacheUsage]:
        """``{name: usage}`` of this store's one bounded cache."""
        return {self.name: self._lru.usage()}

    def clear(self) -> None:
        """Drop every entry (counters are kept)."""
        with self._lock:
            self._lru.clear()

    def close(self) -> None:
        """Release the memory held."""
        self.clear()


__all__ = ["InMemoryStore"]
