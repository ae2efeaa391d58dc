"""The paper's Table 1 on this machine: B shapes, one query each, preprocessing included.

Each batch registers B point clouds of 2000 points (canonicalization, UDF-PCA, embeddings)
and answers one distance query per shape; time is the median over runs after a warm-up.
Memory is the growth of the process's peak resident set while the batch runs (the CPU
analogue of the paper's peak activation memory; it includes allocator slack, so it is an
upper bound).
"""

from __future__ import annotations

import resource
import time
from collections.abc import Sequence

import numpy as np

from litege_core.shape import Shape


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def batch_query_table(
    predictor,
    clouds: Sequence[Shape],
    counts: Sequence[int] = (1, 4, 8, 32, 64, 96),
    runs: int = 5,
) -> list[dict[str, float]]:
    """Rows ``{"shapes", "median_ms", "ms_per_shape", "peak_rss_growth_mb"}`` per batch size."""
    rows = []
    query = np.array([0])
    for count in sorted(counts):
        batch = [clouds[i % len(clouds)] for i in range(count)]
        before = _peak_rss_mb()
        times = []
        for run in range(runs + 1):
            start = time.perf_counter()
            states = predictor.register_many(batch)
            predictor.distances_many(states, [query] * count, [np.array([1])] * count)
            if run:  # the first run warms up
                times.append((time.perf_counter() - start) * 1000.0)
        median = float(np.median(times))
        rows.append(
            {
                "shapes": count,
                "median_ms": median,
                "ms_per_shape": median / count,
                "peak_rss_growth_mb": max(0.0, _peak_rss_mb() - before),
            }
        )
    return rows
