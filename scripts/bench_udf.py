#!/usr/bin/env python
"""Benchmark the UDF backends, mesh occupancy and the streamed PCA; print markdown tables.

    .venv/bin/python scripts/bench_udf.py                 # UDF table (M = 25,000 voxels)
    .venv/bin/python scripts/bench_udf.py --occupancy     # mesh_occupancy, ~5K faces, 121³
    .venv/bin/python scripts/bench_udf.py --pca 4000 25000 400
    .venv/bin/python scripts/bench_udf.py --fit 40           # fit_basis on 40 primitives
    .venv/bin/python scripts/bench_udf.py --quick         # smoke run (5 repeats, fewer cells)

UDF: the centres are the 25,000 highest-occupancy-std voxels of the default 121³ grid over 30
random primitives (as informative voxels are chosen); clouds are area-weighted samples of
other random primitives. Each cell times one call of the backend on B clouds of P points
(tree build + query for k-d trees; one batched call for torch), reports the median over
``--repeats`` runs after one warm-up, per call and per shape. Cells whose warm-up exceeds
``--max-call-seconds`` are not repeated and are reported as a single run, marked ``(1 run)``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import tempfile
import time
import tracemalloc
from collections.abc import Callable

import numpy as np
import scipy
import torch
import trimesh

from litege_core.descriptor.grid import VoxelGrid
from litege_core.descriptor.informative import OccupancyStatistics
from litege_core.descriptor.occupancy import mesh_occupancy
from litege_core.descriptor.pca import fit_pca_streamed
from litege_core.descriptor.udf import UdfEvaluator, pykdtree_available
from litege_core.sampling import sample_surface


def random_mesh(rng: np.random.Generator) -> trimesh.Trimesh:
    makers = [
        lambda: trimesh.creation.icosphere(subdivisions=3, radius=0.5),
        lambda: trimesh.creation.box(extents=[0.8, 0.8, 0.8]),
        lambda: trimesh.creation.capsule(height=0.6, radius=0.25, count=[16, 16]),
        lambda: trimesh.creation.torus(0.4, 0.15, major_sections=32, minor_sections=16),
    ]
    mesh = makers[int(rng.integers(len(makers)))]()
    mesh.apply_scale(rng.uniform(0.6, 1.4, 3))
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
    mesh.apply_translation(rng.uniform(-0.15, 0.15, 3))
    return mesh


def informative_centers(grid: VoxelGrid, n_voxels: int, n_shapes: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    stats = OccupancyStatistics(grid)
    for _ in range(n_shapes):
        mesh = random_mesh(rng)
        stats.add(mesh_occupancy(mesh.vertices, mesh.faces, grid))
    std = stats.std()
    top = np.sort(np.argsort(-std, kind="stable")[:n_voxels])
    return grid.centers(top)


def timed(fn: Callable[[], object], repeats: int, max_call_seconds: float) -> tuple[float, int]:
    """Median seconds of ``fn`` over ``repeats`` runs after one warm-up (see module doc)."""
    start = time.perf_counter()
    fn()
    warm = time.perf_counter() - start
    if warm > max_call_seconds:
        start = time.perf_counter()
        fn()
        return time.perf_counter() - start, 1
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - start)
    return statistics.median(samples), repeats


def header() -> str:
    versions = (
        f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
        f"torch {torch.__version__} ({torch.get_num_threads()} threads)"
    )
    if pykdtree_available():
        from importlib.metadata import version

        versions += f", pykdtree {version('pykdtree')}"
    return (
        f"- date: {dt.datetime.now(dt.UTC).strftime('%Y-%m-%d %H:%M UTC')}\n"
        f"- machine: {platform.machine()}, {os.cpu_count()} logical CPUs "
        f"({platform.processor() or platform.platform()}), device cpu\n"
        f"- versions: {versions}"
    )


def bench_udf(args: argparse.Namespace) -> None:
    grid = VoxelGrid()
    centers = informative_centers(grid, args.voxels, args.shapes, args.seed)
    rng = np.random.default_rng(args.seed + 1)
    meshes = [random_mesh(rng) for _ in range(max(args.batches))]
    backends = ["kdtree", "kdtree-par", "torch"] + (["pykdtree"] if pykdtree_available() else [])
    evaluators = {
        "kdtree": UdfEvaluator(centers, backend="kdtree", workers=1),
        "kdtree-par": UdfEvaluator(centers, backend="kdtree", workers=-1),
        "torch": UdfEvaluator(centers, backend="torch"),
    }
    if pykdtree_available():
        evaluators["pykdtree"] = UdfEvaluator(centers, backend="pykdtree")
    print(header())
    print(f"- M = {centers.shape[0]} voxel centres; median of {args.repeats} runs after warm-up\n")
    print("| P | B | " + " | ".join(f"{b} ms/call (ms/shape)" for b in backends) + " |")
    print("|---|---|" + "---|" * len(backends))
    for n_points in args.points:
        clouds = np.stack(
            [
                sample_surface(m.vertices, m.faces, n_points, seed=i).points.astype(np.float32)
                for i, m in enumerate(meshes)
            ]
        )
        for batch in args.batches:
            cells = []
            for name in backends:
                evaluator, data = evaluators[name], clouds[:batch]
                seconds, runs = timed(lambda e=evaluator, d=data: e(d), args.repeats, args.max_call)
                mark = "" if runs > 1 else " (1 run)"
                cells.append(f"{1e3 * seconds:.1f} ({1e3 * seconds / batch:.2f}){mark}")
            print(f"| {n_points} | {batch} | " + " | ".join(cells) + " |", flush=True)


def bench_occupancy(args: argparse.Namespace) -> None:
    grid = VoxelGrid()
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.6)  # 5120 faces
    mesh.apply_scale([1.0, 0.7, 0.5])
    rotation = np.random.default_rng(0).random(3)
    mesh.apply_transform(trimesh.transformations.random_rotation_matrix(rotation))
    print(header())
    seconds, runs = timed(
        lambda: mesh_occupancy(mesh.vertices, mesh.faces, grid), args.repeats, 30.0
    )
    print(
        f"\nmesh_occupancy: {len(mesh.faces)} faces on the 121³ grid: "
        f"{1e3 * seconds:.1f} ms (median of {runs})"
    )


def bench_pca(args: argparse.Namespace) -> None:
    n, d, k = args.pca
    rng = np.random.default_rng(args.seed)
    rank = 2 * k
    print(header())
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "rows.f32")
        mm = np.memmap(path, np.float32, "w+", shape=(n, d))
        right = rng.standard_normal((rank, d)).astype(np.float32) / np.sqrt(d)
        scales = (0.8 ** np.arange(rank)).astype(np.float32)
        for s in range(0, n, 1024):
            rows = min(1024, n - s)
            left = rng.standard_normal((rows, rank)).astype(np.float32) * scales
            noise = 0.01 * rng.standard_normal((rows, d)).astype(np.float32)
            mm[s : s + rows] = left @ right + noise
        mm.flush()
        ro = np.memmap(path, np.float32, "r", shape=(n, d))
        for dtype in [np.dtype(name).type for name in args.pca_dtypes]:
            tracemalloc.start()
            start = time.perf_counter()
            pca = fit_pca_streamed(
                lambda: (ro[s : s + 256] for s in range(0, n, 256)), k, dtype=dtype
            )
            seconds = time.perf_counter() - start
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            print(
                f"\nfit_pca_streamed n={n} d={d} k={k} dtype={np.dtype(dtype).name}: "
                f"{seconds:.1f} s, peak traced allocations {peak / 2**20:.0f} MiB "
                f"(data {n * d * 4 / 2**20:.0f} MiB on disk), "
                f"explained ratio k: {pca.explained_variance_ratio.sum():.4f}",
                flush=True,
            )


def bench_fit(args: argparse.Namespace) -> None:
    from litege_core.descriptor.fit import fit_basis

    rng = np.random.default_rng(args.seed)
    meshes = [random_mesh(rng) for _ in range(args.fit)]
    shapes = [(np.asarray(m.vertices), np.asarray(m.faces)) for m in meshes]
    k = min(30, args.fit)
    print(header())
    start = time.perf_counter()
    basis = fit_basis(shapes, VoxelGrid(), std_threshold=0.14, n_components=k, seed=args.seed)
    seconds = time.perf_counter() - start
    counts = [c for c in (1, 5, 10, 20, 30) if c <= k]
    curve = basis.pca.explained_variance_curve(counts)
    print(
        f"\nfit_basis on {args.fit} random primitives (121³ grid, std > 0.14, 2000 samples, "
        f"k={k}): {seconds:.1f} s, {basis.n_voxels} informative voxels"
    )
    print("\n| components | " + " | ".join(map(str, counts)) + " |")
    print("|---|" + "---|" * len(counts))
    print("| cumulative explained variance | " + " | ".join(f"{c:.3f}" for c in curve) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--voxels", type=int, default=25_000)
    parser.add_argument("--shapes", type=int, default=30)
    parser.add_argument("--points", type=int, nargs="+", default=[300, 2000, 8000])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 16, 64])
    parser.add_argument("--max-call", type=float, default=3.0, help="seconds; see module doc")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--occupancy", action="store_true")
    parser.add_argument("--pca", type=int, nargs=3, metavar=("N", "D", "K"))
    parser.add_argument("--pca-dtypes", nargs="+", default=["float32", "float64"])
    parser.add_argument("--fit", type=int, metavar="N_SHAPES", help="fit_basis on N primitives")
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.points, args.batches, args.shapes = 5, [300, 2000], [1, 4], 8
    if args.occupancy:
        bench_occupancy(args)
    elif args.pca:
        bench_pca(args)
    elif args.fit:
        bench_fit(args)
    else:
        bench_udf(args)


if __name__ == "__main__":
    main()
