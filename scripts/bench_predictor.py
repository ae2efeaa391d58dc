"""Time the geodesic predictor on a CPU (or any torch device): register, distance field,
distance matrix, many shapes per batch, and a path.

Usage:
    python scripts/bench_predictor.py BUNDLE_DIR [--runs 20] [--threads N] [--device cpu]
    python scripts/bench_predictor.py --make-synthetic /tmp/litege-bench-bundle
    python scripts/bench_predictor.py /tmp/litege-bench-bundle

``--make-synthetic DIR`` writes a bundle of the production size with *random* weights (width
200, 240 components, ``--voxels`` informative voxels on the default 121³ grid): its timings
are those of a trained bundle of that size (nothing in the hot paths depends on the weight
values, except the number of path steps), its distances are meaningless.

What is timed (median over ``--runs`` runs after two warm-up runs; ``time.perf_counter``):

* ``register``: :meth:`Predictor.register` of a procedural dog (``generate_shape("quadruped",
  "dog", 2_000_000)``) isotropically remeshed to ~5K vertices — surface sampling,
  canonicalization, UDF at the informative voxels, PCA projection, shape embedding, point
  embeddings and head features of every vertex. The ``describe only`` row is the first half.
* ``distance field``: one source → all vertices, from a registered state.
* ``1K × 1K``: 1000 sources × 1000 targets (distinct random vertices).
* ``64 shapes × 1 query``: :meth:`Predictor.distances_many` over 64 registered states, one
  (source, target) pair each; ``incl. register`` adds :meth:`Predictor.register_many` of the
  64 shapes (8 distinct procedural quadrupeds, each sent 8 times; nothing is cached between
  them) — the paper's "preprocessing included" setting.
* ``path``: one path between two far-apart vertices (steps reported).

Prints a markdown table with the machine, the date and the versions.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable
from datetime import date
from pathlib import Path

import numpy as np
import torch

from litege_core import __version__
from litege_core.bundle import PipelineConfig, load_bundle, save_bundle
from litege_core.describe import describe_shape
from litege_core.descriptor import UdfPcaBasis, VoxelGrid
from litege_core.nets import GeodesicNet
from litege_core.predictor import Predictor
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import isotropic_remesh


def make_synthetic_bundle(directory: Path, n_voxels: int, n_components: int, width: int) -> None:
    """A production-size bundle with random weights and a random orthonormal basis."""
    rng = np.random.default_rng(0)
    grid = VoxelGrid()
    indices = np.sort(rng.choice(grid.n_voxels, n_voxels, replace=False))
    components, _ = np.linalg.qr(rng.normal(size=(n_voxels, n_components)))
    variance = np.sort(rng.uniform(0.1, 1.0, n_components))[::-1]
    basis = UdfPcaBasis(
        grid=grid,
        voxel_indices=indices,
        centers=grid.centers(indices, dtype=np.float32),
        mean=rng.uniform(0.0, 0.3, n_voxels).astype(np.float32),
        components=components.T.astype(np.float32),
        explained_variance=variance,
        explained_variance_ratio=0.9 * variance / variance.sum(),
        n_fit_shapes=max(n_components, 1),
        metadata={"synthetic": True},
    )
    torch.manual_seed(0)
    net = GeodesicNet(width=width, descriptor_dim=n_components)
    net.set_coord_normalization([0.0, 0.0, 0.0], [0.35, 0.2, 0.11])
    save_bundle(
        directory,
        name="synthetic-bench",
        category="synthetic",
        basis=basis,
        network=net.eval(),
        pipeline=PipelineConfig(),
        training={"note": "random weights, for timing only"},
    )


def median_ms(fn: Callable[[], object], runs: int, warmup: int = 2) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundle", nargs="?", help="model bundle directory")
    parser.add_argument("--make-synthetic", metavar="DIR", help="write a random bundle and exit")
    parser.add_argument("--voxels", type=int, default=25_000)
    parser.add_argument("--components", type=int, default=240)
    parser.add_argument("--width", type=int, default=200)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--batch-runs", type=int, default=20, help="runs of the 64-shape rows")
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()

    if args.make_synthetic:
        make_synthetic_bundle(Path(args.make_synthetic), args.voxels, args.components, args.width)
        print(f"wrote {args.make_synthetic}")
        return
    if args.bundle is None:
        parser.error("a bundle directory is required (or --make-synthetic DIR)")
    if args.threads:
        torch.set_num_threads(args.threads)

    bundle = load_bundle(args.bundle, args.device)
    predictor = Predictor(bundle, args.device)
    sync = torch.cuda.synchronize if predictor.device.type == "cuda" else (lambda: None)

    dog = generate_shape("quadruped", "dog", 2_000_000)
    remeshed = isotropic_remesh(dog.vertices, dog.faces, 5000)
    shape = Shape.from_arrays(remeshed.vertices, remeshed.faces)
    n = shape.n_points
    rng = np.random.default_rng(0)
    state = predictor.register(shape)
    sources = rng.choice(n, 1000, replace=False)
    targets = rng.choice(n, 1000, replace=False)

    distinct = [
        generate_shape("quadruped", families("quadruped")[i % 5], 2_000_100 + i) for i in range(8)
    ]
    batch = [Shape.from_arrays(distinct[i % 8].vertices, distinct[i % 8].faces) for i in range(64)]
    states = predictor.register_many(batch)
    pair_src = [[int(i)] for i in rng.integers(0, batch[0].n_points, 64)]
    pair_dst = [[int(i)] for i in rng.integers(0, batch[0].n_points, 64)]

    far = int(np.argmax(np.linalg.norm(shape.vertices - shape.vertices[0], axis=1)))
    path = predictor.path(state, 0, far)

    def timed(fn: Callable[[], object]) -> Callable[[], object]:
        def run() -> object:
            out = fn()
            sync()
            return out

        return run

    rows = [
        (
            f"register ({n} vertices)",
            median_ms(timed(lambda: predictor.register(shape)), args.runs),
            "≤ 50",
        ),
        (
            "  describe only (sample, canonicalize, UDF, PCA)",
            median_ms(
                lambda: describe_shape(
                    shape, bundle.basis, n_samples=predictor.n_mesh_samples, device=args.device
                ),
                args.runs,
            ),
            "",
        ),
        (
            f"distance field (1 → {n})",
            median_ms(timed(lambda: predictor.distance_field(state, 17)), args.runs),
            "≤ 20",
        ),
        (
            "1K × 1K distance matrix",
            median_ms(timed(lambda: predictor.distances(state, sources, targets)), args.runs),
            "",
        ),
        (
            "64 shapes × 1 query (registered)",
            median_ms(
                timed(lambda: predictor.distances_many(states, pair_src, pair_dst)),
                args.batch_runs,
            ),
            "",
        ),
        (
            "64 shapes × 1 query incl. register",
            median_ms(
                timed(
                    lambda: predictor.distances_many(
                        predictor.register_many(batch), pair_src, pair_dst
                    )
                ),
                args.batch_runs,
                warmup=1,
            ),
            "",
        ),
        (
            f"path ({path.n_steps} steps, {path.points.shape[0]} points)",
            median_ms(timed(lambda: predictor.path(state, 0, far)), args.runs),
            "",
        ),
    ]

    print(f"### Predictor timings ({date.today().isoformat()})\n")
    print(
        f"- machine: {cpu_name()}, {os.cpu_count()} logical CPUs, "
        f"torch threads {torch.get_num_threads()}, device {predictor.device}"
    )
    print(
        f"- versions: litege {__version__}, python {platform.python_version()}, "
        f"torch {torch.__version__}, numpy {np.__version__}"
    )
    print(
        f"- bundle: {bundle.name} ({bundle.content_hash[:12]}), width {bundle.network.width}, "
        f"{bundle.basis.n_components} components, {bundle.basis.n_voxels} voxels; "
        f"mesh: procedural dog remeshed to {n} vertices; median of {args.runs} runs "
        f"({args.batch_runs} for the 64-shape rows) after warm-up\n"
    )
    print("| operation | median ms | design target ms |")
    print("|---|---:|---:|")
    for name, ms, target in rows:
        print(f"| {name} | {ms:.2f} | {target} |")


if __name__ == "__main__":
    main()
