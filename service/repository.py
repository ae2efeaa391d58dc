"""Where registered shapes live: their bytes in the store, live states in a bounded LRU.

The store (through :class:`~service.store.ShapeStore`, the one owner of its layout) holds a
shape's **geometry** once per shape id (the source of truth: without it the shape is gone
and the client must upload it again) and, per geodesic model bundle, its ``record``: the
:class:`~litege_core.learned.ShapeRecord` (transform, UDF-PCA descriptor, residual), a few
hundred bytes from which :meth:`Predictor.restore` rebuilds the embeddings in milliseconds.

A live :class:`ShapeState` (embeddings on the device) is kept, with its :class:`Shape`, in a
:class:`~service.store.ByteLRU` bounded by ``state_cache_bytes`` and measured with
:func:`~service.store.footprint` (so a surface projector built later counts too).

Lookups go live state → stored record (restore) → stored geometry (compute the record with
the model asked for and write it back: a shape registered under one model can be queried
under another without uploading it again) → :class:`ShapeNotFoundError`. Corrupt entries
are deleted and read as missing.

Model ``"auto"`` (:data:`AUTO_MODEL`; the default when the settings say so) registers or looks
a shape up under **every** loaded model (records found are restored, missing ones computed in
one batch per model and written back) and answers with the model of the shape's category where
the category router (:mod:`litege_core.learned.router`) is confident, else with the one of
lowest OOD score (:attr:`ShapeState.ood_score`) weighed with how well each model's network
agrees with its own fusion graph on the shape (:func:`~litege_core.learned.routing.choose_model`;
ties to the first loaded), with every model's score. Records, router inputs and agreements
are deterministic, so the choice is too; it is remembered with the chosen live state, so a
later ``auto`` lookup of a live shape costs what a named one does.

The runtime calls the repository from its single compute thread;
:meth:`ShapeRepository.shape` is also safe from other threads (the viewer).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from litege_core.errors import ArtifactError, LiteGEError
from litege_core.learned import Predictor, ShapeRecord, ShapeState
from litege_core.learned.router import CategoryRouter, first_of_each_category
from litege_core.learned.routing import choose_model
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits
from service.errors import ShapeNotFoundError, UnknownModelError
from service.metrics import ServiceMetrics
from service.settings import AUTO_MODEL
from service.store import Artifact, ArtifactStore, ByteLRU, Footprint, ShapeStore, Stored, footprint

log = logging.getLogger("litege.repository")

RECORD = "record"


def record_artifact(predictor: Predictor) -> Artifact:
    """Where a predictor's shape records are stored: ``record`` for the full descriptor lattice,
    ``record.<lattice>`` for a sparser one (an approximation: never mixed with full ones)."""
    lattice = predictor.descriptor_lattice
    name = RECORD if lattice == "full" else f"{RECORD}.{lattice}"
    return Artifact(predictor.bundle.content_hash, name)


@dataclass(frozen=True)
class Registered:
    """A shape's live state, the model it is registered with, and whether it was computed now.

    ``scores``: when the model was chosen automatically (``"auto"``), every loaded model's OOD
    score of the shape (the chosen one is the lowest); ``None`` when a model was named."""

    model: str
    state: ShapeState
    created: bool
    scores: Mapping[str, float] | None = None


@dataclass(frozen=True)
class _Live:
    """A live state and the shape it was built from (they share the vertex and face arrays);
    ``scores`` set when this state is the shape's ``auto`` choice."""

    shape: Shape
    state: ShapeState
    scores: Mapping[str, float] | None = None


def _live_footprint(live: _Live) -> Footprint:
    return footprint(live.shape, live.state)


def _not_found(shape_id: str, model: str | None = None) -> ShapeNotFoundError:
    where = f" with model {model!r}" if model is not None else ""
    return ShapeNotFoundError(
        f"shape {shape_id!r} is not registered{where} (unknown, deleted, or expired from the "
        "cache); upload it again with POST /shapes"
    )


class ShapeRepository:
    """Register shapes and find their states again (see the module docstring).

    Args:
        predictors: model name → predictor (one device).
        default_model: the model of a registration or lookup that names none: a loaded one
            (a lookup then tries it first) or :data:`AUTO_MODEL`.
        store: the byte store (in-process LRU, Redis, or both tiers).
        state_cache_bytes: budget of the live states.
        ttl_s: expiry of what is written to the store (sliding where the store supports it).
        metrics: the process's metrics (cache hits and misses, cache sizes).
        limits: the upload limits (stored geometry is validated again when read back).
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
        router: CategoryRouter | None = None,
    ) -> None:
        if default_model != AUTO_MODEL and default_model not in predictors:
            raise UnknownModelError(f"default model {default_model!r} is not loaded")
        self.predictors = dict(predictors)
        self.default_model = default_model
        self.router = router
        self.artifacts = ShapeStore(store, limits=limits, ttl_s=ttl_s)
        self.metrics = metrics
        self._live: ByteLRU[tuple[str, str], _Live] = ByteLRU(
            state_cache_bytes, sizeof=_live_footprint
        )
        metrics.watch_cache("state", self._live.usage)
        metrics.watch_store(store)
        metrics.live_states.set_function(lambda: len(self._live))
        metrics.live_state_bytes.set_function(lambda: self._live.nbytes)

    # ------------------------------------------------------------------ models

    def model_name(self, model: str | None) -> str:
        """``model`` checked against the loaded ones and :data:`AUTO_MODEL` (``None`` → the
        default)."""
        name = self.default_model if model is None else model
        if name != AUTO_MODEL and name not in self.predictors:
            raise UnknownModelError(
                f"unknown model {name!r}; this service has {sorted(self.predictors)} "
                f"(or {AUTO_MODEL!r}: the one that fits the shape best)"
            )
        return name

    def _candidates(self, model: str | None) -> list[str]:
        if model is not None:
            return [self.model_name(model)]
        return [self.default_model, *(m for m in self.predictors if m != self.default_model)]

    def _record(self, model: str) -> Artifact:
        """The stored record of ``model`` (:func:`record_artifact`)."""
        return record_artifact(self.predictors[model])

    # ------------------------------------------------------------------ registration

    def register_many(self, shapes: Sequence[Shape], model: str | None) -> list[Registered]:
        """Register shapes with one model (``"auto"``: under every model, answering with the
        best, see the module docstring); shapes already known are not recomputed."""
        name = self.model_name(model)
        if name == AUTO_MODEL:
            return self._auto([(shape.content_hash, shape) for shape in shapes])
        results: list[Registered | None] = []
        missing: dict[str, list[int]] = {}
        for i, shape in enumerate(shapes):
            found = self._find(shape.content_hash, [name], known=shape)
            results.append(Registered(name, found[1], created=False) if found else None)
            if found is None:
                missing.setdefault(shape.content_hash, []).append(i)
        if missing:
            fresh = [shapes[positions[0]] for positions in missing.values()]
            states = self.predictors[name].register_many(fresh)
            for shape, state, positions in zip(fresh, states, missing.values(), strict=True):
                self._write_record(name, state, shape=shape)
                self._remember(name, shape, state)
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

        ``model`` given: its state under that model, computed now from the stored geometry
        when the shape was registered under another one. ``None``: under the first model
        (default first) that has it registered, else computed with the default model.
        ``"auto"`` (or ``None`` with an ``auto`` default): under the model of lowest OOD
        score, with every model's score (records computed from the stored geometry where
        missing).

        Raises:
            UnknownModelError: ``model`` is not loaded.
            ShapeNotFoundError: the store has no geometry for the shape (never uploaded,
                deleted, or evicted): the client must upload it again.
        """
        if self.model_name(model) == AUTO_MODEL:
            return self._auto([(shape_id, None)])[0]
        found = self._find(shape_id, self._candidates(model))
        if found is None:
            raise _not_found(shape_id, model)
        return Registered(found[0], found[1], created=False)

    # ------------------------------------------------------------------ auto

    def _auto(self, items: Sequence[tuple[str, Shape | None]]) -> list[Registered]:
        """``(shape_id, shape or None)`` items under the best model each (see the module
        docstring); a shape is given for a registration, else read from the store.

        Raises:
            ShapeNotFoundError: an item without a shape whose geometry is not stored.
        """
        names = list(self.predictors)
        results: list[Registered | None] = [None] * len(items)
        pending: dict[str, list[int]] = {}
        for i, (shape_id, _) in enumerate(items):
            remembered = self._auto_live(shape_id)
            if remembered is not None:
                results[i] = remembered
            else:
                pending.setdefault(shape_id, []).append(i)
        shapes: dict[str, Shape] = {}
        states: dict[str, dict[str, ShapeState]] = {}
        unstored: set[str] = set()  # registrations whose geometry the store lacks
        for shape_id, positions in pending.items():
            known = items[positions[0]][1]
            states[shape_id], shape, stored = self._states_found(shape_id, names, known)
            if shape is None:
                raise _not_found(shape_id)
            shapes[shape_id] = shape
            if known is not None and not stored:
                unstored.add(shape_id)
        new = {shape_id for shape_id in pending if not states[shape_id]}
        for name in names:
            missing = [shape_id for shape_id in pending if name not in states[shape_id]]
            if not missing:
                continue
            computed = self.predictors[name].register_many([shapes[s] for s in missing])
            for shape_id, state in zip(missing, computed, strict=True):
                geometry = shapes[shape_id] if shape_id in unstored else None
                self._write_record(name, state, shape=geometry)
                unstored.discard(shape_id)
                states[shape_id][name] = state
        routed: list[str | None] = [None] * len(pending)
        if self.router is not None and len(names) > 1:
            by_category = first_of_each_category(
                {name: self.predictors[name].bundle.category for name in names}
            )
            routed = self.router.route([shapes[s] for s in pending], by_category)
        for (shape_id, positions), by_router in zip(pending.items(), routed, strict=True):
            scores = {name: float(states[shape_id][name].ood_score) for name in names}
            chosen = by_router or self._choose(states[shape_id], scores)
            state = states[shape_id][chosen]
            self._remember(chosen, shapes[shape_id], state, scores)
            for n, i in enumerate(positions):
                created = shape_id in new and n == 0 and items[i][1] is not None
                results[i] = Registered(chosen, state, created=created, scores=scores)
                if items[i][1] is not None:
                    self.metrics.registered.labels(chosen, str(created).lower()).inc()
        return [r for r in results if r is not None]

    def _choose(self, states: Mapping[str, ShapeState], scores: Mapping[str, float]) -> str:
        """The lowest OOD score, weighed with each model's network-to-graph agreement where
        several models are loaded (:func:`~litege_core.learned.routing.choose_model`)."""
        if len(scores) < 2:
            return next(iter(scores))
        agreements = {name: self.predictors[name].agreement(states[name]) for name in scores}
        return choose_model(scores, agreements)

    def _auto_live(self, shape_id: str) -> Registered | None:
        """The shape's remembered ``auto`` choice, when its state is live."""
        for name in self.predictors:
            live = self._live.peek((name, shape_id))
            if live is not None and live.scores is not None:
                self._live.get((name, shape_id))  # most recent
                self.metrics.cache.labels("state", "hit").inc()
                return Registered(name, live.state, created=False, scores=live.scores)
        return None

    def _states_found(
        self, shape_id: str, names: list[str], known: Shape | None
    ) -> tuple[dict[str, ShapeState], Shape | None, bool]:
        """The shape's states under those of ``names`` that have it (live, or a stored record
        restored; nothing computed), its shape (``known``, live or stored; ``None``: gone),
        and whether the store holds its geometry (``True`` when not read: all live)."""
        states: dict[str, ShapeState] = {}
        shape = known
        for name in names:
            live = self._live.get((name, shape_id))
            if live is not None:
                self.metrics.cache.labels("state", "hit").inc()
                states[name] = live.state
                if shape is None:
                    shape = live.shape
        rest = [name for name in names if name not in states]
        if not rest:
            return states, shape, True
        stored = self.artifacts.read(
            shape_id, [self._record(n) for n in rest], ShapeRecord.from_arrays
        )
        try:
            for name, record in zip(rest, stored.artifacts, strict=True):
                if record is not None and stored.exists:
                    state = self._restore(name, stored, record, shape)
                    if state is not None:
                        self.metrics.cache.labels("store", "hit").inc()
                        states[name] = state
            if shape is None and stored.exists:
                shape = stored.shape()
            if known is None and len(states) < len(names):
                self.metrics.cache.labels("store", "miss" if shape is None else "recompute").inc()
        finally:
            if stored.corrupt:
                self.metrics.cache.labels("store", "corrupt").inc(stored.corrupt)
        return states, shape, stored.exists

    def shape(self, shape_id: str) -> Shape:
        """The registered shape's own geometry (under any model), without building a state:
        the live one's shape, else the stored geometry. Thread-safe.

        Raises:
            ShapeNotFoundError: as :meth:`get`.
        """
        for name in self.predictors:
            live = self._live.peek((name, shape_id))
            if live is not None:
                return live.shape
        shape = self.artifacts.geometry(shape_id)
        if shape is None:
            raise _not_found(shape_id)
        return shape

    def _find(
        self, shape_id: str, names: list[str], known: Shape | None = None
    ) -> tuple[str, ShapeState] | None:
        """``(model, state)`` of the first of ``names`` with the shape registered (live, or
        a stored record), else computed with ``names[0]`` from the stored geometry; ``None``
        when the store has no geometry. ``known`` (a re-upload: same content hash) spares
        decoding the stored geometry."""
        live = self._live.get((names[0], shape_id))
        if live is not None:
            self.metrics.cache.labels("state", "hit").inc()
            return names[0], live.state
        stored = self.artifacts.read(
            shape_id, [self._record(n) for n in names], ShapeRecord.from_arrays
        )
        try:
            return self._find_stored(stored, names, known)
        finally:
            if stored.corrupt:  # known only now: the geometry is decoded on demand
                self.metrics.cache.labels("store", "corrupt").inc(stored.corrupt)

    def _find_stored(
        self, stored: Stored[ShapeRecord], names: list[str], known: Shape | None
    ) -> tuple[str, ShapeState] | None:
        shape_id = stored.shape_id
        for name, record in zip(names, stored.artifacts, strict=True):
            live = self._live.get((name, shape_id))
            if live is not None:  # a later candidate is live: registered with it
                self.metrics.cache.labels("state", "hit").inc()
                return name, live.state
            if record is not None and stored.exists:
                state = self._restore(name, stored, record, known)
                if state is not None:
                    self.metrics.cache.labels("state", "miss").inc()
                    self.metrics.cache.labels("store", "hit").inc()
                    return name, state
        self.metrics.cache.labels("state", "miss").inc()
        shape = (known if stored.exists else None) or stored.shape()
        if shape is None:
            self.metrics.cache.labels("store", "miss").inc()
            return None
        # geometry without a (usable) record under the model asked for: compute it now
        self.metrics.cache.labels("store", "recompute").inc()
        name = names[0]
        state = self.predictors[name].register(shape)
        self._write_record(name, state)
        self._remember(name, shape, state)
        return name, state

    def _restore(
        self, model: str, stored: Stored[ShapeRecord], record: ShapeRecord, known: Shape | None
    ) -> ShapeState | None:
        shape = known or stored.shape()
        if shape is None:
            return None
        try:
            state = self.predictors[model].restore(shape, record)
        except LiteGEError as exc:
            log.warning("discarding unusable record of %s (%s): %s", stored.shape_id, model, exc)
            self.artifacts.discard(stored.shape_id, self._record(model))
            return None
        self._remember(model, shape, state)
        return state

    def _write_record(self, model: str, state: ShapeState, *, shape: Shape | None = None) -> None:
        """Write a state's record (and ``shape``'s geometry when given) to the store."""
        if state.record is None:  # pragma: no cover - states from the predictor always carry one
            raise ArtifactError("shape state has no record to store")
        self.artifacts.write(
            state.shape_id,
            {self._record(model): (state.record.to_arrays(), {"model": model})},
            shape=shape,
        )

    # ------------------------------------------------------------------ live LRU

    def _remember(
        self,
        model: str,
        shape: Shape,
        state: ShapeState,
        scores: Mapping[str, float] | None = None,
    ) -> None:
        self._live.put((model, state.shape_id), _Live(shape, state, scores))

    def forget_live(self) -> None:
        """Drop every live state (tests: simulate a restart or an eviction)."""
        self._live.clear()

    # ------------------------------------------------------------------ delete

    def delete(self, shape_id: str) -> bool:
        """Forget a shape: its live states, its geometry and its records under every loaded
        model; ``True`` if anything was there."""
        found = False
        for model in self.predictors:
            found = self._live.pop((model, shape_id)) is not None or found
        records = [self._record(m) for m in self.predictors]
        return self.artifacts.delete(shape_id, records, geometry=True) > 0 or found
