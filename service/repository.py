"""Where registered shapes live: artifacts in the store, live states in a bounded LRU.

Per shape and model bundle the store holds two artifacts (keys
``litege:{bundle_hash}:{shape_id}:{artifact}``):

- ``arrays``: the shape's own vertices and faces (the source of truth; without them the shape
  is gone and the client must upload it again);
- ``record``: the :class:`~litege_core.predictor.ShapeRecord` (transform, UDF-PCA descriptor,
  residual), a few hundred bytes from which :meth:`Predictor.restore` rebuilds the embeddings
  in milliseconds without recomputing the descriptor.

A live :class:`ShapeState` (embeddings on the device) is kept in an in-process LRU bounded in
bytes. Lookups go live state → store record (restore) → store arrays (recompute the record,
write it back) → :class:`ShapeNotFoundError`. Corrupt artifacts are deleted and treated as
missing. Not thread-safe by itself beyond one lock around the LRU: the runtime calls it from
its single compute thread.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from litege_core.errors import ArtifactError, LiteGEError
from litege_core.predictor import Predictor, ShapeRecord, ShapeState
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits
from service.errors import ShapeNotFoundError, UnknownModelError
from service.metrics import ServiceMetrics
from service.store import ArtifactStore, artifact_key, decode_arrays, encode_arrays

log = logging.getLogger("litege.repository")

ARRAYS = "arrays"
RECORD = "record"
ARTIFACTS = (ARRAYS, RECORD)


@dataclass(frozen=True)
class Registered:
    """A shape's live state, the model it is registered with, and whether it was computed now."""

    model: str
    state: ShapeState
    created: bool


class ShapeRepository:
    """Register shapes and find their states again (see the module docstring).

    Args:
        predictors: model name → predictor (one device).
        default_model: tried first when a lookup names no model.
        store: artifact store (in-process LRU, Redis, or both tiers).
        state_cache_bytes: bound of the live states (device memory).
        ttl_s: expiry of the artifacts in the store (sliding where the store supports it).
        metrics: the process's metrics (cache hits and misses, live states).
        limits: the upload limits (stored arrays are validated again when read back).
    """

    def __init__(
        self,
        predictors: Mapping[str, Predictor],
        default_model: str,
        store: ArtifactStore,
        *,
        state_cache_bytes: int,
        ttl_s: float | None,
        metrics: ServiceMetrics,
        limits: ShapeLimits,
    ) -> None:
        if default_model not in predictors:
            raise UnknownModelError(f"default model {default_model!r} is not loaded")
        self.predictors = dict(predictors)
        self.default_model = default_model
        self.store = store
        self.state_cache_bytes = int(state_cache_bytes)
        self.ttl_s = ttl_s
        self.metrics = metrics
        self.limits = limits
        self._live: OrderedDict[tuple[str, str], ShapeState] = OrderedDict()
        self._live_bytes = 0
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ models

    def model_name(self, model: str | None) -> str:
        """``model`` checked against the loaded ones (``None`` → the default)."""
        name = self.default_model if model is None else model
        if name not in self.predictors:
            raise UnknownModelError(
                f"unknown model {name!r}; this service has {sorted(self.predictors)}"
            )
        return name

    def _candidates(self, model: str | None) -> list[str]:
        if model is not None:
            return [self.model_name(model)]
        return [self.default_model, *(m for m in self.predictors if m != self.default_model)]

    def _key(self, model: str, shape_id: str, artifact: str) -> str:
        return artifact_key(self.predictors[model].bundle.content_hash, shape_id, artifact)

    # ------------------------------------------------------------------ registration

    def register_many(self, shapes: Sequence[Shape], model: str | None) -> list[Registered]:
        """Register shapes with one model; shapes already known are not recomputed."""
        name = self.model_name(model)
        results: list[Registered | None] = []
        missing: dict[str, list[int]] = {}
        for i, shape in enumerate(shapes):
            found = self._lookup(shape.content_hash, name, shape_hint=shape)
            results.append(Registered(name, found, created=False) if found else None)
            if found is None:
                missing.setdefault(shape.content_hash, []).append(i)
        if missing:
            fresh = [shapes[positions[0]] for positions in missing.values()]
            states = self.predictors[name].register_many(fresh)
            for shape, state, positions in zip(fresh, states, missing.values(), strict=True):
                self._write(name, shape, state.record)
                self._remember(name, state)
                self.metrics.registered.labels(name, "true").inc()
                for n, i in enumerate(positions):
                    results[i] = Registered(name, state, created=n == 0)
        for r in results:
            if r is not None and not r.created:
                self.metrics.registered.labels(name, "false").inc()
        return [r for r in results if r is not None]

    # ------------------------------------------------------------------ lookup

    def get(self, shape_id: str, model: str | None = None) -> Registered:
        """The live state of a registered shape.

        Raises:
            UnknownModelError: ``model`` is not loaded.
            ShapeNotFoundError: no model has the shape's arrays (never uploaded, deleted, or
                evicted from the store): the client must upload it again.
        """
        for name in self._candidates(model):
            state = self._lookup(shape_id, name)
            if state is not None:
                return Registered(name, state, created=False)
        where = f" with model {model!r}" if model is not None else ""
        raise ShapeNotFoundError(
            f"shape {shape_id!r} is not registered{where} (unknown, deleted, or expired from "
            "the cache); upload it again with POST /shapes"
        )

    def shape(self, shape_id: str) -> Shape:
        """The registered shape's own geometry (under any model), without building its state:
        from a live state, else from the stored arrays.

        Raises:
            ShapeNotFoundError: as :meth:`get`.
        """
        with self._lock:
            live = [self._live.get((name, shape_id)) for name in self.predictors]
        state = next((s for s in live if s is not None), None)
        if state is not None:
            return Shape.from_arrays(
                state.vertices, state.faces, kind=state.kind.value, limits=self.limits
            )
        for name in self._candidates(None):
            keys = [self._key(name, shape_id, a) for a in ARTIFACTS]
            (raw,) = self.store.get_many(keys[:1])
            if raw is not None:
                shape = self._decode_shape(shape_id, raw, keys)
                if shape is not None:
                    return shape
        raise ShapeNotFoundError(
            f"shape {shape_id!r} is not registered (unknown, deleted, or expired from the "
            "cache); upload it again with POST /shapes"
        )

    def _lookup(
        self, shape_id: str, model: str, shape_hint: Shape | None = None
    ) -> ShapeState | None:
        """The shape's live state, restored from the store if needed; ``None`` if unknown.
        ``shape_hint`` (a re-upload: same content hash) spares decoding the stored arrays."""
        with self._lock:
            state = self._live.get((model, shape_id))
            if state is not None:
                self._live.move_to_end((model, shape_id))
        if state is not None:
            self.metrics.cache.labels("state", "hit").inc()
            return state
        self.metrics.cache.labels("state", "miss").inc()
        keys = [self._key(model, shape_id, a) for a in ARTIFACTS]
        raw_arrays, raw_record = self.store.get_many(keys)
        if raw_arrays is None:
            self.metrics.cache.labels("store", "miss").inc()
            return None
        shape = shape_hint or self._decode_shape(shape_id, raw_arrays, keys)
        if shape is None:
            self.metrics.cache.labels("store", "corrupt").inc()
            return None
        predictor = self.predictors[model]
        record = self._decode_record(raw_record, keys[1]) if raw_record is not None else None
        if record is not None:
            try:
                state = predictor.restore(shape, record)
            except LiteGEError as exc:
                log.warning("discarding unusable record %s: %s", keys[1], exc)
                self.store.delete([keys[1]])
                record = None
        if record is None:
            # the record was evicted or unusable but the arrays survived: recompute it
            self.metrics.cache.labels("store", "recompute").inc()
            state = predictor.register(shape)
            self._write(model, shape, state.record)
        else:
            self.metrics.cache.labels("store", "hit").inc()
        self._remember(model, state)
        return state

    def _decode_shape(self, shape_id: str, raw: bytes, keys: list[str]) -> Shape | None:
        try:
            arrays, meta = decode_arrays(raw)
            faces = arrays.get("faces")
            shape = Shape.from_arrays(
                arrays["vertices"], faces, kind=meta.get("kind"), limits=self.limits
            )
            if shape.content_hash != shape_id:
                raise ArtifactError("stored arrays do not hash to their shape id")
        except (LiteGEError, KeyError) as exc:
            log.warning("deleting corrupt shape artifacts %s: %s", keys[0], exc)
            self.store.delete(keys)
            return None
        return shape

    def _decode_record(self, raw: bytes, key: str) -> ShapeRecord | None:
        try:
            arrays, _ = decode_arrays(raw)
            return ShapeRecord.from_arrays(arrays)
        except ArtifactError as exc:
            log.warning("deleting corrupt record %s: %s", key, exc)
            self.store.delete([key])
            return None

    def _write(self, model: str, shape: Shape, record: ShapeRecord | None) -> None:
        if record is None:  # pragma: no cover - states from the predictor always carry one
            raise ArtifactError("shape state has no record to store")
        arrays: dict[str, np.ndarray] = {"vertices": np.asarray(shape.vertices)}
        if shape.faces is not None:
            arrays["faces"] = np.asarray(shape.faces)
        items = {
            self._key(model, shape.content_hash, ARRAYS): encode_arrays(
                arrays, {"kind": shape.kind.value}
            ),
            self._key(model, shape.content_hash, RECORD): encode_arrays(
                record.to_arrays(), {"model": model}
            ),
        }
        if not self.store.put_many(items, ttl_s=self.ttl_s):
            log.warning("could not write shape %s to the store (degraded)", shape.content_hash)

    # ------------------------------------------------------------------ live LRU

    def _remember(self, model: str, state: ShapeState) -> None:
        size = state.nbytes
        with self._lock:
            key = (model, state.shape_id)
            old = self._live.pop(key, None)
            if old is not None:
                self._live_bytes -= old.nbytes
            if size <= self.state_cache_bytes:
                self._live[key] = state
                self._live_bytes += size
            while self._live_bytes > self.state_cache_bytes and self._live:
                _, evicted = self._live.popitem(last=False)
                self._live_bytes -= evicted.nbytes
            self.metrics.live_states.set(len(self._live))
            self.metrics.live_state_bytes.set(self._live_bytes)

    def forget_live(self) -> None:
        """Drop every live state (tests: simulate a restart or an eviction)."""
        with self._lock:
            self._live.clear()
            self._live_bytes = 0

    # ------------------------------------------------------------------ delete

    def delete(self, shape_id: str) -> bool:
        """Forget a shape under every model; ``True`` if anything was there."""
        found = False
        with self._lock:
            for model in self.predictors:
                if self._live.pop((model, shape_id), None) is not None:
                    found = True
            self._live_bytes = sum(s.nbytes for s in self._live.values())
        keys = [self._key(m, shape_id, a) for m in self.predictors for a in ARTIFACTS]
        return self.store.delete(keys) > 0 or found
