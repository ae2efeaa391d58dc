"""Where real-shape geodesic error comes from: sources on parts that touch other parts (issue 14).

A folded hind paw pressed against the haunch, a tail laid along the feet or a paw held to the
face put surface points side by side in space that are far apart along the surface. A network
that reads point coordinates and a global descriptor sees them as neighbours. For every
farthest-point source of every real dev shape this script measures, from the exact rows alone:

    contact(source) = share of the mesh vertices within Euclidean distance ``--radius`` of the
                      source whose exact geodesic from it exceeds ``--stretch`` × that radius

(unit-area meshes; 0 on a source whose neighbourhood is all plain surface), and the model's
error of the source's row (GT mean = 100 per shape, mesh setting, the trained network: full
head, full lattice). It prints, per real set, the Spearman correlation between the two over
all sources, the mean error and signed error of the sources with and without contact, and the
shapes whose worst row has contact; then the ``--worst`` shapes of each set: their error, signed
error, worst row and its contact, and their error in the best of the 24 signed axis
permutations of the PCA frame (is the frame to blame?). Every number comes from this script::

    python scripts/contact_error.py --sets tosca,faust --sources 12 --cache out/exact-cache
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
from datetime import UTC, datetime

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.stats import spearmanr

from litege_core.evaluation.geodesic import (
    REAL_SETS,
    make_input,
    real_eval_shapes,
    real_shape_paths,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned.bundle import load_model
from litege_core.learned.frame import candidate_rotations
from litege_core.learned.predictor import Predictor


def contact_shares(
    vertices: NDArray, sources: NDArray, rows: NDArray, radius: float, stretch: float
) -> NDArray:
    """``(S,)``: per source, the share of vertices within ``radius`` (Euclidean) whose exact
    geodesic ``rows[s]`` exceeds ``stretch · radius``."""
    euclid = np.linalg.norm(vertices[None, :, :] - vertices[sources][:, None, :], axis=2)
    near = euclid < radius
    folded = near & (rows > stretch * radius)
    return folded.sum(axis=1) / vertices.shape[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", default="tosca,faust")
    parser.add_argument("--model", action="append", default=[], help="SET=NAME_OR_DIR")
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--radius", type=float, default=0.08, help="unit-area units")
    parser.add_argument("--stretch", type=float, default=3.0)
    parser.add_argument("--worst", type=int, default=5, help="shapes per set in the detail table")
    parser.add_argument("--cache", default="out/diagnose/cache", help="exact-row cache")
    args = parser.parse_args()
    torch.set_num_threads(1)
    chosen = dict(item.split("=", 1) for item in args.model)
    details = []

    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; "
        f"{args.sources} FPS sources per shape, "
        f"exact MMP rows, unit area; contact radius {args.radius}, stretch {args.stretch}; "
        "error of each source's row, GT mean 100 per shape, mesh input, full head and lattice; "
        f"command `python scripts/contact_error.py --sets {args.sets} --sources {args.sources} "
        f"--radius {args.radius} --stretch {args.stretch} --worst {args.worst}"
        + "".join(f" --model {m}" for m in args.model)
        + "`\n"
    )
    print(
        "| set | model | sources | Spearman ρ (error, contact) | sources with contact | "
        "error, contact | error, none | signed error, contact | signed error, none | "
        "worst rows with contact |"
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for key in args.sets.split(","):
        real = REAL_SETS[key]
        paths = real_shape_paths(args.eval_data, key)
        if not paths:
            print(f"| {key} | – | no shapes under {args.eval_data} | | | | | | | |")
            continue
        name = chosen.get(key, real.model)
        predictor = Predictor(
            load_model(name), head="full", descriptor_lattice="full", fusion="none"
        )
        shapes = real_eval_shapes(paths, real.group, args.sources, cache_dir=args.cache)
        errors, signed, contact, worst_in_contact = [], [], [], 0
        per_shape = []  # (name, error, signed, worst row error, its contact, item)
        for shape in shapes:
            item = make_input(shape, "mesh", 0)
            rows = predictor.distances(predictor.register(item.shape), item.source_index)
            scale = float(item.gt.mean()) / 100.0
            diff = (rows - item.gt) / scale
            row_error = np.abs(diff).mean(axis=1)
            share = contact_shares(
                shape.vertices, shape.sources, shape.gt, args.radius, args.stretch
            )
            errors.append(row_error)
            signed.append(diff.mean(axis=1))
            contact.append(share)
            worst = int(np.argmax(row_error))
            worst_in_contact += int(share[worst] > 0)
            per_shape.append(
                (shape.name, row_error.mean(), diff.mean(), row_error[worst], share[worst], item)
            )
        error, bias, touch = (np.concatenate(v) for v in (errors, signed, contact))
        rho = spearmanr(error, touch).statistic
        has = touch > 0
        print(
            f"| {real.group} | `{name}` | {error.size} | {rho:.2f} | {int(has.sum())} | "
            f"{error[has].mean():.2f} | {error[~has].mean():.2f} | {bias[has].mean():+.2f} | "
            f"{bias[~has].mean():+.2f} | {worst_in_contact} of {len(shapes)} |"
        )
        per_shape.sort(key=lambda row: -row[1])
        details.append((real.group, predictor, per_shape[: args.worst]))

    print(
        "\n| set | shape | error | signed error | worst row | its contact % | "
        "error, best of 24 frames |"
    )
    print("|---|---|---:|---:|---:|---:|---:|")
    rotations = np.stack(candidate_rotations("all"))
    for group, predictor, worst_shapes in details:
        for name, error, shape_bias, worst, share, item in worst_shapes:
            states = predictor.register_turned(item.shape, rotations)
            fields = predictor.distances_many(states, [item.source_index] * len(states))
            scale = float(item.gt.mean()) / 100.0
            best = min(float(np.abs(f - item.gt).mean()) / scale for f in fields)
            print(
                f"| {group} | {name} | {error:.2f} | {shape_bias:+.2f} | {worst:.1f} | "
                f"{100 * share:.2f} | {best:.2f} |"
            )


if __name__ == "__main__":
    main()
