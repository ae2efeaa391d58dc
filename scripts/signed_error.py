"""Are a geodesic network's distances too short or too long, and where (issue 14, step 1)?

For each group of shapes (held-out procedural shapes of the model's category, the test split of
each ``--dataset``, each real dev set) and each input setting, the trained network's mean
absolute and mean signed error (prediction − truth, GT mean 100 per shape; full head, full
lattice, no fusion) and the median OOD z-score. A bias that the calibration sets share could
be corrected from them; one that only the real dev sets show cannot (never fit on the dev set)::

    python scripts/signed_error.py --model quadrupeds --dataset data/folder-cal --sets tosca
    python scripts/signed_error.py --model humans --dataset data/makehuman-cal --sets faust

``--by-ratio`` splits the mesh error by each pair's geodesic / Euclidean ratio (and a real set by
class); ``--stretch-from DATASET`` fits an affine stretch of the detours on a calibration set and
shows every group's error with it (BENCHMARKS "winding-bias"). ``--graph-limits 1,0.8,0.6`` adds
the same two errors for the graph of the bundle's fusion on each cloud setting (its veto, each
normal limit, divided by its graph bias; per class of a real set): shortcuts between parts that
touch make it short (BENCHMARKS "fusion-normal-limits").
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import itertools
from collections.abc import Iterator
from datetime import UTC, datetime

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.evaluation.fusion import FusionSample, collect_samples
from litege_core.evaluation.geodesic import (
    REAL_SETS,
    EvalInput,
    EvalShape,
    collection_eval_shapes,
    generated_eval_shapes,
    make_input,
    real_eval_shapes,
    real_shape_paths,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned.bundle import load_model
from litege_core.learned.fusion import corrected_graph
from litege_core.learned.fusion_calibration import FusionCalibration, load_fusion
from litege_core.learned.predictor import Predictor
from litege_core.shape import Shape


def predicted_inputs(
    predictor: Predictor, shapes: list[EvalShape], setting: str
) -> Iterator[tuple[EvalInput, NDArray, float, float]]:
    """Per shape, the input of ``setting`` as ``litege eval geodesic`` makes it (seed = index),
    the network's rows for its sources, its OOD z-score and its GT mean / 100."""
    for index, shape in enumerate(shapes):
        item = make_input(shape, setting, index)
        state = predictor.register(item.shape)
        rows = predictor.distances(state, item.source_index)
        yield item, rows, state.ood_score, float(item.gt.mean()) / 100.0


def graph_row(samples: list[FusionSample], calibration: FusionCalibration) -> tuple[float, float]:
    """``(mean |error|, mean signed error)`` of the fusion's graph over ``samples`` (per-shape
    means, GT mean 100 per shape): rows divided by the calibration's graph bias at each input's
    point count, the network's value where the graph joins no path (as the fusion reads them)."""
    absolute, signed = [], []
    for sample in samples:
        graph = corrected_graph(
            sample.network,
            sample.graph,
            calibration,
            sample.n_points,
            sample.mesh,
            sample.roughness,
        )
        residual = graph - sample.truth
        scale = float(sample.truth.mean()) / 100.0
        absolute.append(float(np.abs(residual).mean()) / scale)
        signed.append(float(residual.mean()) / scale)
    return float(np.mean(absolute)), float(np.mean(signed))


def signed_row(predictor: Predictor, shapes: list[EvalShape], setting: str) -> tuple[float, ...]:
    """``(mean |error|, mean signed error, median z)`` over ``shapes`` (per-shape means, GT mean
    100 per shape)."""
    absolute, signed, z = [], [], []
    for item, rows, ood, scale in predicted_inputs(predictor, shapes, setting):
        absolute.append(float(np.abs(rows - item.gt).mean()) / scale)
        signed.append(float((rows - item.gt).mean()) / scale)
        z.append(ood)
    return float(np.mean(absolute)), float(np.mean(signed)), float(np.median(z))


def residual_pairs(
    predictor: Predictor, shapes: list[EvalShape], setting: str
) -> list[tuple[NDArray, NDArray, NDArray]]:
    """Per shape ``(Euclidean, predicted, true)`` distances of every (source, point) pair of
    the input ``setting`` (seed = index), all divided by the shape's GT mean / 100."""
    out = []
    for item, rows, _, scale in predicted_inputs(predictor, shapes, setting):
        points = item.shape.vertices
        euclid = np.linalg.norm(points[item.source_index][:, None] - points[None], axis=2)
        out.append((euclid / scale, rows / scale, item.gt / scale))
    return out


def fit_stretch(pairs: list[tuple[NDArray, NDArray, NDArray]]) -> tuple[float, float]:
    """Least-squares ``(α, β)`` of ``true − e ≈ α + β (predicted − e)`` over all pairs. A
    network that only shrank its detours would give β > 1; its scatter pulls β the other way
    (the truth regresses toward the mean given the prediction too)."""
    predicted = np.concatenate([(p - e).ravel() for e, p, _ in pairs])
    true = np.concatenate([(t - e).ravel() for e, _, t in pairs])
    design = np.stack([np.ones_like(predicted), predicted], axis=1)
    (alpha, beta), *_ = np.linalg.lstsq(design, true, rcond=None)
    return float(alpha), float(beta)


def stretched_error(
    pairs: list[tuple[NDArray, NDArray, NDArray]], alpha: float, beta: float
) -> float:
    """Mean per-shape |error| (GT mean 100) after ``e + max(α + β (predicted − e), 0)``."""
    errors = [
        float(np.abs(e + np.maximum(alpha + beta * (p - e), 0.0) - t).mean()) for e, p, t in pairs
    ]
    return float(np.mean(errors))


RATIO_BINS = (1.0, 1.05, 1.15, 1.3, 1.6, 2.2, np.inf)
"""Bins of a pair's geodesic / Euclidean ratio (1 = straight across; large = limb to limb)."""


def ratio_rows(predictor: Predictor, shapes: list[EvalShape]) -> list[tuple[float, float, float]]:
    """Per bin of :data:`RATIO_BINS` on the meshes: ``(share of pairs, mean signed error, mean
    |error|)`` (GT mean 100 per shape), to tell a bias along straight paths (scale) from one
    on winding paths (limbs, contact)."""
    ratios, errors = [], []
    for shape in shapes:
        state = predictor.register(Shape.from_arrays(shape.vertices, shape.faces))
        rows = predictor.distances(state, shape.sources)
        euclid = np.linalg.norm(
            shape.vertices[shape.sources][:, None] - shape.vertices[None], axis=2
        )
        valid = euclid > 0.05
        ratios.append((shape.gt / np.maximum(euclid, 1e-12))[valid])
        errors.append(((rows - shape.gt) * 100.0 / shape.gt.mean())[valid])
    ratio, error = np.concatenate(ratios), np.concatenate(errors)
    out = []
    for low, high in itertools.pairwise(RATIO_BINS):
        chosen = (ratio >= low) & (ratio < high)
        if not chosen.any():
            out.append((0.0, float("nan"), float("nan")))
            continue
        picked = error[chosen]
        out.append((float(chosen.mean()), float(picked.mean()), float(np.abs(picked).mean())))
    return out


def by_class(name: str, shapes: list[EvalShape]) -> dict[str, list[EvalShape]]:
    """``{name: shapes}``, then, for a real set of several classes (TOSCA's cats, dogs, ...:
    the shape names without their digits), one entry per class."""
    classes: dict[str, list[EvalShape]] = {}
    for shape in shapes:
        classes.setdefault(shape.name.rstrip("0123456789"), []).append(shape)
    out = {name: shapes}
    if "(real)" in name and len(classes) > 1:
        out.update({f"{name}: {label} ({len(group)})": group for label, group in classes.items()})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="quadrupeds", help="shipped name or bundle dir")
    parser.add_argument("--dataset", action="append", default=[], help="collection dataset")
    parser.add_argument("--sets", default="tosca", help="real dev sets")
    parser.add_argument("--synthetic", type=int, default=16)
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--settings", default="mesh,cloud_2000,cloud_300")
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache", help="exact-row cache")
    parser.add_argument(
        "--stretch-from",
        default=None,
        metavar="DATASET",
        help="fit a detour stretch (true − e ≈ α + β (predicted − e)) on this collection's test "
        "split and show every group's error with it, per setting",
    )
    parser.add_argument(
        "--by-ratio", action="store_true", help="also split the mesh error by geodesic/Euclidean"
    )
    parser.add_argument(
        "--graph-limits",
        default=None,
        metavar="C,C,...",
        help="also the errors of the fusion's cloud graph with each of these normal limits",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    bundle = load_model(args.model)
    predictor = Predictor(bundle, head="full", descriptor_lattice="full", fusion="none")
    category = bundle.category
    groups = {
        f"synthetic {category}s (held-out seeds)": generated_eval_shapes(
            category, args.synthetic, args.sources, cache_dir=args.cache
        )
    }
    for dataset in args.dataset:
        groups[f"{dataset} (test split)"] = collection_eval_shapes(dataset, "test")
    for key in filter(None, args.sets.split(",")):
        real = REAL_SETS[key]
        paths = real_shape_paths(args.eval_data, key)
        if paths:
            groups[real.group] = real_eval_shapes(paths, real.group, args.sources, args.cache)
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; "
        f"model `{args.model}` "
        f"({bundle.content_hash[:12]}), full head and lattice; {args.sources} FPS sources, "
        "exact rows, GT mean 100 per shape; command `python scripts/signed_error.py "
        f"--model {args.model}"
        + "".join(f" --dataset {d}" for d in args.dataset)
        + f" --sets {args.sets} --synthetic {args.synthetic} --settings {args.settings}"
        + (f" --stretch-from {args.stretch_from}" if args.stretch_from else "")
        + (" --by-ratio" if args.by_ratio else "")
        + (f" --graph-limits {args.graph_limits}" if args.graph_limits else "")
        + "`\n"
    )
    print("| shapes | n | setting | mean abs error | mean signed error | median z |")
    print("|---|---:|---|---:|---:|---:|")
    for name, shapes in groups.items():
        for setting in args.settings.split(","):
            absolute, signed, z = signed_row(predictor, shapes, setting)
            print(
                f"| {name} | {len(shapes)} | {setting} | {absolute:.2f} | {signed:+.2f} | {z:.2f} |"
            )
    if args.stretch_from:
        calibration = collection_eval_shapes(args.stretch_from, "test")
        print(
            f"\nDetour stretch fitted on {args.stretch_from} (test split, per setting): mean "
            "|error| (GT mean 100 per shape) of the network, then with the stretch\n"
        )
        print("| shapes | setting | α | β | network | stretched |")
        print("|---|---|---:|---:|---:|---:|")
        for setting in args.settings.split(","):
            alpha, beta = fit_stretch(residual_pairs(predictor, calibration, setting))
            for name, shapes in groups.items():
                pairs = residual_pairs(predictor, shapes, setting)
                plain, stretched = (
                    stretched_error(pairs, 0.0, 1.0),
                    stretched_error(pairs, alpha, beta),
                )
                print(
                    f"| {name} | {setting} | {alpha:+.2f} | {beta:.3f} | {plain:.2f} | "
                    f"{stretched:.2f} |"
                )
    if args.by_ratio:
        bins = [
            f"{low:g}–{high:g}" if np.isfinite(high) else f"≥ {low:g}"
            for low, high in itertools.pairwise(RATIO_BINS)
        ]
        print(
            "\nMesh pairs (Euclidean > 0.05) by geodesic / Euclidean ratio: share of pairs, "
            "mean signed error, mean |error| (GT mean 100 per shape)\n"
        )
        print("| shapes | " + " | ".join(bins) + " |")
        print("|---|" + "---:|" * len(bins))
        for name, shapes in groups.items():
            for label, chosen in by_class(name, shapes).items():
                cells = [
                    f"{share:.0%}: {signed:+.1f} / {absolute:.1f}"
                    for share, signed, absolute in ratio_rows(predictor, chosen)
                ]
                print(f"| {label} | " + " | ".join(cells) + " |")
    if args.graph_limits:
        print_graph_table(predictor, groups, args)


def print_graph_table(
    predictor: Predictor, groups: dict[str, list[EvalShape]], args: argparse.Namespace
) -> None:
    """The ``--graph-limits`` table: the fusion graph's errors per group (and class), cloud
    setting and normal limit."""
    calibration = load_fusion(predictor.bundle.path, predictor.bundle.content_hash, args.model)
    limits = [float(c) for c in args.graph_limits.split(",")]
    settings = [s for s in args.settings.split(",") if s != "mesh"]
    print(
        f"\nThe fusion's cloud graph (k = {calibration.k}, edges cut above "
        f"{calibration.prune_ratio} × chord by the {calibration.veto_head} head, then chords "
        "with |n·ĉ| above each normal limit; rows / the fitted graph bias): mean |error| / mean "
        "signed error (GT mean 100 per shape)\n"
    )
    print("| shapes | setting | " + " | ".join(f"limit {c:g}" for c in limits) + " |")
    print("|---|---|" + "---:|" * len(limits))
    for name, shapes in groups.items():
        by_limit = collect_samples(
            predictor,
            shapes,
            settings,
            k=calibration.k,
            prune_ratios=(calibration.prune_ratio,),
            normal_limits=limits,
            mutual_ks=(calibration.mutual_k,),
            veto_head=calibration.veto_head,
        )
        for label, chosen in by_class(name, shapes).items():
            names = {shape.name for shape in chosen}
            for setting in settings:
                cells = []
                for limit in limits:
                    samples = [
                        s
                        for s in by_limit[(calibration.prune_ratio, limit, calibration.mutual_k)]
                        if s.setting == setting and s.shape in names
                    ]
                    absolute, signed = graph_row(samples, calibration)
                    cells.append(f"{absolute:.2f} / {signed:+.2f}")
                print(f"| {label} | {setting} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
