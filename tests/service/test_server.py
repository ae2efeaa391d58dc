"""The milestone server answers over real HTTP and says what it does not serve yet."""

import socket
import threading
import time

import httpx
import pytest
import uvicorn

from service.server import NOT_YET_SERVED, create_app


@pytest.fixture(scope="module")
def base_url():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = uvicorn.Server(
        uvicorn.Config(create_app(), host="127.0.0.1", port=port, log_level="warning")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not server.started:
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.02)
    yield f"http://127.0.0.1:{port}"
    server.should_exit = True
    thread.join(timeout=10)


def test_healthz(base_url):
    response = httpx.get(f"{base_url}/healthz")
    assert response.status_code == 200 and response.json() == {"status": "ok"}


def test_version_is_honest_about_missing_endpoints(base_url):
    body = httpx.get(f"{base_url}/version").json()
    assert body["not_yet_served"] == list(NOT_YET_SERVED)
    for route in NOT_YET_SERVED:
        assert httpx.post(f"{base_url}{route}").status_code == 404
