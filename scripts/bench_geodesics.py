"""Benchmark the reference geodesic engines; prints a markdown table.

Shapes (generated, no external data):

* ``torus-5k``: a 5000-vertex torus (R=1, r=0.35, 100x50 sections) with seeded vertex jitter
  of 0.003, an irregular ~5K-vertex mesh;
* ``cloud-2k``: 2000 area-uniform samples of that torus (seed 0), as a point cloud;
* ``tosca``: one ``.off`` of ``../shared/eval-data/tosca_5k`` when that folder exists (real
  shape, evaluation only; skipped cleanly otherwise).

For every engine: *build* = constructor + ``prepare()`` (fresh engine each run); *per source*
= one ``distances([s])`` call on a prepared engine, a different source each run. Both are the
median over ``--runs`` runs (default 15) after ``--warmup`` runs (default 2), wall clock,
single process. Accuracy column: mean relative error against the exact engine over the
benchmarked sources (for the cloud: exact geodesics between the samples, by inserting them
into the mesh). ``--pool N`` also times a batch of rows with ``n_workers=N``.

Usage::

    .venv/bin/python scripts/bench_geodesics.py [--runs 15] [--warmup 2] [--pool 4]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

import numpy as np
import trimesh

from litege_core.engines import ExactGeodesicEngine, insert_surface_points, make_engine
from litege_core.evaluation.speed import cpu_name
from litege_core.io import load_shape
from litege_core.sampling import sample_surface
from litege_core.shape import Shape

REPO_ROOT = Path(__file__).resolve().parents[1]
TOSCA_DIR = REPO_ROOT.parent / "shared" / "eval-data" / "tosca_5k"
PACKAGES = ("numpy", "scipy", "pygeodesic", "tvb-gdist", "potpourri3d", "trimesh")


def median_ms(fn: Callable[[int], object], runs: int, warmup: int) -> float:
    """Median wall time of ``fn(i)`` in ms over ``runs`` calls after ``warmup`` calls."""
    for i in range(warmup):
        fn(i)
    times = []
    for i in range(runs):
        start = time.perf_counter()
        fn(warmup + i)
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def bumpy_torus() -> Shape:
    torus = trimesh.creation.torus(1.0, 0.35, major_sections=100, minor_sections=50)
    rng = np.random.default_rng(0)
    jitter = 0.003 * rng.standard_normal(torus.vertices.shape)
    return Shape.from_arrays(np.asarray(torus.vertices) + jitter, torus.faces)


def mean_relative_error(approx: np.ndarray, exact: np.ndarray) -> float:
    mask = np.isfinite(exact) & (exact > 1e-9)
    return float((np.abs(approx - exact)[mask] / exact[mask]).mean())


def bench_engine(
    shape: Shape,
    method: str,
    sources: np.ndarray,
    runs: int,
    warmup: int,
    exact_rows: np.ndarray | None,
    **options: object,
) -> tuple[float, float, float | None]:
    """(build ms, per-source ms, mean relative error vs exact rows or None)."""
    build = median_ms(lambda i: make_engine(shape, method, **options).prepare(), runs, warmup)
    engine = make_engine(shape, method, **options).prepare()
    per_source = median_ms(lambda i: engine.distances([sources[i % sources.size]]), runs, warmup)
    error = None
    if exact_rows is not None:
        error = mean_relative_error(engine.distances(sources).distances, exact_rows)
    return build, per_source, error


def cloud_reference(mesh: Shape, n_points: int, sources: np.ndarray) -> tuple[Shape, np.ndarray]:
    """A sampled cloud and its exact source rows ``(S, n_points)`` on the mesh surface."""
    samples = sample_surface(mesh.vertices, mesh.faces, n_points, seed=0)
    refined = insert_surface_points(
        mesh.vertices, mesh.faces, samples.face_index, samples.barycentric
    )
    engine = ExactGeodesicEngine(Shape.from_arrays(refined.vertices, refined.faces))
    rows = engine.distances(refined.point_vertex[sources]).distances
    return Shape.from_arrays(samples.points), rows[:, refined.point_vertex]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--runs", type=int, default=15, help="timed runs (>= 10)")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--pool", type=int, default=0, help="also time n_workers=N batches")
    args = parser.parse_args()
    runs, warmup = max(args.runs, 10), args.warmup

    mesh = bumpy_torus()
    n_sources = max(runs + warmup, 20)
    sources = np.linspace(0, mesh.n_points - 1, n_sources).astype(np.int64)
    exact_rows = ExactGeodesicEngine(mesh).distances(sources).distances

    rows: list[tuple[str, str, str, float, float, float | None]] = []
    label = f"torus-5k ({mesh.n_points} v)"
    for backend in ("pygeodesic", "gdist"):
        build, per, err = bench_engine(
            mesh, "exact", sources, runs, warmup, exact_rows, backend=backend
        )
        rows.append((f"exact ({backend})", label, "", build, per, err))
    for method, options in (
        ("heat", {"t_coef": 1.0, "use_robust": True}),
        ("pointcloud_heat", {}),
        ("knn_graph", {"k": 8}),
        ("edge_dijkstra", {}),
    ):
        build, per, err = bench_engine(mesh, method, sources, runs, warmup, exact_rows, **options)
        rows.append((method, label, str(options or ""), build, per, err))

    cloud_sources = np.linspace(0, 1999, n_sources).astype(np.int64)
    cloud, cloud_exact = cloud_reference(mesh, 2000, cloud_sources)
    for method, options in (("pointcloud_heat", {}), ("knn_graph", {"k": 8})):
        build, per, err = bench_engine(
            cloud, method, cloud_sources, runs, warmup, cloud_exact, **options
        )
        rows.append((method, "cloud-2k (torus samples)", str(options or ""), build, per, err))

    if TOSCA_DIR.is_dir() and (offs := sorted(TOSCA_DIR.glob("*.off"))):
        tosca = load_shape(offs[0])
        tosca_sources = np.linspace(0, tosca.n_points - 1, n_sources).astype(np.int64)
        tosca_label = f"tosca {offs[0].stem} ({tosca.n_points} v)"
        try:
            tosca_exact = ExactGeodesicEngine(tosca).distances(tosca_sources).distances
            for backend in ("pygeodesic", "gdist"):
                build, per, _ = bench_engine(
                    tosca, "exact", tosca_sources, runs, warmup, None, backend=backend
                )
                rows.append((f"exact ({backend})", tosca_label, "", build, per, None))
            build, per, err = bench_engine(tosca, "heat", tosca_sources, runs, warmup, tosca_exact)
            rows.append(("heat", tosca_label, "", build, per, err))
        except Exception as exc:  # report, do not abort the benchmark
            print(f"tosca skipped: {type(exc).__name__}: {exc}")
    else:
        print(f"tosca skipped: {TOSCA_DIR} not found")

    versions = ", ".join(f"{name} {metadata.version(name)}" for name in PACKAGES)
    print()
    print(f"Geodesic engines, {dt.date.today().isoformat()}, {cpu_name()}, ")
    print(f"{os.cpu_count()} logical CPUs, Python {platform.python_version()}; {versions}.")
    print(f"Median of {runs} runs after {warmup} warm-up runs, single process, wall clock.")
    print()
    print("| engine | shape | options | build (ms) | per source (ms) | mean rel. err vs exact |")
    print("|---|---|---|---:|---:|---:|")
    for engine, shape, options, build, per, err in rows:
        err_text = "—" if err is None else f"{100 * err:.2f} %"
        print(f"| {engine} | {shape} | {options} | {build:.2f} | {per:.2f} | {err_text} |")

    if args.pool > 1:
        batch = np.linspace(0, mesh.n_points - 1, 8 * args.pool).astype(np.int64)
        for workers in (1, args.pool):
            engine = ExactGeodesicEngine(mesh, n_workers=workers)
            start = time.perf_counter()
            engine.distances(batch)
            elapsed = time.perf_counter() - start
            print(
                f"\nexact batch of {batch.size} rows, n_workers={workers}: {elapsed:.2f} s "
                f"({1e3 * elapsed / batch.size:.1f} ms/row, pool start-up included)"
            )


if __name__ == "__main__":
    main()
