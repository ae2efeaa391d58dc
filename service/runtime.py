"""The service's one object: models, shape repository, store, solvers and micro-batcher.

REST (:mod:`service.app`) and gRPC (:mod:`service.grpc_server`) are thin translations onto
this class; it owns no maths (that is :mod:`litege_core`) and no protocol details.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import replace
from typing import Any, TypeVar

import numpy as np
import torch

from litege_core.device import resolve_device
from litege_core.errors import LiteGEError, MethodNotApplicableError, ShapeTooLargeError
from litege_core.io import SUPPORTED_FORMATS, load_shape
from litege_core.learned import Predictor, load_shipped, shipped_bundles
from litege_core.learned.router import CategoryRouter, first_of_each_category, load_router
from litege_core.matching.model import MatchingModel
from litege_core.matching.refine import REFINE_METHODS
from litege_core.query import PointQuery, QueryLike, parse_query
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits
from service.admission import Admission, Deadline
from service.answers import (
    LEARNED,
    NO_REFINEMENT,
    Correspondence,
    FrameInfo,
    GeodesicAnswer,
    PathResult,
    Readiness,
    ShapeInfo,
)
from service.batcher import CancelToken, MicroBatcher
from service.classical import METHODS, SolverCache
from service.errors import (
    DeadlineExceededError,
    OutOfMemoryError,
    PayloadTooLargeError,
    RequestError,
    TooManyQueriesError,
    UnknownModelError,
)
from service.jobs import (
    ClassicalGeodesicJob,
    ClassicalPathJob,
    CorrespondJob,
    GeodesicJob,
    PathJob,
    PrepareJob,
    Split,
)
from service.matching import MatchingRepository
from service.metrics import ServiceMetrics
from service.repository import Registered, ShapeRepository
from service.settings import AUTO_MODEL, Settings
from service.store import ArtifactStore, make_store

log = logging.getLogger("litege.runtime")

T = TypeVar("T")

CORRESPOND_CHUNK_QUERIES = 512
"""Correspondence queries per compute job: a large request runs as several jobs, so that other
requests interleave with it and a timed-out or cancelled one stops after the current chunk.
A refined request (``refine`` other than ``"none"``) runs in the same chunks: its first chunk
computes the refined map of the pair (seconds), which the library keeps on the prepared source
shape, and every later chunk (and stream batch) maps its queries through that map."""
GEODESIC_CHUNK_PAIRS = 1 << 18
"""Most source × target pairs per geodesic compute job (larger requests run in row blocks)."""
INLINE_PARSE_VALUES = 4096
"""Query values parsed on the event loop up to this many top-level items; more in a thread."""
CLASSICAL_CHUNK_SOURCES = {"exact": 4, "heat": 64, "graph": 256}
"""Most sources per classical geodesic compute job (one solve each: exact ~0.1-1 s, heat and
graph ~1 ms at 5K-20K vertices), so that other requests interleave with a large one."""


def is_out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` says the device or the host ran out of memory (CUDA's
    ``OutOfMemoryError``, a ``RuntimeError`` saying "out of memory", or ``MemoryError``)."""
    if isinstance(exc, torch.cuda.OutOfMemoryError | MemoryError):
        return True
    return isinstance(exc, RuntimeError) and "out of memory" in str(exc).lower()


def _parse(value: QueryLike, what: str, **options: Any) -> PointQuery:
    """:func:`parse_query`, with a query too large for memory reported as one (413)."""
    try:
        return parse_query(value, what, **options)
    except MemoryError:
        raise PayloadTooLargeError(f"{what} are too large to hold in memory") from None


def _is_small(value: Any) -> bool:
    """Whether parsing ``value`` is cheap enough for the event loop."""
    if isinstance(value, np.ndarray):
        return value.size <= INLINE_PARSE_VALUES
    if isinstance(value, list | tuple):
        return len(value) <= INLINE_PARSE_VALUES // 3
    return True


def _blocks(query: PointQuery, size: int) -> Iterator[PointQuery]:
    """``query`` (indices or points, not "all") in consecutive blocks of ``size``."""
    if query.indices is not None:
        for start in range(0, query.indices.shape[0], size):
            yield PointQuery(indices=query.indices[start : start + size])
    elif query.points is not None:
        for start in range(0, query.points.shape[0], size):
            yield PointQuery(points=query.points[start : start + size])
    else:
        raise ValueError("an 'all' query has no blocks before the shape is known")


def _load_router(setting: str) -> CategoryRouter | None:
    """The category router a ``router`` setting names (``shipped``: ``None`` if the package
    ships none; ``none``; or a directory, which must hold one)."""
    if setting == "none":
        return None
    try:
        return load_router(None if setting == "shipped" else setting)
    except LiteGEError as exc:
        raise UnknownModelError(f"router {setting!r}: {exc}") from exc


class Runtime:
    """Models, store, repository and batcher of one process (build with :meth:`start`)."""

    def __init__(
        self,
        settings: Settings,
        predictors: dict[str, Predictor],
        store: ArtifactStore,
        metrics: ServiceMetrics,
        matching_models: Mapping[str, MatchingModel] | None = None,
        router: CategoryRouter | None = None,
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
            router=router,
        )
        self.matching = MatchingRepository(
            matching_models or {},
            self.repository,
            cache_bytes=settings.matching_cache_bytes,
            metrics=metrics,
        )
        self.solvers = SolverCache(
            self.repository,
            cache_bytes=settings.solver_cache_bytes,
            max_exact_vertices=settings.max_exact_vertices,
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
                "classical_geodesic": self._handle_classical_geodesic,
                "classical_path": self._handle_classical_path,
                "prepare_pair": self._handle_prepare,
                "correspond": self._handle_correspond,
            },
            max_batch=settings.batch_max_size,
            max_wait_s=settings.batch_max_wait_ms / 1000.0,
            queue_size=settings.queue_size,
            metrics=metrics,
            thread_initializer=self._init_compute_thread,
        )
        self.admission = Admission(settings.max_concurrency, metrics, self.batcher.retry_after_s)
        self.correspond_chunk = CORRESPOND_CHUNK_QUERIES
        self.geodesic_chunk_pairs = GEODESIC_CHUNK_PAIRS
        self.classical_chunk_sources = dict(CLASSICAL_CHUNK_SOURCES)
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

        ``matching_model`` replaces the ones ``settings.matching_model`` names (tests inject
        :meth:`MatchingModel.tiny_random`). Matching models named explicitly
        (``LITEGE_MATCHING_MODEL``) must load; a default one that is not shipped is skipped
        with a warning (requests for it then answer unknown-model).
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
                bundle = load_shipped(name)
                predictors[name] = Predictor(
                    bundle,
                    device,
                    head=settings.geodesic_head,
                    precision=settings.geodesic_precision,
                    embed_precision=settings.geodesic_precision,
                    descriptor_lattice=settings.descriptor_lattice,
                    fusion=settings.geodesic_fusion,
                )
                metrics.model_load_seconds.labels(name).set(time.perf_counter() - started)
            return predictors

        def load_matching() -> dict[str, MatchingModel]:
            if matching_model is not None:
                return {matching_model.name: matching_model}
            loaded: dict[str, MatchingModel] = {}
            for name in settings.matching_model:
                started = time.perf_counter()
                try:
                    model = MatchingModel.load(name, device, settings.matching_precision)
                except LiteGEError as exc:
                    if "matching_model" in settings.model_fields_set:
                        raise UnknownModelError(f"matching model {name!r}: {exc}") from exc
                    log.warning("matching model %s is unavailable and skipped: %s", name, exc)
                    continue
                metrics.model_load_seconds.labels(f"{model.name}-matching").set(
                    time.perf_counter() - started
                )
                loaded[model.name] = model
            return loaded

        predictors = await asyncio.to_thread(load)
        matching = await asyncio.to_thread(load_matching)
        router = await asyncio.to_thread(_load_router, settings.router)
        if store is None:
            store = make_store(
                settings.redis_url,
                memory_bytes=settings.memory_cache_bytes,
                hot_bytes=settings.hot_cache_bytes,
                ttl_s=settings.cache_ttl_s,
                write_behind_bytes=settings.write_behind_bytes,
            )
        runtime = cls(settings, predictors, store, metrics, matching, router)
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

    async def close(self, timeout_s: float | None = None) -> None:
        """Drain queued work (for at most ``timeout_s``), then release the store."""
        await self.batcher.close(timeout_s)
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
                        "fusion": "none" if p.fusion is None else "graph",
                        "head": p.head,
                        "lattice": p.descriptor_lattice,
                        "precision": p.precision,
                        "embed_precision": p.embed_precision,
                    }
                    for name, p in self.repository.predictors.items()
                },
                "matching_models": {
                    name: {
                        "bundle_hash": m.content_hash,
                        "category": m.category,
                        "precision": m.precision,
                    }
                    for name, m in self.matching.models.items()
                },
                "router": None
                if (router := self.repository.router) is None
                else {
                    "categories": list(router.categories),
                    "min_probability": router.min_probability,
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
    # (parsing runs in a worker thread: callers use asyncio.to_thread / parse_upload)

    def load_upload(self, data: bytes, file_format: str, kind: str | None = None) -> Shape:
        """Parse and validate an uploaded file within the upload limits.

        Raises:
            ShapeTooLargeError: the file declares more than memory can hold.
        """
        try:
            return load_shape(data, file_format=file_format, kind=kind, limits=self.limits)
        except MemoryError:
            raise ShapeTooLargeError(
                "the file declares arrays too large to hold in memory"
            ) from None

    def shape_from_arrays(self, vertices: Any, faces: Any = None, kind: str | None = None) -> Shape:
        """Validate JSON/proto arrays within the upload limits."""
        try:
            return Shape.from_arrays(vertices, faces, kind=kind, limits=self.limits)
        except MemoryError:
            raise ShapeTooLargeError("the arrays are too large to hold in memory") from None

    async def parse_upload(self, parse: Callable[..., T], *args: Any) -> T:
        """Run an upload parser (:meth:`load_upload`, :meth:`shape_from_arrays`, or a
        protocol's own decoding around them) in a worker thread, off the event loop."""
        try:
            return await asyncio.to_thread(parse, *args)
        except MemoryError:
            raise PayloadTooLargeError("the upload is too large to hold in memory") from None

    async def parse_query(self, value: QueryLike, what: str, **options: Any) -> PointQuery:
        """:func:`litege_core.query.parse_query` (the one rule for every protocol), in a
        worker thread unless ``value`` is small."""
        if _is_small(value):
            return _parse(value, what, **options)
        return await asyncio.to_thread(_parse, value, what, **options)

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
        sources: QueryLike,
        targets: QueryLike = None,
        model: str | None = None,
        timeout_s: float | None = None,
        method: str | None = None,
    ) -> tuple[GeodesicAnswer, np.ndarray]:
        """``(S, T)`` float32 distances in the user's units, and who answered.

        ``sources``: indices or xyz points; ``targets``: the same or ``None`` / ``"all"``
        (raw values or :class:`PointQuery`). ``method``: ``learned`` (default; ``model``
        picks the bundle), ``heat``, ``exact`` or ``graph`` (``model`` is then only checked).
        A request of more than ``geodesic_chunk_pairs`` pairs (classical: more sources than
        ``classical_chunk_sources[method]``) runs as row blocks, one compute job each.

        Raises:
            RequestError: an unknown method.
            TooManyQueriesError: more pairs than ``max_queries``, or ``exact`` with more
                sources than ``max_exact_sources``.
        """
        method = self.method_name(method)
        if method != LEARNED and model is not None:
            self.repository.model_name(model)  # an unknown model is refused all the same
        src = await self.parse_query(sources, "sources", allow_all=False)
        dst = await self.parse_query(targets, "targets")
        if method == "exact":
            self._check_exact_sources(src.count(0))
        deadline = Deadline(self._timeout(timeout_s))
        with _cancel_on_exit() as token:
            if method != LEARNED:
                return await self._classical_geodesic(shape_id, method, src, dst, deadline, token)
            job = GeodesicJob(shape_id, model, src, dst, token, self.geodesic_chunk_pairs)
            answer = await self._submit("geodesic", job, deadline, token)
            if not isinstance(answer, Split):
                info, distances = answer
                return GeodesicAnswer(shape_id, LEARNED, LEARNED, info), distances
            rows = max(1, self.geodesic_chunk_pairs // max(1, answer.n_targets))
            found, blocks = None, []
            for block in _blocks(src, rows):
                part = replace(job, sources=block, max_pairs=None)
                found, distances = await self._submit("geodesic", part, deadline, token)
                blocks.append(distances)
            assert found is not None
            return GeodesicAnswer(shape_id, LEARNED, LEARNED, found), np.concatenate(blocks)

    async def _classical_geodesic(
        self,
        shape_id: str,
        method: str,
        src: PointQuery,
        dst: PointQuery,
        deadline: Deadline,
        token: CancelToken,
    ) -> tuple[GeodesicAnswer, np.ndarray]:
        max_rows = self.classical_chunk_sources[method]
        job = ClassicalGeodesicJob(
            shape_id, method, src, dst, token, max_rows, self.geodesic_chunk_pairs
        )
        answer = await self._submit("classical_geodesic", job, deadline, token)
        if not isinstance(answer, Split):
            engine, distances = answer
            return GeodesicAnswer(shape_id, method, engine), distances
        rows = max(1, min(max_rows, self.geodesic_chunk_pairs // max(1, answer.n_targets)))
        engine, blocks = "", []
        for block in _blocks(src, rows):
            part = replace(job, sources=block, max_rows=None, max_pairs=None)
            engine, distances = await self._submit("classical_geodesic", part, deadline, token)
            blocks.append(distances)
        return GeodesicAnswer(shape_id, method, engine), np.concatenate(blocks)

    async def path(
        self,
        shape_id: str,
        source: QueryLike,
        target: QueryLike,
        model: str | None = None,
        timeout_s: float | None = None,
        method: str | None = None,
    ) -> PathResult:
        """The path from ``source`` to ``target`` (one index or one xyz point each) by
        ``method`` (see :meth:`geodesic`; ``exact`` on a mesh: the exact geodesic)."""
        method = self.method_name(method)
        if method != LEARNED and model is not None:
            self.repository.model_name(model)
        src = await self.parse_query(source, "source", allow_all=False, single=True)
        dst = await self.parse_query(target, "target", allow_all=False, single=True)
        timeout = self._timeout(timeout_s)
        if method == LEARNED:
            job = PathJob(shape_id, model, src, dst)
            return await self.batcher.submit("path", job, timeout_s=timeout)
        with _cancel_on_exit() as token:
            classical = ClassicalPathJob(shape_id, method, src, dst, token)
            return await self.batcher.submit(
                "classical_path", classical, timeout_s=timeout, token=token
            )

    async def correspond(
        self,
        source_shape_id: str,
        target_shape_id: str,
        queries: QueryLike = "all",
        model: str | None = None,
        timeout_s: float | None = None,
        refine: str | None = None,
    ) -> Correspondence:
        """Match ``queries`` of the source shape (indices, xyz points in its units, or
        ``"all"``) on the target shape; both must be registered. ``model`` ``None``: the
        matching model of the source shape's category (:meth:`_matching_model_of`: the
        category router's where it is confident, else its ``auto`` geodesic model's), else the
        first loaded.

        The queries run in chunks of ``correspond_chunk``, one compute job each, so other
        requests interleave with a large one; a request that times out or is cancelled stops
        before its next chunk. ``refine`` (``None`` → ``"none"``; one of the library's
        ``REFINE_METHODS``) refines the matches of two meshes
        (:meth:`~litege_core.matching.model.MatchingModel.match`); the pair's refined map is
        computed by the first chunk and reused by the others (see
        :data:`CORRESPOND_CHUNK_QUERIES`).

        Raises:
            RequestError: ``refine`` is not one of ``REFINE_METHODS``.
            MethodNotApplicableError: a refinement with a point cloud (from the job).
            MissingDependencyError: a refinement without pyFM (from the job).
        """
        if model is None and len(self.matching.models) > 1:
            name = await asyncio.to_thread(self._matching_model_of, source_shape_id)
        else:
            name = self.matching.model_name(model)  # unknown model: fail before queueing
        refine = self.refine_name(refine)
        query = await self.parse_query(queries, "queries")
        if not query.is_all:
            self._check_match_count(query.count(0))
        deadline = Deadline(self._timeout(timeout_s))
        with _cancel_on_exit() as token:
            if query.is_all:
                prepare = PrepareJob(source_shape_id, target_shape_id, name, token)
                n_points = await self._submit("prepare_pair", prepare, deadline, token)
                self._check_match_count(n_points)
                query = PointQuery(indices=np.arange(n_points, dtype=np.int64))
            parts: list[Correspondence] = []
            for block in _blocks(query, self.correspond_chunk):
                job = CorrespondJob(
                    source_shape_id, target_shape_id, name, block, token, refine=refine
                )
                parts.append(await self._submit("correspond", job, deadline, token))
        return Correspondence(
            source_shape_id,
            target_shape_id,
            name,
            np.concatenate([p.matches for p in parts]),
            np.concatenate([p.distances for p in parts]),
            np.concatenate([p.distances_unit_area for p in parts]),
            sum(p.evaluations for p in parts),
            refinement=parts[0].refinement,
            source_frame=parts[0].source_frame,
            target_frame=parts[0].target_frame,
        )

    def _matching_model_of(self, source_shape_id: str) -> str:
        """The matching model of a request naming none: the (first) matching model of the
        source shape's category, that category being the router's where it is loaded and
        confident, else that of the geodesic model ``auto`` registers the shape with (the
        lowest OOD score weighed with agreement, as a registration chooses: a shape registered
        as a human is matched as one) where several are loaded; else the default one.
        Thread-safe (the shape's geometry, the router's forward pass, the repository).

        Raises:
            ShapeNotFoundError: the source shape is not registered.
        """
        by_category = first_of_each_category(
            {name: matching.category for name, matching in self.matching.models.items()}
        )
        if self.repository.router is not None:
            shape = self.repository.shape(source_shape_id)
            routed = self.repository.router.route([shape], by_category)[0]
            if routed:
                return routed
        if len(self.repository.predictors) > 1:
            chosen = self.repository.get(source_shape_id, AUTO_MODEL).model
            category = self.repository.predictors[chosen].bundle.category
            if category in by_category:
                return by_category[category]
        return self.matching.model_name(None)

    async def _submit(self, kind: str, job: Any, deadline: Deadline, token: CancelToken) -> Any:
        return await self.batcher.submit(kind, job, timeout_s=deadline.remaining(), token=token)

    @staticmethod
    def method_name(method: str | None) -> str:
        """``method`` checked (``None`` → ``learned``).

        Raises:
            RequestError: not one of :data:`service.classical.METHODS`.
        """
        name = LEARNED if method is None else method
        if name not in METHODS:
            raise RequestError(f"unknown method {name!r}; expected one of {list(METHODS)}")
        return name

    @staticmethod
    def refine_name(refine: str | None) -> str:
        """``refine`` checked (``None`` → ``"none"``).

        Raises:
            RequestError: not one of the library's ``REFINE_METHODS``.
        """
        name = NO_REFINEMENT if refine is None else refine
        if name not in REFINE_METHODS:
            raise RequestError(f"unknown refine {name!r}; expected one of {list(REFINE_METHODS)}")
        return name

    def _check_exact_sources(self, n_sources: int) -> None:
        limit = self.settings.max_exact_sources
        if n_sources > limit:
            raise TooManyQueriesError(
                f"method 'exact' takes at most {limit} sources per request (one exact solve "
                f"each; LITEGE_MAX_EXACT_SOURCES) and this one has {n_sources}: send fewer, "
                "or use method 'heat', 'graph' or 'learned'"
            )

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
    # (run on the compute thread; one result or exception per job: a job's failure, a device
    # out of memory included, is its own and never its batch neighbours')

    def _handle_register(self, jobs: list[tuple[Shape, str | None]]) -> list[Any]:
        by_model: dict[str | None, list[int]] = {}
        for i, (_, model) in enumerate(jobs):
            by_model.setdefault(model, []).append(i)
        results: list[Any] = [None] * len(jobs)
        for model, positions in by_model.items():
            shapes = [jobs[i][0] for i in positions]
            outcomes = self._batched(
                functools.partial(self._register, shapes, model),
                [functools.partial(self._register_one, *jobs[i]) for i in positions],
            )
            for i, outcome in zip(positions, outcomes, strict=True):
                results[i] = outcome
        return results

    def _register(self, shapes: list[Shape], model: str | None) -> list[ShapeInfo]:
        return [ShapeInfo.of(r) for r in self.repository.register_many(shapes, model)]

    def _register_one(self, shape: Shape, model: str | None) -> ShapeInfo:
        return ShapeInfo.of(self.repository.register_many([shape], model)[0])

    def _handle_info(self, jobs: list[tuple[str, str | None]]) -> list[Any]:
        return [self._capture(functools.partial(self._info, *j)) for j in jobs]

    def _info(self, shape_id: str, model: str | None) -> ShapeInfo:
        return ShapeInfo.of(self.repository.get(shape_id, model))

    def _handle_delete(self, jobs: list[str]) -> list[Any]:
        return [self._capture(functools.partial(self._delete, j)) for j in jobs]

    def _delete(self, shape_id: str) -> bool:
        prepared = self.matching.delete(shape_id)
        solvers = self.solvers.delete(shape_id)
        return self.repository.delete(shape_id) or prepared or solvers

    def _handle_prepare(self, jobs: list[PrepareJob]) -> list[Any]:
        return [self._capture(functools.partial(self._prepare, j), token=j.token) for j in jobs]

    def _prepare(self, job: PrepareJob) -> int:
        source = self.matching.get(job.source_id, job.model)
        self.matching.get(job.target_id, job.model)
        return source.n_points

    def _handle_correspond(self, jobs: list[CorrespondJob]) -> list[Any]:
        return [self._capture(functools.partial(self._correspond, j), token=j.token) for j in jobs]

    def _correspond(self, job: CorrespondJob) -> Correspondence:
        source = self.matching.get(job.source_id, job.model)
        target = self.matching.get(job.target_id, job.model)
        if job.refine != NO_REFINEMENT:
            for role, shape_id, prepared in (
                ("source", job.source_id, source),
                ("target", job.target_id, target),
            ):
                if prepared.faces is None:
                    raise MethodNotApplicableError(
                        f"refine={job.refine!r} needs two meshes; the {role} shape {shape_id} "
                        "is a point cloud (use refine 'none')"
                    )
        result = self.matching.models[job.model].match(
            source, target, job.queries, refine=job.refine
        )
        self.metrics.correspond_batches.labels(job.model).inc()
        unit_area = np.asarray(result.distance, dtype=np.float32)
        in_target_units = target.transform.unscale_distance(unit_area.astype(np.float64))
        return Correspondence(
            job.source_id,
            job.target_id,
            job.model,
            result.indices,
            np.asarray(in_target_units, dtype=np.float32),
            unit_area,
            result.evaluations,
            refinement=result.refinement,
            source_frame=FrameInfo(source.frame, source.frame_check),
            target_frame=FrameInfo(target.frame, target.frame_check),
        )

    def _handle_geodesic(self, jobs: list[GeodesicJob]) -> list[Any]:
        results: list[Any] = [None] * len(jobs)
        ready: dict[str, list[tuple[int, Registered]]] = {}
        for i, job in enumerate(jobs):
            if job.token.cancelled:
                results[i] = _given_up()
                continue
            try:
                registered = self.repository.get(job.shape_id, job.model)
                n_targets = job.targets.count(registered.state.n_points)
                self._check_query_count(job.sources.count(0), n_targets)
            except LiteGEError as exc:
                results[i] = exc
                continue
            if job.max_pairs is not None and job.sources.count(0) * n_targets > job.max_pairs:
                results[i] = Split(n_targets)
                continue
            ready.setdefault(registered.model, []).append((i, registered))
        for model, items in ready.items():
            predictor = self.repository.predictors[model]
            states = [r.state for _, r in items]
            sources = [jobs[i].sources for i, _ in items]
            targets = [jobs[i].targets for i, _ in items]
            outputs = self._batched(
                functools.partial(predictor.distances_many, states, sources, targets),
                [
                    functools.partial(predictor.distances, s, a, b)
                    for s, a, b in zip(states, sources, targets, strict=True)
                ],
            )
            for (i, registered), out in zip(items, outputs, strict=True):
                results[i] = out if isinstance(out, Exception) else (ShapeInfo.of(registered), out)
        return results

    def _check_query_count(self, n_sources: int, n_targets: int) -> None:
        if n_sources * n_targets > self.settings.max_queries:
            raise TooManyQueriesError(
                f"{n_sources} sources × {n_targets} targets = {n_sources * n_targets} pairs "
                f"exceeds the limit of {self.settings.max_queries} per request"
            )

    def _handle_path(self, jobs: list[PathJob]) -> list[Any]:
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
            sources = _stacked([jobs[i].source for i in positions])
            targets = _stacked([jobs[i].target for i in positions])
            singles = [
                functools.partial(self._path, predictor, registered, jobs[i].source, jobs[i].target)
                for i in positions
            ]
            if sources is None or targets is None:  # indices and points mixed: one by one
                outcomes = [self._capture(call) for call in singles]
            else:
                outcomes = self._batched(
                    functools.partial(self._paths, predictor, registered, sources, targets),
                    singles,
                )
            for i, outcome in zip(positions, outcomes, strict=True):
                results[i] = outcome
        return results

    # The queries are PointQuery objects: Predictor.path/paths pass them to parse_query, which
    # takes any QueryLike (their `int | ArrayLike` annotations are narrower than that).
    @staticmethod
    def _path(
        predictor: Predictor, registered: Registered, source: QueryLike, target: QueryLike
    ) -> PathResult:
        state = registered.state
        distance = float(predictor.distances(state, source, target)[0, 0])
        return PathResult.of(predictor.path(state, source, target), registered.model, distance)

    @staticmethod
    def _paths(
        predictor: Predictor, registered: Registered, sources: QueryLike, targets: QueryLike
    ) -> list[PathResult]:
        state = registered.state
        paths = predictor.paths(state, sources, targets)
        distances = np.diagonal(predictor.distances(state, sources, targets))  # as /geodesic
        return [
            PathResult.of(path, registered.model, float(distance))
            for path, distance in zip(paths, distances, strict=True)
        ]

    def _handle_classical_geodesic(self, jobs: list[ClassicalGeodesicJob]) -> list[Any]:
        return [
            self._capture(functools.partial(self._classical_distances, j), token=j.token)
            for j in jobs
        ]

    def _classical_distances(self, job: ClassicalGeodesicJob) -> tuple[str, np.ndarray] | Split:
        solver = self.solvers.get(job.shape_id, job.method)
        n_sources = job.sources.count(0)
        n_targets = job.targets.count(solver.shape.n_points)
        self._check_query_count(n_sources, n_targets)
        if job.max_rows is not None and (
            n_sources > job.max_rows
            or (job.max_pairs is not None and n_sources * n_targets > job.max_pairs)
        ):
            return Split(n_targets)
        return solver.engine, solver.distances(job.sources, job.targets)

    def _handle_classical_path(self, jobs: list[ClassicalPathJob]) -> list[Any]:
        return [
            self._capture(functools.partial(self._classical_path, j), token=j.token) for j in jobs
        ]

    def _classical_path(self, job: ClassicalPathJob) -> PathResult:
        solver = self.solvers.get(job.shape_id, job.method)
        return PathResult.of_classical(solver.path(job.source, job.target), job.method)

    # ------------------------------------------------------------------ failure isolation

    def _batched(
        self, call_all: Callable[[], Sequence[Any]], calls: Sequence[Callable[[], Any]]
    ) -> list[Any]:
        """``call_all()`` (one result per job); when it raises (one bad job, a device out of
        memory), each job alone, so that only the jobs that fail by themselves fail."""
        try:
            results = list(call_all())
        except Exception as exc:
            if len(calls) == 1:
                return [self._failure(exc)]
            if is_out_of_memory(exc):
                _free_device_memory()
            log.info("a batch of %d jobs failed (%s); retrying them one by one", len(calls), exc)
            return [self._capture(call) for call in calls]
        if len(results) != len(calls):
            raise RuntimeError(f"a batched call gave {len(results)} results for {len(calls)}")
        return results

    def _capture(self, call: Callable[[], Any], token: CancelToken | None = None) -> Any:
        """``call()``, or the exception it raised (as its job's answer)."""
        if token is not None and token.cancelled:
            return _given_up()
        try:
            return call()
        except Exception as exc:
            return self._failure(exc)

    def _failure(self, exc: Exception) -> Exception:
        """What a job that raised ``exc`` answers: an out-of-memory becomes a retry-later
        problem (503 / RESOURCE_EXHAUSTED); anything else as it is."""
        if not is_out_of_memory(exc):
            return exc
        _free_device_memory()
        log.warning("out of memory in a compute job: %s", exc)
        error = OutOfMemoryError(
            f"the {self.device} device ran out of memory for this request; retry later or "
            "send fewer queries",
            retry_after_s=self.batcher.retry_after_s(),
        )
        error.__cause__ = exc
        return error


@contextlib.contextmanager
def _cancel_on_exit() -> Iterator[CancelToken]:
    """A token for one request's compute jobs, cancelled when the request ends without its
    answer (deadline, client gone, error), so queued jobs of it are skipped."""
    token = CancelToken()
    try:
        yield token
    except BaseException:
        token.cancel()
        raise


def _given_up() -> DeadlineExceededError:
    return DeadlineExceededError("the request ended (deadline or cancellation) before this job ran")


def _free_device_memory() -> None:
    if torch.cuda.is_available():
        torch.cuda.empty_cache()


def _stacked(queries: Sequence[PointQuery]) -> PointQuery | None:
    """Single-point queries as one query (all indices, or all points); ``None`` if mixed."""
    if all(q.indices is not None for q in queries):
        return PointQuery(indices=np.concatenate([q.indices for q in queries]))
    if all(q.points is not None for q in queries):
        return PointQuery(points=np.concatenate([q.points for q in queries]))
    return None
