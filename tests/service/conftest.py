"""Fixtures of the service tests: real servers on loopback, and real Redis servers.

The shared Redis (``LITEGE_TEST_REDIS_URL``, default ``redis://127.0.0.1:6379/15``) must be
running: tests FAIL, not skip, without it (CI starts one). Outage tests start their own
``redis-server`` on a free port (``private_redis``) so they can kill, freeze and restart it.

:class:`LiveService` runs the real :class:`~service.runtime.Runtime`, the real uvicorn server
(REST) and the real gRPC server on one asyncio loop in a daemon thread, bound to free loopback
ports, exactly as ``litege serve`` wires them.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import redis
import trimesh
import uvicorn
from redis.backoff import NoBackoff
from redis.retry import Retry

from litege_core.shape import Shape
from service.app import create_app
from service.runtime import Runtime
from service.settings import Settings

TEST_MODEL = "quadrupeds"
SHARED_REDIS_URL = os.environ.get("LITEGE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
REDIS_SERVER = shutil.which("redis-server") or "/usr/bin/redis-server"


def service_settings(**overrides: Any) -> Settings:
    """Settings of a test service: one model, CPU, loopback, quiet text logs."""
    values: dict[str, Any] = {
        "models": (TEST_MODEL,),
        "default_model": TEST_MODEL,
        "device": "cpu",
        "host": "127.0.0.1",
        "log_format": "text",
        "torch_threads": 1,
    }
    values.update(overrides)
    return Settings(**values)


class LiveService:
    """The REST (and optionally gRPC) server of one runtime, on its own loop and thread."""

    def __init__(self, settings: Settings, *, grpc: bool = False, matching: Any = None) -> None:
        self.settings = settings
        self.with_grpc = grpc
        self.matching = matching
        self.loop = asyncio.new_event_loop()
        self.runtime: Runtime | None = None
        self.base_url = ""
        self.grpc_target = ""
        self._uvicorn: uvicorn.Server | None = None
        self._grpc_server: Any = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._main, daemon=True, name="live-service")

    def start(self) -> LiveService:
        self._thread.start()
        if not self._ready.wait(120) or self._error is not None:
            raise RuntimeError(f"service did not start: {self._error!r}")
        return self

    def _main(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_until_complete(self._serve())

    async def _serve(self) -> None:
        try:
            self.runtime = await Runtime.start(self.settings, matching_model=self.matching)
            if self.with_grpc:
                from service.grpc_server import start_grpc_server

                self._grpc_server, port = await start_grpc_server(self.runtime, "127.0.0.1", 0)
                self.grpc_target = f"127.0.0.1:{port}"
            sock = socket.socket()
            sock.bind(("127.0.0.1", 0))
            self.base_url = f"http://127.0.0.1:{sock.getsockname()[1]}"
            config = uvicorn.Config(
                create_app(runtime=self.runtime), log_level="warning", access_log=False
            )
            self._uvicorn = uvicorn.Server(config)
            serving = asyncio.ensure_future(self._uvicorn.serve(sockets=[sock]))
            while not self._uvicorn.started:
                if serving.done():
                    serving.result()
                await asyncio.sleep(0.01)
        except BaseException as exc:
            self._error = exc
            self._ready.set()
            raise
        self._ready.set()
        await serving
        if self._grpc_server is not None:
            await self._grpc_server.stop(1.0)
        await self.runtime.close()

    def call(self, coroutine: Any, timeout_s: float = 60.0) -> Any:
        """Run a coroutine on the service's loop (e.g. to poke the runtime)."""
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(timeout_s)

    def stop(self) -> None:
        if self._uvicorn is not None:
            self._uvicorn.should_exit = True
        self._thread.join(timeout=30)


@pytest.fixture(scope="module")
def live_service_factory() -> Iterator[Callable[..., LiveService]]:
    """``factory(**settings)`` → a started :class:`LiveService`; all stopped at module end.
    ``matching=`` injects a matching model (e.g. ``MatchingModel.tiny_random()``)."""
    started: list[LiveService] = []

    def factory(*, grpc: bool = False, matching: Any = None, **overrides: Any) -> LiveService:
        service = LiveService(service_settings(**overrides), grpc=grpc, matching=matching).start()
        started.append(service)
        return service

    yield factory
    for service in started:
        service.stop()


@pytest.fixture(scope="session")
def test_shape(blob: Callable[..., Any]) -> Callable[[int], Shape]:
    """``test_shape(seed)``: the ``blob`` mesh with coordinates on a 1/256 grid, so that every
    file format (8 decimals in OBJ, float32 in PLY) stores them exactly and the same mesh gets
    the same content hash whatever the format."""

    def make(seed: int) -> Shape:
        shape = blob(seed)
        return Shape.from_arrays(np.round(shape.vertices * 256) / 256, shape.faces)

    return make


@pytest.fixture(scope="session")
def mesh_bytes(test_shape: Callable[[int], Shape]) -> Callable[[int, str], bytes]:
    """``mesh_bytes(seed, fmt)``: ``test_shape(seed)`` exported as OBJ/PLY/OFF bytes (vertex
    order kept)."""

    def export(seed: int, file_format: str) -> bytes:
        shape = test_shape(seed)
        mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
        data = mesh.export(file_type=file_format)
        return data.encode() if isinstance(data, str) else data

    return export


@pytest.fixture(scope="session")
def thread_pool() -> Iterator[concurrent.futures.ThreadPoolExecutor]:
    with concurrent.futures.ThreadPoolExecutor(16) as pool:
        yield pool


# --------------------------------------------------------------------------- Redis


@pytest.fixture(scope="session")
def shared_redis_url() -> str:
    """URL of the shared test Redis; fails the test clearly when it does not answer."""
    client = redis.Redis.from_url(SHARED_REDIS_URL, socket_timeout=1, socket_connect_timeout=1)
    try:
        client.ping()
    except redis.exceptions.RedisError as exc:
        pytest.fail(
            f"the store tests need a Redis server at {SHARED_REDIS_URL} ({exc}); start one "
            "with: redis-server --daemonize yes --bind 127.0.0.1 --port 6379 --save '' "
            "--appendonly no   (or set LITEGE_TEST_REDIS_URL)",
            pytrace=False,
        )
    finally:
        client.close()
    return SHARED_REDIS_URL


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class RedisProcess:
    """A private ``redis-server`` subprocess on a fixed port that tests may kill/restart."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.url = f"redis://127.0.0.1:{port}/0"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self, timeout_s: float = 5.0) -> None:
        assert self.proc is None or self.proc.poll() is not None, "already running"
        self.proc = subprocess.Popen(
            [
                REDIS_SERVER,
                "--port",
                str(self.port),
                "--bind",
                "127.0.0.1",
                "--save",
                "",
                "--appendonly",
                "no",
                "--daemonize",
                "no",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        client = redis.Redis(
            port=self.port,
            socket_timeout=0.2,
            socket_connect_timeout=0.2,
            retry=Retry(NoBackoff(), 0),  # redis-py's default retries sleep for seconds
        )
        deadline = time.monotonic() + timeout_s
        try:
            while True:
                try:
                    client.ping()
                    return
                except redis.exceptions.RedisError as exc:
                    if self.proc.poll() is not None or time.monotonic() > deadline:
                        msg = f"redis-server did not start on port {self.port}"
                        raise RuntimeError(msg) from exc
                    time.sleep(0.02)
        finally:
            client.close()

    def kill(self) -> None:
        """SIGKILL the server (an abrupt outage) and wait for it to be gone."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=5)

    def freeze(self) -> None:
        """SIGSTOP: the port still accepts connections but nothing answers (a hung server)."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGSTOP)

    def thaw(self) -> None:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGCONT)

    def client(self) -> redis.Redis:
        return redis.Redis(port=self.port, socket_timeout=1, socket_connect_timeout=1)


@pytest.fixture
def private_redis() -> Iterator[RedisProcess]:
    """A running private redis-server on a free port, killed after the test."""
    if not os.path.exists(REDIS_SERVER):
        pytest.fail(f"the outage tests need {REDIS_SERVER}", pytrace=False)
    server = RedisProcess(_free_port())
    server.start()
    yield server
    server.kill()
