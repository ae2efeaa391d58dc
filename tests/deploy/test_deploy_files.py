"""Deployment files, validated offline, and the container health probe against real servers.

* docker/ and deploy/ pass hadolint, the Compose Specification schema, the Kubernetes OpenAPI
  schemas (1.30 and the newest bundled) and the cross-file consistency checks of
  scripts/validate_deploy.py; each validator is also shown to reject a broken file, so a
  silently disabled check cannot pass.
* ``python -m service.healthcheck`` against a stdlib HTTP server (200, 503, slow, nothing
  listening) and a real gRPC server with the standard health servicer (SERVING, NOT_SERVING,
  unknown service, nothing listening).
"""

from __future__ import annotations

import copy
import importlib.util
import os
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent import futures
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, ClassVar

import grpc  # noqa: TID251 (a test of the service's probe, not litege_core)
import pytest
from grpc_health.v1 import health, health_pb2, health_pb2_grpc

from service import healthcheck

REPO = Path(__file__).resolve().parents[2]


def _load_validator():
    path = REPO / "scripts" / "validate_deploy.py"
    spec = importlib.util.spec_from_file_location("litege_validate_deploy", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve annotations through sys.modules
    spec.loader.exec_module(module)
    return module


vd = _load_validator()


# --------------------------------------------------------------------------------------------
# The real files pass every validator
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("variant", ["cpu", "gpu"])
def test_dockerfiles_pass_hadolint(variant):
    assert vd.hadolint(vd.DOCKERFILES[variant]) == []


def test_compose_files_match_the_compose_specification():
    assert vd.validate_compose() == []


def test_kubernetes_manifests_and_kustomizations_match_the_openapi_schemas():
    assert vd.validate_k8s() == []


def test_files_are_consistent_with_each_other_and_the_service_contract():
    assert vd.check_consistency() == []


def test_command_line_prints_a_summary_and_succeeds():
    result = subprocess.run(
        [sys.executable, str(REPO / "scripts" / "validate_deploy.py"), "--only", "consistency"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "consistency" in result.stdout and "1 of 1 checks clean" in result.stdout


# --------------------------------------------------------------------------------------------
# Each validator rejects broken input
# --------------------------------------------------------------------------------------------


def test_hadolint_reports_problems(tmp_path):
    dockerfile = tmp_path / "Dockerfile"
    dockerfile.write_text("FROM python\nRUN pip install requests\n")
    codes = " ".join(vd.hadolint(dockerfile))
    assert "DL3006" in codes and "DL3013" in codes and "DL3042" in codes


def test_a_hadolint_ignore_needs_a_reason(tmp_path):
    dockerfile = tmp_path / "Dockerfile"
    dockerfile.write_text(
        "FROM debian:12.8\n# hadolint ignore=DL3008\n"
        "RUN apt-get update && apt-get install -y --no-install-recommends curl "
        "&& rm -rf /var/lib/apt/lists/*\n"
    )
    assert any("without a reason" in p for p in vd.hadolint(dockerfile))
    dockerfile.write_text(dockerfile.read_text().replace("# hadolint", "# Because.\n# hadolint"))
    assert vd.unjustified_hadolint_ignores(dockerfile) == []


def test_compose_schema_rejects_unknown_and_mistyped_fields():
    document = vd.load_compose(vd.COMPOSE_FILE)
    document["services"]["api"]["heathcheck"] = document["services"]["api"]["healthcheck"]
    document["services"]["grpc"]["depends_on"] = 5
    problems = vd.validate_compose_document(document, "broken")
    assert any("heathcheck" in p for p in problems)
    assert any("services/grpc/depends_on" in p for p in problems)


def test_kubernetes_validation_rejects_typos_and_unknown_api_versions():
    documents = vd.load_k8s_documents([vd.K8S_BASE / "api.yaml"])
    deployment = copy.deepcopy(next(doc for _, doc in documents if doc["kind"] == "Deployment"))
    container = deployment["spec"]["template"]["spec"]["containers"][0]
    container["readinessProbe"]["httpGett"] = container["readinessProbe"].pop("httpGet")
    hpa = copy.deepcopy(next(doc for _, doc in documents if doc["kind"].startswith("Horizontal")))
    hpa["apiVersion"] = "autoscaling/v2beta1"  # removed in Kubernetes 1.25
    problems = vd.validate_k8s_documents([("x", deployment), ("y", hpa)], ["1.30.0"])
    assert any("httpGett" in p for p in problems)
    assert any("autoscaling/v2beta1" in p for p in problems)


def test_kustomize_render_failure_is_reported(tmp_path):
    (tmp_path / "kustomization.yaml").write_text("resources:\n  - missing.yaml\n")
    with pytest.raises(RuntimeError, match="kustomize"):
        vd.kustomize_build(tmp_path)


def _k8s() -> list[dict[str, Any]]:
    """The plain base manifests, parsed."""
    return [doc for _, doc in vd.load_k8s_documents(vd.k8s_manifest_files())]


def _find(documents, kind, name):
    return next(d for d in documents if d["kind"] == kind and d["metadata"]["name"] == name)


def _container(documents, name):
    return _find(documents, "Deployment", name)["spec"]["template"]["spec"]["containers"][0]


def _set(mapping: dict, dotted: str, value: Any) -> None:
    *parents, last = dotted.split(".")
    for key in parents:
        mapping = mapping[key]
    mapping[last] = value


K8S_BREAKAGES: dict[str, tuple[Callable[[list], None], str]] = {
    "readiness on /healthz": (
        lambda d: _set(_container(d, "litege-api"), "readinessProbe.httpGet.path", "/healthz"),
        "readinessProbe",
    ),
    "liveness on another port": (
        lambda d: _set(_container(d, "litege-api"), "livenessProbe.httpGet.port", 9000),
        "livenessProbe",
    ),
    "grpc probe on another port": (
        lambda d: _set(_container(d, "litege-grpc"), "readinessProbe.grpc.port", 50052),
        "readinessProbe",
    ),
    "service misses the container": (
        lambda d: _set(_find(d, "Service", "litege-api")["spec"]["ports"][0], "targetPort", 8080),
        "does not reach",
    ),
    "api key in the ConfigMap": (
        lambda d: _set(_find(d, "ConfigMap", "litege-config"), "data.LITEGE_API_KEY", "x"),
        "secret",
    ),
    "unknown setting": (
        lambda d: _set(_find(d, "ConfigMap", "litege-config"), "data.LITEGE_MAX_UPLOAD", "1"),
        "LITEGE_MAX_UPLOAD",
    ),
    "root allowed": (
        lambda d: _find(d, "Deployment", "litege-api")["spec"]["template"]["spec"][
            "securityContext"
        ].pop("runAsNonRoot"),
        "runAsNonRoot",
    ),
    "not litege serve": (
        lambda d: _set(_container(d, "litege-grpc"), "command", ["python", "-m", "service"]),
        "litege serve",
    ),
    "redis persists": (
        lambda d: _container(d, "litege-redis")["args"].extend(["--appendonly", "yes"]),
        "appendonly",
    ),
    "no scrape annotation": (
        lambda d: _find(d, "Deployment", "litege-api")["spec"]["template"]["metadata"].pop(
            "annotations"
        ),
        "prometheus",
    ),
    "latest image": (
        lambda d: _set(_container(d, "litege-redis"), "image", "redis:latest"),
        "not pinned",
    ),
}


@pytest.mark.parametrize("breakage", list(K8S_BREAKAGES))
def test_kubernetes_consistency_catches(breakage):
    documents = _k8s()
    assert vd.check_k8s(documents) == []
    mutate, expected = K8S_BREAKAGES[breakage]
    mutate(documents)
    problems = vd.check_k8s(documents)
    assert any(expected in p for p in problems), problems


def _api(document):
    return document["services"]["api"]


COMPOSE_BREAKAGES: dict[str, tuple[Callable[[dict], None], str]] = {
    "healthcheck on another port": (
        lambda c: _set(
            _api(c),
            "healthcheck.test",
            ["CMD", "python", "-m", "service.healthcheck", "http://127.0.0.1:8080/readyz"],
        ),
        "healthcheck",
    ),
    "fixed host port": (lambda c: _set(_api(c), "ports", ["8000:8000"]), "fixed host port"),
    "container_name": (lambda c: _set(_api(c), "container_name", "api"), "container_name"),
    "api key in environment": (
        lambda c: _set(_api(c), "environment", {**_api(c)["environment"], "LITEGE_API_KEY": ""}),
        "secret",
    ),
    "typo in a setting": (
        lambda c: _set(_api(c), "environment", {**_api(c)["environment"], "LITEGE_DEVCE": "cpu"}),
        "LITEGE_DEVCE",
    ),
    "grpc serves REST too": (
        lambda c: c["services"]["grpc"]["command"].remove("--no-rest"),
        "--no-rest",
    ),
    "redis without LRU": (
        lambda c: _set(c["services"]["redis"], "command", ["redis-server"]),
        "allkeys-lru",
    ),
    "no healthy dependency": (lambda c: _api(c).pop("depends_on"), "service_healthy"),
}


@pytest.mark.parametrize("breakage", list(COMPOSE_BREAKAGES))
def test_compose_consistency_catches(breakage):
    base = vd.load_compose(vd.COMPOSE_FILE)
    gpu = vd.load_compose(vd.COMPOSE_GPU_FILE)
    assert vd.check_compose(base, gpu) == []
    mutate, expected = COMPOSE_BREAKAGES[breakage]
    mutate(base)
    problems = vd.check_compose(base, gpu)
    assert any(expected in p for p in problems), problems


def test_gpu_overlay_renders_and_a_drain_blocking_budget_is_caught():
    rendered = vd.kustomize_build(vd.K8S_GPU)
    assert vd.check_gpu_render(rendered, "litege:0.1.0-gpu") == []
    budget = _find(rendered, "PodDisruptionBudget", "litege-grpc")["spec"]
    budget.pop("maxUnavailable")
    budget["minAvailable"] = 1  # the base value, with one GPU replica: drains would hang
    problems = vd.check_gpu_render(rendered, "litege:0.1.0-gpu")
    assert any("blocks node drains" in p for p in problems), problems
    _container(rendered, "litege-api")["resources"]["limits"].pop("nvidia.com/gpu")
    assert any("nvidia.com/gpu" in p for p in vd.check_gpu_render(rendered, "litege:0.1.0-gpu"))


def test_gpu_overlay_runs_the_gpu_image_as_shipped_and_after_the_documented_retargeting():
    """kubectl kustomize of deploy/gpu: the CUDA image for api and grpc, also when the base
    image was pointed at a registry first (the CPU image once ran there with cuda)."""
    rendered = vd.kustomize_build(vd.K8S_GPU)
    for name in ("litege-api", "litege-grpc"):
        assert _container(rendered, name)["image"] == "litege:0.1.0-gpu"
    base = vd.kustomize_build(vd.K8S_BASE)
    assert _container(base, "litege-api")["image"] == "litege:0.1.0-cpu"

    registry = "registry.example.com/litege"
    only_base = vd.gpu_images_after_retargeting(registry)
    assert set(only_base.values()) == {"litege:0.1.0-gpu"}, only_base
    both = vd.gpu_images_after_retargeting(registry, gpu_too=True)
    assert set(both.values()) == {f"{registry}:0.1.0-gpu"}, both
    assert vd.check_gpu_image_survives_a_retargeted_base() == []


def test_a_tag_only_gpu_image_override_is_caught(tmp_path, monkeypatch):
    """Without the overlay's own image (only `images: newTag`), a base retargeted to a registry
    renders the CPU image in the GPU overlay: the check names it."""
    copy_dir = tmp_path / "deploy"
    shutil.copytree(vd.DEPLOY_DIR, copy_dir)
    patch = copy_dir / "gpu" / "deployments-gpu.yaml"
    patch.write_text(patch.read_text().replace("          image: litege:0.1.0-gpu\n", ""))
    monkeypatch.setattr(vd, "DEPLOY_DIR", copy_dir)
    problems = vd.check_gpu_image_survives_a_retargeted_base()
    assert any("registry.example.com/litege:0.1.0-cpu" in p for p in problems), problems


def test_compose_gpu_override_needs_a_device_reservation():
    base = vd.load_compose(vd.COMPOSE_FILE)
    gpu = vd.load_compose(vd.COMPOSE_GPU_FILE)
    del gpu["services"]["grpc"]["deploy"]["resources"]["reservations"]
    assert any("compose gpu grpc" in p for p in vd.check_compose(base, gpu))


DOCKERFILE_BREAKAGES: dict[str, tuple[Callable[[str], str], str]] = {
    "stubs before the install": (
        lambda t: t.replace("    && python -m service.grpc_stubs \\\n", "").replace(
            "WORKDIR /app\n", "WORKDIR /app\nRUN python -m service.grpc_stubs\n"
        ),
        "stubs",
    ),
    "runs as root": (lambda t: t.replace("USER 10001:10001", "USER root"), "root"),
    "pip cache kept": (
        lambda t: t.replace("pip install --no-cache-dir torch", "pip install torch"),
        "--no-cache-dir",
    ),
    "wrong port": (lambda t: t.replace("EXPOSE 8000 50051", "EXPOSE 8080 50051"), "EXPOSE"),
    "CUDA torch in the CPU image": (
        lambda t: t.replace("whl/cpu", "whl/cu128"),
        "torch index",
    ),
    "unknown setting": (lambda t: t.replace("LITEGE_DEVICE=", "LITEGE_DEV="), "LITEGE_DEV"),
    "no health check": (
        lambda t: t.replace("HEALTHCHECK", "# HEALTHCHECK").replace('    CMD ["python"', "#"),
        "HEALTHCHECK",
    ),
    "/docs assets left out": (
        lambda t: t.replace("COPY --from=viewer /src/service/static/docs service/", "# "),
        "service/static/docs",
    ),
}


@pytest.mark.parametrize("breakage", list(DOCKERFILE_BREAKAGES))
def test_dockerfile_checks_catch(breakage, tmp_path):
    mutate, expected = DOCKERFILE_BREAKAGES[breakage]
    broken = tmp_path / "Dockerfile"
    broken.write_text(mutate(vd.DOCKERFILES["cpu"].read_text()))
    assert vd.check_dockerfile(vd.DOCKERFILES["cpu"], "cpu") == []
    problems = vd.check_dockerfile(broken, "cpu")
    assert any(expected in p for p in problems), problems


# --------------------------------------------------------------------------------------------
# LITEGE_* names: exactly the service's Settings fields
# --------------------------------------------------------------------------------------------


def test_every_settings_field_is_a_known_setting_and_nothing_else():
    from service.settings import Settings

    names = {f"LITEGE_{field.upper()}" for field in Settings.model_fields}
    assert {"LITEGE_MATCHING_MODEL", "LITEGE_STATE_CACHE_BYTES"} <= names
    assert names == vd.SETTINGS
    assert vd.unknown_settings(names) == []
    assert vd.SECRET_SETTINGS <= vd.SETTINGS
    assert vd.unknown_settings(["LITEGE_NOT_A_SETTING", "PATH", *names]) == ["LITEGE_NOT_A_SETTING"]


def test_every_setting_is_documented_for_deployments(tmp_path):
    assert vd.undocumented_settings() == []
    for name in ("LITEGE_MATCHING_CACHE_BYTES", "LITEGE_WRITE_BEHIND_BYTES"):
        assert name in (vd.K8S_BASE / "configmap.yaml").read_text()
        assert name in (vd.DOCKER_DIR / "README.md").read_text()
    assert "LITEGE_BODY_READ_TIMEOUT_S" in (vd.DOCKER_DIR / "README.md").read_text()
    stale = tmp_path / "README.md"
    stale.write_text((vd.DOCKER_DIR / "README.md").read_text().replace("LITEGE_WRITE_BEHIND", "X"))
    problems = vd.undocumented_settings([stale])
    assert len(problems) == 1 and "LITEGE_WRITE_BEHIND_BYTES" in problems[0], problems


@pytest.mark.parametrize("name", ["LITEGE_MATCHING_MODEL", "LITEGE_STATE_CACHE_BYTES"])
def test_a_deployment_may_set_settings_a_hand_written_list_missed(name, tmp_path):
    dockerfile = tmp_path / "Dockerfile"
    text = vd.DOCKERFILES["cpu"].read_text()
    dockerfile.write_text(text.replace("LITEGE_DEVICE=cpu", f"LITEGE_DEVICE=cpu \\\n    {name}=1"))
    assert f"{name}=1" in dockerfile.read_text()
    assert vd.check_dockerfile(dockerfile, "cpu") == []
    base = vd.load_compose(vd.COMPOSE_FILE)
    _set(_api(base), "environment", {**_api(base)["environment"], name: "1"})
    assert vd.check_compose(base, vd.load_compose(vd.COMPOSE_GPU_FILE)) == []


# --------------------------------------------------------------------------------------------
# compose_service_commands (reused by the compose integration test)
# --------------------------------------------------------------------------------------------


def test_compose_service_commands_give_argv_and_environment():
    commands = vd.compose_service_commands(vd.COMPOSE_FILE)
    assert set(commands) == {"api", "grpc", "redis"}
    api_argv, api_env = commands["api"]
    assert api_argv[:2] == ["litege", "serve"] and "--no-grpc" in api_argv
    assert api_env["LITEGE_REDIS_URL"] == "redis://redis:6379/0"
    assert all(isinstance(v, str) for v in api_env.values())
    grpc_argv, _ = commands["grpc"]
    assert "--no-rest" in grpc_argv and vd._option(grpc_argv, "--grpc-port") == "50051"
    redis_argv, _ = commands["redis"]
    assert redis_argv[0] == "redis-server" and vd._option(redis_argv, "--save") == ""


def test_compose_service_commands_read_env_files_and_the_gpu_override(tmp_path):
    compose = tmp_path / "docker-compose.yml"
    compose.write_text(vd.COMPOSE_FILE.read_text())
    (tmp_path / "litege.env").write_text("# secret\nLITEGE_API_KEY='s3cret'\n")
    commands = vd.compose_service_commands(compose, override=vd.COMPOSE_GPU_FILE)
    _, env = commands["grpc"]
    assert env["LITEGE_API_KEY"] == "s3cret" and env["LITEGE_DEVICE"] == "cuda"


def test_interpolation_follows_compose_rules():
    env = {"SET": "v", "EMPTY": ""}
    assert vd.interpolate("${SET:-d} ${EMPTY:-d} ${EMPTY-d} ${UNSET-d} $$SET $SET", env) == (
        "v d  d $SET v"
    )
    assert vd.interpolate({"k": ["${SET:+yes}", "${UNSET:+yes}", 3]}, env) == {"k": ["yes", "", 3]}
    with pytest.raises(vd.InterpolationError, match="needed"):
        vd.interpolate("${UNSET:?needed}", env)


# --------------------------------------------------------------------------------------------
# service.healthcheck against real servers
# --------------------------------------------------------------------------------------------


class _Handler(BaseHTTPRequestHandler):
    seen_api_keys: ClassVar[list[str | None]] = []

    def do_GET(self):
        type(self).seen_api_keys.append(self.headers.get("X-API-Key"))
        if self.path == "/slow":
            time.sleep(2)
        status = {"/readyz": 200, "/slow": 200}.get(self.path, 503)
        body = b'{"ready": true}' if status == 200 else b'{"ready": false}'
        self.send_response(status)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args):
        pass


@pytest.fixture(scope="module")
def http_base() -> Iterator[str]:
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_http_200_is_healthy(http_base):
    assert healthcheck.main([f"{http_base}/readyz"]) == 0


def test_http_503_is_unhealthy(http_base):
    assert healthcheck.check_http(f"{http_base}/not-ready") == (False, "HTTP 503")
    assert healthcheck.main([f"{http_base}/not-ready"]) == 1


def test_http_nothing_listening_is_unhealthy():
    ok, reason = healthcheck.check_http(f"http://127.0.0.1:{_free_port()}/readyz", timeout=2)
    assert not ok and reason.startswith("unreachable")


def test_http_timeout_is_unhealthy_and_bounded(http_base):
    start = time.monotonic()
    assert healthcheck.main(["--timeout", "0.3", f"{http_base}/slow"]) == 1
    assert time.monotonic() - start < 1.5


def test_http_probe_ignores_proxies_and_sends_the_api_key(http_base, monkeypatch):
    monkeypatch.setenv("http_proxy", f"http://127.0.0.1:{_free_port()}")
    monkeypatch.setenv("HTTP_PROXY", f"http://127.0.0.1:{_free_port()}")
    monkeypatch.setenv("LITEGE_API_KEY", "k3y")
    _Handler.seen_api_keys.clear()
    assert healthcheck.main([f"{http_base}/readyz"]) == 0
    assert _Handler.seen_api_keys == ["k3y"]


def test_every_target_must_be_healthy_and_bad_usage_is_unhealthy(http_base):
    assert healthcheck.main([f"{http_base}/readyz", f"{http_base}/not-ready"]) == 1
    assert healthcheck.main(["ftp://127.0.0.1/"]) == 1
    assert healthcheck.main(["grpc://"]) == 1
    assert healthcheck.main([]) == 1
    assert healthcheck.main(["--timeout", "soon", f"{http_base}/readyz"]) == 1


@pytest.fixture(scope="module")
def grpc_health() -> Iterator[tuple[str, health.HealthServicer]]:
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=2))
    servicer = health.HealthServicer()
    health_pb2_grpc.add_HealthServicer_to_server(servicer, server)
    port = server.add_insecure_port("127.0.0.1:0")
    server.start()
    yield f"127.0.0.1:{port}", servicer
    server.stop(grace=None)


def test_grpc_serving_is_healthy(grpc_health):
    target, servicer = grpc_health
    servicer.set("", health_pb2.HealthCheckResponse.SERVING)
    assert healthcheck.check_grpc(target) == (True, "SERVING")
    assert healthcheck.main([f"grpc://{target}"]) == 0


def test_grpc_not_serving_is_unhealthy(grpc_health):
    target, servicer = grpc_health
    servicer.set("", health_pb2.HealthCheckResponse.NOT_SERVING)
    try:
        assert healthcheck.check_grpc(target) == (False, "NOT_SERVING")
        assert healthcheck.main([f"grpc://{target}"]) == 1
    finally:
        servicer.set("", health_pb2.HealthCheckResponse.SERVING)


def test_grpc_named_service(grpc_health):
    target, servicer = grpc_health
    servicer.set("litege.v1.LiteGE", health_pb2.HealthCheckResponse.SERVING)
    assert healthcheck.main([f"grpc://{target}/litege.v1.LiteGE"]) == 0
    ok, reason = healthcheck.check_grpc(target, "no.such.Service")
    assert not ok and "NOT_FOUND" in reason


def test_grpc_nothing_listening_is_unhealthy_and_bounded():
    start = time.monotonic()
    ok, reason = healthcheck.check_grpc(f"127.0.0.1:{_free_port()}", timeout=2)
    assert not ok and "UNAVAILABLE" in reason
    assert time.monotonic() - start < 5


def test_grpc_probe_ignores_proxies(grpc_health, monkeypatch):
    target, servicer = grpc_health
    servicer.set("", health_pb2.HealthCheckResponse.SERVING)
    for name in ("grpc_proxy", "https_proxy", "http_proxy"):
        monkeypatch.setenv(name, f"http://127.0.0.1:{_free_port()}")
    assert healthcheck.main([f"grpc://{target}"]) == 0


def test_module_entry_point_as_docker_runs_it(http_base, grpc_health):
    target, servicer = grpc_health
    servicer.set("", health_pb2.HealthCheckResponse.SERVING)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run(
        [sys.executable, "-m", "service.healthcheck", f"{http_base}/readyz", f"grpc://{target}"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=REPO,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr.count("healthy") == 2
