"""Two tiers: a small in-process LRU in front of a shared (Redis) store, with write-behind.

Reads try the local tier first and fill it from remote hits; writes go to both. When the
remote tier is down the local tier keeps serving what it holds and the store reports itself
*degraded* (still available).

Write-behind. A write or delete the remote tier did not take (unreachable, or refused) is
queued in a bounded FIFO (:class:`~service.store.lru.ByteLRU`, budget ``write_behind_bytes``;
the oldest entries are dropped and counted when it is full) and replayed, oldest first, by a
background flusher once the remote tier answers again (the flusher probes it itself, so no
traffic is needed); a later write or delete of the same key replaces the queued one. Reads
see the queue: a queued value is a hit, a queued delete a miss. When the remote tier comes
back after an outage, or restarted unnoticed, it may have lost everything (a Redis restart
without persistence), so the flusher also *refills* it: every key the local tier holds that
the remote tier lacks is written back. :meth:`TieredStore.close` replays what is left once
more and logs what it has to drop.

Artifacts are content-addressed (shape id + bundle hash), so a stale copy cannot be wrong,
only kept alive after a delete issued on *another* replica, until its TTL or LRU eviction
drops it (or a refill copies it back).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping, Sequence

from service.store.base import SharedStore, StoreHealth, as_bytes
from service.store.lru import ByteLRU, CacheUsage
from service.store.memory import InMemoryStore

logger = logging.getLogger("litege.store")

MiB = 1024 * 1024
_LOG_EVERY_S = 10.0
_MAX_RETRY_S = 10.0  # longest flusher wait after a failed replay (the remote refuses writes)

_Pending = tuple[bytes | None, float | None]  # value (None: a delete), ttl_s


def _size(key: str, entry: _Pending) -> int:
    """What a queued write costs the write-behind budget: its value, or a delete's key."""
    return len(entry[0]) if entry[0] is not None else len(key)


class TieredStore:
    """``local`` (hot, per process) over ``remote`` (shared), writing behind the remote.

    Args:
        local: the hot tier; entries filled from remote hits get its default TTL.
        remote: the shared tier, e.g. a :class:`~service.store.redis_store.RedisStore`.
        write_behind_bytes: budget of the queue of writes the remote tier missed (values
            count their length, deletes their key's).
        flush_interval_s: how often the background flusher looks for work; ``None`` starts
            no flusher (call :meth:`flush` yourself).
        flush_batch_bytes: most bytes replayed in one remote transaction.
        refill_batch_keys: most keys checked and refilled per remote round trip.
    """

    def __init__(
        self,
        local: InMemoryStore,
        remote: SharedStore,
        *,
        write_behind_bytes: int = 64 * MiB,
        flush_interval_s: float | None = 0.5,
        flush_batch_bytes: int = 4 * MiB,
        refill_batch_keys: int = 256,
    ) -> None:
        if flush_interval_s is not None and not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s must be positive or None, got {flush_interval_s}")
        self.local = local
        self.remote = remote
        self.flush_interval_s = flush_interval_s
        self.flush_batch_bytes = max(1, int(flush_batch_bytes))
        self.refill_batch_keys = max(1, int(refill_batch_keys))
        self._pending: ByteLRU[str, _Pending] = ByteLRU(write_behind_bytes)
        self._lock = threading.Lock()  # counters
        # Remote writes and queue changes happen together under this lock, so that a replay
        # cannot undo a newer write or delete of the same key.
        self._write_lock = threading.RLock()
        self._flush_lock = threading.Lock()  # one replay at a time
        self._seen_generation = remote.generation
        self._counts = dict.fromkeys(
            (
                "hits",
                "misses",
                "writes",
                "write_failures",
                "write_behind_queued",
                "write_behind_flushed",
                "write_behind_dropped",
                "refilled",
            ),
            0,
        )
        self._last_drop_log = -float("inf")
        self._wake = threading.Event()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        if flush_interval_s is not None:
            self._thread = threading.Thread(
                target=self._flusher, name="litege-write-behind", daemon=True
            )
            self._thread.start()

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._counts[name] += n

    # -- reads ------------------------------------------------------------------------------

    def get(self, key: str) -> bytes | None:
        """Local value, else queued value, else remote value (copied into the local tier)."""
        return self.get_many([key])[0]

    def get_many(self, keys: Sequence[str]) -> list[bytes | None]:
        """Values in order: local hits, queued writes, then one remote batch for the rest
        (filling the local tier). A key whose delete is queued is a miss."""
        keys = list(keys)
        values = self.local.get_many(keys)
        ask: list[int] = []
        fill: dict[str, bytes] = {}
        for i, value in enumerate(values):
            if value is not None:
                continue
            queued = self._pending.peek(keys[i])
            if queued is None:
                ask.append(i)
            elif queued[0] is not None:
                values[i] = fill[keys[i]] = queued[0]
        if ask:
            remote_values = self.remote.get_many([keys[i] for i in ask])
            for i, value in zip(ask, remote_values, strict=True):
                if value is not None:
                    values[i] = fill[keys[i]] = value
            self._notice_reconnect()
        if fill:
            self.local.put_many(fill)
        hits = sum(v is not None for v in values)
        with self._lock:
            self._counts["hits"] += hits
            self._counts["misses"] += len(values) - hits
        return values

    # -- writes -----------------------------------------------------------------------------

    def put_many(self, items: Mapping[str, bytes], ttl_s: float | None = None) -> bool:
        """Write to both tiers; ``True`` iff the remote write succeeded now (else it is
        queued for the remote tier).

        The local write is always attempted (it only fails for a batch larger than the
        local bound, which is then simply not cached locally).
        """
        values = {key: as_bytes(key, value) for key, value in items.items()}
        if not values:
            return True
        self.local.put_many(values, ttl_s)
        with self._write_lock:
            ok = self.remote.put_many(values, ttl_s)
            if ok:
                for key in values:
                    self._pending.pop(key)
            else:
                self._queue([(key, (value, ttl_s)) for key, value in values.items()])
        with self._lock:
            self._counts["writes" if ok else "write_failures"] += len(values)
        self._notice_reconnect()
        return ok

    def delete(self, keys: Sequence[str]) -> int:
        """Delete from both tiers (queued for the remote tier when it is unreachable); the
        larger of the two counts (a key counts once)."""
        keys = list(dict.fromkeys(keys))
        if not keys:
            return 0
        local = self.local.delete(keys)
        with self._write_lock:
            queued = sum(
                1 for key in keys if (e := self._pending.pop(key)) is not None and e[0] is not None
            )
            remote = self.remote.try_delete(keys)
            if remote is None:
                self._queue([(key, (None, None)) for key in keys])
        self._notice_reconnect()
        return max(local, queued, remote or 0)

    def _queue(self, entries: list[tuple[str, _Pending]]) -> None:
        """Queue writes/deletes for the remote tier (write lock held)."""
        sized = [(key, entry, _size(key, entry)) for key, entry in entries]
        dropped = self._pending.put_many(sized, partial=True)
        self._count("write_behind_queued", len(entries))
        if dropped:
            self._count("write_behind_dropped", len(dropped))
            now = time.monotonic()
            if now - self._last_drop_log >= _LOG_EVERY_S:
                self._last_drop_log = now
                logger.warning(
                    "write-behind queue full (%d bytes): dropped %d queued writes for the "
                    "shared store",
                    self._pending.max_bytes,
                    len(dropped),
                )
        self._wake.set()

    # -- replay and refill ------------------------------------------------------------------

    def _notice_reconnect(self) -> None:
        if self._pending or self.remote.generation != self._seen_generation:
            self._wake.set()

    def _work_due(self) -> bool:
        return bool(self._pending) or self.remote.generation != self._seen_generation

    def flush(self) -> bool:
        """Replay queued writes and deletes to the remote tier (oldest first), then refill it
        from the local tier if it came back from an outage. ``True`` when nothing is left to
        do; ``False`` when the remote tier is still unreachable or refused."""
        with self._flush_lock:
            return self._replay() and self._refill()

    def _replay(self) -> bool:
        while True:
            batch: list[tuple[str, _Pending]] = []
            size = 0
            for key, entry in self._pending.items():
                if batch and size + _size(key, entry) > self.flush_batch_bytes:
                    break
                batch.append((key, entry))
                size += _size(key, entry)
            if not batch:
                return True
            with self._write_lock:
                # what a request wrote or deleted since the snapshot is newer: skip it
                batch = [(k, e) for k, e in batch if self._pending.peek(k) is e]
                if not self._write_remote(batch):
                    return False
                for key, entry in batch:
                    if self._pending.peek(key) is entry:
                        self._pending.pop(key)
            self._count("write_behind_flushed", len(batch))

    def _write_remote(self, batch: list[tuple[str, _Pending]]) -> bool:
        by_ttl: dict[float | None, dict[str, bytes]] = {}
        deletes: list[str] = []
        for key, (value, ttl_s) in batch:
            if value is None:
                deletes.append(key)
            else:
                by_ttl.setdefault(ttl_s, {})[key] = value
        for ttl_s, values in by_ttl.items():
            if not self.remote.put_many(values, ttl_s):
                return False
        return not deletes or self.remote.try_delete(deletes) is not None

    def _refill(self) -> bool:
        generation = self.remote.generation
        if generation == self._seen_generation:
            return True
        keys = [k for k in reversed(self.local.keys()) if k not in self._pending]  # recent first
        refilled = 0
        for start in range(0, len(keys), self.refill_batch_keys):
            chunk = keys[start : start + self.refill_batch_keys]
            exists = self.remote.exists_many(chunk)
            if exists is None:
                return False
            missing = [key for key, there in zip(chunk, exists, strict=True) if not there]
            if not missing:
                continue
            with self._write_lock:
                # re-read under the lock: a key deleted meanwhile is gone from the local tier
                values = self.local.peek_many(missing)
                items = {k: v for k, v in zip(missing, values, strict=True) if v is not None}
                if items and not self.remote.put_many(items):
                    return False
            refilled += len(items)
        self._seen_generation = generation
        self._count("refilled", refilled)
        if refilled:
            logger.warning("refilled the shared store with %d entries after an outage", refilled)
        return True

    def _flusher(self) -> None:
        assert self.flush_interval_s is not None
        wait_s = self.flush_interval_s
        while not self._closing.is_set():
            self._wake.wait(wait_s)
            self._wake.clear()
            if self._closing.is_set():
                return
            if not self.remote.available:
                # probe (once per backoff period, else without I/O) so that a Redis coming
                # back is noticed, and refilled, without waiting for traffic
                self.remote.health()
            if not self._work_due():
                wait_s = self.flush_interval_s
                continue
            try:
                done = self.flush()
            except Exception:  # the flusher must survive anything a backend raises
                logger.exception("write-behind flush failed")
                done = False
            if done or not self.remote.available:
                wait_s = self.flush_interval_s
            else:  # reachable but refusing (e.g. OOM): back off
                wait_s = min(2.0 * wait_s, _MAX_RETRY_S)

    # -- reporting --------------------------------------------------------------------------

    def health(self) -> StoreHealth:
        """Available always (the local tier serves); degraded while remote is unreachable."""
        remote = self.remote.health()
        detail = remote.detail
        queued = len(self._pending)
        if queued:
            detail += f"; {queued} writes queued for it"
        return StoreHealth(
            backend=f"tiered({self.local.health().backend}+{remote.backend})",
            available=True,
            degraded=not remote.available,
            detail=detail,
        )

    def stats(self) -> dict[str, float]:
        """``local_*`` and ``remote_*`` counters of the tiers, plus this store's own hits,
        misses (a miss everywhere), writes and write_failures (remote outcome, keys),
        write_behind_queued / _flushed / _dropped (keys), pending_writes, pending_bytes and
        refilled (keys written back into a remote tier that had lost them)."""
        out: dict[str, float] = {}
        out.update({f"local_{k}": v for k, v in self.local.stats().items()})
        out.update({f"remote_{k}": v for k, v in self.remote.stats().items()})
        pending = self._pending.usage()
        with self._lock:
            out.update({k: float(v) for k, v in self._counts.items()})
        out["pending_writes"] = float(pending.entries)
        out["pending_bytes"] = float(pending.bytes)
        return out

    def usage(self) -> dict[str, CacheUsage]:
        """The local tier's cache and the write-behind queue."""
        return {**self.local.usage(), "write_behind": self._pending.usage()}

    def close(self) -> None:
        """Stop the flusher, replay what is queued once more, then close both tiers."""
        self._closing.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
        try:
            if self._pending and not self.flush():
                lost = len(self._pending)
                self._count("write_behind_dropped", lost)
                logger.warning("closing with %d writes the shared store never got", lost)
        finally:
            try:
                self.remote.close()
            finally:
                self.local.close()


__all__ = ["TieredStore"]
