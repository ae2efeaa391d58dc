"""Where shapes prepared for matching live: one artifact per shape in the store, a bounded
live LRU.

A :class:`~litege_core.matching.model.MatchingShape` (aligned points, descriptor, NN cache) is
computed once per shape and matching bundle and kept beside the shape's geometry
(``litege:{<shape_id>}:<matching_bundle_hash>:matching-v<N>``, pickle-free, through the
shape repository's :class:`~service.store.ShapeStore`; ``N`` is the library's
:data:`~litege_core.matching.model.PREPARATION_VERSION`, so an upgrade that prepares shapes
differently never reads the old entries), with a :class:`~service.store.ByteLRU` of
live ones in front, bounded by ``matching_cache_bytes`` (feature tables included). Lookups
go live → store → prepare from the registered shape's geometry
(:meth:`ShapeRepository.shape`; :class:`ShapeNotFoundError` when the shape is not
registered) and write back. A corrupt artifact is deleted and recomputed. Like the shape
repository, it runs on the runtime's single compute thread.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import partial

from litege_core.errors import ArtifactError
from litege_core.matching.model import PREPARATION_VERSION, MatchingModel, MatchingShape
from service.errors import UnknownModelError
from service.metrics import ServiceMetrics
from service.repository import ShapeRepository
from service.store import Artifact, ByteLRU, footprint

MATCHING = f"matching-v{PREPARATION_VERSION}"
"""Artifact name of a prepared shape (versioned: see the module docstring)."""
PREPARE_SEED = 0
"""Seed of every random draw of a preparation: the same shape always gets the same state."""


def _parse(shape_id: str, arrays: dict) -> MatchingShape:
    prepared = MatchingShape.from_arrays(arrays)
    if prepared.shape_id != shape_id:
        raise ArtifactError("stored prepared shape belongs to another shape id")
    return prepared


class MatchingRepository:
    """Prepared shapes per matching model (see the module docstring).

    Args:
        models: matching model name → model (empty: correspondence is off).
        shapes: the shape repository (registered geometry, and the store it owns).
        cache_bytes: budget of the live prepared shapes.
        metrics: the process's metrics.
    """

    def __init__(
        self,
        models: Mapping[str, MatchingModel],
        shapes: ShapeRepository,
        *,
        cache_bytes: int,
        metrics: ServiceMetrics,
    ) -> None:
        self.models = dict(models)
        self.default_model = next(iter(self.models), None)
        self.shapes = shapes
        self.metrics = metrics
        self._live: ByteLRU[tuple[str, str], MatchingShape] = ByteLRU(cache_bytes, sizeof=footprint)
        metrics.watch_cache("matching", self._live.usage)

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

    def _artifact(self, model: str) -> Artifact:
        return Artifact(self.models[model].content_hash, MATCHING)

    def get(self, shape_id: str, model: str) -> MatchingShape:
        """The prepared shape, from the live LRU, the store, or computed now.

        Raises:
            ShapeNotFoundError: the shape is not registered (and was never prepared).
        """
        prepared = self._live.get((model, shape_id))
        if prepared is not None:
            self.metrics.cache.labels("matching_state", "hit").inc()
            return prepared
        self.metrics.cache.labels("matching_state", "miss").inc()
        artifact = self._artifact(model)
        stored = self.shapes.artifacts.read(
            shape_id, [artifact], partial(_parse, shape_id), geometry=False
        )
        if stored.corrupt:
            self.metrics.cache.labels("matching_store", "corrupt").inc(stored.corrupt)
        prepared = stored.artifacts[0]
        if prepared is not None:
            self.metrics.cache.labels("matching_store", "hit").inc()
        else:
            self.metrics.cache.labels("matching_store", "miss").inc()
            shape = self.shapes.shape(shape_id)
            prepared = self.models[model].prepare(shape, seed=PREPARE_SEED)
            self.metrics.matching_prepared.labels(model).inc()
            self.shapes.artifacts.write(
                shape_id, {artifact: (prepared.to_arrays(), {"model": model})}
            )
        self.models[model].features(prepared)  # the point features the searches use, memoized
        self._live.put((model, shape_id), prepared)
        return prepared

    def forget_live(self) -> None:
        """Drop every live prepared shape (tests: simulate a restart or an eviction)."""
        self._live.clear()

    def delete(self, shape_id: str) -> bool:
        """Forget the shape's prepared states under every matching model."""
        found = False
        for model in self.models:
            found = self._live.pop((model, shape_id)) is not None or found
        artifacts = [self._artifact(m) for m in self.models]
        return self.shapes.artifacts.delete(shape_id, artifacts, geometry=False) > 0 or found
