"""The gRPC API (``litege.v1.LiteGE``, see ``proto/litege.proto``): a thin translation onto
:class:`service.runtime.Runtime`, served with ``grpc.aio`` next to the standard health service
and server reflection.

Every LiteGE RPC goes through one wrapper that checks the API key (metadata ``x-api-key``, when
the settings have one), takes a slot of the concurrency limit shared with REST
(:class:`service.admission.Admission`: RESOURCE_EXHAUSTED when full), records metrics, and maps
errors: a :class:`~litege_core.errors.LiteGEError` aborts with the status code of
:func:`service.problems.problem_for` and its message, with trailing metadata
``litege-problem-type`` (the RFC 9457 type URI) and, for a retry-later problem (overload, out
of memory), ``retry-after-ms``; an out-of-memory error is such a problem; anything else is
logged and answered INTERNAL without details. When the client set a deadline, the remaining
time goes to the runtime call as its timeout, so a call that cannot finish in time comes back
DEADLINE_EXCEEDED instead of computing for nobody.

Messages become plain numbers here (proto fields → numpy arrays, flattened xyz → ``(K, 3)``);
what they mean is decided by the runtime with :func:`litege_core.query.parse_query`, the rule
REST uses too. Uploads are read within ``LITEGE_BODY_READ_TIMEOUT_S`` before a slot is taken,
and parsed in a worker thread, never on the event loop.

``Correspond`` is a bidirectional stream (semantics in ``proto/litege.proto``): one batch at a
time, answered in order; the first failing batch ends the stream with its error status, the
same trailing metadata, and ``litege-batch-id``; a cancelled call stops before its next batch.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import math
import time
import weakref
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Any

import grpc
import numpy as np
from grpc_reflection.v1alpha import reflection

from litege_core.errors import ArrayShapeError, LiteGEError
from litege_core.shape import Shape
from service.answers import ShapeInfo
from service.errors import (
    AuthenticationError,
    OutOfMemoryError,
    PayloadTooLargeError,
    RequestError,
    RequestTimeoutError,
    RetryLaterError,
    ShapeNotFoundError,
)
from service.grpc_stubs import load_stubs
from service.problems import bounded, problem_detail, problem_for
from service.runtime import Runtime, is_out_of_memory
from service.schemas import check_shape_id

log = logging.getLogger("litege.grpc")

SERVICE_NAME = "litege.v1.LiteGE"
API_KEY_HEADER = "x-api-key"
PROBLEM_TYPE_KEY = "litege-problem-type"
RETRY_AFTER_KEY = "retry-after-ms"
BATCH_ID_KEY = "litege-batch-id"
MESSAGE_HEADROOM_BYTES = 1 << 20
"""Allowance over the upload limit for a message's framing (header fields, chunk tags)."""
DEADLINE_MARGIN_S = 0.01
"""Time kept back from the client's deadline to send the DEADLINE_EXCEEDED status itself."""
INLINE_VALUES = 4096
"""Repeated fields up to this many values become arrays on the event loop; longer in a thread."""

_health_servicers: weakref.WeakKeyDictionary[grpc.aio.Server, Any] = weakref.WeakKeyDictionary()


# --------------------------------------------------------------------------- helpers


def _optional(message: Any, field: str) -> str | None:
    """An ``optional string`` field: ``None`` when unset or empty."""
    return (getattr(message, field) or None) if message.HasField(field) else None


def _unflatten(flat: np.ndarray, what: str) -> np.ndarray:
    """The wire's flattened ``x0, y0, z0, x1, ...`` as ``(K, 3)`` rows (framing only)."""
    if flat.size % 3:
        raise ArrayShapeError(f"{what} must hold x, y, z triples; got {flat.size} numbers")
    return flat.reshape(-1, 3)


async def _array(values: Sequence[Any], dtype: Any) -> np.ndarray:
    """A repeated proto field as a numpy array (in a worker thread when long)."""
    if len(values) <= INLINE_VALUES:
        return np.asarray(values, dtype=dtype)
    return await asyncio.to_thread(np.asarray, values, dtype)


def _query_point(message: Any) -> int | list[float] | None:
    """A ``QueryPoint`` as plain values: an index, ``[x, y, z]``, or ``None`` when unset."""
    which = message.WhichOneof("point")
    if which == "index":
        return int(message.index)
    if which == "xyz":
        return [float(message.xyz.x), float(message.xyz.y), float(message.xyz.z)]
    return None


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _packed_float_field(number: int, values: np.ndarray) -> bytes:
    """Wire encoding of a packed ``repeated float`` field (≈50× faster than ``extend``)."""
    raw = np.ascontiguousarray(values, dtype="<f4").tobytes()
    return _varint(number << 3 | 2) + _varint(len(raw)) + raw


class LiteGEServicer:
    """The ``litege.v1.LiteGE`` service over a runtime (see the module docstring)."""

    def __init__(self, runtime: Runtime) -> None:
        self.runtime = runtime
        self.settings = runtime.settings
        self.pb2, self.pb2_grpc = load_stubs()
        self._api_key = self.settings.api_key.encode() if self.settings.api_key else None
        self._distances_field = self.pb2.GeodesicResponse.DESCRIPTOR.fields_by_name[
            "distances"
        ].number
        match_fields = self.pb2.CorrespondResponse.DESCRIPTOR.fields_by_name
        self._match_distances_field = match_fields["distances"].number
        self._match_unit_area_field = match_fields["distances_unit_area"].number

    # ------------------------------------------------------------------ plumbing

    def _authenticate(self, context: grpc.aio.ServicerContext) -> None:
        if self._api_key is None:
            return
        for key, value in context.invocation_metadata() or ():
            if key == API_KEY_HEADER:
                given = value.encode() if isinstance(value, str) else bytes(value)
                if hmac.compare_digest(given, self._api_key):
                    return
                break
        raise AuthenticationError(f"missing or wrong {API_KEY_HEADER} metadata")

    def _timeout_s(self, context: grpc.aio.ServicerContext) -> float | None:
        """What is left of the client's deadline (minus a margin), ``None`` without one."""
        remaining = context.time_remaining()
        if remaining is None or not math.isfinite(remaining) or remaining > 1e8:
            return None
        return max(0.0, remaining - DEADLINE_MARGIN_S)

    def _info(self, info: ShapeInfo) -> Any:
        """``service.answers.ShapeInfo`` → ``litege.v1.ShapeInfo``."""
        message = self.pb2.ShapeInfo(
            shape_id=info.shape_id,
            kind=info.kind,
            n_points=info.n_points,
            n_faces=info.n_faces,
            model=info.model,
            bundle_hash=info.bundle_hash,
            ood_score=info.ood_score,
            ood_calibrated=info.ood_calibrated,
            created=info.created,
        )
        if info.out_of_distribution is not None:
            message.out_of_distribution = bool(info.out_of_distribution)
        if info.model_scores is not None:
            message.model_scores.update(info.model_scores)
        return message

    async def _guard(
        self,
        name: str,
        implementation: Callable[[Any, grpc.aio.ServicerContext], Awaitable[Any]],
        request: Any,
        context: grpc.aio.ServicerContext,
        *,
        slot: bool = True,
    ) -> Any:
        """Authentication, a concurrency slot (unless the implementation takes its own),
        metrics and error mapping around one RPC implementation."""
        metrics = self.runtime.metrics
        started = time.perf_counter()
        code = grpc.StatusCode.OK
        metrics.in_flight.labels("grpc").inc()
        try:
            self._authenticate(context)
            if not slot:
                return await implementation(request, context)
            with self.runtime.admission.slot():
                return await implementation(request, context)
        except grpc.aio.AbortError:
            raise
        except asyncio.CancelledError:
            code = grpc.StatusCode.CANCELLED
            raise
        except Exception as exc:
            code = _status_of(exc)
            await self._fail(name, exc, context)
        finally:
            metrics.in_flight.labels("grpc").dec()
            metrics.grpc_latency.labels(name, code.name).observe(time.perf_counter() - started)

    async def _fail(
        self,
        name: str,
        exc: Exception,
        context: grpc.aio.ServicerContext,
        extra: tuple[tuple[str, str], ...] = (),
    ) -> None:
        """End the call for ``exc`` (see :func:`_problem_of`); unexpected errors are logged
        and answered INTERNAL without details."""
        problem = _problem_of(exc)
        if problem is not None:
            await self._abort(name, problem, context, extra)
        log.error("gRPC %s failed", name, exc_info=exc)
        await context.abort(grpc.StatusCode.INTERNAL, "internal error")

    async def _abort(
        self,
        name: str,
        exc: LiteGEError,
        context: grpc.aio.ServicerContext,
        extra: tuple[tuple[str, str], ...] = (),
    ) -> None:
        """End the call with the status of ``exc`` and the problem's trailing metadata."""
        problem = problem_for(exc)
        trailing = [(PROBLEM_TYPE_KEY, problem.type_uri), *((k, bounded(v)) for k, v in extra)]
        if isinstance(exc, RetryLaterError):
            trailing.append((RETRY_AFTER_KEY, str(round(exc.retry_after_s * 1000))))
        if problem.grpc_status == grpc.StatusCode.INTERNAL:
            log.error("gRPC %s failed: %s", name, exc, exc_info=exc)
        elif problem.http_status >= 500:
            log.warning("gRPC %s: %s (%s)", name, problem.code, exc)
        else:
            log.debug("%s: %s %s", name, problem.grpc_status.name, exc)
        await context.abort(
            problem.grpc_status, problem_detail(exc), trailing_metadata=tuple(trailing)
        )

    # ------------------------------------------------------------------ RPCs (gRPC names)

    async def RegisterShape(  # noqa: N802
        self, request_iterator: AsyncIterator[Any], context: grpc.aio.ServicerContext
    ) -> Any:
        """Client stream: a ``ShapeHeader``, then chunks → ``ShapeInfo``."""
        return await self._guard(
            "RegisterShape", self._register_shape, request_iterator, context, slot=False
        )

    async def GetShape(self, request: Any, context: grpc.aio.ServicerContext) -> Any:  # noqa: N802
        """``ShapeRef`` → ``ShapeInfo``."""
        return await self._guard("GetShape", self._get_shape, request, context)

    async def DeleteShape(self, request: Any, context: grpc.aio.ServicerContext) -> Any:  # noqa: N802
        """``ShapeRef`` → ``DeleteShapeResponse``."""
        return await self._guard("DeleteShape", self._delete_shape, request, context)

    async def Geodesic(self, request: Any, context: grpc.aio.ServicerContext) -> Any:  # noqa: N802
        """``GeodesicRequest`` → ``GeodesicResponse`` with ``(S, T)`` distances."""
        return await self._guard("Geodesic", self._geodesic, request, context)

    async def Path(self, request: Any, context: grpc.aio.ServicerContext) -> Any:  # noqa: N802
        """``PathRequest`` → ``PathResponse`` with ``(L, 3)`` points."""
        return await self._guard("Path", self._path, request, context)

    async def Correspond(  # noqa: N802
        self, request_iterator: AsyncIterator[Any], context: grpc.aio.ServicerContext
    ) -> AsyncIterator[Any]:
        """Bidirectional stream: ``CorrespondRequest`` batches → ``CorrespondResponse``s, one
        per batch, in order (see the module docstring and the .proto). Each batch holds a
        concurrency slot while it computes (not while the stream waits for the client).

        A client that cancels while a batch computes stops it (``CANCELLED``). One that
        cancels while the server waits for its next batch ends the request stream as a
        half-close would: grpcio's asyncio server shows both as the end of the iterator and
        ``context.cancelled()`` stays false, so that stream is counted ``OK``."""
        metrics = self.runtime.metrics
        started = time.perf_counter()
        code = grpc.StatusCode.OK
        batch_id: int | None = None
        metrics.in_flight.labels("grpc").inc()
        try:
            self._authenticate(context)
            pair = _Pair()
            async for message in request_iterator:  # one batch at a time: back-pressure
                batch_id = int(message.batch_id)
                pair = pair.updated(message)
                with self.runtime.admission.slot():
                    response = await self._correspond_batch(message, pair, context)
                yield response
                batch_id = None
        except grpc.aio.AbortError:
            raise
        except asyncio.CancelledError:
            code = grpc.StatusCode.CANCELLED
            raise
        except Exception as exc:
            extra = () if batch_id is None else ((BATCH_ID_KEY, str(batch_id)),)
            code = _status_of(exc)
            await self._fail("Correspond", exc, context, extra)
        finally:
            metrics.in_flight.labels("grpc").dec()
            metrics.grpc_latency.labels("Correspond", code.name).observe(
                time.perf_counter() - started
            )

    # ------------------------------------------------------------------ implementations

    async def _correspond_batch(
        self, message: Any, pair: _Pair, context: grpc.aio.ServicerContext
    ) -> Any:
        which = message.WhichOneof("queries")
        if which == "query_indices":
            queries: Any = await _array(message.query_indices.values, np.int64)
        elif which == "query_points":
            flat = await _array(message.query_points.xyz, np.float64)
            queries = _unflatten(flat, "query_points")
        elif which == "all_queries" and message.all_queries:
            queries = "all"
        elif which is None:
            raise RequestError(
                f"batch {message.batch_id} has no queries: set query_indices, query_points "
                "or all_queries"
            )
        else:
            raise RequestError("all_queries = false names no queries")
        timeout = self._timeout_s(context)
        if message.HasField("deadline_ms") and message.deadline_ms > 0:
            own = message.deadline_ms / 1000.0
            timeout = own if timeout is None else min(timeout, own)
        result = await self.runtime.correspond(
            pair.source,
            pair.target,
            queries,
            model=pair.model,
            timeout_s=timeout,
            refine=pair.refine,
        )
        response = self.pb2.CorrespondResponse(
            batch_id=message.batch_id,
            source_shape_id=result.source_shape_id,
            target_shape_id=result.target_shape_id,
            model=result.model,
            n_queries=result.n_queries,
            matches=result.matches.tolist(),
            refinement=result.refinement,
            source_frame=self.pb2.FrameInfo(**result.source_frame.to_dict()),
            target_frame=self.pb2.FrameInfo(**result.target_frame.to_dict()),
        )
        if message.return_distance:
            response.MergeFromString(
                _packed_float_field(self._match_distances_field, result.distances)
                + _packed_float_field(self._match_unit_area_field, result.distances_unit_area)
            )
        return response

    async def _register_shape(
        self, request_iterator: AsyncIterator[Any], context: grpc.aio.ServicerContext
    ) -> Any:
        """Read the stream (within the body-read timeout), then take a slot; the parsing runs
        in a worker thread."""
        timeout_s = self.settings.body_read_timeout_s
        try:
            async with asyncio.timeout(timeout_s):
                header, data = await self._read_upload(request_iterator)
        except TimeoutError:
            raise RequestTimeoutError(
                f"the upload stream did not complete within {timeout_s:g} s"
            ) from None
        file_format = header.file_format.strip().lower().lstrip(".")
        kind = _optional(header, "kind")
        if file_format != "arrays":
            if not file_format:
                raise RequestError("the header's file_format is required")
            if len(header.vertices) or len(header.faces):
                raise RequestError("inline vertices/faces need file_format 'arrays'")
        with self.runtime.admission.slot():
            if file_format == "arrays":
                shape = await self.runtime.parse_upload(self._shape_from_arrays, header, data, kind)
            else:
                shape = await self.runtime.parse_upload(
                    self.runtime.load_upload, data, file_format, kind
                )
            info = await self.runtime.register_shape(shape, model=_optional(header, "model"))
        return self._info(info)

    async def _read_upload(self, request_iterator: AsyncIterator[Any]) -> tuple[Any, bytes]:
        """The header and the concatenated chunks of a ``RegisterShape`` stream (bounded by
        the upload limit)."""
        limit = self.settings.max_upload_bytes
        header = None
        chunks: list[bytes] = []
        total = 0
        async for message in request_iterator:
            which = message.WhichOneof("payload")
            if header is None:
                if which != "header":
                    raise RequestError("the first RegisterShape message must carry a header")
                header = message.header
                total = 8 * (len(header.vertices) + len(header.faces))
            elif which == "header":
                raise RequestError("only the first RegisterShape message may carry a header")
            else:
                total += len(message.chunk)
                chunks.append(message.chunk)
            if total > limit:
                raise PayloadTooLargeError(
                    f"upload exceeds the limit of {limit} bytes", limit=limit
                )
        if header is None:
            raise RequestError("empty RegisterShape stream: the first message must be a header")
        return header, b"".join(chunks)

    def _shape_from_arrays(self, header: Any, data: bytes, kind: str | None) -> Shape:
        """The two ``arrays`` encodings of ``ShapeHeader`` → a validated shape (worker
        thread)."""
        if header.HasField("n_vertices"):
            if len(header.vertices) or len(header.faces):
                raise RequestError("send the arrays either inline or as raw chunks, not both")
            n_vertices, n_faces = header.n_vertices, header.n_faces
            expected = 24 * (n_vertices + n_faces)
            if len(data) != expected:
                raise ArrayShapeError(
                    f"raw arrays of {n_vertices} vertices and {n_faces} faces need "
                    f"{expected} bytes, got {len(data)}"
                )
            vertices = np.frombuffer(data, dtype="<f8", count=3 * n_vertices).reshape(-1, 3)
            faces = np.frombuffer(
                data, dtype="<i8", count=3 * n_faces, offset=24 * n_vertices
            ).reshape(-1, 3)
        else:
            if data:
                raise RequestError("chunks after an 'arrays' header need n_vertices (raw mode)")
            vertices = _unflatten(np.asarray(header.vertices, dtype=np.float64), "vertices")
            flat_faces = np.asarray(header.faces, dtype=np.int64)
            if flat_faces.size % 3:
                raise ArrayShapeError(f"faces must be index triples; got {flat_faces.size}")
            faces = flat_faces.reshape(-1, 3)
        return self.runtime.shape_from_arrays(vertices, faces if faces.size else None, kind)

    async def _get_shape(self, request: Any, context: grpc.aio.ServicerContext) -> Any:
        info = await self.runtime.shape_info(_shape_id(request), _optional(request, "model"))
        return self._info(info)

    async def _delete_shape(self, request: Any, context: grpc.aio.ServicerContext) -> Any:
        shape_id = _shape_id(request)
        if not await self.runtime.delete_shape(shape_id):
            raise ShapeNotFoundError(f"shape {shape_id} is not registered (or has expired)")
        return self.pb2.DeleteShapeResponse(shape_id=shape_id, deleted=True)

    async def _geodesic(self, request: Any, context: grpc.aio.ServicerContext) -> Any:
        which = request.WhichOneof("sources")
        if which == "source_indices":
            sources: Any = await _array(request.source_indices.values, np.int64)
        elif which == "source_points":
            flat = await _array(request.source_points.xyz, np.float64)
            sources = _unflatten(flat, "source_points")
        else:
            raise RequestError("sources are required: source_indices or source_points")
        which = request.WhichOneof("targets")
        if which == "target_indices":
            targets: Any = await _array(request.target_indices.values, np.int64)
        elif which == "target_points":
            flat = await _array(request.target_points.xyz, np.float64)
            targets = _unflatten(flat, "target_points")
        elif which is None or request.all_targets:
            targets = "all"
        else:
            raise RequestError("all_targets = false names no targets")
        answer, distances = await self.runtime.geodesic(
            _shape_id(request),
            sources,
            targets,
            model=_optional(request, "model"),
            timeout_s=self._timeout_s(context),
            method=_optional(request, "method"),
        )
        rows, cols = distances.shape
        response = self.pb2.GeodesicResponse(
            rows=rows,
            cols=cols,
            method=answer.method,
            engine=answer.engine,
            shape_id=answer.shape_id,
        )
        if answer.info is not None:
            response.shape.CopyFrom(self._info(answer.info))
        response.MergeFromString(_packed_float_field(self._distances_field, distances))
        return response

    async def _path(self, request: Any, context: grpc.aio.ServicerContext) -> Any:
        source = _query_point(request.source) if request.HasField("source") else None
        target = _query_point(request.target) if request.HasField("target") else None
        if source is None:
            raise RequestError("source is required: an index or an xyz point")
        if target is None:
            raise RequestError("target is required: an index or an xyz point")
        result = await self.runtime.path(
            _shape_id(request),
            source,
            target,
            model=_optional(request, "model"),
            timeout_s=self._timeout_s(context),
            method=_optional(request, "method"),
        )
        response = self.pb2.PathResponse(
            points=np.asarray(result.points, dtype=np.float64).ravel().tolist(),
            length=result.length,
            method=result.method,
            engine=result.engine,
            distance=result.distance,
            segments=[self.pb2.PathSegment(start=i, method=how) for i, how in result.segments],
            model=result.model or "",
        )
        if result.predicted_distance is not None:
            response.predicted_distance = result.predicted_distance
        if result.n_steps is not None:
            response.n_steps = result.n_steps
        if result.converged is not None:
            response.converged = result.converged
        return response


def _problem_of(exc: Exception) -> LiteGEError | None:
    """The LiteGE problem ``exc`` is: itself, an out-of-memory problem for a device or host
    out of memory, or ``None`` (an unexpected error)."""
    if isinstance(exc, LiteGEError):
        return exc
    if is_out_of_memory(exc):
        return OutOfMemoryError("the service ran out of memory for this request")
    return None


def _status_of(exc: Exception) -> grpc.StatusCode:
    problem = _problem_of(exc)
    return grpc.StatusCode.INTERNAL if problem is None else problem_for(problem).grpc_status


@dataclass(frozen=True)
class _Pair:
    """The shapes, model and refinement a ``Correspond`` stream is on (set by its first
    message; ``refine`` ``None``: the runtime's default, ``"none"``)."""

    source: str = ""
    target: str = ""
    model: str | None = None
    refine: str | None = None

    def updated(self, message: Any) -> _Pair:
        source = message.source_shape_id.strip() or self.source
        target = message.target_shape_id.strip() or self.target
        if not source or not target:
            raise RequestError(
                "the first Correspond message must name source_shape_id and target_shape_id"
            )
        source = check_shape_id(source, "source_shape_id")
        target = check_shape_id(target, "target_shape_id")
        model = _optional(message, "model") if message.HasField("model") else self.model
        refine = _optional(message, "refine") if message.HasField("refine") else self.refine
        return _Pair(source, target, model, refine)


def _shape_id(request: Any) -> str:
    return check_shape_id(request.shape_id)


# --------------------------------------------------------------------------- server


def _address(host: str, port: int) -> str:
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"  # IPv6 literal
    return f"{host}:{port}"


async def start_grpc_server(runtime: Runtime, host: str, port: int) -> tuple[grpc.aio.Server, int]:
    """Build, bind and start the gRPC server on ``host:port`` (``port`` 0: any free port).

    Serves ``litege.v1.LiteGE`` over ``runtime``, ``grpc.health.v1.Health`` (overall and
    ``litege.v1.LiteGE`` SERVING) and server reflection. Must be awaited on the event loop the
    runtime lives on.

    Returns:
        The started server and the port it is bound to.
    """
    from grpc_health.v1 import health, health_pb2, health_pb2_grpc

    settings = runtime.settings
    receive_limit = settings.max_upload_bytes + MESSAGE_HEADROOM_BYTES
    send_limit = max(settings.max_upload_bytes, 4 * settings.max_queries) + MESSAGE_HEADROOM_BYTES
    options = [
        ("grpc.max_receive_message_length", receive_limit),
        ("grpc.max_send_message_length", send_limit),
    ]
    servicer = LiteGEServicer(runtime)
    aio_health = getattr(health, "aio", None)
    if aio_health is not None:
        health_servicer = aio_health.HealthServicer()
        server = grpc.aio.server(options=options)
    else:  # old grpcio-health-checking: the sync servicer runs in a migration thread pool
        from concurrent.futures import ThreadPoolExecutor

        health_servicer = health.HealthServicer()
        server = grpc.aio.server(
            migration_thread_pool=ThreadPoolExecutor(max_workers=2), options=options
        )
    servicer.pb2_grpc.add_LiteGEServicer_to_server(servicer, server)
    health_pb2_grpc.add_HealthServicer_to_server(health_servicer, server)
    for name in ("", SERVICE_NAME):
        result = health_servicer.set(name, health_pb2.HealthCheckResponse.SERVING)
        if asyncio.iscoroutine(result):
            await result
    reflection.enable_server_reflection(
        (SERVICE_NAME, health.SERVICE_NAME, reflection.SERVICE_NAME), server
    )
    address = _address(host, port)
    try:
        bound = server.add_insecure_port(address)
    except RuntimeError as exc:
        raise OSError(f"cannot bind the gRPC server to {address}: {exc}") from exc
    if bound == 0:
        raise OSError(f"cannot bind the gRPC server to {address}")
    await server.start()
    _health_servicers[server] = health_servicer
    log.info("gRPC server listening", extra={"address": _address(host, bound)})
    return server, bound


async def stop_grpc_server(server: grpc.aio.Server, grace_s: float | None = None) -> None:
    """Report NOT_SERVING on the health service, then stop (in-flight calls get ``grace_s``)."""
    health_servicer = _health_servicers.pop(server, None)
    if health_servicer is not None:
        result = health_servicer.enter_graceful_shutdown()
        if asyncio.iscoroutine(result):
            await result
    await server.stop(grace_s)
