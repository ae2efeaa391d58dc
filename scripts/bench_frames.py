"""Cost of judged frames: end to end (prepare X and Y, match 1000 queries) with ``frames="tnet"``
and ``frames="judged"``, interleaved in one process (issue 15, step 1).

Usage:
    python scripts/bench_frames.py [MODEL] [--runs 5] [--threads 1]

The shapes and queries are those of ``scripts/bench_matching.py`` (a procedural dog and cat of
the test seeds, isotropically remeshed to about 5K vertices, 1000 fixed query vertices). One
warm-up builds the frame judge's reference animals (about a second, once per process).
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

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


if __name__ == "__main__":
    main()
