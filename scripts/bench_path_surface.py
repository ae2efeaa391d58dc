"""How far learned geodesic paths leave the surface on real meshes (issue 13, item 6).

For each mesh, ``--pairs`` random (source, target) vertex pairs (seeded) are traced with the
shipped model; every segment of every polyline is sampled at ``--samples`` points and each
sample is projected exactly onto the mesh (:class:`~litege_core.projection.MeshProjector`).

Reported per mesh: paths whose learned walk did not converge, the largest off-surface distance
(fraction of the bounding-box diagonal, and in mean edge lengths), the largest share of a
path's length lying in segments more than one mean edge length off the surface (straight jumps
through the air), the longest segment (in mean edge lengths), the methods of the path parts
(when :class:`~litege_core.learned.GeodesicPath` has ``segments``) and the wall time of all the
paths (one call, batched).

Usage:
    python scripts/bench_path_surface.py [--data ../shared/eval-data/tosca_5k] \
        [--meshes cat0 dog0 horse0 wolf0] [--pairs 30] [--seed 0]

The TOSCA meshes are research-only data: they are read, never copied (the script exits when
the folder is absent).
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections import Counter
from datetime import date
from pathlib import Path

import numpy as np
import torch

from litege_core.io import load_shape
from litege_core.learned import Predictor, load_shipped
from litege_core.projection import MeshProjector

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "eval-data" / "tosca_5k"


def off_surface(projector: MeshProjector, points: np.ndarray, samples: int) -> np.ndarray:
    """Largest distance to the mesh along each segment of ``points (L, 3)`` → ``(L - 1,)``."""
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    dense = points[:-1, None] + t * (points[1:, None] - points[:-1, None])  # (L-1, S, 3)
    distance = projector.project(dense.reshape(-1, 3)).distance
    return distance.reshape(-1, samples).max(axis=1)


def machine() -> str:
    """CPU model (Linux) or the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--meshes", nargs="+", default=["cat0", "dog0", "horse0", "wolf0"])
    parser.add_argument("--pairs", type=int, default=30)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", default="quadrupeds")
    args = parser.parse_args()
    if not args.data.is_dir():
        print(f"{args.data} not found: nothing to measure", file=sys.stderr)
        return 1
    torch.set_num_threads(1)
    predictor = Predictor(load_shipped(args.model), fusion="none")
    print(f"# Learned paths on the surface — {date.today()}, {machine()}, 1 torch thread,")
    print(f"model {args.model}, {args.pairs} random vertex pairs per mesh (seed {args.seed})\n")
    print(
        "| mesh | vertices | not converged | max off-surface (× diag) | (× mean edge) "
        "| max share > 1 edge off | longest segment (× mean edge) | parts | seconds |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.meshes:
        shape = load_shape(args.data / f"{name}.off")
        state = predictor.register(shape)
        projector = MeshProjector(shape.vertices, shape.faces)
        diagonal = float(np.linalg.norm(np.ptp(shape.vertices, axis=0)))
        edge = projector.mean_edge_length
        rng = np.random.default_rng(args.seed)
        sources = rng.integers(0, shape.n_points, args.pairs)
        targets = rng.integers(0, shape.n_points, args.pairs)
        started = time.perf_counter()
        paths = predictor.paths(state, sources, targets)
        seconds = time.perf_counter() - started
        worst = share = longest = 0.0
        parts: Counter[str] = Counter()
        for path in paths:
            points = np.asarray(path.points)
            lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
            off = off_surface(projector, points, args.samples)
            worst = max(worst, float(off.max(initial=0.0)))
            if path.length > 0:
                share = max(share, float(lengths[off > edge].sum()) / path.length)
            longest = max(longest, float(lengths.max(initial=0.0)) / edge)
            for _, method in getattr(path, "segments", ()):
                parts[method] += 1
        failed = sum(not p.converged for p in paths)
        described = ", ".join(f"{m} {c}" for m, c in sorted(parts.items())) or "n/a"
        print(
            f"| {name} | {shape.n_points} | {failed}/{len(paths)} | {worst / diagonal:.1e} "
            f"| {worst / edge:.2f} | {share:.0%} "
            f"| {longest:.1f} | {described} | {seconds:.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
