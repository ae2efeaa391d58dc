"""The service's artifact store: per-shape bytes, cached in process and shared in Redis.

Layout (:mod:`service.store.keys`, owned by :class:`ShapeStore`): a shape's geometry once per
shape id, ``litege:{<shape_id>}:geometry``, and per model bundle what it computed from it,
``litege:{<shape_id>}:<bundle_hash>:<artifact>``. Values are pickle-free safetensors buffers
(:func:`encode_arrays` / :func:`decode_arrays`). Byte stores: :class:`InMemoryStore` (one
process), :class:`RedisStore` (shared, degrades to misses during an outage) and
:class:`TieredStore` (a hot in-process LRU in front of Redis, writing behind it during
outages); :func:`make_store` picks one from the configuration. Every in-process cache is a
:class:`ByteLRU` with its own byte budget.
"""

from __future__ import annotations

from service.store.base import ArtifactStore, SharedStore, StoreHealth
from service.store.codec import FORMAT_TAG, decode_arrays, encode_arrays
from service.store.keys import artifact_key, geometry_key
from service.store.lru import ByteLRU, CacheUsage, Footprint, deep_nbytes, footprint
from service.store.memory import InMemoryStore
from service.store.redis_store import RedisStore
from service.store.shapes import Artifact, ShapeStore, Stored
from service.store.tiered import TieredStore


def make_store(
    redis_url: str | None,
    *,
    memory_bytes: int,
    hot_bytes: int,
    ttl_s: float | None,
    write_behind_bytes: int,
) -> ArtifactStore:
    """The store the configuration asks for.

    Args:
        redis_url: ``None``/empty for a process-local store, else the Redis URL.
        memory_bytes: bound in bytes of the process-local store (no Redis).
        hot_bytes: bound in bytes of the local hot tier in front of Redis.
        ttl_s: sliding lifetime in seconds of artifacts in Redis, and lifetime of local
            entries; ``None`` for no expiry (LRU / Redis eviction only).
        write_behind_bytes: bound in bytes of the writes queued while Redis is unreachable.

    Nothing connects here: a Redis that is down at start-up yields a degraded store.
    """
    if not redis_url:
        return InMemoryStore(memory_bytes, default_ttl_s=ttl_s, name="memory")
    return TieredStore(
        InMemoryStore(hot_bytes, default_ttl_s=ttl_s, name="hot"),
        RedisStore(redis_url, default_ttl_s=ttl_s),
        write_behind_bytes=write_behind_bytes,
    )


__all__ = [
    "FORMAT_TAG",
    "Artifact",
    "ArtifactStore",
    "ByteLRU",
    "CacheUsage",
    "Footprint",
    "InMemoryStore",
    "RedisStore",
    "ShapeStore",
    "SharedStore",
    "StoreHealth",
    "Stored",
    "TieredStore",
    "artifact_key",
    "decode_arrays",
    "deep_nbytes",
    "encode_arrays",
    "footprint",
    "geometry_key",
    "make_store",
]
