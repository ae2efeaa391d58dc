"""Timing and allocator-exact memory for the speed benchmarks (issue 17).

**Memory** is measured where it is allocated, not as resident-set growth (which includes
allocator slack, freed pages the process keeps, and everything else the process does):

* ``numpy``: the peak of :mod:`tracemalloc` above its start. numpy reports every array buffer
  to tracemalloc, so this is the exact peak of numpy data (and Python objects) while the
  function runs; arrays torch shares with numpy (``torch.from_numpy``) count here.
* ``torch``: the peak of torch's CPU allocator above its start, replayed from the allocation
  events of :mod:`torch.profiler` (``profile_memory=True``): every tensor torch allocates on
  the CPU, exactly, in the order it happened.
* ``cuda``: ``torch.cuda.max_memory_allocated`` above the allocation at the start (when the
  function runs on a CUDA device).

The numpy and torch peaks come from two separate runs of the function (tracemalloc would
count the profiler's own bookkeeping); their sum bounds the joint peak from above. Memory
allocated by C libraries behind numpy's back (the k-d trees' nodes, BLAS workspaces) is not
counted; it is small here (a k-d tree of 2000 points is about 100 KB).

**Time** is the median of wall-clock (``perf_counter``) and process CPU time
(``process_time``) over runs after a warm-up. On a shared machine the CPU time of a
single-threaded run is the steadier figure: it does not count the time other processes hold
the core.
"""

from __future__ import annotations

import platform
import statistics
import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from litege_core.shape import Shape

MB = 1024.0 * 1024.0


@dataclass(frozen=True)
class MemoryPeak:
    """Peak memory of one call above what was allocated when it started (bytes).

    Attributes:
        numpy_bytes: tracemalloc peak (numpy buffers and Python objects).
        torch_bytes: torch CPU-allocator peak.
        cuda_bytes: CUDA-allocator peak, or ``None`` when no CUDA device was used.
    """

    numpy_bytes: int
    torch_bytes: int
    cuda_bytes: int | None = None

    @property
    def cpu_bytes(self) -> int:
        """``numpy + torch``: an upper bound of the joint CPU peak."""
        return self.numpy_bytes + self.torch_bytes

    @property
    def numpy_mb(self) -> float:
        return self.numpy_bytes / MB

    @property
    def torch_mb(self) -> float:
        return self.torch_bytes / MB

    @property
    def cpu_mb(self) -> float:
        return self.cpu_bytes / MB

    @property
    def cuda_mb(self) -> float | None:
        return None if self.cuda_bytes is None else self.cuda_bytes / MB


def cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``; ``platform`` elsewhere), for benchmark headers."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as handle:
            for line in handle:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return f"{platform.machine()} {platform.processor() or platform.system()}"


def numpy_peak(fn: Callable[[], Any]) -> tuple[Any, int]:
    """Run ``fn`` under tracemalloc; return its result and the peak bytes above the start."""
    was_tracing = tracemalloc.is_tracing()
    if not was_tracing:
        tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        start, _ = tracemalloc.get_traced_memory()
        result = fn()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        if not was_tracing:
            tracemalloc.stop()
    return result, max(0, peak - start)


def torch_cpu_peak(fn: Callable[[], Any]) -> tuple[Any, int]:
    """Run ``fn`` under the torch profiler with memory events; return its result and the peak
    of torch's CPU allocator above the start (bytes), replayed event by event."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
        result = fn()
    events = prof.profiler.kineto_results.events() if prof.profiler is not None else []
    total = peak = 0
    for _, nbytes in _cpu_memory_deltas(events):
        total += nbytes
        peak = max(peak, total)
    return result, peak


def _cpu_memory_deltas(events: Sequence[Any]) -> list[tuple[int, int]]:
    """``(time ns, bytes)`` of the CPU allocator's events, in time order."""
    out = []
    for event in events:
        if event.name() != "[memory]":
            continue
        device = event.device_type()
        if getattr(device, "name", str(device)).upper().endswith("CPU"):
            out.append((int(event.start_ns()), int(event.nbytes())))
    out.sort()
    return out


def peak_memory(fn: Callable[[], Any], device: torch.device | str = "cpu") -> MemoryPeak:
    """:class:`MemoryPeak` of ``fn`` (called twice, or three times on CUDA; see the module
    docstring)."""
    _, numpy_bytes = numpy_peak(fn)
    _, torch_bytes = torch_cpu_peak(fn)
    cuda_bytes = None
    dev = torch.device(device)
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)
        start = torch.cuda.memory_allocated(dev)
        torch.cuda.reset_peak_memory_stats(dev)
        fn()
        torch.cuda.synchronize(dev)
        cuda_bytes = max(0, torch.cuda.max_memory_allocated(dev) - start)
    return MemoryPeak(numpy_bytes, torch_bytes, cuda_bytes)


@dataclass(frozen=True)
class Timing:
    """Medians over runs (milliseconds) and the raw wall-clock samples."""

    wall_ms: float
    cpu_ms: float
    runs: int
    samples_ms: tuple[float, ...]


def time_call(
    fn: Callable[[], Any],
    runs: int = 5,
    warmup: int = 1,
    sync: Callable[[], None] | None = None,
) -> Timing:
    """Median wall-clock and CPU time of ``fn`` over ``runs`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
        if sync is not None:
            sync()
    walls, cpus = [], []
    for _ in range(max(1, runs)):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        if sync is not None:
            sync()
        walls.append(1000.0 * (time.perf_counter() - wall))
        cpus.append(1000.0 * (time.process_time() - cpu))
    return Timing(statistics.median(walls), statistics.median(cpus), len(walls), tuple(walls))


def device_sync(device: torch.device | str) -> Callable[[], None] | None:
    """A synchronisation callable for timing on ``device`` (``None`` on a CPU)."""
    dev = torch.device(device)
    if dev.type == "cuda":
        return lambda: torch.cuda.synchronize(dev)
    return None


def batch_query_table(
    predictor,
    clouds: Sequence[Shape],
    counts: Sequence[int] = (1, 4, 8, 32, 64, 96),
    runs: int = 5,
    memory: bool = True,
) -> list[dict[str, float]]:
    """The paper's Table 1 setting: ``B`` clouds registered and queried once each.

    Each row times :meth:`Predictor.register_many` of ``B`` shapes (``clouds`` reused
    cyclically) followed by :meth:`Predictor.distances_many` with one (0 → 1) pair per shape.

    Returns:
        Rows ``{"shapes", "median_ms", "ms_per_shape", "cpu_ms", "numpy_peak_mb",
        "torch_peak_mb", "peak_mb", "cuda_peak_mb"}`` per batch size (memory keys only with
        ``memory=True``; ``cuda_peak_mb`` only on a CUDA predictor).
    """
    rows = []
    query, target = np.array([0]), np.array([1])
    sync = device_sync(predictor.device)
    for count in sorted(counts):
        batch = [clouds[i % len(clouds)] for i in range(count)]

        def run(batch: list[Shape] = batch, count: int = count) -> object:
            states = predictor.register_many(batch)
            return predictor.distances_many(states, [query] * count, [target] * count)

        timing = time_call(run, runs=runs, warmup=1, sync=sync)
        row: dict[str, float] = {
            "shapes": count,
            "median_ms": timing.wall_ms,
            "ms_per_shape": timing.wall_ms / count,
            "cpu_ms": timing.cpu_ms,
        }
        if memory:
            peak = peak_memory(run, predictor.device)
            row.update(
                numpy_peak_mb=peak.numpy_mb, torch_peak_mb=peak.torch_mb, peak_mb=peak.cpu_mb
            )
            if peak.cuda_mb is not None:
                row["cuda_peak_mb"] = peak.cuda_mb
        rows.append(row)
    return rows


__all__ = [
    "MemoryPeak",
    "Timing",
    "batch_query_table",
    "cpu_name",
    "device_sync",
    "numpy_peak",
    "peak_memory",
    "time_call",
    "torch_cpu_peak",
]
