"""Cost of judged frames: end to end (prepare X and Y, match 1000 queries) with ``frames="tnet"``
and ``frames="judged"``, interleaved in one process (issue 15, step 1).

Usage:
    python scripts/bench_frames.py [MODEL] [--runs 5] [--threads 1] [--prepare FILE ...]

The shapes and queries are those of ``scripts/bench_matching.py`` (a procedural dog and cat of
the test seeds, isotropically remeshed to about 5K vertices, 1000 fixed query vertices). One
warm-up builds the frame judge's reference animals (about a second, once per process).
``--prepare FILE ...`` also times ``prepare`` alone on each file in both modes (a shape whose
turned T-Net runs disagree pays for the judge; one whose runs agree only for the runs).
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from litege_core.io import load_shape
from litege_core.matching import MatchingModel
from litege_core.shape import Shape
from litege_core.synth import generate_shape
from litege_core.variants import isotropic_remesh


def _remeshed(family: str, seed: int) -> Shape:
    generated = generate_shape("quadruped", family, seed)
    vertices, faces = isotropic_remesh(generated.vertices, generated.faces, 5000)[:2]
    return Shape.from_arrays(vertices, faces)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", default="quadrupeds")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--prepare", nargs="*", default=[], help="shape files to prepare")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    model = MatchingModel.load(args.model)
    x, y = _remeshed("dog", 2_000_000), _remeshed("cat", 2_000_001)
    queries = np.sort(np.random.default_rng(0).choice(x.n_points, 1000, replace=False))
    model.prepare_many([x, y], frames="judged")  # warm-up: reference animals, allocations
    times: dict[str, list[float]] = {"tnet": [], "judged": []}
    for _ in range(args.runs):
        for mode in times:
            start = time.perf_counter()
            px, py = model.prepare_many([x, y], frames=mode)
            model.match(px, py, queries)
            times[mode].append(time.perf_counter() - start)
    print(f"| frames | end to end ms (median of {args.runs}) |\n|---|---:|")
    for mode, values in times.items():
        print(f"| {mode} | {1000 * statistics.median(values):.1f} |")
    if args.prepare:
        print("\n| shape | prepare, tnet ms | prepare, judged ms | judged frame |")
        print("|---|---:|---:|---|")
    for path in args.prepare:
        loaded = load_shape(path)
        shape = Shape.from_arrays(loaded.vertices, loaded.faces)
        spent: dict[str, list[float]] = {"tnet": [], "judged": []}
        chosen = ""
        for _ in range(args.runs):
            for mode in spent:
                start = time.perf_counter()
                prepared = model.prepare(shape, frames=mode)
                spent[mode].append(time.perf_counter() - start)
                chosen = prepared.frame if mode == "judged" else chosen
        cells = " | ".join(f"{1000 * statistics.median(v):.1f}" for v in spent.values())
        print(f"| {Path(path).stem} | {cells} | {chosen} |")


if __name__ == "__main__":
    main()
