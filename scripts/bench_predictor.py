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

``--accuracy`` instead measures the speed options of issue 17 against accuracy, side by side
in one run (BENCHMARKS.md section ``predictor-accuracy``): the shipped ``quadrupeds`` model in
the default configuration (float32 head, full descriptor) and with a reduced-precision head
(``precision`` bfloat16 / int8), bfloat16 point features, a truncated head (``head_rank``)
and sparser descriptor lattices (``descriptor_lattice`` bcc / stride2). Accuracy: mean error
(ground truth rescaled to mean 100, ``litege eval geodesic`` convention) on ``--shapes``
held-out procedural quadrupeds (generated, exact MMP rows from ``--sources`` sources) and, when
``../shared/eval-data`` exists, 8 TOSCA animals (research-only data, read in place), as meshes
and as 2000-point clouds. Speed: median CPU ms over ``--runs`` interleaved rounds of one pair,
a distance field (2000-point cloud) and a 1K × 1K matrix (5K mesh), preprocessing included.
A configuration may become a default only if no error rises by more than 0.2::

    python scripts/bench_predictor.py --accuracy [--shapes 10] [--sources 16] [--runs 5]
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
from litege_core.descriptor import UdfPcaBasis, VoxelGrid
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import PipelineConfig, Predictor, describe_shape, load_bundle, save_bundle
from litege_core.nets import GeodesicNet
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


ACCURACY_CONFIGS: dict[str, dict] = {
    "float32 (default)": {},
    "bfloat16 head": {"precision": "bfloat16"},
    "int8 head": {"precision": "int8"},
    "head rank 200": {"folded": {"head_rank": 200}},
    "head rank 100": {"folded": {"head_rank": 100}},
    "bfloat16 head + features": {
        "folded": {"precision": "bfloat16", "embed_precision": "bfloat16"}
    },
    "lattice bcc": {"lattice": "bcc"},
    "lattice stride2": {"lattice": "stride2"},
    "bfloat16 head + lattice stride2": {"precision": "bfloat16", "lattice": "stride2"},
}
TOSCA_NAMES = ("cat0", "cat1", "dog0", "dog1", "horse0", "horse5", "wolf0", "wolf1")


def _configured(bundle, config: dict) -> Predictor:
    from litege_core.nets import FoldedGeodesicNet

    predictor = Predictor(
        bundle,
        precision=config.get("precision", "float32"),
        descriptor_lattice=config.get("lattice", "full"),
        fusion="none",
    )
    if "folded" in config:
        predictor.folded = FoldedGeodesicNet(
            predictor.network, predictor.device, **config["folded"]
        )
    return predictor


def accuracy_table(args: argparse.Namespace) -> None:
    """The ``--accuracy`` report (see the module docstring)."""
    from litege_core.evaluation.geodesic import (
        generated_eval_shapes,
        make_input,
        real_eval_shapes,
    )
    from litege_core.learned import load_shipped
    from litege_core.metrics import geodesic_error
    from litege_core.variants import point_cloud

    bundle = load_shipped("quadrupeds")
    groups = {
        "synthetic": generated_eval_shapes(
            "quadruped", args.shapes, args.sources, cache_dir=args.cache
        )
    }
    tosca = Path(__file__).resolve().parents[1].parent / "shared" / "eval-data" / "tosca_5k"
    if tosca.is_dir():
        paths = [tosca / f"{name}.off" for name in TOSCA_NAMES if (tosca / f"{name}.off").exists()]
        groups["TOSCA"] = real_eval_shapes(paths, "TOSCA", args.sources, cache_dir=args.cache)
    settings = ("mesh", "cloud_2000")
    inputs = {
        (g, st): [make_input(shape, st, i) for i, shape in enumerate(shapes)]
        for g, shapes in groups.items()
        for st in settings
    }
    predictors = {name: _configured(bundle, config) for name, config in ACCURACY_CONFIGS.items()}
    errors: dict[str, dict[tuple[str, str], float]] = {}
    for name, predictor in predictors.items():
        errors[name] = {}
        for key, items in inputs.items():
            predicted, truth = [], []
            for item in items:
                state = predictor.register(item.shape)
                predicted.append(
                    predictor.distances(state, item.source_index).astype(np.float64).ravel()
                )
                truth.append(item.gt.ravel())
            pred, gt = np.concatenate(predicted), np.concatenate(truth)
            keep = gt > 0
            errors[name][key] = geodesic_error(pred[keep], gt[keep]).mean

    dog = generate_shape("quadruped", "dog", 2_000_000)
    cloud = Shape.from_arrays(point_cloud(dog.vertices, dog.faces, 2000, 0).points)
    remeshed = isotropic_remesh(dog.vertices, dog.faces, 5000)
    mesh = Shape.from_arrays(remeshed.vertices, remeshed.faces)
    rng = np.random.default_rng(0)
    src = rng.choice(mesh.n_points, 1000, replace=False)
    dst = rng.choice(mesh.n_points, 1000, replace=False)
    work = {
        "pair": lambda p: p.distances(p.register(cloud), [0], [1]),
        "field": lambda p: p.distance_field(p.register(cloud), 0),
        "matrix": lambda p: p.distances(p.register(mesh), src, dst),
    }
    cpu: dict[tuple[str, str], list[float]] = {}
    for round_ in range(args.runs + 1):
        for name, predictor in predictors.items():
            for w, fn in work.items():
                start = time.process_time()
                fn(predictor)
                if round_:
                    cpu.setdefault((name, w), []).append(1000.0 * (time.process_time() - start))

    keys = list(inputs)
    base = errors["float32 (default)"]
    print("### Speed options vs accuracy: shipped `quadrupeds` model (issue 17)\n")
    real = f", 8 TOSCA animals ({len(groups.get('TOSCA', []))} read)" if "TOSCA" in groups else ""
    print(
        f"- date {date.today()}; {cpu_name()}, {os.cpu_count()} logical CPUs (shared), torch "
        f"{torch.__version__} with 1 thread; command `python scripts/bench_predictor.py "
        f"--accuracy --shapes {args.shapes} --sources {args.sources} --runs {args.runs}`"
    )
    print(
        f"- accuracy: mean error (GT mean 100) on {args.shapes} held-out procedural quadrupeds"
        f"{real}; {args.sources} exact source rows each; as meshes and as 2000-point clouds"
    )
    print(
        "- speed: median process CPU ms over "
        f"{args.runs} interleaved rounds, preprocessing included: 1 pair and a distance field "
        f"on a 2000-point cloud, 1K × 1K on a {mesh.n_points}-vertex mesh; "
        f"bfloat16 runs on AMX / AVX512-BF16 here: {Predictor(bundle, precision='auto').precision}"
    )
    print("- Δ: the largest rise of a mean error over the float32 default (criterion ≤ +0.2)\n")
    header = " | ".join(f"{g} {st}" for g, st in keys)
    print(f"| configuration | {header} | Δ | 1 pair ms | field ms | 1K × 1K ms |")
    print("|---|" + "---:|" * (len(keys) + 4))
    for name in predictors:
        delta = max(errors[name][k] - base[k] for k in keys)
        cells = " | ".join(f"{errors[name][k]:.3f}" for k in keys)
        times = " | ".join(f"{statistics.median(cpu[(name, w)]):.1f}" for w in work)
        print(f"| {name} | {cells} | {delta:+.3f} | {times} |")


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
    parser.add_argument("--accuracy", action="store_true", help="speed options vs accuracy")
    parser.add_argument("--shapes", type=int, default=10, help="--accuracy: procedural shapes")
    parser.add_argument("--sources", type=int, default=16, help="--accuracy: exact rows per shape")
    parser.add_argument(
        "--cache", default=None, help="--accuracy: exact-row cache (keep out of git)"
    )
    args = parser.parse_args()
    if args.accuracy:
        torch.set_num_threads(args.threads or 1)
        accuracy_table(args)
        return

    if args.make_synthetic:
        make_synthetic_bundle(Path(args.make_synthetic), args.voxels, args.components, args.width)
        print(f"wrote {args.make_synthetic}")
        return
    if args.bundle is None:
        parser.error("a bundle directory is required (or --make-synthetic DIR)")
    if args.threads:
        torch.set_num_threads(args.threads)

    bundle = load_bundle(args.bundle, args.device)
    predictor = Predictor(bundle, args.device, fusion="none")
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
