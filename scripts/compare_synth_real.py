"""Compare statistics of the procedural shape families with real shapes (evaluation data).

For each group of shapes, on unit-area meshes:
  * the ratio geodesic / Euclidean over vertex pairs (exact MMP from ``--sources`` farthest-point
    sources per shape): median, 90th, 99th percentile and maximum (long tail = limb-to-limb
    paths, expected on real animals);
  * the PCA-aligned extents (sorted, divided by the longest) — body proportions;
  * thickness: the length of an inward ray from 800 area-uniform surface samples to the
    opposite side (10th percentile: limbs, ears, tails; median: the body);
  * triangle quality: mean minimum angle and mean longest/shortest edge ratio.

Groups: procedural quadrupeds (test seeds, one row per family), procedural bipeds, with
``--rigged N`` the posed rigged train-data animals (val seeds, the 12 animals cycled) straight and
with ``--bend`` of them bent (``litege data build --bend``), and, when ``../shared/eval-data``
exists, TOSCA animals (cat, dog, horse, wolf) and FAUST humans. Real shapes are read for
evaluation only and never copied.

With ``--spread X`` / ``--girth-std S``, a group of procedural quadrupeds whose proportion
ranges are X times their families' and whose builds vary lean to stocky (``litege data build
--spread X --girth-std S``).

Usage: python scripts/compare_synth_real.py [--per-group 6] [--sources 12] [--rigged 0]
    [--bend 0.7] [--spread 3] [--girth-std 0.3]
"""

from __future__ import annotations

import argparse
import platform
from datetime import date
from pathlib import Path

import numpy as np

from litege_core.engines import compute_distances
from litege_core.io import load_shape
from litege_core.sampling import farthest_point_sampling
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape

EVAL = Path(__file__).resolve().parents[1].parent / "shared" / "eval-data"


def unit_area(shape: Shape) -> Shape:
    vertices = shape.vertices - shape.vertices.mean(axis=0)
    return shape.with_vertices(vertices / np.sqrt(shape.area))


def shape_stats(shape: Shape, n_sources: int) -> dict[str, np.ndarray | float]:
    shape = unit_area(shape)
    vertices, faces = shape.vertices, shape.faces
    sources = farthest_point_sampling(vertices, n_sources)
    geodesic = compute_distances(shape, sources, method="exact").distances
    euclid = np.linalg.norm(vertices[sources][:, None] - vertices[None], axis=2)
    valid = (euclid > 0.05) & np.isfinite(geodesic)
    centred = vertices - vertices.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    extents = np.sort(np.ptp(centred @ axes.T, axis=0))[::-1]
    corners = vertices[faces]
    edges = np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2)
    a, b, c = edges[:, 1], edges[:, 2], edges[:, 0]  # side opposite corner 0, 1, 2
    cosines = np.stack(
        [
            (b**2 + c**2 - a**2) / (2 * b * c),
            (a**2 + c**2 - b**2) / (2 * a * c),
            (a**2 + b**2 - c**2) / (2 * a * b),
        ],
        axis=1,
    )
    angles = np.degrees(np.arccos(np.clip(cosines, -1, 1)))
    return {
        "thickness": thickness(vertices, faces),
        "ratio": geodesic[valid] / euclid[valid],
        "extents": extents / extents[0],
        "min_angle": float(angles.min(axis=1).mean()),
        "edge_ratio": float((edges.max(axis=1) / edges.min(axis=1)).mean()),
    }


def thickness(vertices: np.ndarray, faces: np.ndarray, n_samples: int = 800) -> np.ndarray:
    """``(10th percentile, median)`` of the inward ray length from ``n_samples`` area-uniform
    surface points (seed 0) of a closed, outward-oriented mesh to the opposite side."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    points, face_index = trimesh.sample.sample_surface(mesh, n_samples, seed=0)
    inward = -mesh.face_normals[face_index]
    origins = points + 1e-4 * inward
    hits, rays, _ = mesh.ray.intersects_location(origins, inward, multiple_hits=False)
    lengths = np.linalg.norm(hits - origins[rays], axis=1)
    return np.percentile(lengths, [10, 50])


def rigged_shapes(n: int, bend: float) -> list[Shape]:
    """``n`` posed rigged animals of the val seeds (the animals cycled), ``bend`` of them bent."""
    from litege_core.datasets.factories import factory_for
    from litege_core.datasets.spec import SPLIT_SEED_OFFSETS
    from litege_core.synth.rigged import ANIMALS, bent_pose_settings

    factory = factory_for("rigged", None, bent_pose_settings(bend))
    return [
        Shape.from_arrays(
            *factory.generate_mesh(ANIMALS[i % len(ANIMALS)], SPLIT_SEED_OFFSETS["val"] + i)
        )
        for i in range(n)
    ]


def groups(
    per_group: int, rigged: int = 0, bend: float = 0.7, spread: float = 1.0, girth: float = 0.0
) -> dict[str, list[Shape]]:
    result: dict[str, list[Shape]] = {}
    for category in ("quadruped", "biped"):
        names = families(category)
        result[f"procedural {category}s"] = [
            generate_shape(category, names[i % len(names)], 2_000_000 + i).to_shape()
            for i in range(per_group)
        ]
        if category == "quadruped" and (spread != 1.0 or girth):
            result[f"procedural quadrupeds, spread {spread:g}, girth std {girth:g}"] = [
                generate_shape(
                    category, names[i % len(names)], 2_000_000 + i, spread=spread, girth_std=girth
                ).to_shape()
                for i in range(per_group)
            ]
    if rigged:
        result["posed rigged animals"] = rigged_shapes(rigged, 0.0)
        result[f"posed rigged animals, {bend:.0%} bent"] = rigged_shapes(rigged, bend)
    if EVAL.is_dir():
        tosca = sorted((EVAL / "tosca_5k").glob("*.off"))
        by_class: dict[str, list[Path]] = {}
        for path in tosca:
            by_class.setdefault(path.stem.rstrip("0123456789"), []).append(path)
        picked = [p for paths in by_class.values() for p in paths[: max(1, per_group // 4)]]
        result["TOSCA animals (real)"] = [load_shape(p) for p in picked]
        faust = sorted((EVAL / "faust_5k").glob("*.off"))[:per_group]
        result["FAUST humans (real)"] = [load_shape(p) for p in faust]
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--per-group", type=int, default=6)
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--rigged", type=int, default=0, help="posed rigged animals per group")
    parser.add_argument("--bend", type=float, default=0.7, help="share bent in the bent group")
    parser.add_argument("--spread", type=float, default=1.0, help="widened quadrupeds group")
    parser.add_argument("--girth-std", type=float, default=0.0, help="its lean/stocky builds")
    args = parser.parse_args()
    print("### Procedural families vs real shapes (unit-area meshes)\n")
    print(
        f"- date {date.today()}; machine {platform.processor() or platform.machine()}; "
        f"command `python scripts/compare_synth_real.py --per-group {args.per_group} "
        f"--sources {args.sources} --rigged {args.rigged} --bend {args.bend} "
        f"--spread {args.spread:g} --girth-std {args.girth_std:g}`; exact MMP "
        f"geodesics from {args.sources} FPS sources per shape to all vertices, pairs with "
        "Euclidean distance > 0.05\n"
    )
    print(
        "| group | shapes | vertices | geo/euc median | p90 | p99 | max | pairs ≥ 1.3 "
        "| extents (2nd, 3rd) | thickness p10, median | mean min angle ° | mean edge ratio |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|---|---:|---:|")
    for name, shapes in groups(
        args.per_group, args.rigged, args.bend, args.spread, args.girth_std
    ).items():
        stats = [shape_stats(s, args.sources) for s in shapes]
        ratio = np.concatenate([s["ratio"] for s in stats])
        extents = np.mean([s["extents"] for s in stats], axis=0)
        thick = np.mean([s["thickness"] for s in stats], axis=0)
        q50, q90, q99 = np.percentile(ratio, [50, 90, 99])
        print(
            f"| {name} | {len(shapes)} | {int(np.mean([s.n_points for s in shapes]))} | "
            f"{q50:.2f} | {q90:.2f} | {q99:.2f} | {ratio.max():.2f} | "
            f"{(ratio >= 1.3).mean():.0%} | "
            f"{extents[1]:.2f}, {extents[2]:.2f} | {thick[0]:.3f}, {thick[1]:.3f} | "
            f"{np.mean([s['min_angle'] for s in stats]):.1f} | "
            f"{np.mean([s['edge_ratio'] for s in stats]):.2f} |"
        )


if __name__ == "__main__":
    main()
