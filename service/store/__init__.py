"""The service's artifact store: per-shape artifacts cached as bytes.

Keys are ``litege:{bundle_hash}:{shape_id}:{artifact}`` (:func:`artifact_key`); values are
pickle-free safetensors buffers (:func:`encode_arrays` / :func:`decode_arrays`). Backends:
:class:`InMemoryStore` (one process), :class:`RedisStore` (shared, degrades to misses during
an outage) and :class:`TieredStore` (a hot in-process LRU in front of Redis).
:func:`make_store` picks one from the configuration.
"""

from __future__ import annotations

from service.store.base import ArtifactStore, StoreHealth
from service.store.codec import FORMAT_TAG, decode_arrays, encode_arrays
from service.store.keys import artifact_key
from service.store.memory import InMemoryStore
from service.store.redis_store import RedisStore
from service.store.tiered import TieredStore


def make_store(
    redis_url: str | None, *, memory_bytes: int, hot_bytes: int, ttl_s: float | None
) -> ArtifactStore:
    """The store the configuration asks for.

    Args:
        redis_url: ``None``/empty for a process-local store, else the Redis URL.
        memory_bytes: bound in bytes of the process-local store (no Redis).
        hot_bytes: bound in bytes of the local hot tier in front of Redis.
        ttl_s: sliding lifetime in seconds of artifacts in Redis, and lifetime of local
            entries; ``None`` for no expiry (LRU / Redis eviction only).

    Nothing connects here: a Redis that is down at start-up yields a degraded store.
    """
    if not redis_url:
        return InMemoryStore(memory_bytes, default_ttl_s=ttl_s)
    return TieredStore(
        InMemoryStore(hot_bytes, default_ttl_s=ttl_s),
        RedisStore(redis_url, default_ttl_s=ttl_s),
    )


__all__ = [
    "FORMAT_TAG",
    "ArtifactStore",
    "InMemoryStore",
    "RedisStore",
    "StoreHealth",
    "TieredStore",
    "artifact_key",
    "decode_arrays",
    "encode_arrays",
    "make_store",
]
