"""evaluation.speed: allocator-exact peaks and timing helpers (no speed targets here)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from litege_core.evaluation.speed import (
    MemoryPeak,
    device_sync,
    numpy_peak,
    peak_memory,
    time_call,
    torch_cpu_peak,
)

MB = 2**20


def _numpy_work() -> float:
    first = np.ones(4 * MB // 8)  # 4 MB, freed before the next one
    total = float(first.sum())
    del first
    second = np.ones(2 * MB // 8)
    return total + float(second.sum())


def _torch_work() -> float:
    a = torch.ones(MB)  # 4 MB
    b = a * 2.0  # 4 MB more: peak 8 MB
    del a
    c = b + 1.0  # 4 + 4 MB again
    return float(c.sum())


def test_numpy_peak_is_the_largest_live_set() -> None:
    result, peak = numpy_peak(_numpy_work)
    assert result == 4 * MB // 8 + 2 * MB // 8
    assert 4 * MB <= peak < 4.5 * MB  # the 4 MB array, not 4 + 2


def test_torch_cpu_peak_replays_the_allocator() -> None:
    result, peak = torch_cpu_peak(_torch_work)
    assert result == 3.0 * MB
    assert 8 * MB <= peak < 8.2 * MB
    _, none = torch_cpu_peak(lambda: 1 + 1)
    assert none == 0


def test_peak_memory_keeps_numpy_and_torch_apart() -> None:
    def both() -> float:
        return _numpy_work() + _torch_work()

    peak = peak_memory(both)
    assert isinstance(peak, MemoryPeak) and peak.cuda_bytes is None and peak.cuda_mb is None
    assert 4 <= peak.numpy_mb < 4.5 and 8 <= peak.torch_mb < 8.2
    assert peak.cpu_bytes == peak.numpy_bytes + peak.torch_bytes
    assert peak.cpu_mb == pytest.approx(peak.numpy_mb + peak.torch_mb)


def test_time_call_counts_runs_and_warmups() -> None:
    calls = []
    timing = time_call(lambda: calls.append(1), runs=3, warmup=2)
    assert len(calls) == 5 and timing.runs == 3 and len(timing.samples_ms) == 3
    assert timing.wall_ms >= 0 and timing.cpu_ms >= 0
    assert device_sync("cpu") is None
