"""The paper's Table 1 on this machine: B point clouds (2000 points), one query each,
preprocessing included (canonicalization, UDF-PCA, embeddings), for B = 1, 4, 8, 32, 64, 96.

Usage: python scripts/bench_batch_table.py [--model quadrupeds] [--runs 5] [--threads 1]
Clouds: area-weighted samples of 8 distinct procedural quadrupeds (test seeds), reused
cyclically; nothing is cached between runs. See litege_core.evaluation.speed for what the
memory column measures.
"""

from __future__ import annotations

import argparse
import os
import platform
from datetime import date

import torch

from litege_core.bundle import load_shipped
from litege_core.evaluation.speed import batch_query_table
from litege_core.predictor import Predictor
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.variants import point_cloud

PAPER_MS = {1: 1.9, 4: 2.0, 8: 2.6, 32: 7.3, 64: 13.4, 96: 19.1}  # RTX A4000, reference only


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="quadrupeds")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    predictor = Predictor(load_shipped(args.model))
    names = families("quadruped")
    clouds = []
    for i in range(8):
        shape = generate_shape("quadruped", names[i % len(names)], 2_000_000 + i)
        clouds.append(Shape.from_arrays(point_cloud(shape.vertices, shape.faces, 2000, i).points))
    rows = batch_query_table(predictor, clouds, runs=args.runs)
    print("### B shapes × 1 query, preprocessing included (paper Table 1 setting), CPU\n")
    print(
        f"- date {date.today()}; {os.cpu_count()} logical CPUs x86_64 "
        f"({platform.processor() or platform.machine()}); torch {torch.__version__}, "
        f"{args.threads} thread(s); model `{args.model}`; 2000-point clouds; median of "
        f"{args.runs} runs after 1 warm-up; command `python scripts/bench_batch_table.py "
        f"--runs {args.runs} --threads {args.threads}`"
    )
    print(
        "- the paper's GPU figures (RTX A4000) are shown for reference only: different "
        "hardware, not a like-for-like comparison\n"
    )
    print("| shapes | median ms | ms per shape | peak RSS growth MB | paper GPU ms |")
    print("|---:|---:|---:|---:|---:|")
    for row in rows:
        print(
            f"| {row['shapes']} | {row['median_ms']:.1f} | {row['ms_per_shape']:.1f} | "
            f"{row['peak_rss_growth_mb']:.1f} | {PAPER_MS[row['shapes']]} |"
        )


if __name__ == "__main__":
    main()
