"""The docker-compose entrypoints, run as plain processes against a real Redis: the REST-only
``api`` and the gRPC-only ``grpc`` service share shapes through Redis, answer their
healthchecks, and shut down cleanly on SIGTERM (no Docker engine here, so the same commands
run without containers)."""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from service.client import LiteGEClient
from service.grpc_client import GrpcClient

ROOT = Path(__file__).resolve().parents[2]


def _validate_deploy():
    spec = importlib.util.spec_from_file_location(
        "validate_deploy", ROOT / "scripts/validate_deploy.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve annotations through sys.modules
    spec.loader.exec_module(module)
    return module


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _with_flag(argv: list[str], flag: str, value: str) -> list[str]:
    argv = list(argv)
    argv[argv.index(flag) + 1] = value
    return argv


def _healthy(target: str, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        probe = subprocess.run(
            [sys.executable, "-m", "service.healthcheck", target], capture_output=True
        )
        if probe.returncode == 0:
            return
        time.sleep(0.5)
    raise AssertionError(f"{target} never became healthy")


@pytest.fixture
def compose_processes(private_redis, tmp_path):
    commands = _validate_deploy().compose_service_commands()
    assert set(commands) >= {"api", "grpc", "redis"}
    rest_port, grpc_port = _free_port(), _free_port()
    launched = {}
    for name, port_flag, port in (("api", "--port", rest_port), ("grpc", "--grpc-port", grpc_port)):
        argv, env = commands[name]
        assert argv[:2] == ["litege", "serve"]
        argv = _with_flag(_with_flag(argv, "--host", "127.0.0.1"), port_flag, str(port))
        argv[0] = shutil.which("litege", path=str(Path(sys.executable).parent)) or "litege"
        env = {**os.environ, **env}
        assert env["LITEGE_REDIS_URL"].startswith("redis://redis:")
        env.update(
            LITEGE_REDIS_URL=private_redis.url,
            LITEGE_MODELS="quadrupeds",
            LITEGE_TORCH_THREADS="1",
            OMP_NUM_THREADS="1",
        )
        log = (tmp_path / f"{name}.log").open("wb")
        launched[name] = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        _healthy(f"http://127.0.0.1:{rest_port}/readyz")
        _healthy(f"grpc://127.0.0.1:{grpc_port}")
        yield launched, f"http://127.0.0.1:{rest_port}", f"127.0.0.1:{grpc_port}", tmp_path
    finally:
        for process in launched.values():
            if process.poll() is None:
                process.kill()
                process.wait(10)


def test_api_and_grpc_share_shapes_through_redis(compose_processes, mesh_bytes):
    processes, base_url, grpc_target, logs = compose_processes
    with LiteGEClient(base_url) as rest:
        info = rest.register_file(mesh_bytes(1, "obj"), file_format="obj")
        over_rest = rest.geodesic(info["shape_id"], [0, 5], [7, 8, 9])
    with GrpcClient(grpc_target) as grpc_client:
        assert grpc_client.health() == "SERVING"
        shape = grpc_client.get_shape(info["shape_id"])
        over_grpc = grpc_client.geodesic(info["shape_id"], [0, 5], [7, 8, 9])
    assert shape["created"] is False  # the gRPC process found it in Redis
    np.testing.assert_allclose(over_grpc, over_rest, rtol=1e-6)

    for process in processes.values():
        process.send_signal(signal.SIGTERM)
    for name, process in processes.items():
        assert process.wait(30) == 0, (logs / f"{name}.log").read_text()[-2000:]
