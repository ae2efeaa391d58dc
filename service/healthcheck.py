"""Container health probe, so images need neither curl nor grpc_health_probe.

Usage::

    python -m service.healthcheck http://127.0.0.1:8000/readyz
    python -m service.healthcheck grpc://127.0.0.1:50051
    python -m service.healthcheck http://127.0.0.1:8000/readyz grpc://127.0.0.1:50051

Every target must be healthy; the exit status is 0 when they all are, 1 otherwise (the exit codes
Docker ``HEALTHCHECK`` and compose healthchecks expect). A target is healthy when:

* ``http://`` / ``https://``: the URL answers HTTP 200 (a 503 from ``/readyz`` while the models
  load is unhealthy). Uses the standard library only; proxies from the environment are ignored,
  since the probe always talks to the local container. When ``LITEGE_API_KEY`` is set it is sent
  as ``X-API-Key``, so the probe keeps working if health routes ever require the key.
* ``grpc://host:port[/service]``: the standard ``grpc.health.v1.Health/Check`` answers
  ``SERVING`` for ``service`` (default ``""``, the whole server).

Each check is bounded by ``--timeout`` seconds. One line per target goes to stderr; Docker keeps
it in ``docker inspect`` output. This module imports nothing from the service, so it stays cheap
even while the service is busy.
"""

from __future__ import annotations

import argparse
import os
import sys
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Sequence

DEFAULT_TIMEOUT_S = 3.0


def check_http(url: str, timeout: float = DEFAULT_TIMEOUT_S) -> tuple[bool, str]:
    """``(healthy, reason)`` for an HTTP(S) URL: healthy iff it answers 200."""
    request = urllib.request.Request(url, method="GET")
    api_key = os.environ.get("LITEGE_API_KEY")
    if api_key:
        request.add_header("X-API-Key", api_key)
    # An empty ProxyHandler: never route a local probe through HTTP(S)_PROXY.
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))
    try:
        with opener.open(request, timeout=timeout) as response:
            status = response.status
    except urllib.error.HTTPError as exc:
        return False, f"HTTP {exc.code}"
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        return False, f"unreachable: {reason}"
    return status == 200, f"HTTP {status}"


def check_grpc(
    target: str, service: str = "", timeout: float = DEFAULT_TIMEOUT_S
) -> tuple[bool, str]:
    """``(healthy, reason)`` for ``host:port``: healthy iff Health/Check(service) is SERVING."""
    import grpc
    from grpc_health.v1 import health_pb2, health_pb2_grpc

    options = [("grpc.enable_http_proxy", 0)]
    with grpc.insecure_channel(target, options=options) as channel:
        stub = health_pb2_grpc.HealthStub(channel)
        try:
            response = stub.Check(health_pb2.HealthCheckRequest(service=service), timeout=timeout)
        except grpc.RpcError as exc:
            code = exc.code() if hasattr(exc, "code") else None
            name = code.name if code is not None else type(exc).__name__
            return False, f"RPC failed: {name}"
    status = health_pb2.HealthCheckResponse.ServingStatus.Name(response.status)
    return response.status == health_pb2.HealthCheckResponse.SERVING, status


def check_target(target: str, timeout: float = DEFAULT_TIMEOUT_S) -> tuple[bool, str]:
    """Dispatch on the URL scheme; see the module docstring."""
    parsed = urllib.parse.urlsplit(target)
    if parsed.scheme in ("http", "https"):
        return check_http(target, timeout)
    if parsed.scheme == "grpc":
        if not parsed.netloc:
            return False, "grpc target needs host:port"
        return check_grpc(parsed.netloc, parsed.path.lstrip("/"), timeout)
    return False, f"unsupported scheme {parsed.scheme!r} (use http, https or grpc)"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m service.healthcheck",
        description="Exit 0 when every target is healthy, 1 otherwise.",
    )
    parser.add_argument("targets", nargs="+", metavar="TARGET", help="http(s)://… or grpc://…")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, help="seconds each")
    parser.add_argument("--quiet", action="store_true", help="print nothing")
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # Docker reserves exit status 2: a usage error is "unhealthy"
        return 0 if exc.code == 0 else 1
    healthy = True
    for target in args.targets:
        ok, reason = check_target(target, args.timeout)
        healthy = healthy and ok
        if not args.quiet:
            print(f"{'healthy' if ok else 'UNHEALTHY'} {target}: {reason}", file=sys.stderr)
    return 0 if healthy else 1


if __name__ == "__main__":
    sys.exit(main())
