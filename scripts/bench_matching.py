"""Time shape matching on a CPU (or any torch device): preparation, search, end to end.

Usage:
    python scripts/bench_matching.py [MODEL_NAME_OR_BUNDLE_DIR] [--runs 5] [--threads 1]

X and Y are the first two procedural families of the model's category (a dog and a cat for
quadrupeds, an average and a slim human for bipeds; test seeds), isotropically remeshed to about
5K vertices; 1000 query vertices of X (fixed random draw) are matched on Y.

* ``prepare``: :meth:`MatchingModel.prepare` of one 5K mesh (unit-area frame, T-Net, UDF
  descriptor, FPS NN cache).
* ``match 1K``: :meth:`MatchingModel.match` of the 1000 queries on prepared shapes whose point
  features are cached (what the service does for a known shape); ``features`` is the one-off
  point-feature table of a 5K shape.
* ``end to end``: prepare X and Y, then match 1000 queries — nothing cached.
* search settings: evaluations per query and the fraction of queries whose match equals the
  exhaustive argmin over all of Y's vertices (the search's own error, not the model's).

Median over ``--runs`` runs after one warm-up. Prints a markdown block (machine, date, versions).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import statistics
import time
from collections.abc import Callable
from datetime import date

import numpy as np
import torch

from litege_core import __version__
from litege_core.matching import MatchingModel
from litege_core.matching.cache import NNCache
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import isotropic_remesh

SEARCH_VARIANTS = (
    ("bundle default", None, None, None),
    ("tiers 60/650, k 65/60, beam 2", (60, 650), (65, 60), 2),
    ("tiers 32/256, k 32/40, beam 1", (32, 256), (32, 40), 1),
    ("tiers 32/256, k 32/40, beam 2", (32, 256), (32, 40), 2),
)


def _median_seconds(fn: Callable[[], object], runs: int) -> float:
    fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _remeshed(category: str, family: str, seed: int) -> Shape:
    generated = generate_shape(category, family, seed)
    vertices, faces = isotropic_remesh(generated.vertices, generated.faces, 5000)[:2]
    return Shape.from_arrays(vertices, faces)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", default="quadrupeds")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--queries", type=int, default=1000)
    parser.add_argument("--precision", default="float32", help="the search head's arithmetic")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    model = MatchingModel.load(args.model, args.device, args.precision)
    names = {"quadruped": ("dog", "cat")}.get(model.category, families(model.category)[:2])
    x_shape = _remeshed(model.category, names[0], 2_000_000)
    y_shape = _remeshed(model.category, names[1], 2_000_001)
    queries = np.sort(
        np.random.default_rng(0).choice(x_shape.n_points, args.queries, replace=False)
    )
    x, y = model.prepare_many([x_shape, y_shape])
    model.features(x), model.features(y)

    def fresh_features() -> None:
        y._lazy.clear()
        model.features(y)

    def end_to_end() -> None:
        px, py = model.prepare_many([x_shape, y_shape])
        model.match(px, py, queries)

    rows = [
        ("prepare (5K mesh)", _median_seconds(lambda: model.prepare(y_shape), args.runs)),
        ("point features (5K mesh)", _median_seconds(fresh_features, args.runs)),
        (
            f"match {args.queries} queries",
            _median_seconds(lambda: model.match(x, y, queries), args.runs),
        ),
        (
            f"end to end: prepare X, Y + match {args.queries}",
            _median_seconds(end_to_end, max(1, args.runs // 2)),
        ),
    ]
    exhaustive = model.match(x, y, queries, exhaustive=True)
    search_rows = []
    for name, tiers, neighbours, beams in SEARCH_VARIANTS:
        target = y
        if tiers is not None:
            cache = NNCache.build(
                y.aligned.astype(np.float64), tier_sizes=tiers, neighbours=neighbours
            )
            target = dataclasses.replace(y, cache=cache, _lazy=y._lazy)
        seconds = _median_seconds(
            lambda t=target, b=beams: model.match(x, t, queries, beams=b), args.runs
        )
        result = model.match(x, target, queries, beams=beams)
        same = float((result.indices == exhaustive.indices).mean()) * 100
        search_rows.append((name, result.evaluations / args.queries, seconds, same))
    exhaustive_s = _median_seconds(lambda: model.match(x, y, queries, exhaustive=True), 1)

    print(f"### Matching speed: `{model.name}` matching model ({args.device})")
    print()
    print(
        f"- date {date.today().isoformat()}; machine {platform.machine()}, "
        f"{os.cpu_count()} logical CPUs, torch threads {args.threads}; Python "
        f"{platform.python_version()}, torch {torch.__version__}, litege {__version__}"
    )
    widths = [net.width for net in model.bundle.networks]
    print(
        f"- model: {len(widths)} network(s) of width {widths}, "
        f"{model.bundle.basis.n_components} components, {model.bundle.basis.n_voxels} voxels, "
        f"search head in {model.precision}; "
        f"X = procedural {names[0]}, Y = procedural {names[1]} (test seeds), isotropic remesh to "
        f"{x_shape.n_points} / {y_shape.n_points} vertices; median of {args.runs} runs"
    )
    print(
        f"- command `python scripts/bench_matching.py {args.model} --runs {args.runs} "
        f"--threads {args.threads} --queries {args.queries} --precision {args.precision}`"
    )
    print()
    print("| step | ms |")
    print("|---|---:|")
    for name, seconds in rows:
        print(f"| {name} | {seconds * 1000:.1f} |")
    print()
    print("| search setting | evaluations / query | ms for the queries | same as exhaustive % |")
    print("|---|---:|---:|---:|")
    for name, evals, seconds, same in search_rows:
        print(f"| {name} | {evals:.0f} | {seconds * 1000:.1f} | {same:.1f} |")
    print(
        f"| exhaustive (all {y.n_points} vertices) | {y.n_points} | {exhaustive_s * 1000:.1f} "
        f"| 100.0 |"
    )


if __name__ == "__main__":
    main()
