"""Benchmark: time to compute the UDF-PCA descriptor of a shape, canonicalization included.

Cases: a ~5K-vertex mesh (isotropic remesh of a held-out procedural quadruped; 2000 surface
samples), and point clouds of 300, 2000 and 8000 area-weighted samples of the same shape. Each
timing covers the whole ``describe_shape`` call (sampling for meshes, centring, PCA alignment,
bounding-box scale, UDF at the informative voxels, projection), with a per-stage breakdown.
Median and 90th percentile over ``--runs`` runs after 3 warm-up runs, on the CPU.

Usage:
    python scripts/bench_descriptor.py [--basis data/basis-quadruped.safetensors] [--runs 30]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from datetime import date

import numpy as np
import torch

from litege_core.canonical import canonicalize_bbox
from litege_core.descriptor import UdfPcaBasis
from litege_core.learned import describe_shape, shape_samples
from litege_core.shape import Shape
from litege_core.synth import generate_shape
from litege_core.variants import isotropic_remesh, point_cloud

TARGET_MS = 50.0


def timed(fn, runs: int) -> np.ndarray:
    for _ in range(3):
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1000.0)
    return np.asarray(times)


def stage_times(shape: Shape, basis: UdfPcaBasis, runs: int) -> dict[str, float]:
    engine = basis.engine("cpu")
    points = shape_samples(shape)
    transform = canonicalize_bbox(points)
    canonical = transform.apply(points)[None]
    udf = engine.udf(canonical)
    stages = {
        "sample": lambda: shape_samples(shape),
        "canonicalize": lambda: canonicalize_bbox(points).apply(points),
        "udf": lambda: engine.udf(canonical),
        "project": lambda: (udf - engine.mean) @ engine._components_t,
    }
    return {name: float(np.median(timed(fn, runs))) for name, fn in stages.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--basis", default="data/basis-quadruped.safetensors")
    parser.add_argument("--runs", type=int, default=30)
    args = parser.parse_args()

    basis = UdfPcaBasis.load(args.basis)
    generated = generate_shape("quadruped", "dog", 2_000_000)  # a test seed: never trained on
    remeshed = isotropic_remesh(generated.vertices, generated.faces, target_vertices=5000)
    cases = {
        f"mesh, {remeshed.vertices.shape[0]} vertices": Shape.from_arrays(
            remeshed.vertices, remeshed.faces
        )
    }
    for n_points in (300, 2000, 8000):
        cloud = point_cloud(generated.vertices, generated.faces, n_points, seed=1).points
        cases[f"point cloud, {n_points} points"] = Shape.from_arrays(cloud)

    print("### Descriptor time (canonicalization included), CPU\n")
    print(
        f"- date {date.today()}; machine {platform.processor() or platform.machine()}, "
        f"{os.cpu_count()} logical CPUs; torch {torch.__version__} "
        f"({torch.get_num_threads()} threads); numpy {np.__version__}"
    )
    print(
        f"- basis: {basis.n_voxels} informative voxels × {basis.n_components} components "
        f"(`{args.basis}`); shape: procedural dog, test seed 2000000"
    )
    print(
        f"- median / p90 of {args.runs} runs after 3 warm-ups; command "
        f"`python scripts/bench_descriptor.py --runs {args.runs}`\n"
    )
    print(
        "| input | total median ms | p90 ms | sample | canonicalize | UDF | project | "
        f"≤ {TARGET_MS:.0f} ms |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---|")
    for name, shape in cases.items():
        total = timed(lambda shape=shape: describe_shape(shape, basis), args.runs)
        stages = stage_times(shape, basis, args.runs)
        sample = f"{stages['sample']:.1f}" if shape.is_mesh else "—"
        meets = "yes" if np.median(total) <= TARGET_MS else "no"
        print(
            f"| {name} | {np.median(total):.1f} | {np.percentile(total, 90):.1f} | {sample} | "
            f"{stages['canonicalize']:.1f} | {stages['udf']:.1f} | {stages['project']:.1f} | "
            f"{meets} |"
        )


if __name__ == "__main__":
    main()
