"""Where shapes prepared for matching live: one artifact in the store, a bounded live LRU.

A :class:`~litege_core.matching.model.MatchingShape` (aligned points, descriptor, NN cache) is
computed once per shape and matching bundle and kept in the store under
``litege:{matching_bundle_hash}:{shape_id}:matching`` (pickle-free safetensors, via
``to_arrays`` / ``from_arrays``), with an in-process LRU of live ones in front. Lookups go
live → store → prepare from the registered shape's geometry (:meth:`ShapeRepository.shape`;
:class:`ShapeNotFoundError` when the shape is not registered) and write back. A corrupt
artifact is deleted and recomputed. Like the shape repository, it runs on the runtime's
single compute thread (one lock guards the LRU).
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Mapping

from litege_core.errors import ArtifactError
from litege_core.matching.model import MatchingModel, MatchingShape
from service.errors import UnknownModelError
from service.metrics import ServiceMetrics
from service.repository import ShapeRepository
from service.store import ArtifactStore, artifact_key, decode_arrays, encode_arrays

log = logging.getLogger("litege.matching")

MATCHING = "matching"
PREPARE_SEED = 0
"""Seed of every random draw of a preparation: the same shape always gets the same state."""


class MatchingRepository:
    """Prepared shapes per matching model (see the module docstring).

    Args:
        models: matching model name → model (empty: correspondence is off).
        shapes: the shape repository (registered geometry).
        store: the artifact store shared with ``shapes``.
        cache_bytes: bound of the live prepared shapes.
        ttl_s: expiry of the artifacts in the store.
        metrics: the process's metrics.
    """

    def __init__(
        self,
        models: Mapping[str, MatchingModel],
        shapes: ShapeRepository,
        store: ArtifactStore,
        *,
        cache_bytes: int,
        ttl_s: float | None,
        metrics: ServiceMetrics,
    ) -> None:
        self.models = dict(models)
        self.default_model = next(iter(self.models), None)
        self.shapes = shapes
        self.store = store
        self.cache_bytes = int(cache_bytes)
        self.ttl_s = ttl_s
        self.metrics = metrics
        self._live: OrderedDict[tuple[str, str], tuple[MatchingShape, int]] = OrderedDict()
        self._live_bytes = 0
        self._lock = threading.Lock()

    def model_name(self, model: str | None) -> str:
        """``model`` checked against the loaded matching models (``None`` → the default)."""
        name = self.default_model if model is None else model
        if name is None:
            raise UnknownModelError("this service has no matching model (LITEGE_MATCHING_MODEL)")
        if name not in self.models:
            raise UnknownModelError(
                f"unknown matching model {name!r}; this service has {sorted(self.models)}"
            )
        return name

    def _key(self, model: str, shape_id: str) -> str:
        return artifact_key(self.models[model].content_hash, shape_id, MATCHING)

    def get(self, shape_id: str, model: str) -> MatchingShape:
        """The prepared shape, from the live LRU, the store, or computed now.

        Raises:
            ShapeNotFoundError: the shape is not registered (and was never prepared).
        """
        with self._lock:
            entry = self._live.get((model, shape_id))
            if entry is not None:
                self._live.move_to_end((model, shape_id))
        if entry is not None:
            prepared = entry[0]
            self.metrics.cache.labels("matching_state", "hit").inc()
            return prepared
        self.metrics.cache.labels("matching_state", "miss").inc()
        key = self._key(model, shape_id)
        (raw,) = self.store.get_many([key])
        prepared = self._decode(raw, key, shape_id) if raw is not None else None
        if prepared is not None:
            self.metrics.cache.labels("matching_store", "hit").inc()
        else:
            self.metrics.cache.labels("matching_store", "miss").inc()
            shape = self.shapes.shape(shape_id)
            prepared = self.models[model].prepare(shape, seed=PREPARE_SEED)
            self.metrics.matching_prepared.labels(model).inc()
            items = {key: encode_arrays(prepared.to_arrays(), {"model": model})}
            if not self.store.put_many(items, ttl_s=self.ttl_s):
                log.warning("could not write prepared shape %s to the store (degraded)", shape_id)
        self.models[model].features(prepared)  # the point features the searches use, memoized
        self._remember(model, prepared)
        return prepared

    def _decode(self, raw: bytes, key: str, shape_id: str) -> MatchingShape | None:
        try:
            arrays, _ = decode_arrays(raw)
            prepared = MatchingShape.from_arrays(arrays)
            if prepared.shape_id != shape_id:
                raise ArtifactError("stored prepared shape belongs to another shape id")
        except ArtifactError as exc:
            log.warning("deleting corrupt prepared shape %s: %s", key, exc)
            self.metrics.cache.labels("matching_store", "corrupt").inc()
            self.store.delete([key])
            return None
        return prepared

    def _remember(self, model: str, prepared: MatchingShape) -> None:
        size = prepared.nbytes
        with self._lock:
            key = (model, prepared.shape_id)
            old = self._live.pop(key, None)
            if old is not None:
                self._live_bytes -= old[1]
            if size <= self.cache_bytes:
                self._live[key] = (prepared, size)
                self._live_bytes += size
            while self._live_bytes > self.cache_bytes and self._live:
                _, (_, evicted) = self._live.popitem(last=False)
                self._live_bytes -= evicted

    def forget_live(self) -> None:
        """Drop every live prepared shape (tests: simulate a restart or an eviction)."""
        with self._lock:
            self._live.clear()
            self._live_bytes = 0

    def delete(self, shape_id: str) -> bool:
        """Forget the shape's prepared states under every matching model."""
        found = False
        with self._lock:
            for model in self.models:
                if self._live.pop((model, shape_id), None) is not None:
                    found = True
            self._live_bytes = sum(size for _, size in self._live.values())
        keys = [self._key(m, shape_id) for m in self.models]
        return (self.store.delete(keys) > 0 if keys else False) or found
