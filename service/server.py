"""``litege serve``: the REST and gRPC servers in one process, sharing one runtime."""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys

import uvicorn

from litege_core import __version__
from service.logs import configure_logging
from service.settings import Settings

SHUTDOWN_GRACE_S = 10.0


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


async def serve(settings: Settings, *, rest: bool = True, grpc: bool = True) -> None:
    """Run until SIGINT/SIGTERM, then drain: stop accepting, finish in-flight requests and
    queued work, close the store."""
    from service.app import create_app
    from service.grpc_server import start_grpc_server, stop_grpc_server
    from service.runtime import Runtime

    if not (rest or grpc):
        raise ValueError("nothing to serve: both REST and gRPC are disabled")
    runtime = await Runtime.start(settings)
    grpc_server = None
    try:
        if grpc:
            grpc_server, _ = await start_grpc_server(runtime, settings.host, settings.grpc_port)
        print(banner(settings, rest, grpc, str(runtime.device)), flush=True)
        stop = _stop_on_signals()
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
            await asyncio.wait(
                [serving, asyncio.ensure_future(stop.wait())], return_when="FIRST_COMPLETED"
            )
            rest_server.should_exit = True  # stop accepting, finish in-flight requests
            await serving
        else:
            await stop.wait()
    finally:
        if grpc_server is not None:
            await stop_grpc_server(grpc_server, SHUTDOWN_GRACE_S)
        await runtime.close()


def _stop_on_signals() -> asyncio.Event:
    """An event set by SIGINT/SIGTERM (the process then drains and exits with status 0)."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, stop.set)
    return stop


class _DrainingServer(uvicorn.Server):
    """uvicorn without its own signal handling: :func:`serve` owns the signals so that the
    gRPC server and the runtime drain after the REST server, and the exit status is 0 (uvicorn
    would re-raise the signal and kill the process before that)."""

    @contextlib.contextmanager
    def capture_signals(self):  # type: ignore[override]
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
    overrides = {
        k: v for k, v in (("host", host), ("port", port), ("grpc_port", grpc_port)) if v is not None
    }
    settings = Settings(**overrides)
    configure_logging(settings.log_format, settings.log_level)
    try:
        asyncio.run(serve(settings, rest=rest, grpc=grpc))
    except KeyboardInterrupt:  # pragma: no cover - second Ctrl-C
        sys.exit(130)
