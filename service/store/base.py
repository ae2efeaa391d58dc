"""The interface every artifact store implements, and its health report.

An artifact store is a byte cache keyed by strings (see :mod:`service.store.keys`). It is a
*cache*: a backend that is down reads as misses and failed writes, never as exceptions, so a
request can always fall back to recomputing the artifact.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from service.store.lru import CacheUsage


@dataclass(frozen=True)
class StoreHealth:
    """What a store can say about itself right now."""

    backend: str
    """``"memory"``, ``"redis"`` or ``"tiered(memory+redis)"``."""
    available: bool
    """The backing store answers now."""
    degraded: bool
    """Serving, but the shared/remote tier is unreachable."""
    detail: str
    """Human-readable, e.g. ``"connected to redis://host:6379/0"``."""


@runtime_checkable
class ArtifactStore(Protocol):
    """A byte cache of per-shape artifacts. Implementations are thread-safe."""

    def get(self, key: str) -> bytes | None:
        """The value of ``key``, or ``None`` on a miss (also when the backend is down)."""
        ...

    def get_many(self, keys: Sequence[str]) -> list[bytes | None]:
        """The values of ``keys`` in order (``None`` for each miss), in one round trip."""
        ...

    def put_many(self, items: Mapping[str, bytes], ttl_s: float | None = None) -> bool:
        """Write all ``items`` or none; ``ttl_s`` (seconds) defaults to the store's TTL.

        Returns ``False`` when they could not be written (backend down, value too large);
        never raises for that.
        """
        ...

    def delete(self, keys: Sequence[str]) -> int:
        """Delete ``keys``; return how many existed."""
        ...

    def health(self) -> StoreHealth:
        """Reachability of the backend now."""
        ...

    def stats(self) -> dict[str, float]:
        """Counters: hits, misses, writes, write_failures, errors, items, bytes, evictions.

        ``items``/``bytes``/``evictions`` appear only where the backend knows them.
        """
        ...

    def usage(self) -> dict[str, CacheUsage]:
        """The process memory this store holds: its bounded caches by name (empty for a
        store that holds nothing in this process)."""
        ...

    def close(self) -> None:
        """Release connections; the store must not be used afterwards."""
        ...


@runtime_checkable
class SharedStore(ArtifactStore, Protocol):
    """A store shared between processes (Redis), as the tiered store needs it: writes it
    missed during an outage are replayed, and what it lost is refilled."""

    @property
    def available(self) -> bool:
        """Whether the last contact succeeded (no I/O)."""
        ...

    @property
    def generation(self) -> int:
        """Changes each time the store comes back after an outage."""
        ...

    def try_delete(self, keys: Sequence[str]) -> int | None:
        """Delete ``keys``; how many existed, or ``None`` when it could not be done."""
        ...

    def exists_many(self, keys: Sequence[str]) -> list[bool] | None:
        """Whether each key exists, or ``None`` when the store cannot be asked now."""
        ...


def as_bytes(key: str, value: object) -> bytes:
    """``value`` as ``bytes`` (bytearray/memoryview copied); TypeError otherwise."""
    if isinstance(value, bytes):
        return value
    if isinstance(value, bytearray | memoryview):
        return bytes(value)
    raise TypeError(f"value of {key!r} must be bytes, got {type(value).__name__}")


def check_ttl(ttl_s: float | None) -> None:
    """Raise ValueError unless ``ttl_s`` is ``None`` or positive seconds."""
    if ttl_s is not None and not ttl_s > 0:
        raise ValueError(f"ttl_s must be positive seconds or None, got {ttl_s!r}")


__all__ = ["ArtifactStore", "SharedStore", "StoreHealth", "as_bytes", "check_ttl"]
