"""How good are LiteGE's geodesic paths on real shapes? (issue 14, diagnosis)

For every real dev shape and input (the mesh, a 2000-point cloud), pairs from each of the
shape's farthest-point sources (whose exact rows are known) to random targets; each pair's
path is traced by the shipped model (``Predictor.paths``) with its defaults (``route="auto"``:
the fused model's surface route) and with the learned walk (``route="learned"``: gradient
descent of the network's distance, finished on the surface where it stalls); each polyline's
length is compared with the exact geodesic distance. Beside it, the classical path of the same
input: on a mesh the edge-flip geodesic (potpourri3d's ``EdgeFlipGeodesicSolver``, locally
shortest from the edge path), on a cloud the Dijkstra path on its symmetric 10-NN graph.

Reported per (set, input): the mean |length − truth| and the mean signed (length − truth),
both with the shape's ground-truth mean at 100 (as ``litege eval geodesic``), the share of
paths that converged (``GeodesicPath.converged``) and of paths with a surface route (the whole
path, or the finish of a stalled walk), and the CPU milliseconds per path (one thread)::

    python scripts/eval_paths.py --sets tosca,faust --sources 12 --targets 4
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import time
from datetime import UTC, datetime

import numpy as np
import torch

from litege_core.engines.graph import dijkstra_rows, knn_graph
from litege_core.evaluation.geodesic import (
    REAL_SETS,
    make_input,
    real_eval_shapes,
    real_shape_paths,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import Predictor
from litege_core.learned.bundle import load_model
from litege_core.learned.paths import LEARNED

KNN = 10
"""Neighbours of the classical cloud path's graph (as ``litege eval geodesic``'s kNN row)."""


def polyline_length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def edge_flip_lengths(vertices, faces, sources, targets) -> tuple[list[float], float]:
    """Edge-flip geodesic lengths from each source vertex to its target vertex, and the CPU
    seconds they took (the solver built once per mesh)."""
    import potpourri3d as pp3d

    start = time.process_time()
    solver = pp3d.EdgeFlipGeodesicSolver(np.asarray(vertices), np.asarray(faces))
    lengths = [
        polyline_length(np.asarray(solver.find_geodesic_path(int(s), int(t)))) if s != t else 0.0
        for s, t in zip(sources, targets, strict=True)
    ]
    return lengths, time.process_time() - start


def knn_path_lengths(points, sources, targets) -> tuple[list[float], float]:
    """Dijkstra path lengths on the symmetric k-NN graph (the path's polyline length is its
    Dijkstra distance), and the CPU seconds they took."""
    start = time.process_time()
    rows = dijkstra_rows(knn_graph(np.asarray(points, np.float64), KNN), np.asarray(sources))
    lengths = [float(rows[i, t]) for i, t in enumerate(targets)]
    return lengths, time.process_time() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sets", default="tosca,faust")
    parser.add_argument("--settings", default="mesh,cloud_2000")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--targets", type=int, default=4, help="random targets per source")
    parser.add_argument("--eval-root", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache")
    parser.add_argument("--limit", type=int, default=None, help="the first shapes of each set")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings = args.settings.split(",")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; one thread; "
        f"{args.sources} FPS sources × {args.targets} random targets (seed 0) per shape; "
        f"exact MMP truth, GT mean 100 per shape; command `python scripts/eval_paths.py "
        f"--sets {args.sets} --settings {args.settings} --sources {args.sources} --targets "
        f"{args.targets}`\n"
    )
    print(
        "| shapes | input | method | pairs | mean error | mean signed error | converged "
        "| with a surface route | CPU ms per path |"
    )
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for key in args.sets.split(","):
        real = REAL_SETS[key]
        predictor = Predictor(load_model(real.model))
        paths = real_shape_paths(args.eval_root, key, args.limit)
        shapes = real_eval_shapes(paths, real.group, args.sources, args.cache)
        for setting in settings:
            routes = ["auto", "learned"]
            names = [*routes, "classical"]
            rows: dict[str, dict[str, list[float]]] = {
                name: {"error": [], "signed": [], "converged": [], "finished": []} for name in names
            }
            seconds = dict.fromkeys(names, 0.0)
            for index, shape in enumerate(shapes):
                item = make_input(shape, setting, seed=0)
                rng = np.random.default_rng([0, index])
                n_points = item.shape.n_points
                sources = np.repeat(item.source_index, args.targets)
                source_rows = np.repeat(np.arange(item.source_index.size), args.targets)
                targets = rng.integers(0, n_points, sources.size)
                truth = item.gt[source_rows, targets]
                scale = 100.0 / float(np.mean(item.gt))
                state = predictor.register(item.shape)
                lengths: dict[str, list[float]] = {}
                for route in routes:
                    start = time.process_time()
                    traced = predictor.paths(state, sources, targets, route=route)
                    seconds[route] += time.process_time() - start
                    lengths[route] = [path.length for path in traced]
                    rows[route]["converged"] += [path.converged for path in traced]
                    rows[route]["finished"] += [
                        any(method != LEARNED for _, method in path.segments) for path in traced
                    ]
                if setting == "mesh":
                    classical, spent = edge_flip_lengths(
                        item.shape.vertices, item.shape.faces, sources, targets
                    )
                else:
                    classical, spent = knn_path_lengths(item.shape.vertices, sources, targets)
                seconds["classical"] += spent
                lengths["classical"] = classical
                for name in names:
                    difference = (np.asarray(lengths[name]) - truth) * scale
                    rows[name]["error"] += list(np.abs(difference))
                    rows[name]["signed"] += list(difference)
            labels = {
                "auto": "LiteGE (shipped, defaults)",
                "learned": 'LiteGE, learned walk (`route="learned"`)',
                "classical": "edge-flip geodesic" if setting == "mesh" else f"{KNN}-NN Dijkstra",
            }
            for name in names:
                label = labels[name]
                row = rows[name]
                count = len(row["error"])
                reached = f"{100 * np.mean(row['converged']):.0f} %" if row["converged"] else "—"
                finished = f"{100 * np.mean(row['finished']):.0f} %" if row["finished"] else "—"
                print(
                    f"| {real.group} ({len(shapes)}) | {setting} | {label} | {count} | "
                    f"{np.mean(row['error']):.2f} | {np.mean(row['signed']):+.2f} | {reached} | "
                    f"{finished} | {1000 * seconds[name] / count:.1f} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
