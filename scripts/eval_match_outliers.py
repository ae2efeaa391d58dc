"""Matching a real mesh to a point cloud of another real shape, with and without stray points.

Usage: python scripts/eval_match_outliers.py [--set faust] [--pairs 5] [--queries 500]
    [--fractions 0,0.01,0.05] [--model humans]

FAUST's dense ``corres/NAME.vts`` maps give the true match of each query vertex of X on Y. Each
pair ``(X, Y)`` of consecutive dev shapes: X as its mesh, Y as the point cloud of its
vertices followed by ``fraction · N`` stray points (``litege_core.variants.add_outliers``:
uniform in its bounding box grown by 10 % per side) and, for reference, Y as its mesh. Error:
the mean Euclidean distance from each query's match to its true vertex, ×100, at unit area
(a stray point matched counts with its own distance; no geodesics: a cloud with strays has no
surface to measure them on), and the share of matches that land on a stray point. Prints
markdown.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import time
from datetime import UTC, datetime

import numpy as np
import torch

from litege_core.evaluation.geodesic import real_shape_paths, unit_area
from litege_core.evaluation.matching_data import read_vts
from litege_core.evaluation.speed import cpu_name
from litege_core.io import load_shape
from litege_core.matching import MatchingModel
from litege_core.shape import Shape
from litege_core.variants import add_outliers

SETS = {"faust": "humans"}
"""Real sets with dense correspondence between all their shapes, and the matching model of
each."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", choices=sorted(SETS), default="faust")
    parser.add_argument("--model", default=None, help="matching model (default: the set's)")
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--queries", type=int, default=500)
    parser.add_argument("--fractions", default="0,0.01,0.05")
    args = parser.parse_args()
    torch.set_num_threads(1)
    start = time.perf_counter()
    model = MatchingModel.load(args.model or SETS[args.set])
    fractions = [float(f) for f in args.fractions.split(",")]
    paths = real_shape_paths(args.eval_data, args.set)
    if len(paths) < 2 * args.pairs:
        raise SystemExit(f"{args.set}: {len(paths)} shapes, fewer than 2 × --pairs")
    errors: dict[str, list[float]] = {"Y as its mesh": []}
    errors.update({f"Y as a cloud, {100 * f:g} % stray points": [] for f in fractions})
    on_strays: dict[str, list[float]] = {label: [] for label in errors}
    for p in range(args.pairs):
        pair = (paths[2 * p], paths[2 * p + 1])
        x, y = (load_shape(path) for path in pair)
        x_vertices, _ = unit_area(x.vertices, x.faces)
        y_vertices, _ = unit_area(y.vertices, y.faces)
        source = model.prepare(Shape.from_arrays(x_vertices, x.faces))
        x_map, y_map = (read_vts(path.parent / "corres" / f"{path.stem}.vts") for path in pair)
        rows = np.random.default_rng(p).choice(len(x_map), args.queries, replace=False)
        queries, truth = x_map[rows], y_map[rows]
        targets = [("Y as its mesh", Shape.from_arrays(y_vertices, y.faces))]
        targets += [
            (f"Y as a cloud, {100 * f:g} % stray points", add_outliers(y_vertices, f, seed=p))
            for f in fractions
        ]
        for label, target in targets:
            shape = target if isinstance(target, Shape) else Shape.from_arrays(target)
            matched = model.match(source, model.prepare(shape), queries).indices
            offset = shape.vertices[matched] - y_vertices[truth]
            errors[label].append(100.0 * float(np.linalg.norm(offset, axis=1).mean()))
            on_strays[label].append(100.0 * float((matched >= len(y_vertices)).mean()))
    print(f"### Matching a mesh to a cloud with stray points: {args.set}\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; "
        f"{args.pairs} pairs of consecutive shapes, {args.queries} query vertices each, "
        f"matching model `{args.model or SETS[args.set]}` (default options); "
        f"{time.perf_counter() - start:.0f} s; command `python scripts/eval_match_outliers.py "
        f"--set {args.set} --pairs {args.pairs} --queries {args.queries} "
        f"--fractions {args.fractions}`\n"
    )
    print("| target | mean error ×100 | matches on stray points, % | per pair |")
    print("|---|---:|---:|---|")
    for label, values in errors.items():
        shown = ", ".join(f"{v:.2f}" for v in values)
        print(f"| {label} | {np.mean(values):.2f} | {np.mean(on_strays[label]):.1f} | {shown} |")


if __name__ == "__main__":
    main()
