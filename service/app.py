"""The REST API (FastAPI): thin translation of HTTP onto :class:`service.runtime.Runtime`."""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import math
import time
from collections.abc import AsyncIterator
from pathlib import Path, PurePath
from typing import Annotated, Any, TypeVar

import msgpack
import numpy as np
import pydantic
from fastapi import Depends, FastAPI, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from litege_core import __version__
from litege_core.errors import LiteGEError
from service.answers import GeodesicAnswer, ShapeInfo
from service.errors import (
    AuthenticationError,
    OutOfMemoryError,
    OverloadedError,
    PayloadTooLargeError,
    RequestTimeoutError,
    RetryLaterError,
    ShapeNotFoundError,
    UnsupportedMediaTypeError,
)
from service.problems import PROBLEM_BASE_URI, problem_detail, problem_for
from service.runtime import Runtime, is_out_of_memory
from service.schemas import (
    CorrespondenceRequest,
    CorrespondenceResponse,
    GeodesicRequest,
    GeodesicResponse,
    PathRequest,
    PathResponse,
    PathSegment,
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
BODY_METHODS = ("POST", "PUT", "PATCH")
"""Methods whose body is read only once the API key is checked."""
MULTIPART_OVERHEAD = 64 * 1024
DRAIN_BYTES = 64 * 1024
"""A refused request declaring a body of at most this many bytes has it read and dropped
before the refusal (so the connection closes cleanly, or stays open); a larger one is refused
unread and its connection closed."""
DRAIN_TIMEOUT_S = 1.0
"""Longest wait for such a body (at most the body-read timeout)."""
INLINE_JSON_BYTES = 64 * 1024
"""JSON bodies up to this size are validated on the event loop; larger ones in a thread."""

PROBLEM_RESPONSES: dict[int | str, dict[str, Any]] = {
    status: {"model": Problem, "content": {PROBLEM_JSON: {}}, "description": text}
    for status, text in (
        (400, "Malformed file"),
        (401, "Missing or wrong API key"),
        (404, "Unknown shape id"),
        (408, "Request body not received in time"),
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
        "detail": problem_detail(exc),
        "instance": instance,
        "code": kind.code,
    }
    headers = {}
    if isinstance(exc, RetryLaterError):
        headers["Retry-After"] = str(max(1, math.ceil(exc.retry_after_s)))
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


def _internal_error(instance: str) -> JSONResponse:
    return _plain_problem(
        500,
        "internal-error",
        "Internal error",
        "the service failed unexpectedly; the error is logged",
        instance=instance,
    )


def _log_problem(path: str, exc: LiteGEError, status: int) -> None:
    """A traceback for internal errors (5xx but 503/504: a bug or a broken artifact); one
    warning line for the service's expected conditions (overload, deadline, not ready)."""
    if status >= 500 and status not in (503, 504):
        log.error("request to %s failed: %s", path, exc, exc_info=exc)
    elif status >= 500:
        log.warning("request to %s: %s (%s)", path, problem_for(exc).code, exc)


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(LiteGEError)
    async def _litege(request: Request, exc: LiteGEError) -> JSONResponse:
        response = problem_response(exc, request.url.path)
        _log_problem(request.url.path, exc, response.status_code)
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


def _declared_length(scope: Scope) -> int | None:
    """The request's ``Content-Length`` (``None``: absent or not a number)."""
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            with contextlib.suppress(ValueError):
                return int(value)
            return None
    return None


class GuardMiddleware:
    """Pure ASGI middleware around every request, in this order:

    1. API key, for requests with a body (``POST``/``PUT``/``PATCH``): a wrong or missing key
       is answered 401; a body declared at most :data:`DRAIN_BYTES` long is read and dropped
       first (a server that closes with unread bytes sends a TCP reset, which can reach the
       client before the 401 does), a longer one is never read and its connection closed;
    2. the body, read in full under ``LITEGE_BODY_READ_TIMEOUT_S`` (408) and the size limit
       (413), so a slow or huge upload holds no concurrency slot;
    3. a concurrency slot of :class:`service.admission.Admission`, shared with gRPC (429);
    4. the app; an exception escaping it becomes a 500 problem here (an out-of-memory one a
       503), so the connection stays open (Starlette's last-resort handler re-raises, and the
       server then drops the keep-alive connection);
    5. latency metrics and one JSON access-log line.

    Probes (:data:`UNMETERED`) skip 1-3.
    """

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.max_body = settings.max_upload_bytes + MULTIPART_OVERHEAD
        self.body_timeout_s = settings.body_read_timeout_s
        self.api_key = settings.api_key.encode() if settings.api_key else None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        path = scope.get("path", "")
        runtime: Runtime = scope["app"].state.runtime  # exists after start-up
        metrics = runtime.metrics
        state = {"status": 500, "started": False}

        async def send_wrapper(message: Message) -> None:
            if message["type"] == "http.response.start":
                state["status"] = message["status"]
                state["started"] = True
            await send(message)

        metered = path not in UNMETERED
        metrics.in_flight.labels("http").inc()
        try:
            if not metered:
                await self._call_app(scope, receive, send_wrapper, state)
                return
            refusal: LiteGEError | None = self._authenticate(scope)
            drained = False
            if refusal is None:
                body, refusal = await self._read_body(scope, receive)
            else:
                drained = await self._drain_small_body(scope, receive)
            if refusal is not None:
                response = problem_response(refusal, path)
                if not drained:
                    response.headers["Connection"] = "close"  # the unread body cannot be skipped
                await response(scope, receive, send_wrapper)
                return
            try:
                with runtime.admission.slot():
                    await self._call_app(scope, _replay(body, receive), send_wrapper, state)
            except OverloadedError as exc:
                await problem_response(exc, path)(scope, receive, send_wrapper)
        finally:
            metrics.in_flight.labels("http").dec()
            elapsed = time.perf_counter() - started
            route = scope.get("route")
            route_path = getattr(route, "path", "unmatched")
            status = state["status"]
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

    async def _call_app(
        self, scope: Scope, receive: Receive, send: Send, state: dict[str, Any]
    ) -> None:
        """The app; an exception escaping it is answered here (see the class docstring)."""
        path = scope.get("path", "")
        try:
            await self.app(scope, receive, send)
        except Exception as exc:
            if state["started"]:
                log.error("unexpected error on %s after the response started", path, exc_info=exc)
                return
            if is_out_of_memory(exc):
                error = OutOfMemoryError("the service ran out of memory for this request")
                _log_problem(path, error, 503)
                await problem_response(error, path)(scope, receive, send)
                return
            log.error("unexpected error on %s", path, exc_info=exc)
            await _internal_error(path)(scope, receive, send)

    def _authenticate(self, scope: Scope) -> AuthenticationError | None:
        """The refusal of a body-carrying request without the right key (others: the
        routes' own :func:`require_api_key`)."""
        if self.api_key is None or scope.get("method") not in BODY_METHODS:
            return None
        for name, value in scope.get("headers", ()):
            if name == b"x-api-key":
                if hmac.compare_digest(value, self.api_key):
                    return None
                break
        return AuthenticationError("missing or wrong X-API-Key header")

    async def _drain_small_body(self, scope: Scope, receive: Receive) -> bool:
        """Read and drop a body declared at most :data:`DRAIN_BYTES` long (within
        :data:`DRAIN_TIMEOUT_S`); whether all of it came."""
        declared = _declared_length(scope)
        if declared is None or declared > DRAIN_BYTES:
            return False
        size = 0
        try:
            async with asyncio.timeout(min(self.body_timeout_s, DRAIN_TIMEOUT_S)):
                while True:
                    message = await receive()
                    if message["type"] == "http.disconnect":
                        return False
                    size += len(message.get("body", b""))
                    if size > DRAIN_BYTES:
                        return False
                    if not message.get("more_body", False):
                        return True
        except TimeoutError:
            return False

    async def _read_body(self, scope: Scope, receive: Receive) -> tuple[bytes, LiteGEError | None]:
        """The whole body, or the refusal: over the size limit (declared or actual), or not
        sent within the body-read timeout."""
        declared = _declared_length(scope)
        if declared is not None and declared > self.max_body:
            return b"", self._too_large()
        chunks, size = [], 0
        try:
            async with asyncio.timeout(self.body_timeout_s):
                while True:
                    message = await receive()
                    if message["type"] == "http.disconnect":
                        break
                    chunk = message.get("body", b"")
                    size += len(chunk)
                    if size > self.max_body:
                        return b"", self._too_large()
                    chunks.append(chunk)
                    if not message.get("more_body", False):
                        break
        except TimeoutError:
            return b"", RequestTimeoutError(
                f"the request body did not arrive within {self.body_timeout_s:g} s"
            )
        return b"".join(chunks), None

    def _too_large(self) -> PayloadTooLargeError:
        return PayloadTooLargeError(f"request body exceeds the limit of {self.max_body} bytes")


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
        docs_url=None,  # served by _add_docs_routes from local files, not from a CDN
        redoc_url=None,
    )
    if runtime is not None:
        app.state.runtime = runtime

    _install_error_handlers(app)
    app.add_middleware(GuardMiddleware, settings=settings)
    _add_probe_routes(app)
    _add_shape_routes(app)
    _add_query_routes(app)
    add_viewer_routes(app, require_api_key)  # /viewer: the web viewer (service/viewer.py)
    _add_docs_routes(app)
    return app


# --------------------------------------------------------------------------- /docs

DOCS_DIR = Path(__file__).resolve().parent / "static" / "docs"
"""Swagger UI (swagger-ui-dist, pinned in ``viewer/package.json``), copied here by ``make
viewer`` (``viewer/build.mjs``); generated, not committed. ``/docs`` loads nothing else."""
DOCS_ASSETS = {
    "swagger-ui-bundle.js": "text/javascript; charset=utf-8",
    "swagger-ui.css": "text/css; charset=utf-8",
    "favicon-32x32.png": "image/png",
    "LICENSE.txt": "text/plain; charset=utf-8",
    "NOTICE.txt": "text/plain; charset=utf-8",
    "swagger-ui-bundle.js.LICENSE.txt": "text/plain; charset=utf-8",
    "VERSION.txt": "text/plain; charset=utf-8",
}
DOCS_NOT_BUILT = """<!doctype html><html lang="en"><meta charset="utf-8"><title>LiteGE API</title>
<body style="font-family:sans-serif;max-width:40em;margin:3em auto">
<h1>API docs not built</h1><p>Swagger UI's files are generated, not committed. Build them with
<code>make viewer</code> (or any <code>make serve</code> / <code>make test</code>). The OpenAPI
document itself is at <a href="{openapi}">{openapi}</a>.</p></body></html>"""


def _add_docs_routes(app: FastAPI) -> None:
    """``/docs``: Swagger UI from the service's own files (:data:`DOCS_DIR`), so the page
    works offline; ``/docs/assets/<name>`` serves exactly the files of :data:`DOCS_ASSETS`."""

    @app.get("/docs", include_in_schema=False)
    def docs(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "").rstrip("/")
        openapi = f"{root}{app.openapi_url}"
        if not (DOCS_DIR / "swagger-ui-bundle.js").is_file():
            return HTMLResponse(DOCS_NOT_BUILT.format(openapi=openapi), status_code=503)
        return get_swagger_ui_html(
            openapi_url=openapi,
            title=f"{app.title} API",
            swagger_js_url=f"{root}/docs/assets/swagger-ui-bundle.js",
            swagger_css_url=f"{root}/docs/assets/swagger-ui.css",
            swagger_favicon_url=f"{root}/docs/assets/favicon-32x32.png",
            swagger_ui_parameters={"validatorUrl": None},  # no online spec validator
        )

    @app.get("/docs/assets/{name}", include_in_schema=False)
    def docs_asset(name: str) -> FileResponse:
        path = DOCS_DIR / name
        if name not in DOCS_ASSETS or not path.is_file():
            raise StarletteHTTPException(404, f"no docs asset {name!r}")
        headers = {"Cache-Control": "no-cache"}  # revalidated (ETag): a rebuild is seen at once
        return FileResponse(path, media_type=DOCS_ASSETS[name], headers=headers)


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
                        "model": {
                            "type": "string",
                            "description": "geodesic model bundle, or 'auto' (the loaded "
                            "model with the lowest OOD score weighed with its "
                            "network-to-graph agreement; the default unless "
                            "LITEGE_DEFAULT_MODEL names one)",
                        },
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
        hash of the loaded arrays, so the same shape in any format is registered once.
        ``model: auto`` (the default while several models are loaded) scores the shape under
        every loaded model and keeps the one of lowest OOD score, weighed with each model's
        network-to-graph agreement: ``model`` names it and
        ``model_scores`` gives every model's score. A registered shape can be queried under
        any loaded model without uploading it again."""
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
    fields: dict[str, str | None] = {}
    for name in ("format", "kind", "model"):
        value = form.get(name)
        if value is not None and not isinstance(value, str):
            raise ShapeFileError(f"form field {name!r} must be text")
        fields[name] = value
    file_format = fields["format"] or PurePath(upload.filename or "").suffix.lstrip(".")
    if not file_format:
        raise UnsupportedMediaTypeError(
            "cannot tell the file format: give the file a known extension or a 'format' field"
        )
    data = await upload.read()
    shape = await runtime.parse_upload(
        runtime.load_upload, data, str(file_format), fields["kind"] or None
    )
    return shape, fields["model"] or None


async def _shape_from_json(request: Request, runtime: Runtime) -> tuple[Any, str | None]:
    def parse(body: bytes) -> tuple[Any, str | None]:
        parsed = _validated(ShapeArraysRequest, body)
        shape = runtime.shape_from_arrays(parsed.vertices, parsed.faces, parsed.kind)
        return shape, parsed.model

    return await runtime.parse_upload(parse, await request.body())


Body = TypeVar("Body", bound=pydantic.BaseModel)


def _validated(model: type[Body], body: bytes) -> Body:
    """``body`` validated as ``model`` (pydantic errors become the 422 invalid-request
    problem)."""
    try:
        return model.model_validate_json(body)
    except pydantic.ValidationError as exc:
        raise RequestValidationError(exc.errors(include_url=False)) from exc


async def _json_body(request: Request, model: type[Body]) -> Body:
    """The request's JSON body as ``model``: small bodies validated on the event loop, large
    ones in a worker thread."""
    content_type = request.headers.get("content-type", "application/json")
    media_type = content_type.split(";")[0].strip().lower()
    if media_type != "application/json" and not media_type.endswith("+json"):
        raise UnsupportedMediaTypeError(
            f"{request.url.path} takes application/json, not {media_type or 'no content type'}"
        )
    body = await request.body()
    if len(body) <= INLINE_JSON_BYTES:
        return _validated(model, body)
    try:
        return await asyncio.to_thread(_validated, model, body)
    except MemoryError:
        raise PayloadTooLargeError("the request body is too large to hold in memory") from None


def _json_request_body(model: type[pydantic.BaseModel]) -> dict[str, Any]:
    """OpenAPI of a body read by :func:`_json_body` (not by FastAPI's own body parameter)."""
    schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
    return {"requestBody": {"required": True, "content": {"application/json": {"schema": schema}}}}


def _add_query_routes(app: FastAPI) -> None:
    auth = [Depends(require_api_key)]

    @app.post(
        "/geodesic",
        tags=["queries"],
        dependencies=auth,
        response_model=GeodesicResponse,
        openapi_extra=_json_request_body(GeodesicRequest),
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
    async def geodesic(request: Request, runtime: RuntimeDep) -> Response:
        """Geodesic distances ``sources × targets`` in the shape's input units, predicted
        (``method: learned``, the default) or by a classical engine (``heat``, ``exact``,
        ``graph``); ``method`` and ``engine`` say which ran. JSON by default; ``Accept:
        application/octet-stream`` or ``application/msgpack`` for large matrices (headers
        ``X-Method``, ``X-Engine`` and, for learned, ``X-Model``)."""
        body = await _json_body(request, GeodesicRequest)
        answer, distances = await runtime.geodesic(
            body.shape_id, body.sources, body.targets, body.model, method=body.method
        )
        return _matrix_response(request, answer, distances)

    @app.post(
        "/paths",
        tags=["queries"],
        dependencies=auth,
        response_model=PathResponse,
        openapi_extra=_json_request_body(PathRequest),
    )
    async def paths(request: Request, runtime: RuntimeDep) -> PathResponse:
        """A geodesic path (polyline on the surface from source to target): the learned
        method's (``method: learned``, the default: where the model fuses its distances with
        a graph, the on-surface route they follow, an edge-flip geodesic on a mesh and the
        k-NN graph's shortest path on a cloud; elsewhere traced on the learned field,
        ``converged`` saying whether the walk reached the source), or a classical engine's
        (``exact``: the exact geodesic of a mesh; ``heat``: descent of the heat-method
        distance; ``graph``: the k-NN graph's shortest path). ``segments`` says which method
        produced which part."""
        body = await _json_body(request, PathRequest)
        result = await runtime.path(
            body.shape_id, body.source, body.target, body.model, method=body.method
        )
        return PathResponse(
            shape_id=body.shape_id,
            model=result.model,
            method=result.method,
            engine=result.engine,
            points=result.points.tolist(),
            length=result.length,
            distance=result.distance,
            segments=[PathSegment(start=i, method=how) for i, how in result.segments],
            predicted_distance=result.predicted_distance,
            n_steps=result.n_steps,
            converged=result.converged,
        )

    @app.post(
        "/correspondences",
        tags=["queries"],
        dependencies=auth,
        response_model=CorrespondenceResponse,
        openapi_extra=_json_request_body(CorrespondenceRequest),
    )
    async def correspondences(request: Request, runtime: RuntimeDep) -> Response:
        """Dense correspondence: for each query point of the source shape, the matched
        vertex/point of the target shape (learned cross-shape geodesic, coarse-to-fine
        search). Both shapes must be registered first (``POST /shapes``). With
        ``return_distance``: the distance at each match in the target's input units
        (``distances``) and in unit-area units (``distances_unit_area``). With ``refine``
        (meshes only): the matches refined with ZoomOut, ``refinement`` saying how.
        ``source_frame`` and ``target_frame`` say how each shape's canonical frame was chosen;
        a ``"split"`` check marks an uncertain frame (matches may be turned or mirrored)."""
        body = await _json_body(request, CorrespondenceRequest)
        result = await runtime.correspond(
            body.source_shape_id,
            body.target_shape_id,
            body.queries,
            body.model,
            refine=body.refine,
        )
        payload = {
            "source_shape_id": result.source_shape_id,
            "target_shape_id": result.target_shape_id,
            "model": result.model,
            "n_queries": result.n_queries,
            "matches": result.matches.tolist(),
            "distances": result.distances.tolist() if body.return_distance else None,
            "distances_unit_area": (
                result.distances_unit_area.tolist() if body.return_distance else None
            ),
            "refinement": result.refinement,
            "source_frame": result.source_frame.to_dict(),
            "target_frame": result.target_frame.to_dict(),
        }
        return Response(json.dumps(payload, allow_nan=False), media_type="application/json")


def _matrix_response(request: Request, answer: GeodesicAnswer, distances: np.ndarray) -> Response:
    rows, cols = distances.shape
    accept = request.headers.get("accept", "").lower()
    headers = {"X-Shape-Id": answer.shape_id, "X-Method": answer.method, "X-Engine": answer.engine}
    if answer.model is not None:
        headers["X-Model"] = answer.model
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
                "shape_id": answer.shape_id,
                "model": answer.model,
                "method": answer.method,
                "engine": answer.engine,
                "dtype": "<f4",
                "shape": [rows, cols],
                "data": np.ascontiguousarray(distances, dtype="<f4").tobytes(),
            }
            return Response(msgpack.packb(payload), media_type=media_type, headers=headers)
    body = {
        "shape_id": answer.shape_id,
        "model": answer.model,
        "method": answer.method,
        "engine": answer.engine,
        "rows": rows,
        "cols": cols,
        "units": "input",
        "distances": _json_matrix(distances),
    }
    return Response(json.dumps(body, allow_nan=False), media_type="application/json")


def _json_matrix(distances: np.ndarray) -> list[list[float | None]]:
    """Rows of floats; ``+inf`` (a classical engine's answer between points on different
    connected components) becomes ``null``, which JSON can say."""
    if np.isfinite(distances).all():
        return distances.tolist()
    rows = distances.astype(object)
    rows[~np.isfinite(distances)] = None
    return rows.tolist()
