"""The interface every artifact store implements, and its health report.

An artifact store is a byte cache keyed by strings (see :mod:`service.store.keys`). It is a
*cache*: a backend that is down reads as misses and failed writes, never as exceptions, so a
request can always fall back to recomputing the artifact.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable


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

    def close(self) -> None:
        """Release connections; the store must not be used afterwards."""
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


__all__ = ["ArtifactStore", "StoreHealth", "as_bytes", "check_ttl"]
