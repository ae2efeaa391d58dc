"""How far heat-method ground truth is from exact MMP on the shapes we train on (issue 14, step 4).

Heat-target datasets (``litege data build --solver heat``) cost a seventh of exact ones per
shape (docs/jobs.md). This measures what they trade: for every shape of exact-GT datasets (the
same generators the heat-target sets use), the heat rows from the same sources are compared
with the stored exact rows, in the units of ``litege eval geodesic`` (mean absolute error over
all (source, vertex) pairs, exact GT mean = 100) and as a signed bias, plus the cost of each
solver on one core. ``--t-coef`` compares diffusion times (multiples of the squared mean edge
length; the datasets' ``heat`` solver uses potpourri3d's default, 1).

Usage: python scripts/heat_target_error.py data/rigged-cal data/makehuman-cal [--split test]
    [--t-coef 1,0.5,0.35,0.25]
"""

from __future__ import annotations

import argparse
import time
from datetime import UTC, datetime

import numpy as np
import torch

from litege_core.datasets import GeodesicDataset
from litege_core.datasets.build import exact_distance_rows, heat_distance_rows
from litege_core.datasets.reader import shape_mesh
from litege_core.evaluation.speed import cpu_name


def compare(directory: str, split: str, timed: int, t_coef: float) -> dict[str, object]:
    """Per-shape and pooled heat-vs-exact errors of one dataset split."""
    dataset = GeodesicDataset(directory)
    arrays = dataset.load_split(split)
    abs_sum = signed_sum = gt_sum = 0.0
    per_shape, heat_s, exact_s = [], [], []
    for index in range(arrays["vertices"].shape[0]):
        vertices, faces = shape_mesh(arrays, index, dataset.faces)
        sources = np.asarray(arrays["sources"][index], dtype=np.int64)
        exact = np.asarray(arrays["distances"][index][:, : vertices.shape[0]], dtype=np.float64)
        start = time.process_time()
        heat = heat_distance_rows(vertices, faces, sources, t_coef)
        heat_s.append(time.process_time() - start)
        if index < timed:
            start = time.process_time()
            exact_distance_rows(vertices, faces, sources)
            exact_s.append(time.process_time() - start)
        difference = heat - exact
        abs_sum += float(np.abs(difference).sum())
        signed_sum += float(difference.sum())
        gt_sum += float(exact.sum())
        per_shape.append(100.0 * np.abs(difference).sum() / exact.sum())
    return {
        "dataset": dataset.spec.name,
        "t_coef": t_coef,
        "category": dataset.spec.category,
        "shapes": len(per_shape),
        "sources": int(arrays["sources"].shape[1]),
        "error": 100.0 * abs_sum / gt_sum,
        "bias": 100.0 * signed_sum / gt_sum,
        "median": float(np.median(per_shape)),
        "worst": float(np.max(per_shape)),
        "heat_s": float(np.mean(heat_s)),
        "exact_s": float(np.mean(exact_s)) if exact_s else float("nan"),
        "timed": len(exact_s),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", help="exact-GT dataset directories")
    parser.add_argument("--split", default="test")
    parser.add_argument("--timed", type=int, default=4, help="shapes whose exact rows are re-timed")
    parser.add_argument("--t-coef", default="1", help="comma-separated heat diffusion times")
    args = parser.parse_args()
    torch.set_num_threads(1)
    t_coefs = [float(t) for t in args.t_coef.split(",")]
    rows = [
        compare(directory, args.split, args.timed if i == 0 else 0, t_coef)
        for directory in args.datasets
        for i, t_coef in enumerate(t_coefs)
    ]
    print("### Heat-method ground truth against exact MMP (issue 14, step 4)\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; one thread; "
        f"command `python scripts/heat_target_error.py {' '.join(args.datasets)} "
        f"--split {args.split} --timed {args.timed} --t-coef {args.t_coef}`"
    )
    print(
        "- error: mean |heat − exact| over every (source, vertex) pair, exact GT mean = 100 "
        "(the unit of `litege eval geodesic`); bias: mean (heat − exact) in the same unit; "
        "per-shape median and worst; CPU seconds per shape for all its sources (exact re-timed "
        "on the first shapes)\n"
    )
    print(
        "| dataset | generator | shapes × sources | heat t_coef | error | bias | per-shape median "
        "| worst | heat s/shape | exact s/shape |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        exact = "" if r["timed"] == 0 else f"{r['exact_s']:.2f}"
        print(
            f"| {r['dataset']} | {r['category']} | {r['shapes']} × {r['sources']} | "
            f"{r['t_coef']:g} | {r['error']:.2f} | {r['bias']:+.2f} | {r['median']:.2f} | "
            f"{r['worst']:.2f} | {r['heat_s']:.2f} | {exact} |"
        )


if __name__ == "__main__":
    main()
