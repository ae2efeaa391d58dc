"""A/B timing of the paper's Table 1 setting for two checkouts on one machine (issue 17).

Run it alternately with two code versions on ``PYTHONPATH`` (for example the working tree and
``git archive OLD litege_core`` unpacked elsewhere, its ``models`` a link to this one's), so
that machine-to-machine and run-to-run noise shows up beside the difference between them:

    for v in new old new old; do
        PYTHONPATH=<tree of $v> python3 scripts/device/ab_batch_table.py $v
    done

Prints one line per run: the label, the package it imported, and the median wall ms of
``register_many`` + ``distances_many`` for B = 1, 8, 64 clouds of 2000 points (9 runs after a
warm-up; the clouds of scripts/bench_batch_table.py), on CUDA when there is a GPU.
"""

from __future__ import annotations

import sys

import torch

import litege_core
from litege_core.evaluation.speed import batch_query_table
from litege_core.learned import Predictor, load_shipped
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import point_cloud


def main() -> None:
    label = sys.argv[1] if len(sys.argv) > 1 else "run"
    torch.set_num_threads(1)
    names = families("quadruped")
    clouds = []
    for i in range(8):
        shape = generate_shape("quadruped", names[i % len(names)], 2_000_000 + i)
        clouds.append(Shape.from_arrays(point_cloud(shape.vertices, shape.faces, 2000, i).points))
    device = "cuda" if torch.cuda.is_available() else "cpu"
    predictor = Predictor(load_shipped("quadrupeds", device), device, fusion="none")
    rows = batch_query_table(predictor, clouds, counts=(1, 8, 64), runs=9, memory=False)
    timings = [(int(row["shapes"]), round(row["median_ms"], 2)) for row in rows]
    print(label, litege_core.__file__, device, timings, flush=True)


if __name__ == "__main__":
    main()
