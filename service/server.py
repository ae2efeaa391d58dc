"""``litege serve``: the REST and gRPC servers in one process, sharing one runtime."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pydantic
import uvicorn

from litege_core import __version__
from service.logs import configure_logging
from service.settings import Settings

if TYPE_CHECKING:
    from service.runtime import Runtime

log = logging.getLogger("litege.server")

SHUTDOWN_GRACE_S = 10
"""Time in-flight requests and calls get after SIGTERM, over REST and gRPC together (whole
seconds: uvicorn's ``timeout_graceful_shutdown`` is an int)."""


def banner(settings: Settings, rest: bool, grpc: bool, device: str) -> str:
    """What ``litege serve`` prints at start-up: where it listens and with which defaults."""
    store = (
        f"redis {settings.public_summary()['redis_url']} (+ {settings.hot_cache_bytes >> 20} MiB "
        "in-process hot tier)"
        if settings.redis_url
        else f"in-process ({settings.memory_cache_bytes >> 20} MiB, set LITEGE_REDIS_URL for Redis)"
    )
    lines = [f"LiteGE {__version__}"]
    if rest:
        url = f"http://{settings.host}:{settings.port}"
        lines.append(f"  REST   {url}  (docs {url}/docs, metrics {url}/metrics)")
    if grpc:
        lines.append(f"  gRPC   {settings.host}:{settings.grpc_port}  (health, reflection)")
    lines += [
        f"  models {', '.join(settings.models)} (default {settings.default_model}) on {device}",
        f"  cache  {store}",
        f"  auth   {'X-API-Key required' if settings.api_key else 'none (set LITEGE_API_KEY)'}",
    ]
    return "\n".join(lines)


async def serve(
    settings: Settings,
    *,
    rest: bool = True,
    grpc: bool = True,
    stop: asyncio.Event | None = None,
) -> None:
    """Run until SIGINT/SIGTERM (or ``stop`` is set), then drain within
    :data:`SHUTDOWN_GRACE_S` (see :func:`_drain`)."""
    from service.app import create_app
    from service.grpc_server import start_grpc_server
    from service.runtime import Runtime

    if not (rest or grpc):
        raise ValueError("nothing to serve: both REST and gRPC are disabled")
    runtime = await Runtime.start(settings)
    grpc_server = None
    rest_server = serving = None
    try:
        if grpc:
            grpc_server, _ = await start_grpc_server(runtime, settings.host, settings.grpc_port)
        stop = stop if stop is not None else _stop_on_signals()
        waits: list[asyncio.Future[Any]] = [asyncio.ensure_future(stop.wait())]
        if rest:
            config = uvicorn.Config(
                create_app(runtime=runtime),
                host=settings.host,
                port=settings.port,
                log_config=None,
                access_log=False,
                http="httptools",
                timeout_graceful_shutdown=SHUTDOWN_GRACE_S,
            )
            rest_server = _DrainingServer(config)
            serving = asyncio.ensure_future(rest_server.serve())
            waits.append(serving)
        print(banner(settings, rest, grpc, str(runtime.device)), flush=True)
        await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        waits[0].cancel()
        if serving is not None and serving.done():
            serving.result()  # the REST server could not start (e.g. port in use)
    finally:
        await _drain(runtime, rest_server, serving, grpc_server, SHUTDOWN_GRACE_S)


async def _drain(
    runtime: Runtime,
    rest_server: uvicorn.Server | None,
    serving: asyncio.Future[Any] | None,
    grpc_server: Any,
    grace_s: float,
) -> None:
    """Stop both servers at once (neither takes new requests or calls from here on; in-flight
    ones get the grace period, the same for both), then the runtime with what is left of it
    (queued compute jobs beyond it answer not-ready). Total: about ``grace_s``, not the sum
    of the servers' graces."""
    from service.grpc_server import stop_grpc_server

    deadline = time.monotonic() + grace_s
    stopping = []
    if grpc_server is not None:
        stopping.append(stop_grpc_server(grpc_server, grace_s))
    if rest_server is not None and serving is not None:
        rest_server.should_exit = True  # stop accepting, finish in-flight requests

        async def rest_drained() -> None:
            with contextlib.suppress(Exception, SystemExit):
                await serving

        stopping.append(rest_drained())
    results = await asyncio.gather(*stopping, return_exceptions=True)
    for result in results:
        if isinstance(result, BaseException):
            log.warning("shutdown: a server did not stop cleanly: %s", result)
    await runtime.close(timeout_s=max(0.0, deadline - time.monotonic()))


def _stop_on_signals() -> asyncio.Event:
    """An event set by SIGINT/SIGTERM (the process then drains and exits with status 0)."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    return stop


class _DrainingServer(uvicorn.Server):
    """uvicorn without its own signal handling: :func:`serve` owns the signals so that both
    servers and the runtime drain together, and the exit status is 0 (uvicorn would re-raise
    the signal and kill the process before that)."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


def run(
    host: str | None = None,
    port: int | None = None,
    grpc_port: int | None = None,
    *,
    rest: bool = True,
    grpc: bool = True,
) -> None:
    """Blocking entry point of ``litege serve`` (settings from ``LITEGE_*``, flags win)."""
    overrides: dict[str, Any] = {  # checked by Settings
        k: v for k, v in (("host", host), ("port", port), ("grpc_port", grpc_port)) if v is not None
    }
    try:
        settings = Settings(**overrides)
    except pydantic.ValidationError as exc:
        sys.exit(f"litege serve: invalid settings:\n{_settings_errors(exc)}")
    configure_logging(settings.log_format, settings.log_level)
    try:
        asyncio.run(serve(settings, rest=rest, grpc=grpc))
    except KeyboardInterrupt:  # pragma: no cover - second Ctrl-C
        sys.exit(130)


def _settings_errors(exc: pydantic.ValidationError) -> str:
    """One line per invalid setting, naming its variable and never echoing its value (an API
    key, a URL with a password)."""
    lines = []
    for error in exc.errors(include_url=False, include_input=False, include_context=False):
        field = ".".join(str(part) for part in error["loc"])
        name = f"LITEGE_{field.upper()}" if field else "settings"
        lines.append(f"  {name}: {error['msg']}")
    return "\n".join(lines)


def add_serve_command(commands: argparse._SubParsersAction) -> None:
    """Register ``litege serve`` on the CLI (entry point ``litege.commands``, pyproject)."""
    serve = commands.add_parser(
        "serve",
        help="start the REST and gRPC service",
        description="Start the REST (FastAPI) and gRPC servers in one process. Every setting "
        "comes from LITEGE_* environment variables (see README); these flags override them.",
    )
    serve.add_argument("--host", default=None, help="bind address (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=None, help="REST port (default 8000)")
    serve.add_argument("--grpc-port", type=int, default=None, help="gRPC port (default 50051)")
    serve.add_argument("--no-rest", action="store_true", help="serve gRPC only")
    serve.add_argument("--no-grpc", action="store_true", help="serve REST only")

    def handler(args: argparse.Namespace) -> int:
        run(args.host, args.port, args.grpc_port, rest=not args.no_rest, grpc=not args.no_grpc)
        return 0

    serve.set_defaults(handler=handler)
