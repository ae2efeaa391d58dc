"""Frames chosen by agreement with a reference answer (issue 14, step 2): a diagnosis.

For every shape and setting the shipped network answers the sources' rows in each of the 24
proper signed axis permutations of the shape's PCA frame (``candidate_rotations("all")``,
registered by ``Predictor.register_turned`` with the predictor's own descriptor; inputs as in
``litege eval geodesic``, so the default frame's columns are its figures). A frame is scored by

    log(UDF-PCA residual) + log(dispersion),

the dispersion being the median absolute deviation of ``log(network / reference)`` over the
pairs whose reference distance is below its median (scale-free: the network's overall bias
does not count), and the lowest score is kept. The reference is the default answer of the
fused predictor (``--reference fused``: network in the PCA frame blended with the cloud
graph) or the plain k-NN graph (``--reference knn``, k = 10). Columns, each the mean error
(GT mean 100, pooled over pairs): the network alone and the fused predictor in the default
frame, in the agreeing frame, and in the frame of lowest true network error (``oracle``, not a
method, and an optimistic bound on any selector over these candidates: the least of 24 noisy
answers is low even where the default frame is right).

Usage::

    python scripts/frame_agreement.py --sets faust,data/makehuman-steep-cal@humans \\
        --settings cloud_300,noise_0.01,cloud_2000 --cache out/exact-cache-h

``--per-frame`` adds a table of the network's error in each frame that keeps the first axis
(and any frame some shape errs least in), with the number of shapes whose lowest error is
there; ``--model`` answers every set with one bundle (a name or a directory) instead of the
set's shipped model.

Sets: real dev sets (``faust``, ``tosca``, ``leopard``), the test split of a dataset we build
(``DIR@MODEL``) or held-out procedural shapes (``synth-CATEGORY@MODEL``, 16 shapes).
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.engines import compute_distances
from litege_core.evaluation.geodesic import (
    KNN_NEIGHBOURS,
    EvalShape,
    generated_eval_shapes,
    make_input,
    named_eval_set,
)
from litege_core.evaluation.matching import machine_header
from litege_core.learned import Predictor, load_model
from litege_core.learned.frame import candidate_rotations

REPO = Path(__file__).resolve().parents[1]
EVAL_DATA = REPO.parent / "shared" / "eval-data"
RULES = ("default", "agreement", "oracle")
SYNTHETIC_SHAPES = 16


def agreement_scores(predictions: NDArray, residuals: NDArray, reference: NDArray) -> NDArray:
    """``(F,)`` scores of ``F`` candidate frames, lowest best: ``log residual + log
    dispersion`` of each frame's ``(S, T)`` rows against the ``(S, T)`` reference.

    Args:
        predictions: ``(F, S, T)`` the network's rows in each frame.
        residuals: ``(F,)`` the UDF-PCA reconstruction residual of each frame (> 0).
        reference: ``(S, T)`` the reference rows, same units (``inf`` / 0: left out).
    """
    finite = np.isfinite(reference) & (reference > 0)
    near = finite & (reference < np.median(reference[finite]))
    ratios = np.log(np.maximum(predictions[:, near], 1e-12) / reference[near])  # (F, P)
    spread = np.median(np.abs(ratios - np.median(ratios, axis=1, keepdims=True)), axis=1)
    return np.log(np.asarray(residuals, np.float64)) + np.log(np.maximum(spread, 1e-12))


def error_sums(pred: NDArray, gt: NDArray) -> NDArray:
    """``[Σ|pred − gt|, Σ gt]`` over the pairs with ``gt > 0``."""
    keep = gt > 0
    return np.array([np.abs(pred[keep] - gt[keep]).sum(), gt[keep].sum()])


def run_case(
    shape: EvalShape, setting: str, seed: int, network: Predictor, fused: Predictor, reference: str
) -> dict:
    """Error sums of every rule, network alone and fused, and the frame each rule keeps."""
    item = make_input(shape, setting, seed)
    states = network.register_turned(item.shape, np.stack(candidate_rotations("all")))
    residuals = np.array([state.record.residual for state in states])

    def rows(predictor: Predictor, f: int) -> NDArray:
        state = (
            states[f] if predictor is network else predictor.restore(item.shape, states[f].record)
        )
        return predictor.distances(state, item.source_index).astype(np.float64)

    predictions = np.stack([rows(network, f) for f in range(len(states))])
    if reference == "fused":
        ref = rows(fused, 0)
    else:
        ref = compute_distances(
            item.shape, item.source_index, method="knn_graph", k=KNN_NEIGHBOURS
        ).distances
    network_sums = [error_sums(p, item.gt) for p in predictions]
    chosen = {
        "default": 0,
        "agreement": int(np.argmin(agreement_scores(predictions, residuals, ref))),
        "oracle": int(np.argmin([s[0] for s in network_sums])),
    }
    return {
        "frames": np.stack(network_sums),
        "network": {rule: network_sums[f] for rule, f in chosen.items()},
        "fused": {rule: error_sums(rows(fused, f), item.gt) for rule, f in chosen.items()},
        "chosen": chosen,
    }


def turn_label(rotation: NDArray) -> str:
    """A signed axis permutation as the axes it puts first, second and third, e.g.
    ``"+x −z +y"`` for the quarter turn about the first axis."""
    names = []
    for row in np.rint(np.asarray(rotation)).astype(int):
        axis = int(np.flatnonzero(row)[0])
        names.append(("+" if row[axis] > 0 else "−") + "xyz"[axis])
    return " ".join(names)


def per_frame_rows(group: str, setting: str, frame_sums: NDArray, rotations: NDArray) -> list[str]:
    """Table rows of the network's pooled error in each candidate frame and the number of
    shapes whose lowest error is there, for ``frame_sums`` ``(S, F, 2)`` (:func:`error_sums`
    of each shape in each frame). Listed: the 8 frames that keep the first axis on itself
    (the PCA frame first) and any other frame some shape errs least in."""
    pooled = frame_sums.sum(axis=0)
    errors = 100 * pooled[:, 0] / pooled[:, 1]
    per_shape = frame_sums[:, :, 0] / frame_sums[:, :, 1]
    best = np.bincount(np.argmin(per_shape, axis=1), minlength=len(rotations))
    keep = [f for f in range(len(rotations)) if abs(rotations[f][0, 0]) == 1 or best[f]]
    return [
        f"| {group} | {setting} | {f} | {turn_label(rotations[f])} | {errors[f]:.2f} | {best[f]} |"
        for f in keep
    ]


def load_set(key: str, sources: int, cache: Path | None) -> tuple[str, str, list[EvalShape]]:
    """(group, model, shapes) of one ``--sets`` entry."""
    if key.startswith("synth-"):
        category, model = key[len("synth-") :].split("@", 1)
        shapes = generated_eval_shapes(category, SYNTHETIC_SHAPES, sources, cache_dir=cache)
        return shapes[0].group, model, shapes
    named = named_eval_set(key, EVAL_DATA, sources, cache)
    return named.group, named.model, named.shapes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", default="faust")
    parser.add_argument("--settings", default="cloud_300,noise_0.01,cloud_2000")
    parser.add_argument("--sources", type=int, default=12, help="FPS sources per real shape")
    parser.add_argument("--cache", type=Path, default=None, help="exact rows of the real sets")
    parser.add_argument("--reference", choices=("fused", "knn"), default="fused")
    parser.add_argument("--model", default=None, help="bundle (name or dir) instead of the sets'")
    parser.add_argument(
        "--per-frame",
        action="store_true",
        help="also each frame's network error and how many shapes err least in it",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    start = time.perf_counter()
    table = [
        "| shapes | setting | n | network: default | agreement | oracle | fused: default "
        "| agreement | oracle | frames changed (agreement / oracle) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    frame_table = [
        "| shapes | setting | frame | axes (PCA frame: +x +y +z) | network error | shapes "
        "erring least in it |",
        "|---|---|---:|---|---:|---:|",
    ]
    rotations = np.stack(candidate_rotations("all"))
    models: list[str] = []
    for key in [k for k in args.sets.split(",") if k]:
        group, model, shapes = load_set(key, args.sources, args.cache)
        if not shapes:
            print(f"frame_agreement: no shapes for {key}; skipped", file=sys.stderr)
            continue
        model = args.model or model
        models += [] if model in models else [model]
        bundle = load_model(model)
        network = Predictor(bundle, fusion="none")
        fused = Predictor(bundle, fusion="graph")
        for setting in args.settings.split(","):
            results = [
                run_case(s, setting, i, network, fused, args.reference)
                for i, s in enumerate(shapes)
            ]
            cells = []
            for kind in ("network", "fused"):
                for rule in RULES:
                    total = sum(r[kind][rule] for r in results)
                    cells.append(f"{100 * total[0] / total[1]:.2f}")
            frame_sums = np.stack([r["frames"] for r in results])
            frame_table += per_frame_rows(group, setting, frame_sums, rotations)
            moved = [sum(r["chosen"][rule] != 0 for r in results) for rule in RULES[1:]]
            table.append(
                f"| {group} | {setting} | {len(shapes)} | "
                + " | ".join(cells)
                + f" | {moved[0]} / {moved[1]} |"
            )
    elapsed = time.perf_counter() - start
    names = ", ".join(f"`{m}`" for m in models)
    print(f"### Frames chosen by agreement with a reference answer: {names}\n")
    print(
        "- "
        + machine_header({"wall": f"{elapsed / 60:.1f} min"})
        + f"\n- command `python scripts/frame_agreement.py {shlex.join(sys.argv[1:])}`; "
        f"reference: {args.reference}; 24 candidate frames per shape; exact rows from "
        f"{args.sources} FPS sources per real shape (the stored rows of a dataset), unit area, "
        "GT mean 100; the models' default head and lattice; seed = shape index"
    )
    print("\n" + "\n".join(table))
    if args.per_frame:
        print("\nThe network alone in each candidate frame:\n\n" + "\n".join(frame_table))


if __name__ == "__main__":
    main()
