"""The REST API (FastAPI): thin translation of HTTP onto :class:`service.runtime.Runtime`."""

from __future__ import annotations

import contextlib
import hmac
import json
import logging
import time
from collections.abc import AsyncIterator
from pathlib import PurePath
from typing import Annotated, Any

import anyio
import msgpack
import numpy as np
import pydantic
from fastapi import Depends, FastAPI, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from litege_core import __version__
from litege_core.errors import LiteGEError
from service.errors import (
    AuthenticationError,
    OverloadedError,
    PayloadTooLargeError,
    ShapeNotFoundError,
    UnsupportedMediaTypeError,
)
from service.metrics import ServiceMetrics
from service.problems import PROBLEM_BASE_URI, problem_for
from service.runtime import Runtime, ShapeInfo
from service.schemas import (
    CorrespondenceRequest,
    CorrespondenceResponse,
    GeodesicRequest,
    GeodesicResponse,
    PathRequest,
    PathResponse,
    Problem,
    ShapeArraysRequest,
    ShapeInfoResponse,
)
from service.settings import Settings
from service.viewer import add_viewer_routes

log = logging.getLogger("litege.http")

PROBLEM_JSON = "application/problem+json"
OCTET_STREAM = "application/octet-stream"
MSGPACK_TYPES = ("application/msgpack", "application/x-msgpack", "application/vnd.msgpack")
UNMETERED = ("/healthz", "/readyz", "/metrics")
"""Probes and scraping: always answered (no API key, no concurrency limit)."""
MULTIPART_OVERHEAD = 64 * 1024

PROBLEM_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": Problem, "content": {PROBLEM_JSON: {}}, "description": text}
    for status, text in (
        (400, "Malformed file"),
        (401, "Missing or wrong API key"),
        (404, "Unknown shape id"),
        (413, "Payload or shape too large"),
        (415, "Unsupported media type or file format"),
        (422, "Invalid input"),
        (429, "Too many concurrent requests"),
        (503, "Overloaded or not ready"),
        (504, "Deadline exceeded"),
    )
}


# --------------------------------------------------------------------------- problems


def problem_response(exc: LiteGEError, instance: str | None = None) -> JSONResponse:
    kind = problem_for(exc)
    body = {
        "type": kind.type_uri,
        "title": kind.title,
        "status": kind.http_status,
        "detail": str(exc),
        "instance": instance,
        "code": kind.code,
    }
    headers = {}
    if isinstance(exc, OverloadedError):
        headers["Retry-After"] = str(max(1, round(exc.retry_after_s)))
    return JSONResponse(body, kind.http_status, headers=headers, media_type=PROBLEM_JSON)


def _plain_problem(status: int, code: str, title: str, detail: str, **extra: Any) -> JSONResponse:
    body = {
        "type": PROBLEM_BASE_URI + code,
        "title": title,
        "status": status,
        "detail": detail,
        "code": code,
        **extra,
    }
    return JSONResponse(body, status, media_type=PROBLEM_JSON)


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(LiteGEError)
    async def _litege(request: Request, exc: LiteGEError) -> JSONResponse:
        response = problem_response(exc, request.url.path)
        if response.status_code >= 500:
            log.error("request failed: %s", exc, exc_info=exc)
        return response

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")), "type": e.get("type")}
            for e in exc.errors()
        ]
        return _plain_problem(
            422,
            "invalid-request",
            "Invalid request",
            "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in errors)[:2000],
            errors=errors,
            instance=request.url.path,
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.error("unexpected error on %s", request.url.path, exc_info=exc)
        return _plain_problem(
            500,
            "internal-error",
            "Internal error",
            "the service failed unexpectedly; the error is logged",
            instance=request.url.path,
        )

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        code = {404: "not-found", 405: "method-not-allowed"}.get(exc.status_code, "http-error")
        response = _plain_problem(
            exc.status_code, code, str(exc.detail), str(exc.detail), instance=request.url.path
        )
        if exc.headers:
            response.headers.update(exc.headers)
        return response


# --------------------------------------------------------------------------- middleware


class GuardMiddleware:
    """Pure ASGI middleware: request body limit (buffered, so the app never sees more than
    the limit), concurrency limit, latency metrics and one JSON access-log line per request."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.max_body = settings.max_upload_bytes + MULTIPART_OVERHEAD
        self.max_concurrency = settings.max_concurrency
        self.in_flight = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        path = scope.get("path", "")
        metrics: ServiceMetrics = scope["app"].state.runtime.metrics  # exists after start-up
        status_holder = {"status": 500}

        async def send_wrapper(message: Message) -> None:
            if message["type"] == "http.response.start":
                status_holder["status"] = message["status"]
            await send(message)

        metered = path not in UNMETERED
        try:
            if metered and self.in_flight >= self.max_concurrency:
                metrics.rejected.labels("concurrency").inc()
                error = OverloadedError(
                    f"more than {self.max_concurrency} concurrent requests; retry later",
                    retry_after_s=1.0,
                    status=429,
                )
                await problem_response(error, path)(scope, receive, send_wrapper)
                return
            self.in_flight += metered
            metrics.in_flight.labels("http").inc()
            try:
                body = await self._read_body(scope, receive)
                if body is None:
                    error = PayloadTooLargeError(
                        f"request body exceeds the limit of {self.max_body} bytes"
                    )
                    await problem_response(error, path)(scope, receive, send_wrapper)
                    return
                await self.app(scope, _replay(body, receive), send_wrapper)
            finally:
                self.in_flight -= metered
                metrics.in_flight.labels("http").dec()
        finally:
            elapsed = time.perf_counter() - started
            route = scope.get("route")
            route_path = getattr(route, "path", "unmatched")
            status = status_holder["status"]
            metrics.http_latency.labels(scope["method"], route_path, str(status)).observe(elapsed)
            if metered:
                log.info(
                    "request",
                    extra={
                        "method": scope["method"],
                        "path": path,
                        "status": status,
                        "duration_ms": round(elapsed * 1000, 3),
                    },
                )

    async def _read_body(self, scope: Scope, receive: Receive) -> bytes | None:
        """The whole body, or ``None`` when it exceeds the limit (declared or actual)."""
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                with contextlib.suppress(ValueError):
                    if int(value) > self.max_body:
                        return None
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                break
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_body:
                return None
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        return b"".join(chunks)


def _replay(body: bytes, receive: Receive) -> Receive:
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if not sent:
            sent = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay


# --------------------------------------------------------------------------- dependencies


def get_runtime(request: Request) -> Runtime:
    return request.app.state.runtime


RuntimeDep = Annotated[Runtime, Depends(get_runtime)]


def require_api_key(request: Request) -> None:
    expected = request.app.state.runtime.settings.api_key
    if expected is None:
        return
    given = request.headers.get("x-api-key", "")
    if not hmac.compare_digest(given.encode(), expected.encode()):
        raise AuthenticationError("missing or wrong X-API-Key header")


def _info_response(info: ShapeInfo) -> ShapeInfoResponse:
    return ShapeInfoResponse(**info.__dict__)


# --------------------------------------------------------------------------- app


def create_app(settings: Settings | None = None, runtime: Runtime | None = None) -> FastAPI:
    """The REST app. With ``runtime`` given, the caller owns its life cycle (one runtime shared
    with the gRPC server); otherwise the app starts and closes its own from ``settings``."""
    settings = settings or (runtime.settings if runtime else Settings())

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        if runtime is not None:
            app.state.runtime = runtime
            yield
            return
        app.state.runtime = await Runtime.start(settings)
        try:
            yield
        finally:
            await app.state.runtime.close()

    app = FastAPI(
        title="LiteGE",
        version=__version__,
        description="Learned geodesic distances, paths and shape correspondence on meshes and "
        "point clouds.",
        lifespan=lifespan,
        responses=PROBLEM_RESPONSES,
    )
    if runtime is not None:
        app.state.runtime = runtime

    _install_error_handlers(app)
    app.add_middleware(GuardMiddleware, settings=settings)
    _add_probe_routes(app)
    _add_shape_routes(app)
    _add_query_routes(app)
    add_viewer_routes(app, require_api_key)  # /viewer: the web viewer (service/viewer.py)
    return app


def _add_probe_routes(app: FastAPI) -> None:
    @app.get("/healthz", tags=["probes"])
    def healthz() -> dict[str, str]:
        """Liveness: the process answers."""
        return {"status": "ok"}

    @app.get("/readyz", tags=["probes"])
    def readyz(runtime: RuntimeDep) -> JSONResponse:
        """Readiness: models loaded; ``degraded`` while the shared store is unreachable."""
        readiness = runtime.readiness()
        body = {
            "status": "ready" if readiness.ready else "not-ready",
            "degraded": readiness.degraded,
            **readiness.detail,
        }
        return JSONResponse(body, 200 if readiness.ready else 503)

    @app.get("/metrics", tags=["probes"], response_class=Response)
    def metrics(runtime: RuntimeDep) -> Response:
        """Prometheus metrics."""
        runtime.readiness()  # refresh the store gauge
        return Response(runtime.metrics.render(), media_type="text/plain; version=0.0.4")

    @app.get("/version", tags=["probes"])
    def version(runtime: RuntimeDep) -> dict[str, Any]:
        return {
            "version": __version__,
            "models": list(runtime.model_names),
            "formats": list(runtime.supported_formats()),
            "settings": runtime.settings.public_summary(),
        }


_SHAPE_BODY = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "required": ["file"],
                    "properties": {
                        "file": {"type": "string", "format": "binary"},
                        "format": {
                            "type": "string",
                            "description": "file format (default: the file name's extension)",
                        },
                        "kind": {"type": "string", "enum": ["mesh", "point_cloud"]},
                        "model": {"type": "string"},
                    },
                }
            },
            "application/json": {"schema": ShapeArraysRequest.model_json_schema()},
        },
    }
}


def _add_shape_routes(app: FastAPI) -> None:
    auth = [Depends(require_api_key)]

    @app.post(
        "/shapes",
        tags=["shapes"],
        dependencies=auth,
        status_code=201,
        response_model=ShapeInfoResponse,
        openapi_extra=_SHAPE_BODY,
        responses={200: {"model": ShapeInfoResponse, "description": "Already registered"}},
    )
    async def post_shape(request: Request, runtime: RuntimeDep) -> JSONResponse:
        """Register a shape (multipart file or JSON arrays). Idempotent: the id is the content
        hash of the loaded arrays, so the same shape in any format is registered once."""
        content_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if content_type == "multipart/form-data":
            shape, model = await _shape_from_form(request, runtime)
        elif content_type == "application/json":
            shape, model = await _shape_from_json(request, runtime)
        else:
            raise UnsupportedMediaTypeError(
                f"POST /shapes takes multipart/form-data or application/json, not "
                f"{content_type or 'no content type'}"
            )
        info = await runtime.register_shape(shape, model)
        return JSONResponse(
            _info_response(info).model_dump(),
            status_code=201 if info.created else 200,
            headers={"Location": f"/shapes/{info.shape_id}"},
        )

    @app.get("/shapes/{shape_id}", tags=["shapes"], dependencies=auth)
    async def get_shape(
        shape_id: str, runtime: RuntimeDep, model: Annotated[str | None, Query()] = None
    ) -> ShapeInfoResponse:
        return _info_response(await runtime.shape_info(shape_id, model))

    @app.delete("/shapes/{shape_id}", tags=["shapes"], dependencies=auth, status_code=204)
    async def delete_shape(shape_id: str, runtime: RuntimeDep) -> Response:
        if not await runtime.delete_shape(shape_id):
            raise ShapeNotFoundError(f"shape {shape_id!r} is not registered")
        return Response(status_code=204)


async def _shape_from_form(request: Request, runtime: Runtime) -> tuple[Any, str | None]:
    from litege_core.errors import ShapeFileError

    try:
        form = await request.form(max_files=1, max_fields=8)
    except Exception as exc:  # starlette raises its own errors for broken multipart bodies
        raise ShapeFileError(f"malformed multipart body: {exc}") from exc
    upload = form.get("file")
    if upload is None or isinstance(upload, str):
        raise ShapeFileError("multipart body has no 'file' part")
    fields = {k: form.get(k) for k in ("format", "kind", "model")}
    for name, value in fields.items():
        if value is not None and not isinstance(value, str):
            raise ShapeFileError(f"form field {name!r} must be text")
    file_format = fields["format"] or PurePath(upload.filename or "").suffix.lstrip(".")
    if not file_format:
        raise UnsupportedMediaTypeError(
            "cannot tell the file format: give the file a known extension or a 'format' field"
        )
    data = await upload.read()
    shape = await anyio.to_thread.run_sync(
        runtime.load_upload, data, str(file_format), fields["kind"] or None
    )
    return shape, fields["model"] or None


async def _shape_from_json(request: Request, runtime: Runtime) -> tuple[Any, str | None]:
    body = await request.body()
    try:
        parsed = ShapeArraysRequest.model_validate_json(body)
    except pydantic.ValidationError as exc:
        raise RequestValidationError(exc.errors(include_url=False)) from exc
    shape = await anyio.to_thread.run_sync(
        runtime.shape_from_arrays, parsed.vertices, parsed.faces, parsed.kind
    )
    return shape, parsed.model


def _add_query_routes(app: FastAPI) -> None:
    auth = [Depends(require_api_key)]

    @app.post(
        "/geodesic",
        tags=["queries"],
        dependencies=auth,
        response_model=GeodesicResponse,
        responses={
            200: {
                "content": {
                    OCTET_STREAM: {
                        "schema": {"type": "string", "format": "binary"},
                        "description": "little-endian float32, row-major; shape in the "
                        "X-Array-Shape header (rows,cols)",
                    },
                    "application/msgpack": {
                        "schema": {"type": "string", "format": "binary"},
                        "description": "map {dtype: '<f4', shape: [rows, cols], data: bytes}",
                    },
                }
            }
        },
    )
    async def geodesic(body: GeodesicRequest, request: Request, runtime: RuntimeDep) -> Response:
        """Predicted geodesic distances ``sources × targets`` in the shape's input units.
        JSON by default; ``Accept: application/octet-stream`` or ``application/msgpack`` for
        large matrices."""
        info, distances = await runtime.geodesic(
            body.shape_id, body.sources, body.targets, body.model
        )
        return _matrix_response(request, info, distances)

    @app.post("/paths", tags=["queries"], dependencies=auth, response_model=PathResponse)
    async def paths(body: PathRequest, runtime: RuntimeDep) -> PathResponse:
        """A geodesic path (polyline from source to target) traced on the learned field."""
        result = await runtime.path(body.shape_id, body.source, body.target, body.model)
        return PathResponse(
            shape_id=body.shape_id,
            points=result.points.tolist(),
            length=result.length,
            predicted_distance=result.predicted_distance,
            n_steps=result.n_steps,
            converged=result.converged,
        )

    @app.post(
        "/correspondences",
        tags=["queries"],
        dependencies=auth,
        response_model=CorrespondenceResponse,
    )
    async def correspondences(body: CorrespondenceRequest, runtime: RuntimeDep) -> Response:
        """Dense correspondence: for each query point of the source shape, the matched
        vertex/point of the target shape (learned cross-shape geodesic, coarse-to-fine
        search). Both shapes must be registered first (``POST /shapes``)."""
        result = await runtime.correspond(
            body.source_shape_id, body.target_shape_id, body.queries, body.model
        )
        payload = {
            "source_shape_id": result.source_shape_id,
            "target_shape_id": result.target_shape_id,
            "model": result.model,
            "n_queries": result.n_queries,
            "matches": result.matches.tolist(),
            "distances": result.distances.tolist() if body.return_distance else None,
        }
        return Response(json.dumps(payload, allow_nan=False), media_type="application/json")


def _matrix_response(request: Request, info: ShapeInfo, distances: np.ndarray) -> Response:
    rows, cols = distances.shape
    accept = request.headers.get("accept", "").lower()
    headers = {"X-Shape-Id": info.shape_id, "X-Model": info.model}
    if OCTET_STREAM in accept:
        headers.update({"X-Array-Shape": f"{rows},{cols}", "X-Array-Dtype": "<f4"})
        return Response(
            np.ascontiguousarray(distances, dtype="<f4").tobytes(),
            media_type=OCTET_STREAM,
            headers=headers,
        )
    for media_type in MSGPACK_TYPES:
        if media_type in accept:
            payload = {
                "shape_id": info.shape_id,
                "model": info.model,
                "dtype": "<f4",
                "shape": [rows, cols],
                "data": np.ascontiguousarray(distances, dtype="<f4").tobytes(),
            }
            return Response(msgpack.packb(payload), media_type=media_type, headers=headers)
    body = {
        "shape_id": info.shape_id,
        "model": info.model,
        "rows": rows,
        "cols": cols,
        "units": "input",
        "distances": distances.tolist(),
    }
    return Response(json.dumps(body, allow_nan=False), media_type="application/json")
