"""The graph of a mesh input for graph fusion: Dijkstra over chords between vertices at most
``R`` mesh edges apart, against exact geodesics, for several ``R`` (issue 14).

Usage::

    python scripts/eval_mesh_graph.py [--set tosca --set faust ...] [--dataset data/folder-cal ...]
        [--rings 1,2,3] [--arcs] [--knn 16] [--smooth 0.08] [--sources 12] [--setting mesh]
        [--cache out/exact-cache]

Each graph's rows are divided by its median ratio to the truth over the shapes of a group (the
fusion's bias correction; the calibrated bias comes from our generated shapes, this is the
best a constant can do), then scored as mean error with ground truth mean 100 per shape:
the mean, the worst shape and the bias. ``--knn K`` adds the plain K-nearest-neighbour graph of
the vertices (what a cloud of the same points gets: touching parts join). Real sets are the
research-only dev sets; datasets are the test split of collection datasets we generate.
``--arcs`` adds, for each ``R`` above 1, the same graph with its chords that are not edges
lengthened to their arcs (``mesh_ring_graph(..., normals=arc_normals(...))``);
``--setting decimated_N`` scores the meshes simplified to about N vertices against their own
exact geodesics (:func:`~litege_core.evaluation.geodesic.make_input`), ``--setting
meshnoise_S`` the meshes with vertex noise against the clean surface's, instead of the meshes
as they are. ``--smooth L`` adds each ring graph again on the mesh smoothed until its vertex
noise is at most ``L`` (:func:`~litege_core.learned.mesh_noise.denoised_mesh`, what a fusion
with ``mesh_smooth_noise = L`` builds its graph on; a mesh no noisier is left as it is). The
``ν`` column is the group's median vertex noise before any smoothing
(:func:`~litege_core.learned.mesh_noise.mesh_noise`, what a fusion's mesh bias reads).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from litege_core.engines.graph import arc_normals, dijkstra_rows, knn_graph, mesh_ring_graph
from litege_core.evaluation.geodesic import (
    REAL_SETS,
    EvalShape,
    collection_eval_shapes,
    is_mesh_setting,
    make_input,
    real_eval_shapes,
    real_shape_paths,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned.mesh_noise import denoised_mesh, mesh_noise
from litege_core.metrics import geodesic_error


def shape_rows(shape: EvalShape, graph) -> tuple[np.ndarray, np.ndarray]:
    """``(R, V)`` graph rows and truth of ``shape`` (inf rows left to the caller)."""
    return dijkstra_rows(graph, shape.sources), shape.gt


def scored(rows: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float, float]:
    """Mean and worst per-shape error after dividing by the group's median ratio, and it."""
    ratios = []
    for graph, truth in rows:
        keep = (truth > 0) & np.isfinite(graph)
        ratios.append(float(np.median(graph[keep] / truth[keep])))
    bias = float(np.median(ratios))
    errors = []
    for graph, truth in rows:
        keep = truth > 0
        finite = np.where(np.isfinite(graph), graph, 0.0)  # a cut pair counts as 0: a full miss
        errors.append(geodesic_error(finite[keep] / bias, truth[keep]).mean)
    return float(np.mean(errors)), float(np.max(errors)), bias


def _as_eval_shape(shape: EvalShape, setting: str, index: int) -> EvalShape:
    """``shape`` as ``setting`` makes it (seed ``index``, as ``evaluate_methods`` does), with
    its own sources and exact rows."""
    item = make_input(shape, setting, index)
    faces = item.shape.faces
    assert faces is not None  # a mesh setting
    return EvalShape(
        shape.name, shape.group, item.shape.vertices, faces, item.source_index, item.gt
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", action="append", default=[], choices=sorted(REAL_SETS))
    parser.add_argument("--dataset", action="append", default=[], help="collection dataset")
    parser.add_argument("--rings", default="1,2,3")
    parser.add_argument("--arcs", action="store_true", help="add the arc-lengthened graphs")
    parser.add_argument("--setting", default="mesh", help="mesh, decimated_N or meshnoise_S")
    parser.add_argument("--knn", type=int, default=16, help="0: no kNN row")
    parser.add_argument("--smooth", type=float, default=None, help="add smoothed-mesh graphs")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--eval-root", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache", help="exact-row cache")
    args = parser.parse_args()
    start = time.perf_counter()
    groups: dict[str, list[EvalShape]] = {}
    for key in args.set:
        paths = real_shape_paths(args.eval_root, key)
        if paths:
            groups[REAL_SETS[key].group] = real_eval_shapes(
                paths, REAL_SETS[key].group, args.sources, cache_dir=args.cache
            )
    for dataset in args.dataset:
        name = f"{Path(dataset).name} (test)"
        groups[name] = [
            dataclasses.replace(s, sources=s.sources[: args.sources], gt=s.gt[: args.sources])
            for s in collection_eval_shapes(dataset, "test", group=name)
        ]
    if not is_mesh_setting(args.setting):
        raise SystemExit(
            f"--setting must be mesh, decimated_N or meshnoise_S, got {args.setting!r}"
        )
    if args.setting != "mesh":
        groups = {
            group: [_as_eval_shape(s, args.setting, i) for i, s in enumerate(shapes)]
            for group, shapes in groups.items()
        }
    rings = [int(r) for r in args.rings.split(",")]
    variants: list[tuple[str, int | None, bool, bool]] = [
        (f"{r}-ring chords", r, False, False) for r in rings
    ]
    if args.arcs:
        variants += [(f"{r}-ring arcs", r, True, False) for r in rings if r > 1]
    if args.smooth is not None:
        variants += [(f"{name}, smoothed", r, a, True) for name, r, a, _ in variants]
    if args.knn:
        variants.append((f"{args.knn}-NN graph of the vertices", None, False, False))
    lines = [
        "| shapes | n | ν | " + " | ".join(name for name, _, _, _ in variants) + " |",
        "|---|---:|---:|" + "---:|" * len(variants),
    ]
    for group, shapes in groups.items():
        cells = []
        smoothed = (
            [denoised_mesh(s.vertices, s.faces, args.smooth).points for s in shapes]
            if args.smooth is not None
            else []
        )
        for _, ring_count, arcs, smooth in variants:
            rows = []
            for index, s in enumerate(shapes):
                points = smoothed[index] if smooth else s.vertices
                if ring_count is None:
                    graph = knn_graph(points, args.knn)
                else:
                    normals = arc_normals(points, s.faces) if arcs else None
                    graph = mesh_ring_graph(points, s.faces, ring_count, normals=normals)
                rows.append(shape_rows(s, graph))
            mean, worst, bias = scored(rows)
            cells.append(f"{mean:.2f} (worst {worst:.2f}, bias {bias:.3f})")
        noise = float(np.median([mesh_noise(s.vertices, s.faces) for s in shapes]))
        lines.append(f"| {group} | {len(shapes)} | {noise:.3f} | " + " | ".join(cells) + " |")
    command = "python scripts/eval_mesh_graph.py " + " ".join(
        [f"--set {s}" for s in args.set]
        + [f"--dataset {d}" for d in args.dataset]
        + [f"--rings {args.rings}" + (" --arcs" if args.arcs else "")]
        + ([f"--smooth {args.smooth:g}"] if args.smooth is not None else [])
        + [f"--knn {args.knn} --sources {args.sources} --setting {args.setting}"]
    )
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; exact rows from "
        f"{args.sources} FPS sources per shape, unit area, GT mean 100 per shape; each graph's "
        "rows divided by its median ratio to the truth over the group (shown as bias); "
        f"{time.perf_counter() - start:.0f} s; command `{command}`\n"
    )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
