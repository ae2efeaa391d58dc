"""``litege serve`` (:mod:`service.server`): both servers stop taking work at once on
shutdown, and a bad setting stops the start-up with a message that never echoes a secret."""

from __future__ import annotations

import asyncio
import socket
import threading
import time
from typing import Any

import grpc
import httpx
import pytest

from service import grpc_stubs, server
from service.settings import Settings


def service_settings(**overrides: Any) -> Settings:
    values = {"models": ("quadrupeds",), "device": "cpu", "log_format": "text"}
    return Settings(**(values | overrides))


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class Served:
    """:func:`service.server.serve` on its own loop and thread, stopped by an event."""

    def __init__(self, **overrides: Any) -> None:
        self.settings = service_settings(port=_free_port(), grpc_port=_free_port(), **overrides)
        self.loop = asyncio.new_event_loop()
        self.stop = asyncio.Event()
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._main, daemon=True)

    def _main(self) -> None:
        try:
            self.loop.run_until_complete(server.serve(self.settings, stop=self.stop))
        except BaseException as exc:  # reported by the test
            self.error = exc

    def start(self) -> Served:
        self.thread.start()
        url = f"http://127.0.0.1:{self.settings.port}/readyz"
        deadline = time.monotonic() + 120
        while True:
            assert self.thread.is_alive(), f"serve() ended: {self.error!r}"
            assert time.monotonic() < deadline, "serve() did not start"
            try:
                if httpx.get(url, timeout=1).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            time.sleep(0.05)

    def wait_in_flight(self, count: int) -> None:
        """Until ``count`` HTTP requests are being served (the asking one included)."""
        url = f"http://127.0.0.1:{self.settings.port}/metrics"
        line = 'litege_requests_in_flight{protocol="http"}'
        for _ in range(1000):
            text = httpx.get(url, timeout=5).text
            value = next(float(v.split()[-1]) for v in text.splitlines() if v.startswith(line))
            if value >= count:
                return
            time.sleep(0.01)
        raise AssertionError("the request never arrived")

    def shutdown(self) -> None:
        self.loop.call_soon_threadsafe(self.stop.set)


def test_grpc_stops_taking_calls_while_rest_drains():
    """A REST request still in flight (its body arrives slowly) keeps the REST server
    draining; meanwhile gRPC takes no new call."""
    served = Served(body_read_timeout_s=5.0).start()
    pb2, pb2_grpc = grpc_stubs.load_stubs()
    target = f"127.0.0.1:{served.settings.grpc_port}"
    with grpc.insecure_channel(target) as channel:
        stub = pb2_grpc.LiteGEStub(channel)
        with pytest.raises(grpc.RpcError) as before:
            stub.GetShape(pb2.ShapeRef(shape_id="0" * 64), timeout=10)
        assert before.value.code() == grpc.StatusCode.NOT_FOUND  # serving
        slow = socket.create_connection(("127.0.0.1", served.settings.port))
        slow.sendall(
            b"POST /geodesic HTTP/1.1\r\nHost: t\r\nContent-Type: application/json\r\n"
            b"Content-Length: 100\r\n\r\n{"
        )
        served.wait_in_flight(2)  # the slow request, and the /metrics request asking
        served.shutdown()
        refused = None
        for _ in range(500):  # the stop reaches the servers within a few loop turns
            try:
                stub.GetShape(pb2.ShapeRef(shape_id="0" * 64), timeout=2)
            except grpc.RpcError as exc:
                if exc.code() != grpc.StatusCode.NOT_FOUND:
                    refused = exc.code()
                    break
            time.sleep(0.02)
        assert refused in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.CANCELLED)  # not taken
        assert served.thread.is_alive(), "REST is still draining the slow request"
    slow.settimeout(30)
    answer = slow.recv(65536).decode()
    slow.close()
    assert answer.startswith("HTTP/1.1 408"), answer
    served.thread.join(60)
    assert not served.thread.is_alive() and served.error is None


@pytest.mark.parametrize(
    ("variable", "value", "secret"),
    [
        ("LITEGE_API_KEY", "short-secret", "short-secret"),
        ("LITEGE_REDIS_URL", "http://admin:hunter2@cache:6379/0", "hunter2"),
        ("LITEGE_MAX_QUERIES", "many-hunter2", "hunter2"),
    ],
)
def test_a_bad_setting_stops_start_up_without_echoing_it(
    monkeypatch, capsys, variable, value, secret
):
    monkeypatch.setenv(variable, value)
    with pytest.raises(SystemExit) as stopped:
        server.run()
    message = str(stopped.value.code)
    captured = capsys.readouterr()
    assert "invalid settings" in message and variable.split("_", 1)[1][:4] in message.upper()
    for text in (message, captured.out, captured.err):
        assert secret not in text
