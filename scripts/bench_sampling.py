"""Time the samplers of litege_core.sampling and print a markdown table.

Usage: ``python scripts/bench_sampling.py [--repeats 20]``. No external data: the mesh is a
unit-area UV sphere with 4,994 vertices and 9,984 faces (SMAL meshes have 3,889 vertices).
Each row is the median (and min) of ``--repeats`` timed runs with ``time.perf_counter``
after one warm-up run.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np
import scipy
import trimesh

from litege_core.evaluation.speed import cpu_name
from litege_core.sampling import (
    farthest_point_sampling,
    mean_nearest_neighbour_distance,
    poisson_disk_subsample,
    sample_surface,
)


def _time(function: Callable[[], object], repeats: int) -> tuple[float, float]:
    """``(median, min)`` wall time in milliseconds after one warm-up call."""
    function()
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        runs.append((time.perf_counter() - start) * 1e3)
    return statistics.median(runs), min(runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()

    mesh = trimesh.creation.uv_sphere(count=[50, 52])
    vertices = np.asarray(mesh.vertices) / np.sqrt(mesh.area)
    faces = np.asarray(mesh.faces)
    cloud = sample_surface(vertices, faces, 8000, seed=0).points
    dense = sample_surface(vertices, faces, 56_000, seed=1).points
    mesh8k = (vertices, faces, 8000)

    cases: list[tuple[str, Callable[[], object]]] = [
        (f"sample_surface 8K on {len(vertices)}-vertex mesh", lambda: sample_surface(*mesh8k)),
        ("farthest_point_sampling 8K → 500", lambda: farthest_point_sampling(cloud, 500)),
        ("farthest_point_sampling 8K → 2000", lambda: farthest_point_sampling(cloud, 2000)),
        ("poisson_disk_subsample 8K → 50", lambda: poisson_disk_subsample(cloud, 50)),
        ("poisson_disk_subsample 8K → 500", lambda: poisson_disk_subsample(cloud, 500)),
        ("poisson_disk_subsample 56K → 7000", lambda: poisson_disk_subsample(dense, 7000)),
        ("mean_nearest_neighbour_distance 8K", lambda: mean_nearest_neighbour_distance(cloud)),
    ]
    print(f"- machine: {cpu_name()}, {os.cpu_count()} CPUs")
    print(f"- date: {datetime.datetime.now(datetime.UTC).strftime('%Y-%m-%d %H:%M UTC')}")
    versions = f"numpy {np.__version__}, scipy {scipy.__version__}"
    print(f"- python {platform.python_version()}, {versions}")
    print(f"- median and min of {args.repeats} runs after one warm-up\n")
    print("| operation | median ms | min ms |")
    print("|---|---:|---:|")
    for name, function in cases:
        median, fastest = _time(function, args.repeats)
        print(f"| {name} | {median:.1f} | {fastest:.1f} |")


if __name__ == "__main__":
    main()
