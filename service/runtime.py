"""The service's one object: models, shape repository, store and micro-batcher.

REST (:mod:`service.app`) and gRPC (:mod:`service.grpc_server`) are thin translations onto
this class; it owns no maths (that is :mod:`litege_core`) and no protocol details.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from litege_core.bundle import load_shipped, shipped_bundles
from litege_core.device import resolve_device
from litege_core.errors import ArrayShapeError, LiteGEError
from litege_core.io import SUPPORTED_FORMATS, load_shape
from litege_core.matching.model import MatchingModel
from litege_core.paths import GeodesicPath
from litege_core.predictor import Predictor
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits
from service.batcher import MicroBatcher
from service.errors import TooManyQueriesError, UnknownModelError
from service.matching import MatchingRepository
from service.metrics import ServiceMetrics
from service.repository import Registered, ShapeRepository
from service.settings import Settings
from service.store import ArtifactStore, make_store

log = logging.getLogger("litege.runtime")


@dataclass(frozen=True)
class ShapeInfo:
    """What the API returns about a registered shape."""

    shape_id: str
    kind: str
    n_points: int
    n_faces: int
    model: str
    bundle_hash: str
    ood_score: float
    ood_calibrated: bool
    out_of_distribution: bool | None
    created: bool

    @classmethod
    def of(cls, registered: Registered) -> ShapeInfo:
        state = registered.state
        return cls(
            shape_id=state.shape_id,
            kind=state.kind.value,
            n_points=state.n_points,
            n_faces=0 if state.faces is None else int(state.faces.shape[0]),
            model=registered.model,
            bundle_hash=state.bundle_hash,
            ood_score=float(state.ood_score),
            ood_calibrated=state.ood_calibrated,
            out_of_distribution=state.is_out_of_distribution,
            created=registered.created,
        )


@dataclass(frozen=True)
class PathResult:
    """A traced geodesic path, from source to target.

    Attributes:
        points: ``(L, 3)`` float64 polyline in the user's frame, ``points[0]`` the source.
        length: polyline length (user units).
        predicted_distance: the network's distance between the end points (user units).
        n_steps: accepted gradient steps.
        converged: whether the walk reached the source.
    """

    points: np.ndarray
    length: float
    predicted_distance: float
    n_steps: int
    converged: bool

    @classmethod
    def of(cls, path: GeodesicPath) -> PathResult:
        return cls(
            points=np.ascontiguousarray(np.asarray(path.points)[::-1]),
            length=float(path.length),
            predicted_distance=float(path.predicted_distance),
            n_steps=int(path.n_steps),
            converged=bool(path.converged),
        )


@dataclass(frozen=True)
class Readiness:
    ready: bool
    degraded: bool
    detail: dict[str, Any]


@dataclass(frozen=True)
class _GeodesicJob:
    shape_id: str
    model: str | None
    sources: Any
    targets: Any


@dataclass(frozen=True)
class _PathJob:
    shape_id: str
    model: str | None
    source: Any
    target: Any


@dataclass(frozen=True)
class _CorrespondJob:
    source_id: str
    target_id: str
    model: str
    indices: np.ndarray | None
    points: np.ndarray | None


@dataclass(frozen=True)
class Correspondence:
    """Matches of query points of a source shape on a target shape.

    Attributes:
        source_shape_id, target_shape_id: the two shapes.
        model: the matching model that answered.
        matches: ``(K,)`` int64 matched target vertex / point indices.
        distances: ``(K,)`` float32 predicted cross-shape geodesic at each match, in unit-area
            units (both shapes scaled to unit surface area), not the shapes' input units.
        evaluations: network pair evaluations used.
    """

    source_shape_id: str
    target_shape_id: str
    model: str
    matches: np.ndarray
    distances: np.ndarray
    evaluations: int

    @property
    def n_queries(self) -> int:
        return int(self.matches.shape[0])


def as_query(value: Any, what: str) -> Any:
    """A JSON/proto query (list of ints, list of xyz triples, ``"all"`` / ``None`` for
    targets) as the array the predictor takes; validation of ranges is the predictor's."""
    if value is None or (isinstance(value, str) and value == "all" and what == "targets"):
        return None
    if isinstance(value, str):
        raise ArrayShapeError(f"{what} must be indices, xyz points or (targets) 'all'")
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ArrayShapeError(f"{what} is not a regular array: {exc}") from exc
    if array.size == 0:
        raise ArrayShapeError(f"{what} is empty")
    if array.dtype == object or array.dtype.kind not in "iuf":
        raise ArrayShapeError(f"{what} must be numbers (indices or xyz points)")
    return array


def as_match_queries(value: Any) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Correspondence queries (``"all"`` / ``None``, indices, or xyz points) as
    ``(indices, points)``: ``(None, None)`` for every source point, else one of the two."""
    if value is None or (isinstance(value, str) and value == "all"):
        return None, None
    if isinstance(value, str):
        raise ArrayShapeError("queries must be indices, xyz points or 'all'")
    array = as_query(value, "queries")
    if array.ndim == 1 and array.dtype.kind in "iu":
        return array.astype(np.int64), None
    if array.ndim == 2 and array.shape[1] == 3:
        return None, array.astype(np.float64)
    raise ArrayShapeError(
        f"queries must be (K,) integer indices or (K, 3) xyz points, got shape {array.shape}"
    )


class Runtime:
    """Models, store, repository and batcher of one process (build with :meth:`start`)."""

    def __init__(
        self,
        settings: Settings,
        predictors: dict[str, Predictor],
        store: ArtifactStore,
        metrics: ServiceMetrics,
        matching_models: Mapping[str, MatchingModel] | None = None,
    ) -> None:
        self.settings = settings
        self.metrics = metrics
        self.store = store
        self.limits = ShapeLimits(
            max_vertices=settings.max_vertices,
            max_faces=settings.max_faces,
            max_file_bytes=settings.max_upload_bytes,
        )
        self.repository = ShapeRepository(
            predictors,
            settings.default_model,
            store,
            state_cache_bytes=settings.state_cache_bytes,
            ttl_s=settings.cache_ttl_s,
            metrics=metrics,
            limits=self.limits,
        )
        self.matching = MatchingRepository(
            matching_models or {},
            self.repository,
            store,
            cache_bytes=settings.state_cache_bytes,
            ttl_s=settings.cache_ttl_s,
            metrics=metrics,
        )
        self.device = next(iter(predictors.values())).device
        self.batcher = MicroBatcher(
            {
                "register": self._handle_register,
                "info": self._handle_info,
                "delete": self._handle_delete,
                "geodesic": self._handle_geodesic,
                "path": self._handle_path,
                "correspond": self._handle_correspond,
            },
            max_batch=settings.batch_max_size,
            max_wait_s=settings.batch_max_wait_ms / 1000.0,
            queue_size=settings.queue_size,
            metrics=metrics,
            thread_initializer=self._init_compute_thread,
        )
        self.started_at = time.time()

    # ------------------------------------------------------------------ life cycle

    @classmethod
    async def start(
        cls,
        settings: Settings,
        store: ArtifactStore | None = None,
        matching_model: MatchingModel | None = None,
    ) -> Runtime:
        """Load the models (in a worker thread), connect the store, start the batcher.

        ``matching_model`` replaces the one ``settings.matching_model`` names (tests inject
        :meth:`MatchingModel.tiny_random`). A matching model named explicitly
        (``LITEGE_MATCHING_MODEL``) must load; the default one is skipped with a warning when
        it is not shipped, and correspondence requests then answer unknown-model.
        """
        available = shipped_bundles()
        unknown = [m for m in settings.models if m not in available]
        if unknown:
            raise UnknownModelError(f"models {unknown} are not shipped; available: {available}")
        metrics = ServiceMetrics()
        if settings.torch_threads:
            torch.set_num_threads(settings.torch_threads)
        device = resolve_device(settings.device)

        def load() -> dict[str, Predictor]:
            predictors = {}
            for name in settings.models:
                started = time.perf_counter()
                predictors[name] = Predictor(load_shipped(name), device)
                metrics.model_load_seconds.labels(name).set(time.perf_counter() - started)
            return predictors

        def load_matching() -> dict[str, MatchingModel]:
            if matching_model is not None:
                return {matching_model.name: matching_model}
            name = settings.matching_model
            if name is None:
                return {}
            started = time.perf_counter()
            try:
                model = MatchingModel.load(name, device)
            except LiteGEError as exc:
                if "matching_model" in settings.model_fields_set:
                    raise UnknownModelError(f"matching model {name!r}: {exc}") from exc
                log.warning("correspondence is off: default matching model unavailable: %s", exc)
                return {}
            metrics.model_load_seconds.labels(f"{model.name}-matching").set(
                time.perf_counter() - started
            )
            return {model.name: model}

        predictors = await asyncio.to_thread(load)
        matching = await asyncio.to_thread(load_matching)
        if store is None:
            store = make_store(
                settings.redis_url,
                memory_bytes=settings.memory_cache_bytes,
                hot_bytes=settings.hot_cache_bytes,
                ttl_s=settings.cache_ttl_s,
            )
        runtime = cls(settings, predictors, store, metrics, matching)
        runtime.batcher.start()
        log.info(
            "runtime ready",
            extra={
                "models": list(predictors),
                "matching_models": list(matching),
                "device": str(device),
                "store": store.health(),
            },
        )
        return runtime

    async def close(self) -> None:
        """Drain queued work, then release the store."""
        await self.batcher.close()
        self.store.close()

    def _init_compute_thread(self) -> None:
        if self.settings.torch_threads:
            torch.set_num_threads(self.settings.torch_threads)

    @property
    def model_names(self) -> tuple[str, ...]:
        return tuple(self.repository.predictors)

    def readiness(self) -> Readiness:
        health = self.store.health()
        degraded = health.degraded or not health.available
        self.metrics.store_degraded.set(1.0 if degraded else 0.0)
        return Readiness(
            ready=self.batcher.accepting,
            degraded=degraded,
            detail={
                "models": {
                    name: {
                        "bundle_hash": p.bundle.content_hash,
                        "version": p.bundle.manifest.get("version"),
                        "category": p.bundle.category,
                    }
                    for name, p in self.repository.predictors.items()
                },
                "matching_models": {
                    name: {"bundle_hash": m.content_hash, "category": m.category}
                    for name, m in self.matching.models.items()
                },
                "device": str(self.device),
                "store": {
                    "backend": health.backend,
                    "available": health.available,
                    "degraded": health.degraded,
                    "detail": health.detail,
                },
                "queue_depth": self.batcher.depth,
            },
        )

    # ------------------------------------------------------------------ inputs

    def load_upload(self, data: bytes, file_format: str, kind: str | None = None) -> Shape:
        """Parse and validate an uploaded file within the upload limits."""
        return load_shape(data, file_format=file_format, kind=kind, limits=self.limits)

    def shape_from_arrays(self, vertices: Any, faces: Any = None, kind: str | None = None) -> Shape:
        """Validate JSON/proto arrays within the upload limits."""
        return Shape.from_arrays(vertices, faces, kind=kind, limits=self.limits)

    @staticmethod
    def supported_formats() -> tuple[str, ...]:
        return tuple(sorted(SUPPORTED_FORMATS))

    # ------------------------------------------------------------------ operations

    async def register_shape(self, shape: Shape, model: str | None = None) -> ShapeInfo:
        self.repository.model_name(model)  # unknown model: fail before queueing
        return await self.batcher.submit(
            "register", (shape, model), timeout_s=self.settings.request_timeout_s
        )

    async def shape_info(self, shape_id: str, model: str | None = None) -> ShapeInfo:
        return await self.batcher.submit(
            "info", (shape_id, model), timeout_s=self.settings.request_timeout_s
        )

    async def delete_shape(self, shape_id: str) -> bool:
        return await self.batcher.submit(
            "delete", shape_id, timeout_s=self.settings.request_timeout_s
        )

    async def geodesic(
        self,
        shape_id: str,
        sources: Any,
        targets: Any = None,
        model: str | None = None,
        timeout_s: float | None = None,
    ) -> tuple[ShapeInfo, np.ndarray]:
        """``(S, T)`` float32 distances in the user's units, and the shape's info."""
        job = _GeodesicJob(
            shape_id, model, as_query(sources, "sources"), as_query(targets, "targets")
        )
        return await self.batcher.submit("geodesic", job, timeout_s=self._timeout(timeout_s))

    async def path(
        self,
        shape_id: str,
        source: Any,
        target: Any,
        model: str | None = None,
        timeout_s: float | None = None,
    ) -> PathResult:
        job = _PathJob(
            shape_id, model, _single_point(source, "source"), _single_point(target, "target")
        )
        return await self.batcher.submit("path", job, timeout_s=self._timeout(timeout_s))

    async def correspond(
        self,
        source_shape_id: str,
        target_shape_id: str,
        queries: Any = "all",
        model: str | None = None,
        timeout_s: float | None = None,
    ) -> Correspondence:
        """Match ``queries`` of the source shape (indices, xyz points in its units, or
        ``"all"``) on the target shape; both must be registered."""
        name = self.matching.model_name(model)  # unknown model: fail before queueing
        indices, points = as_match_queries(queries)
        given = indices if indices is not None else points
        if given is not None:
            self._check_match_count(int(given.shape[0]))
        job = _CorrespondJob(source_shape_id, target_shape_id, name, indices, points)
        return await self.batcher.submit("correspond", job, timeout_s=self._timeout(timeout_s))

    def _check_match_count(self, n_queries: int) -> None:
        if n_queries > self.settings.max_queries:
            raise TooManyQueriesError(
                f"{n_queries} correspondence queries exceed the limit of "
                f"{self.settings.max_queries} per request"
            )

    def _timeout(self, timeout_s: float | None) -> float:
        limit = self.settings.request_timeout_s
        return limit if timeout_s is None else min(limit, max(timeout_s, 0.0))

    # ------------------------------------------------------------------ batch handlers
    # (run on the compute thread; one result or exception per job)

    def _handle_register(self, jobs: list[tuple[Shape, str | None]]) -> list[Any]:
        by_model: dict[str | None, list[int]] = {}
        for i, (_, model) in enumerate(jobs):
            by_model.setdefault(model, []).append(i)
        results: list[Any] = [None] * len(jobs)
        for model, positions in by_model.items():
            shapes = [jobs[i][0] for i in positions]
            try:
                registered = self.repository.register_many(shapes, model)
                for i, r in zip(positions, registered, strict=True):
                    results[i] = ShapeInfo.of(r)
            except LiteGEError:
                for i in positions:  # isolate the failing shape
                    results[i] = _capture(
                        lambda i=i: ShapeInfo.of(
                            self.repository.register_many([jobs[i][0]], jobs[i][1])[0]
                        )
                    )
        return results

    def _handle_info(self, jobs: list[tuple[str, str | None]]) -> list[Any]:
        return [_capture(lambda j=j: ShapeInfo.of(self.repository.get(*j))) for j in jobs]

    def _handle_delete(self, jobs: list[str]) -> list[Any]:
        return [_capture(lambda j=j: self._delete(j)) for j in jobs]

    def _delete(self, shape_id: str) -> bool:
        prepared = self.matching.delete(shape_id)
        return self.repository.delete(shape_id) or prepared

    def _handle_correspond(self, jobs: list[_CorrespondJob]) -> list[Any]:
        return [_capture(lambda j=j: self._correspond(j)) for j in jobs]

    def _correspond(self, job: _CorrespondJob) -> Correspondence:
        source = self.matching.get(job.source_id, job.model)
        target = self.matching.get(job.target_id, job.model)
        if job.indices is None and job.points is None:
            self._check_match_count(source.n_points)
        result = self.matching.models[job.model].match(
            source, target, job.indices, query_points=job.points
        )
        self.metrics.correspond_batches.labels(job.model).inc()
        return Correspondence(
            job.source_id,
            job.target_id,
            job.model,
            result.indices,
            result.distance,
            result.evaluations,
        )

    def _handle_geodesic(self, jobs: list[_GeodesicJob]) -> list[Any]:
        results: list[Any] = [None] * len(jobs)
        ready: dict[str, list[tuple[int, Registered]]] = {}
        for i, job in enumerate(jobs):
            try:
                registered = self.repository.get(job.shape_id, job.model)
                self._check_query_count(job, registered.state.n_points)
                ready.setdefault(registered.model, []).append((i, registered))
            except LiteGEError as exc:
                results[i] = exc
        for model, items in ready.items():
            predictor = self.repository.predictors[model]
            states = [r.state for _, r in items]
            sources = [jobs[i].sources for i, _ in items]
            targets = [jobs[i].targets for i, _ in items]
            try:
                outputs = predictor.distances_many(states, sources, targets)
            except LiteGEError:
                outputs = [  # one bad query must not fail its batch neighbours
                    _capture(lambda s=s, a=a, b=b, p=predictor: p.distances(s, a, b))
                    for s, a, b in zip(states, sources, targets, strict=True)
                ]
            for (i, registered), out in zip(items, outputs, strict=True):
                results[i] = out if isinstance(out, Exception) else (ShapeInfo.of(registered), out)
        return results

    def _check_query_count(self, job: _GeodesicJob, n_points: int) -> None:
        n_sources = _count(job.sources)
        n_targets = n_points if job.targets is None else _count(job.targets)
        if n_sources * n_targets > self.settings.max_queries:
            raise TooManyQueriesError(
                f"{n_sources} sources × {n_targets} targets = {n_sources * n_targets} pairs "
                f"exceeds the limit of {self.settings.max_queries} per request"
            )

    def _handle_path(self, jobs: list[_PathJob]) -> list[Any]:
        results: list[Any] = [None] * len(jobs)
        groups: dict[tuple[str, str], list[int]] = {}
        found: dict[tuple[str, str], Registered] = {}
        for i, job in enumerate(jobs):
            try:
                registered = self.repository.get(job.shape_id, job.model)
            except LiteGEError as exc:
                results[i] = exc
                continue
            key = (registered.model, job.shape_id)
            found[key] = registered
            groups.setdefault(key, []).append(i)
        for key, positions in groups.items():
            registered = found[key]
            predictor = self.repository.predictors[registered.model]
            sources = [jobs[i].source for i in positions]
            targets = [jobs[i].target for i in positions]
            if _same_query_kind(sources) and _same_query_kind(targets):
                try:
                    paths = predictor.paths(
                        registered.state,
                        np.stack(sources),
                        np.stack(targets),
                    )
                    for i, path in zip(positions, paths, strict=True):
                        results[i] = PathResult.of(path)
                    continue
                except LiteGEError:
                    pass
            for i in positions:
                results[i] = _capture(
                    lambda i=i, r=registered, p=predictor: PathResult.of(
                        p.path(r.state, jobs[i].source, jobs[i].target)
                    )
                )
        return results


def _capture(call: Any) -> Any:
    try:
        return call()
    except LiteGEError as exc:
        return exc


def _count(query: np.ndarray) -> int:
    return int(query.shape[0]) if query.ndim >= 1 else 1


def _single_point(value: Any, what: str) -> np.ndarray:
    """One vertex index (0-d int array) or one xyz point ``(3,)`` float64."""
    array = as_query(value, what)
    if array is None:
        raise ArrayShapeError(f"{what} is required")
    if array.ndim == 0 and array.dtype.kind in "iu":
        return array.astype(np.int64)
    if array.shape == (3,):
        return array.astype(np.float64)
    raise ArrayShapeError(f"{what} must be one vertex index or one [x, y, z] point")


def _same_query_kind(queries: Sequence[np.ndarray]) -> bool:
    """Whether the queries can be stacked into one batch (all indices, or all points)."""
    return all(q.ndim == 0 for q in queries) or all(q.shape == (3,) for q in queries)
