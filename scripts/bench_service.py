"""Load-test the REST service on loopback and measure its overhead and cache footprint.

Usage:
    python scripts/bench_service.py [--duration 5] [--concurrency 1,4,16,64] [--redis]

What it does (one machine; the load generator shares the CPUs with the server):

* starts ``litege serve --no-grpc`` as a separate process (quadrupeds model, CPU, one torch
  thread, in-process cache, or a private ``redis-server`` with ``--redis``);
* registers a procedural dog (template topology, 3,900 vertices) and, for each concurrency
  level, runs closed-loop clients (asyncio + httpx, one connection each) for ``--duration``
  seconds against: ``POST /geodesic`` (1 source × 100 targets, JSON) on the cached shape,
  ``POST /shapes`` re-uploading the cached shape (OBJ, idempotent: parse + hash + lookup),
  and ``POST /shapes`` of new shapes (every request a different dog: full registration);
* service overhead: median latency of one client, one request at a time, minus the median of
  the same query through the library in this process (``Predictor.distances``);
* Redis footprint (``--redis``): ``MEMORY USAGE`` of each shape's keys.

Prints markdown with the machine, the date and the versions.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from datetime import date
from http.client import HTTPConnection
from pathlib import Path

import httpx
import numpy as np
import torch
import trimesh

from litege_core import __version__
from litege_core.learned import Predictor, load_shipped
from litege_core.shape import Shape
from litege_core.synth import generate_shape

sys.path.insert(0, str(Path(__file__).parent))
from litege_core.evaluation.speed import cpu_name

N_TARGETS = 100


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def dog(seed: int) -> Shape:
    generated = generate_shape("quadruped", "dog", seed)
    return Shape.from_arrays(generated.vertices, generated.faces)


def obj_bytes(shape: Shape) -> bytes:
    mesh = trimesh.Trimesh(shape.vertices, shape.faces, process=False)
    return mesh.export(file_type="obj").encode()


def start_server(port: int, redis_url: str | None) -> subprocess.Popen[bytes]:
    env = dict(os.environ)
    env.update(
        LITEGE_MODELS="quadrupeds",
        LITEGE_DEFAULT_MODEL="quadrupeds",
        LITEGE_DEVICE="cpu",
        LITEGE_TORCH_THREADS="1",
        LITEGE_LOG_LEVEL="WARNING",
        OMP_NUM_THREADS="1",
    )
    if redis_url:
        env["LITEGE_REDIS_URL"] = redis_url
    command = [sys.executable, "-m", "litege_core.cli", "serve", "--no-grpc", "--port", str(port)]
    process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=1).status_code == 200:
                return process
        except httpx.HTTPError:
            pass
        if process.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError("the service did not start")
        time.sleep(0.2)


async def closed_loop(
    base_url: str, make_request, concurrency: int, duration_s: float
) -> tuple[list[float], int]:
    """``concurrency`` clients each sending the next request as soon as the last returned."""
    latencies: list[float] = []
    errors = 0
    stop_at = time.perf_counter() + duration_s
    counter = iter(range(10**9))

    async def client() -> None:
        nonlocal errors
        async with httpx.AsyncClient(base_url=base_url, timeout=120) as http:
            while time.perf_counter() < stop_at:
                method, url, kwargs = make_request(next(counter))
                started = time.perf_counter()
                response = await http.request(method, url, **kwargs)
                latencies.append(time.perf_counter() - started)
                errors += response.status_code >= 400

    await asyncio.gather(*(client() for _ in range(concurrency)))
    return latencies, errors


def row(name: str, concurrency: int, latencies: list[float], errors: int, duration: float) -> str:
    ms = np.asarray(latencies) * 1000
    return (
        f"| {name} | {concurrency} | {len(ms)} | {len(ms) / duration:.1f} | "
        f"{np.percentile(ms, 50):.2f} | {np.percentile(ms, 99):.2f} | {errors} |"
    )


def redis_process() -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    process = subprocess.Popen(
        [
            "redis-server",
            "--port",
            str(port),
            "--bind",
            "127.0.0.1",
            "--save",
            "",
            "--appendonly",
            "no",
        ],
        stdout=subprocess.DEVNULL,
    )
    time.sleep(0.5)
    return process, f"redis://127.0.0.1:{port}/0"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--concurrency", default="1,4,16,64")
    parser.add_argument("--new-shape-concurrency", default="1,4")
    parser.add_argument("--overhead-runs", type=int, default=300)
    parser.add_argument("--redis", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    levels = [int(c) for c in args.concurrency.split(",")]
    redis_proc, redis_url = redis_process() if args.redis else (None, None)
    port = free_port()
    server = start_server(port, redis_url)
    base_url = f"http://127.0.0.1:{port}"
    try:
        shape = dog(2_000_000)
        data = obj_bytes(shape)
        with httpx.Client(base_url=base_url, timeout=120) as http:
            shape_id = http.post("/shapes", files={"file": ("dog.obj", data)}).json()["shape_id"]
        rng = np.random.default_rng(0)

        def geodesic(i: int):
            picks = rng.integers(0, shape.n_points, N_TARGETS + 1).tolist()
            body = {"shape_id": shape_id, "sources": picks[:1], "targets": picks[1:]}
            return "POST", "/geodesic", {"json": body}

        def upload_cached(i: int):
            return "POST", "/shapes", {"files": {"file": ("dog.obj", data)}}

        fresh = [obj_bytes(dog(3_000_000 + i)) for i in range(400)]

        def upload_new(i: int):
            return "POST", "/shapes", {"files": {"file": ("dog.obj", fresh[i % len(fresh)])}}

        rows = []
        for name, request, concurrencies in (
            ("POST /geodesic, cached shape, 1×100", geodesic, levels),
            ("POST /shapes, cached shape (OBJ re-upload)", upload_cached, levels),
            (
                "POST /shapes, new shape (full registration)",
                upload_new,
                [int(c) for c in args.new_shape_concurrency.split(",")],
            ),
        ):
            for concurrency in concurrencies:
                latencies, errors = asyncio.run(
                    closed_loop(base_url, request, concurrency, args.duration)
                )
                rows.append(row(name, concurrency, latencies, errors, args.duration))

        # overhead: one request at a time through HTTP vs the library in-process
        sources, targets = [17], list(range(0, 3900, 39))
        body = {"shape_id": shape_id, "sources": sources, "targets": targets}
        predictor = Predictor(load_shipped("quadrupeds"))  # the service's defaults
        state = predictor.register(shape)
        library, service = [], []
        # a bare keep-alive connection, so the client's own cost stays out of the overhead
        connection = HTTPConnection("127.0.0.1", port, timeout=120)
        payload = json.dumps(body).encode()
        headers = {"content-type": "application/json"}

        def post() -> None:
            connection.request("POST", "/geodesic", payload, headers)
            response = connection.getresponse()
            response.read()
            if response.status != 200:
                raise RuntimeError(f"/geodesic answered {response.status}")

        for _ in range(20):
            post()
            predictor.distances(state, sources, targets)
        for _ in range(args.overhead_runs):
            started = time.perf_counter()
            predictor.distances(state, sources, targets)
            library.append(time.perf_counter() - started)
            started = time.perf_counter()
            post()
            service.append(time.perf_counter() - started)
        connection.close()
        footprint = []
        if redis_url:
            import redis

            client = redis.Redis.from_url(redis_url)
            for key in sorted(client.keys("litege:*")):
                footprint.append((key.decode().rsplit(":", 1)[1], client.memory_usage(key)))
    finally:
        server.terminate()
        server.wait(30)
        if redis_proc is not None:
            redis_proc.terminate()

    store_name = "Redis (private redis-server)" if redis_url else "in-process"
    print(f"### Service load test ({date.today().isoformat()})\n")
    print(
        f"- machine: {cpu_name()}, {os.cpu_count()} logical CPUs; server and load generator on "
        "the same machine (loopback), server with one torch thread, CPU"
    )
    print(
        f"- versions: litege {__version__}, python {platform.python_version()}, torch "
        f"{torch.__version__}; store: {store_name}"
    )
    print(
        f"- data: procedural dog, {shape.n_points} vertices; closed-loop clients for "
        f"{args.duration:g} s per row; command: `python scripts/bench_service.py "
        f"{' '.join(sys.argv[1:])}`\n"
    )
    print("| request | clients | requests | req/s | p50 ms | p99 ms | errors |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    print("\n".join(rows))
    lib_ms = statistics.median(library) * 1000
    svc_ms = statistics.median(service) * 1000
    print(
        f"\nService overhead for a cached shape (1 source × {len(targets)} targets, "
        f"{args.overhead_runs} alternating runs, medians): library {lib_ms:.3f} ms, "
        f"HTTP round trip {svc_ms:.3f} ms, overhead **{svc_ms - lib_ms:.3f} ms** (target ≤ 2 ms)."
    )
    if footprint:
        by_artifact: dict[str, list[int]] = {}
        for artifact, size in footprint:
            by_artifact.setdefault(artifact, []).append(size)
        parts = ", ".join(
            f"{a} {statistics.mean(s) / 1024:.1f} KiB" for a, s in sorted(by_artifact.items())
        )
        n_shapes = len(by_artifact.get("arrays", []))
        total = sum(size for _, size in footprint) / max(1, n_shapes) / 1024
        print(
            f"\nRedis memory per cached shape ({n_shapes} shapes of {shape.n_points} vertices, "
            f"MEMORY USAGE): {parts}; **{total:.1f} KiB per shape**."
        )


if __name__ == "__main__":
    main()
