"""An in-process artifact store: LRU bounded by value bytes, with per-entry TTL.

Used alone when no Redis is configured, and as the hot tier in front of Redis. One lock
guards everything; every operation is O(number of keys touched) except :meth:`stats`, which
sweeps expired entries (O(entries)).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence

from service.store.base import StoreHealth, as_bytes, check_ttl


class InMemoryStore:
    """Thread-safe LRU byte cache bounded by the total size of its values.

    Args:
        max_bytes: bound on the summed ``len(value)`` of all entries (keys are not counted).
        default_ttl_s: lifetime in seconds of entries written without ``ttl_s``; ``None``
            keeps them until evicted. The TTL is fixed at write time (a ``get`` refreshes
            recency for the LRU, not the expiry).
        clock: monotonic clock in seconds (injectable for tests).
    """

    backend = "memory"

    def __init__(
        self,
        max_bytes: int,
        *,
        default_ttl_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if max_bytes < 0:
            raise ValueError(f"max_bytes must be >= 0, got {max_bytes}")
        check_ttl(default_ttl_s)
        self.max_bytes = int(max_bytes)
        self.default_ttl_s = default_ttl_s
        self._clock = clock
        self._lock = threading.Lock()
        # key -> (value, expires_at or None); order = recency, least recent first
        self._entries: OrderedDict[str, tuple[bytes, float | None]] = OrderedDict()
        self._bytes = 0
        self._counts = dict.fromkeys(
            ("hits", "misses", "writes", "write_failures", "evictions", "expirations"), 0
        )

    # -- internals (call with the lock held) -----------------------------------------------

    def _drop(self, key: str) -> None:
        value, _ = self._entries.pop(key)
        self._bytes -= len(value)

    def _lookup(self, key: str, now: float) -> bytes | None:
        entry = self._entries.get(key)
        if entry is None:
            self._counts["misses"] += 1
            return None
        value, expires_at = entry
        if expires_at is not None and now >= expires_at:
            self._drop(key)
            self._counts["expirations"] += 1
            self._counts["misses"] += 1
            return None
        self._entries.move_to_end(key)
        self._counts["hits"] += 1
        return value

    def _sweep_expired(self, now: float) -> None:
        expired = [k for k, (_, exp) in self._entries.items() if exp is not None and now >= exp]
        for key in expired:
            self._drop(key)
        self._counts["expirations"] += len(expired)

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
        batch_bytes = sum(len(v) for v in values.values())
        with self._lock:
            if batch_bytes > self.max_bytes:
                self._counts["write_failures"] += len(values)
                return False
            now = self._clock()
            expires_at = None if ttl is None else now + ttl
            for key, value in values.items():
                if key in self._entries:
                    self._drop(key)
                self._entries[key] = (value, expires_at)
                self._bytes += len(value)
            # evict from the least recent end; the batch just written is the most recent
            # and fits by itself, so eviction stops before reaching it
            while self._bytes > self.max_bytes:
                oldest = next(iter(self._entries))
                value, exp = self._entries[oldest]
                self._drop(oldest)
                if exp is not None and now >= exp:
                    self._counts["expirations"] += 1
                else:
                    self._counts["evictions"] += 1
            self._counts["writes"] += len(values)
            return True

    def delete(self, keys: Sequence[str]) -> int:
        """Delete ``keys``; return how many were present and unexpired."""
        with self._lock:
            now = self._clock()
            deleted = 0
            for key in dict.fromkeys(keys):  # a repeated key counts once, like Redis DEL
                entry = self._entries.get(key)
                if entry is None:
                    continue
                self._drop(key)
                if entry[1] is None or now < entry[1]:
                    deleted += 1
            return deleted

    def health(self) -> StoreHealth:
        """Always available: the process's own memory."""
        with self._lock:
            detail = f"in-process LRU, {self._bytes} of {self.max_bytes} bytes used"
        return StoreHealth(backend=self.backend, available=True, degraded=False, detail=detail)

    def stats(self) -> dict[str, float]:
        """hits, misses, writes, write_failures (keys), errors (always 0), items, bytes
        (summed value sizes), max_bytes, evictions (LRU), expirations (TTL)."""
        with self._lock:
            self._sweep_expired(self._clock())
            out: dict[str, float] = {k: float(v) for k, v in self._counts.items()}
            out["errors"] = 0.0
            out["items"] = float(len(self._entries))
            out["bytes"] = float(self._bytes)
            out["max_bytes"] = float(self.max_bytes)
            return out

    def clear(self) -> None:
        """Drop every entry (counters are kept)."""
        with self._lock:
            self._entries.clear()
            self._bytes = 0

    def close(self) -> None:
        """Release the memory held."""
        self.clear()


__all__ = ["InMemoryStore"]
