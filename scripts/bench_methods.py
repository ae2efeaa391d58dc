"""Benchmark the geodesic methods of the ``method`` switch; prints "when to use which" tables.

Methods: ``learned`` (the shipped model: ``quadrupeds`` for animals, ``humans`` for bipeds,
through :class:`litege_core.learned.Predictor`) and ``heat``, ``exact``, ``graph``
(:class:`litege_core.engines.ClassicalSolver`).

Shapes:

* procedural: :func:`litege_core.synth.generate_shape` quadrupeds (cat, dog, horse) and one
  biped, held-out seeds (never trained on), about 4K vertices;
* real: 8 TOSCA meshes (two each of cat, dog, horse, wolf; ``tosca_5k/*.off``) when
  ``../shared/eval-data`` exists (research-only data: read, never copied; skipped cleanly
  otherwise).

Settings: ``mesh`` (queries at the vertices) and ``cloud-2000`` (2000 area-uniform surface
samples as a point cloud; ``exact`` does not apply to clouds).

Per (shape, setting, method):

* *build*: a fresh solver's constructor + ``prepare()`` (heat factorisation, k-NN graph, exact
  solver set-up); learned: ``register`` + the point-feature table of every point;
* *per source*: median over the ``--sources`` sources of one ``distances([s])`` call (one
  source to every point) on the built solver;
* *error*: ``|d − exact|`` with the exact distances rescaled to mean 100 over the sources'
  rows, pairs at distance 0 excluded (the ``litege eval geodesic`` convention); the ground
  truth on clouds is the exact geodesic between the samples (inserted into the mesh);
* *per pair*: median over the ``--pairs`` pairs of one ``distances([s], [t])`` call;
* *unreached*: % of the pairs the method answers ``+inf`` for while the exact geodesic is
  finite (a k-NN graph split into pieces); excluded from the error, and so are such paths;
* *path*: median time of ``path(s, t)`` over ``--pairs`` pairs, and the mean of
  ``length / exact distance − 1`` (%; negative: chords shorter than the surface geodesic).

Tables report the median over shapes of the timings and the mean over shapes of the errors.
Wall clock, one process; torch limited to one thread (the classical engines are
single-threaded).

Usage::

    .venv/bin/python scripts/bench_methods.py [--sources 5] [--pairs 3] [--no-real]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import statistics
import time
from collections import defaultdict
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch

from litege_core.engines import ClassicalSolver
from litege_core.errors import InputError
from litege_core.evaluation.speed import cpu_name
from litege_core.io import load_shape
from litege_core.learned import Predictor, load_shipped
from litege_core.sampling import sample_surface
from litege_core.shape import Shape
from litege_core.synth.generate import generate_shape

REPO_ROOT = Path(__file__).resolve().parents[1]
TOSCA_DIR = REPO_ROOT.parent / "shared" / "eval-data" / "tosca_5k"
TOSCA_NAMES = ("cat0", "cat1", "dog0", "dog1", "horse0", "horse5", "wolf0", "wolf1")
PROCEDURAL = (
    ("quadruped", "cat", 2_000_001),
    ("quadruped", "dog", 2_000_002),
    ("quadruped", "horse", 2_000_003),
    ("biped", "average", 2_000_004),
)
MODEL_OF = {"quadruped": "quadrupeds", "biped": "humans"}
METHODS = ("learned", "heat", "exact", "graph")
CLOUD_POINTS = 2000
PACKAGES = ("numpy", "scipy", "torch", "pygeodesic", "potpourri3d")


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """``(result, wall ms)`` of one call."""
    start = time.perf_counter()
    result = fn()
    return result, 1e3 * (time.perf_counter() - start)


def normalized_error(approx: np.ndarray, exact: np.ndarray) -> tuple[np.ndarray, float]:
    """``|approx − exact| × 100 / mean(exact)`` over pairs at finite positive exact distance
    that the method reaches, and the % of those pairs it does not reach (``+inf``)."""
    keep = np.isfinite(exact) & (exact > 0)
    reached = np.isfinite(approx[keep])
    errors = np.abs(approx[keep][reached] - exact[keep][reached]) * 100.0 / exact[keep].mean()
    return errors, 100.0 * float(1.0 - reached.mean())


class LearnedMethod:
    """The learned model behind the ClassicalSolver-like calls the benchmark makes."""

    engine = "learned"

    def __init__(self, predictor: Predictor, shape: Shape) -> None:
        self.predictor = predictor
        self.state = predictor.register(shape)
        predictor.point_table(self.state)

    def distances(self, sources: Any, targets: Any = None) -> np.ndarray:
        return self.predictor.distances(self.state, sources, targets)

    def path_length(self, source: int, target: int) -> float:
        return float(self.predictor.path(self.state, source, target).length)


def build(method: str, shape: Shape, predictor: Predictor | None) -> Any:
    if method == "learned":
        assert predictor is not None
        return LearnedMethod(predictor, shape)
    return ClassicalSolver(shape, method, max_exact_vertices=None).prepare()


def path_length(solver: Any, source: int, target: int) -> float:
    if isinstance(solver, LearnedMethod):
        return solver.path_length(source, target)
    return solver.path(source, target).length


def bench_one(
    shape: Shape,
    method: str,
    sources: np.ndarray,
    pairs: np.ndarray,
    exact_rows: np.ndarray,
    pair_exact: np.ndarray,
    predictor: Predictor | None,
) -> dict[str, float | str]:
    solver, build_ms = timed(lambda: build(method, shape, predictor))
    per_source, rows = [], []
    for source in sources.tolist():
        row, ms = timed(lambda s=source: solver.distances([s]))
        per_source.append(ms)
        rows.append(np.asarray(row, dtype=np.float64)[0])
    pair_ms = [
        timed(lambda s=source, t=target: solver.distances([s], [t]))[1]
        for source, target in pairs.tolist()
    ]
    path_ms, excess = [], []
    for (source, target), geodesic in zip(pairs.tolist(), pair_exact.tolist(), strict=True):
        try:
            length, ms = timed(lambda s=source, t=target: path_length(solver, s, t))
        except InputError:  # no path: the method's graph does not connect the two points
            continue
        path_ms.append(ms)
        excess.append(100.0 * (length / geodesic - 1.0))
    errors, unreached = normalized_error(np.stack(rows), exact_rows)
    return {
        "engine": getattr(solver, "engine", method),
        "build_ms": build_ms,
        "source_ms": statistics.median(per_source),
        "pair_ms": statistics.median(pair_ms),
        "error_mean": float(errors.mean()),
        "error_median": float(np.median(errors)),
        "unreached": unreached,
        "path_ms": statistics.median(path_ms) if path_ms else float("nan"),
        "path_excess": float(np.mean(excess)) if excess else float("nan"),
    }


def shapes(real: bool) -> list[tuple[str, str, Shape]]:
    """``(name, category, mesh)`` of the benchmark shapes."""
    out = []
    for category, family, seed in PROCEDURAL:
        generated = generate_shape(category, family, seed)
        out.append((f"{family}-{seed}", category, generated.to_shape()))
    if real and TOSCA_DIR.is_dir():
        for name in TOSCA_NAMES:
            path = TOSCA_DIR / f"{name}.off"
            if path.is_file():
                out.append((f"tosca/{name}", "quadruped", load_shape(path)))
    return out


def settings(
    mesh: Shape, n_sources: int, n_pairs: int, seed: int
) -> list[tuple[str, Shape, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """``(setting, shape, sources (S,), pairs (P, 2), exact rows (S, N), exact pair
    distances (P,))`` of the mesh and cloud settings of one shape."""
    rng = np.random.default_rng(seed)
    exact = ClassicalSolver(mesh, "exact", max_exact_vertices=None)
    out = []
    sources = rng.choice(mesh.n_points, n_sources, replace=False)
    rows = exact.distances(sources, dtype=np.float64)
    pairs = np.column_stack([sources[:n_pairs], rng.choice(mesh.n_points, n_pairs)])
    out.append(("mesh", mesh, sources, pairs, rows, rows[np.arange(n_pairs), pairs[:, 1]]))
    samples = sample_surface(mesh.vertices, mesh.faces, CLOUD_POINTS, seed=seed)
    cloud = Shape.from_arrays(samples.points)
    sources = rng.choice(CLOUD_POINTS, n_sources, replace=False)
    rows = exact.distances(samples.points[sources], samples.points, dtype=np.float64)
    pairs = np.column_stack([sources[:n_pairs], rng.choice(CLOUD_POINTS, n_pairs)])
    out.append(("cloud-2000", cloud, sources, pairs, rows, rows[np.arange(n_pairs), pairs[:, 1]]))
    return out


def summary(results: list[dict[str, Any]]) -> str:
    grouped: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for row in results:
        grouped[(row["setting"], row["method"])].append(row)
    lines = [
        "| setting | method | engine | shapes | build ms | per source ms | per pair ms | "
        "error mean | error median | unreached % | path ms | path excess % |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for setting in ("mesh", "cloud-2000"):
        for method in METHODS:
            rows = grouped.get((setting, method))
            if not rows:
                continue
            med = {
                k: float(np.nanmedian([r[k] for r in rows]))
                for k in ("build_ms", "source_ms", "pair_ms", "path_ms")
            }
            mean = {
                k: float(np.nanmean([r[k] for r in rows]))
                for k in ("error_mean", "error_median", "unreached", "path_excess")
            }
            lines.append(
                f"| {setting} | {method} | {rows[0]['engine']} | {len(rows)} | "
                f"{med['build_ms']:.1f} | {med['source_ms']:.2f} | {med['pair_ms']:.2f} | "
                f"{mean['error_mean']:.2f} | {mean['error_median']:.2f} | "
                f"{mean['unreached']:.2f} | {med['path_ms']:.1f} | "
                f"{mean['path_excess']:+.2f} |"
            )
    return "\n".join(lines)


def per_group(results: list[dict[str, Any]]) -> str:
    """Error mean per (shape group, setting, method): procedural vs real."""
    grouped: dict[tuple[str, str, str], list[float]] = defaultdict(list)
    for row in results:
        group = "TOSCA (real)" if row["shape"].startswith("tosca/") else "procedural"
        grouped[(group, row["setting"], row["method"])].append(row["error_mean"])
    lines = ["| shapes | setting | " + " | ".join(METHODS) + " |", "|---|---|" + "---:|" * 4]
    for group in ("procedural", "TOSCA (real)"):
        for setting in ("mesh", "cloud-2000"):
            cells = [grouped.get((group, setting, m)) for m in METHODS]
            if not any(cells):
                continue
            text = [f"{np.mean(c):.2f}" if c else "n/a" for c in cells]
            lines.append(f"| {group} | {setting} | " + " | ".join(text) + " |")
    return "\n".join(lines)


WHEN = {
    "learned": "the trained category (quadrupeds / humans), meshes or clouds: a pair costs "
    "no solve, so many scattered pairs and batches are cheap; approximate, and worse on "
    "out-of-distribution shapes (check ood_score)",
    "heat": "any mesh or cloud when a few % error is fine: one factorisation, then one "
    "solve per source; robust on messy meshes (intrinsic Delaunay); smooth surface paths",
    "exact": "meshes only, when the answer must be the polyhedral geodesic (ground truth, "
    "exact paths); cost grows fast with size: refused above max_exact_vertices (422)",
    "graph": "the cheapest build on anything; over-estimates along zig-zags and uses "
    "chords, so the least accurate; paths are vertex / point polylines",
}


def when_table(results: list[dict[str, Any]]) -> str:
    mesh = {m: [r for r in results if r["setting"] == "mesh" and r["method"] == m] for m in METHODS}
    lines = [
        "| method | shapes | per source ms | per pair ms | error mean | unreached % | "
        "path excess % | use when |",
        "|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for method in METHODS:
        rows = mesh[method]
        if not rows:
            continue
        kinds = "meshes" if method == "exact" else "meshes, clouds"
        lines.append(
            f"| {method} | {kinds} | {statistics.median(r['source_ms'] for r in rows):.2f} | "
            f"{statistics.median(r['pair_ms'] for r in rows):.2f} | "
            f"{np.mean([r['error_mean'] for r in rows]):.2f} | "
            f"{np.mean([r['unreached'] for r in rows]):.2f} | "
            f"{np.nanmean([r['path_excess'] for r in rows]):+.2f} | {WHEN[method]} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--sources", type=int, default=5, help="sources per shape and setting")
    parser.add_argument("--pairs", type=int, default=3, help="paths per shape and setting")
    parser.add_argument("--no-real", action="store_true", help="skip the TOSCA meshes")
    args = parser.parse_args()
    n_pairs = min(args.pairs, args.sources)
    torch.set_num_threads(1)
    predictors = {
        name: Predictor(load_shipped(name), fusion="none")
        for name in sorted(set(MODEL_OF.values()))
    }

    results: list[dict[str, Any]] = []
    all_shapes = shapes(real=not args.no_real)
    for index, (name, category, mesh) in enumerate(all_shapes):
        for setting, shape, sources, pairs, rows, pair_exact in settings(
            mesh, args.sources, n_pairs, seed=index
        ):
            for method in METHODS:
                if method == "exact" and not shape.is_mesh:
                    continue
                predictor = predictors[MODEL_OF[category]] if method == "learned" else None
                row = bench_one(shape, method, sources, pairs, rows, pair_exact, predictor)
                row.update(shape=name, setting=setting, method=method, n_points=shape.n_points)
                results.append(row)
        print(f"<!-- done {name} ({mesh.n_points} vertices) -->", flush=True)

    n_real = sum(name.startswith("tosca/") for name, _, _ in all_shapes)
    versions = ", ".join(f"{p} {metadata.version(p)}" for p in PACKAGES)
    print(f"\n### Geodesic methods ({dt.date.today().isoformat()})\n")
    print(
        f"Machine: {cpu_name()}, {os.cpu_count()} logical CPUs, Python "
        f"{platform.python_version()}, {versions}; torch on CPU with 1 thread.\n"
        f"Shapes: {len(all_shapes) - n_real} procedural (held-out seeds) + {n_real} TOSCA "
        f"meshes; {args.sources} sources (each to all points) and {n_pairs} paths per shape "
        f"and setting; clouds of {CLOUD_POINTS} surface samples. Error: mean |d − exact| "
        "with exact rescaled to mean 100; path excess: length / exact − 1. Timings: medians "
        "over shapes; errors: means over shapes.\n"
    )
    print(summary(results))
    print("\nError mean by shape group:\n")
    print(per_group(results))
    print("\n#### When to use which method (mesh setting; clouds: table above)\n")
    print(when_table(results))


if __name__ == "__main__":
    main()
