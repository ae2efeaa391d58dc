"""Fit a UDF-PCA basis on procedural training shapes and report its realism statistics.

The geodesic-regression pipeline (spec §1.2, §2): each shape is sampled (2000 area-weighted
points), canonicalized by PCA alignment + bounding-box scale, voxelized for the informative-voxel
statistics and described by the UDF of its samples. Shapes come from the *train* seeds only.

Usage:
    python scripts/fit_synth_basis.py --category quadruped --shapes 400 --out data/basis.safetensors

Prints the number of informative voxels and the cumulative explained variance (design targets:
≈ 20–30K voxels, > 95 % at 50 components) as a markdown block for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import platform
import time
from datetime import date

import numpy as np

from litege_core.canonical import canonicalize_bbox
from litege_core.descriptor import VoxelGrid, fit_basis
from litege_core.learned import shape_samples
from litege_core.learned.describe import DEFAULT_MESH_SAMPLES
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape

COUNTS = (1, 5, 10, 20, 30, 50, 100, 150, 200, 240)


def canonical_training_shapes(category: str, n_shapes: int):
    """Yield ``(canonical vertices, faces)`` of train seeds 0..n-1, families cycled."""
    names = families(category)
    for index in range(n_shapes):
        generated = generate_shape(category, names[index % len(names)], index)
        shape = Shape.from_arrays(generated.vertices, generated.faces)
        transform = canonicalize_bbox(shape_samples(shape, DEFAULT_MESH_SAMPLES, seed=index))
        yield transform.apply(shape.vertices), np.asarray(shape.faces)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--category", default="quadruped", choices=["quadruped", "biped"])
    parser.add_argument("--shapes", type=int, default=400)
    parser.add_argument("--std-threshold", type=float, default=0.16)
    parser.add_argument("--components", type=int, default=240)
    parser.add_argument("--out", default="data/basis-quadruped.safetensors")
    args = parser.parse_args()

    start = time.perf_counter()
    basis = fit_basis(
        canonical_training_shapes(args.category, args.shapes),
        grid=VoxelGrid(),
        std_threshold=args.std_threshold,
        n_components=args.components,
        n_udf_samples=DEFAULT_MESH_SAMPLES,
        seed=0,
        metadata={"category": args.category, "pipeline": "bbox", "train_seeds": args.shapes},
    )
    seconds = time.perf_counter() - start
    basis.save(args.out)
    counts = [c for c in COUNTS if c <= basis.n_components]
    curve = basis.pca.explained_variance_curve(counts)
    print(f"### UDF-PCA basis on procedural {args.category}s\n")
    print(
        f"- date {date.today()}, machine {platform.processor() or platform.machine()}, "
        f"command `python scripts/fit_synth_basis.py --category {args.category} "
        f"--shapes {args.shapes} --std-threshold {args.std_threshold} "
        f"--components {args.components}`"
    )
    print(
        f"- {args.shapes} training shapes (train seeds), grid 121³ @ 0.02, std > "
        f"{args.std_threshold}: **{basis.n_voxels} informative voxels**; fit {seconds:.0f} s; "
        f"basis file {basis.nbytes_on_disk / 1e6:.1f} MB\n"
    )
    print("| components | " + " | ".join(str(c) for c in counts) + " |")
    print("|---" * (len(counts) + 1) + "|")
    print("| cumulative explained variance | " + " | ".join(f"{v:.3f}" for v in curve) + " |")


if __name__ == "__main__":
    main()
