"""Prometheus metrics of one service process (own registry, so tests can run several)."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

LATENCY_BUCKETS = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5, 10, 30)
BATCH_BUCKETS = (1, 2, 4, 8, 16, 32, 64, 128, 256)


class ServiceMetrics:
    """Counters, gauges and histograms named ``litege_*``."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.http_latency = Histogram(
            "litege_http_request_duration_seconds",
            "REST request latency",
            ("method", "route", "status"),
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.grpc_latency = Histogram(
            "litege_grpc_request_duration_seconds",
            "gRPC call latency",
            ("method", "code"),
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.in_flight = Gauge(
            "litege_requests_in_flight", "Requests being served", ("protocol",), registry=r
        )
        self.batch_size = Histogram(
            "litege_batch_size",
            "Jobs per micro-batch",
            ("kind",),
            buckets=BATCH_BUCKETS,
            registry=r,
        )
        self.queue_wait = Histogram(
            "litege_queue_wait_seconds",
            "Time a job waited in the micro-batcher queue",
            buckets=LATENCY_BUCKETS,
            registry=r,
        )
        self.queue_depth = Gauge("litege_queue_depth", "Jobs waiting", registry=r)
        self.cache = Counter(
            "litege_cache_requests_total",
            "Shape state lookups by tier and result",
            ("tier", "result"),
            registry=r,
        )
        self.rejected = Counter(
            "litege_rejected_total", "Requests refused before work", ("reason",), registry=r
        )
        self.registered = Counter(
            "litege_shapes_registered_total",
            "POST /shapes and RegisterShape by model and whether it computed",
            ("model", "created"),
            registry=r,
        )
        self.matching_prepared = Counter(
            "litege_matching_prepared_total",
            "Shapes prepared for matching (computed: not found live or in the store)",
            ("model",),
            registry=r,
        )
        self.correspond_batches = Counter(
            "litege_correspond_batches_total",
            "Correspondence requests and stream batches computed",
            ("model",),
            registry=r,
        )
        self.model_load_seconds = Gauge(
            "litege_model_load_seconds", "Time to load a model bundle", ("model",), registry=r
        )
        self.store_degraded = Gauge(
            "litege_store_degraded", "1 while the shared store is unreachable", registry=r
        )
        self.live_states = Gauge(
            "litege_live_states", "Shape states held on the device", registry=r
        )
        self.live_state_bytes = Gauge(
            "litege_live_state_bytes", "Bytes of shape states held on the device", registry=r
        )

    def render(self) -> bytes:
        return generate_latest(self.registry)
