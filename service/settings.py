"""Service settings: one validated class, read from ``LITEGE_*`` environment variables."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

MiB = 1024 * 1024
AUTO_MODEL = "auto"
"""The model name that picks, per shape, the loaded model with the lowest OOD score."""


class Settings(BaseSettings):
    """Every knob of the service. Defaults are the embedded single-machine setup: in-process
    cache, shipped models, CPU unless a GPU is present, no API key, loopback only."""

    model_config = SettingsConfigDict(
        env_prefix="LITEGE_", extra="ignore", frozen=True, hide_input_in_errors=True
    )
    """``hide_input_in_errors``: a start-up error never prints a value (API key, URLs)."""

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    grpc_port: int = Field(50051, ge=0, le=65535)

    models: Annotated[tuple[str, ...], NoDecode] = ("quadrupeds", "humans")
    default_model: str = "auto"
    """Geodesic model of a registration or query that names none: ``auto`` (every loaded model
    scores the shape and the lowest out-of-distribution z-score, weighed with the model's
    network-to-graph agreement, wins: ``litege_core.learned.routing.choose_model``; with one
    model loaded, that one) or the name of a loaded model (then a query naming no model uses
    the first model, this one first, that the shape is registered under)."""
    router: str = "shipped"
    """How ``auto`` picks a model: ``shipped`` (the package's category router, where it ships
    one: its category where it is confident, else the rule above), ``none`` (the rule above
    alone) or a router directory (``scripts/train_router.py``)."""
    geodesic_fusion: Literal["auto", "none", "graph"] = "auto"
    """``auto`` (default): every learned geodesic answer of a model that ships a graph-fusion
    calibration (the shipped ones do) blends the network with its calibrated graph Dijkstra (a
    mesh's own edges; a cloud's network-pruned kNN graph; ``litege_core.learned.fusion``: on
    the real dev shapes 2–8× lower error than the network alone, for 1.0–1.6× its time); a
    model without one answers with the network. ``graph``: the same, and every loaded model
    must ship its calibration. ``none``: the network alone (fastest). Paths follow the
    network either way."""
    geodesic_head: Literal["auto", "full", "small"] = "auto"
    """Distance head of every learned answer: ``auto`` (per model: its distilled small head when
    it ships one, as the shipped ones do, else the trained head), ``full`` (the trained head:
    ~18× more operations per pair) or ``small`` (every model must ship one)."""
    geodesic_precision: Literal["float32", "bfloat16", "int8", "auto"] = "float32"
    """Arithmetic of every learned answer: ``float32`` (as trained), ``int8`` (CPU only: the
    point MLP's ``n × n`` products and the small head's per-pair product in dynamic int8,
    ``Predictor(precision="int8", embed_precision="int8")``: ~1.2–1.4× faster distance fields
    and matrices at real-shape error within 0.07, BENCHMARKS.md "int8-point-mlp"),
    ``bfloat16`` (the point MLP's and the head's products in bfloat16: fast on a CPU with AMX
    tiles or a GPU, slow on an AVX2 CPU; BENCHMARKS.md "bf16-point-mlp") or ``auto``
    (bfloat16 where the device multiplies it natively, else float32)."""
    descriptor_lattice: Literal["auto", "full", "bcc", "stride2"] = "auto"
    """Voxels whose UDF a registration samples: ``auto`` (per model: ``stride2`` where its
    basis allows it, as the shipped ones do, else ``full``), ``full`` (the trained descriptor),
    ``bcc`` (1/4) or ``stride2`` (1/8). Records of each lattice are cached under their own
    key."""
    device: str = "auto"
    matching_model: Annotated[tuple[str, ...], NoDecode] = ("quadrupeds", "humans")
    """Matching bundles of ``POST /correspondences`` and the ``Correspond`` RPC, comma-separated
    (shipped names or bundle directories); the first is the default of a request that names
    none. Empty: correspondence is switched off (unknown-model answers)."""
    matching_precision: Literal["auto", "float32", "bfloat16", "int8"] = "auto"
    """Arithmetic of the matching search's per-pair head: ``auto`` (bfloat16 where the CPU or
    GPU runs it fast, else float32), ``float32`` (as trained), ``bfloat16`` (1.5–2.5× faster
    on a CPU with AVX512-BF16 / AMX at unchanged error over three seeds, BENCHMARKS.md
    "matching-bf16") or ``int8``. Frames are judged in float32 either way."""

    redis_url: str | None = None
    cache_ttl_s: float = Field(7 * 24 * 3600.0, gt=0)
    memory_cache_bytes: int = Field(1024 * MiB, ge=MiB)
    """Bound of the in-process artifact store when there is no Redis."""
    hot_cache_bytes: int = Field(256 * MiB, ge=MiB)
    """Bound of the in-process tier in front of Redis."""
    state_cache_bytes: int = Field(512 * MiB, ge=MiB)
    """Bound of the live geodesic shape states (embeddings on the device, the shape's arrays,
    surface projectors once built)."""
    matching_cache_bytes: int = Field(256 * MiB, ge=MiB)
    """Bound of the live shapes prepared for matching (aligned points, NN cache, features)."""
    write_behind_bytes: int = Field(128 * MiB, ge=MiB)
    """Bound of the writes queued for Redis while it is unreachable (oldest dropped)."""

    api_key: str | None = None

    max_upload_bytes: int = Field(64 * MiB, ge=1024)
    max_vertices: int = Field(500_000, ge=4)
    max_faces: int = Field(1_000_000, ge=1)
    max_queries: int = Field(1_000_000, ge=1)
    """Largest sources × targets per request (and points per path request × path count), and
    most correspondence queries per request or stream batch."""
    max_path_requests: int = Field(64, ge=1)
    max_exact_vertices: int = Field(20_000, ge=1)
    """Largest mesh (vertices) that ``method: exact`` runs on; larger ones are refused (422):
    one exact solve takes ~0.1 s at 5K vertices, 0.4 s at 10K and 6 s at 41K."""
    max_exact_sources: int = Field(16, ge=1)
    """Most sources of one ``method: exact`` geodesic request (422 above); each source is one
    exact solve."""
    solver_cache_bytes: int = Field(256 * MiB, ge=MiB)
    """Bound of the live classical solvers (``method`` heat / exact / graph), one per shape and
    method: the engines' arrays plus an estimate of their native memory (factorisations, MMP
    meshes), ~8 KiB per vertex for heat and exact."""
    max_concurrency: int = Field(64, ge=1)

    batch_max_size: int = Field(64, ge=1)
    batch_max_wait_ms: float = Field(0.0, ge=0)
    """Extra wait for more jobs once one arrived. 0 = greedy: jobs that arrive while the compute
    thread is busy form the next batch, so batches grow with load and an idle service adds no
    latency (measured: a 2 ms wait added 2 ms to every single-client request)."""
    queue_size: int = Field(256, ge=1)
    request_timeout_s: float = Field(60.0, gt=0)
    body_read_timeout_s: float = Field(30.0, gt=0)
    """Longest time to receive a request's body (REST: 408) or an upload stream (gRPC:
    DEADLINE_EXCEEDED); a slow client holds no concurrency slot meanwhile."""
    torch_threads: int | None = Field(None, ge=1)

    log_format: Literal["json", "text"] = "json"
    log_level: str = "INFO"

    @field_validator("models", "matching_model", mode="before")
    @classmethod
    def _split_models(cls, value: object) -> object:
        if isinstance(value, str):
            return tuple(part.strip() for part in value.split(",") if part.strip())
        return value

    @field_validator("redis_url", "api_key", mode="before")
    @classmethod
    def _empty_is_none(cls, value: object) -> object:
        return None if isinstance(value, str) and not value.strip() else value

    @model_validator(mode="after")
    def _check(self) -> Settings:
        if not self.models:
            raise ValueError("LITEGE_MODELS must name at least one model")
        if AUTO_MODEL in self.models:
            raise ValueError(f"LITEGE_MODELS cannot name a model {AUTO_MODEL!r} (reserved)")
        if self.default_model != AUTO_MODEL and self.default_model not in self.models:
            raise ValueError(
                f"LITEGE_DEFAULT_MODEL={self.default_model!r} is neither {AUTO_MODEL!r} nor in "
                f"LITEGE_MODELS={self.models}"
            )
        if self.api_key is not None and len(self.api_key) < 16:
            raise ValueError("LITEGE_API_KEY must be at least 16 characters (or unset)")
        if self.redis_url is not None and not self.redis_url.startswith(
            ("redis://", "rediss://", "unix://")
        ):
            scheme = self.redis_url.partition("://")[0] if "://" in self.redis_url else ""
            raise ValueError(
                "LITEGE_REDIS_URL must be a redis://, rediss:// or unix:// URL"
                + (f", not {scheme}://…" if scheme else "")
            )
        return self

    def public_summary(self) -> dict[str, object]:
        """The settings printed at start-up and served by ``/version`` (no secrets)."""
        summary = self.model_dump()
        summary["api_key"] = "set" if self.api_key else None
        if self.redis_url:
            summary["redis_url"] = _redact_url(self.redis_url)
        return summary


def _redact_url(url: str) -> str:
    """``redis://user:secret@host`` → ``redis://user:***@host``."""
    scheme, sep, rest = url.partition("://")
    if "@" not in rest:
        return url
    credentials, _, host = rest.rpartition("@")
    user = credentials.split(":", 1)[0]
    return f"{scheme}{sep}{user}:***@{host}"
