"""Prometheus metrics of one service process (own registry, so tests can run several)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from service.store import ArtifactStore, CacheUsage

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
        self.caches = CacheCollector()
        r.register(self.caches)

    def watch_cache(self, name: str, usage: Callable[[], CacheUsage]) -> None:
        """Report a bounded in-process cache (``litege_cache_*{cache=name}``) at scrape time."""
        self.caches.sources[name] = usage

    def watch_store(self, store: ArtifactStore) -> None:
        """Report the store's in-process caches and its write-behind counters."""
        self.caches.store = store

    def render(self) -> bytes:
        return generate_latest(self.registry)


_STORE_COUNTERS = (
    ("write_behind_queued", "queued"),
    ("write_behind_flushed", "flushed"),
    ("write_behind_dropped", "dropped"),
)


def _fixed(usage: CacheUsage) -> Callable[[], CacheUsage]:
    """A source that reports ``usage`` (already read)."""
    return lambda: usage


class CacheCollector(Collector):
    """Every bounded in-process cache (entries, bytes, budget, evictions) and the store's
    write-behind counters, read when scraped."""

    def __init__(self) -> None:
        self.sources: dict[str, Callable[[], CacheUsage]] = {}
        self.store: ArtifactStore | None = None

    def _families(self) -> tuple[GaugeMetricFamily, ...]:
        return (
            GaugeMetricFamily(
                "litege_cache_entries", "Entries held by an in-process cache", labels=["cache"]
            ),
            GaugeMetricFamily(
                "litege_cache_bytes", "Bytes held by an in-process cache", labels=["cache"]
            ),
            GaugeMetricFamily(
                "litege_cache_budget_bytes",
                "Byte budget of an in-process cache (its LITEGE_*_BYTES setting)",
                labels=["cache"],
            ),
        )

    def _counters(self) -> tuple[CounterMetricFamily, ...]:
        return (
            CounterMetricFamily(
                "litege_cache_evictions",
                "Entries an in-process cache dropped to stay within its budget",
                labels=["cache"],
            ),
            CounterMetricFamily(
                "litege_store_write_behind",
                "Writes for Redis by fate: queued while unreachable, flushed, dropped",
                labels=["result"],
            ),
            CounterMetricFamily(
                "litege_store_refilled",
                "Entries written back into a Redis that came back without them",
            ),
        )

    def describe(self) -> Iterator[Metric]:
        yield from self._families()
        yield from self._counters()

    def collect(self) -> Iterator[Metric]:
        entries, nbytes, budget = self._families()
        evictions, write_behind, refilled = self._counters()
        sources = dict(self.sources)
        stats: dict[str, float] = {}
        if self.store is not None:
            sources.update({name: _fixed(u) for name, u in self.store.usage().items()})
            stats = self.store.stats()
        for name, usage_of in sorted(sources.items()):
            usage = usage_of()
            entries.add_metric([name], usage.entries)
            nbytes.add_metric([name], usage.bytes)
            budget.add_metric([name], usage.max_bytes)
            evictions.add_metric([name], usage.evictions)
        for key, result in _STORE_COUNTERS:
            if key in stats:
                write_behind.add_metric([result], stats[key])
        if "refilled" in stats:
            refilled.add_metric([], stats["refilled"])
        yield from (entries, nbytes, budget, evictions, write_behind, refilled)
