"""Real dev shapes, several geodesic models side by side with heat and kNN (issue 14 ablations).

Usage: python scripts/eval_real_ablation.py [--model NAME_OR_DIR[@OPTIONS]=LABEL ...]
    [--set tosca | --dataset DIR] [--sources 12] [--settings mesh,cloud_2000,cloud_300]
    [--no-baselines] [--knn K ...] [--per-shape] [--per-shape-setting cloud_300]

``OPTIONS`` are ``+``-joined speed options of issue 17: ``small`` / ``fullhead`` (the distilled
small head or the trained one, ``Predictor(bundle, head=...)``) and ``full`` / ``bcc`` /
``stride2`` (descriptor lattice); without them, the predictor's defaults (``auto``: the small
head and the stride2 lattice for the shipped models), e.g. ``quadrupeds@fullhead+full`` (the
trained network as trained), and ``fusion`` (the calibrated graph fusion,
``Predictor(bundle, fusion="graph")``; without it the network alone, ``fusion="none"``,
although the library's default is ``auto``: the labels of earlier runs keep their meaning) and
``ttaC`` / ``ttaCxD`` (test-time augmentation: the distances averaged over the PCA frame and
``C`` turns of it by at most ``D`` degrees, default 10,
``litege_core.evaluation.geodesic.frame_turns``), ``ttaflip`` (averaged over the PCA frame and
its half turn about the first axis: the second and third axes' signs, which the PCA frame's
median rule decides, flipped) or ``ttasigns`` (over the 4 proper sign flips of the PCA axes,
``litege_core.learned.frame.candidate_rotations("signs")``) and ``int8`` (the point MLP's
products in dynamic int8, ``Predictor(bundle, precision="int8", embed_precision="int8")``: the small
head's product too) or ``bf16`` (the point MLP's and the head's products in bfloat16,
``precision="bfloat16", embed_precision="bfloat16"``); ``--no-baselines`` leaves out
heat and kNN; ``--knn K`` adds a kNN-graph Dijkstra row with ``K`` neighbours. ``--dataset DIR``
evaluates the test split of a dataset we build instead of a real set (e.g. the held-out solids
of ``scripts/build_folder_cal.py --primitives test``: shapes of no training family), without
synthetic shapes and with the shipped ``quadrupeds`` unless ``--model`` says otherwise.

Every model answers the same inputs (``litege_core.evaluation.geodesic.evaluate_methods``):
exact MMP rows from farthest-point sources at unit area, ground truth rescaled to mean 100.
Besides the pooled error per setting it reports the per-shape spread of each model (median,
p90 and the worst shape of the per-shape mean errors, mesh setting) and the real / synthetic
ratio against held-out procedural shapes of the same category; ``--per-shape`` adds each real
shape's error under every model (sorted by the first model's) on ``--per-shape-setting``
(default: the mesh).
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import shlex
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.evaluation.geodesic import (
    REAL_SETS,
    Method,
    baseline_method,
    comparison_methods,
    comparison_table,
    dataset_eval_shapes,
    evaluate_methods,
    frame_turns,
    generated_eval_shapes,
    real_eval_shapes,
    real_shape_paths,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import Predictor, load_model
from litege_core.learned.frame import candidate_rotations

TTA_OPTION = re.compile(r"tta(\d+)(?:x(\d+(?:\.\d+)?))?")
SIGN_FLIPS = candidate_rotations("signs")
TTA_FLIPS = {
    "ttaflip": np.stack([SIGN_FLIPS[0], np.diag([1.0, -1.0, -1.0])]),
    "ttasigns": np.stack(SIGN_FLIPS),
}
"""The test-time augmentations over sign flips of the PCA axes: option → ``(C, 3, 3)`` turns."""


def is_tta(option: str) -> bool:
    """Whether ``option`` names a test-time augmentation (``ttaC[xD]``, ``ttaflip``,
    ``ttasigns``)."""
    return option in TTA_FLIPS or TTA_OPTION.fullmatch(option) is not None


def frame_turns_of(name: str) -> NDArray | None:
    """The ``ttaC[xD]`` option of ``NAME_OR_DIR@OPTIONS`` as :func:`frame_turns`, or the turns
    of ``ttaflip`` / ``ttasigns`` (:data:`TTA_FLIPS`), or ``None``."""
    _, _, text = name.partition("@")
    for option in filter(None, text.split("+")):
        if option in TTA_FLIPS:
            return TTA_FLIPS[option]
        found = TTA_OPTION.fullmatch(option)
        if found:
            return frame_turns(int(found[1]), float(found[2] or 10.0))
    return None


def load_predictor(name: str) -> Predictor:
    """``NAME_OR_DIR`` (defaults) or ``NAME_OR_DIR@OPTIONS`` with ``+``-joined options:
    ``small`` / ``fullhead`` (head; default ``auto``), ``full`` / ``bcc`` / ``stride2``
    (descriptor lattice; default ``auto``), ``fusion`` (the bundle's calibrated graph fusion),
    ``int8`` (the point MLP and the small head in dynamic int8);
    ``ttaC[xD]``, ``ttaflip`` and ``ttasigns`` are read by :func:`frame_turns_of`."""
    name, _, text = name.partition("@")
    options = {o for o in text.split("+") if o and not is_tta(o)}
    unknown = options - {"small", "fullhead", "full", "stride2", "bcc", "fusion", "int8", "bf16"}
    if unknown:
        raise SystemExit(f"unknown model options {sorted(unknown)} in {name}@{text}")
    lattices = options & {"full", "stride2", "bcc"}
    heads = options & {"small", "fullhead"}
    arithmetics = options & {"int8", "bf16"}
    if len(lattices) > 1 or len(heads) > 1 or len(arithmetics) > 1:
        raise SystemExit(f"more than one lattice, head or arithmetic in {name}@{text}")
    arithmetic = (
        {"int8": "int8", "bf16": "bfloat16"}[arithmetics.pop()] if arithmetics else "float32"
    )
    return Predictor(
        load_model(name),
        head={"small": "small", "fullhead": "full"}[heads.pop()] if heads else "auto",
        descriptor_lattice=lattices.pop() if lattices else "auto",
        fusion="graph" if "fusion" in options else "none",
        precision=arithmetic,
        embed_precision=arithmetic,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", action="append", default=[], help="NAME_OR_DIR=LABEL")
    parser.add_argument("--set", default="tosca", choices=sorted(REAL_SETS))
    parser.add_argument("--dataset", help="a dataset directory (its test split) instead of --set")
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--synthetic", type=int, default=16)
    parser.add_argument("--settings", default="mesh,cloud_2000,cloud_300")
    parser.add_argument("--cache", default="out/diagnose/cache", help="exact-row cache")
    parser.add_argument("--no-baselines", action="store_true", help="LiteGE rows only")
    parser.add_argument(
        "--knn", type=int, action="append", default=[], help="extra kNN-Dijkstra rows (k)"
    )
    parser.add_argument("--per-shape", action="store_true", help="each real shape's error")
    parser.add_argument(
        "--per-shape-setting", default="mesh", help="the setting of the --per-shape table"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    real = REAL_SETS[args.set]
    models = args.model or [f"{real.model}={real.model} (shipped)"]
    predictors, turns = {}, {}
    for item in models:
        name, _, label = item.partition("=")
        predictors[label or name] = load_predictor(name)
        if (found := frame_turns_of(name)) is not None:
            turns[label or name] = found
    settings = tuple(args.settings.split(","))
    if args.per_shape and args.per_shape_setting not in settings:
        raise SystemExit(f"--per-shape-setting {args.per_shape_setting} is not in --settings")
    if args.dataset:
        group, what = f"{Path(args.dataset).name} (test)", f"--dataset {args.dataset}"
        shapes = [
            dataclasses.replace(s, sources=s.sources[: args.sources], gt=s.gt[: args.sources])
            for s in dataset_eval_shapes(args.dataset, "test", group=group)
        ]
        synthetic: list = []
    else:
        paths = real_shape_paths(args.eval_data, args.set)
        if not paths:
            print(f"no {args.set} shapes under {args.eval_data}: nothing to evaluate")
            return
        group, what = real.group, f"--set {args.set}"
        shapes = real_eval_shapes(paths, real.group, args.sources, cache_dir=args.cache)
        synthetic = generated_eval_shapes(
            real.category, args.synthetic, args.sources, cache_dir=args.cache
        )
    compared = comparison_methods(predictors, baselines=not args.no_baselines, turns=turns)

    def methods(setting: str) -> dict[str, Method]:
        extra = {f"kNN Dijkstra (k={k})": baseline_method("knn_graph", k=k) for k in args.knn}
        return {**compared(setting), **extra}

    pooled = evaluate_methods([*shapes, *synthetic], methods, settings)

    def per_shape_errors(setting: str) -> dict[str, list[float]]:
        """Each model's per-shape mean errors on the real shapes' ``setting`` inputs."""
        return {
            r.method: [error for _, error in r.per_shape]
            for r in pooled
            if r.group == group and r.setting == setting and r.method in predictors
        }

    spread = per_shape_errors("mesh")
    print(f"### {'Ablation' if args.dataset else 'Real-shape ablation'}: {group}\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine "
        f"{cpu_name()}; {len(shapes)} {'' if args.dataset else 'real '}shapes, "
        + (f"{len(synthetic)} held-out procedural {real.category}s; " if synthetic else "")
        + f"{args.sources} FPS sources each, exact MMP, unit area, GT mean 100; "
        "command `python scripts/eval_real_ablation.py "
        + " ".join(f"--model {shlex.quote(m)}" for m in models)
        + f" {what} --sources {args.sources}"
        + f" --settings {args.settings}"
        + (" --no-baselines" if args.no_baselines else "")
        + "".join(f" --knn {k}" for k in args.knn)
        + (" --per-shape" if args.per_shape else "")
        + (
            f" --per-shape-setting {args.per_shape_setting}"
            if args.per_shape_setting != "mesh"
            else ""
        )
        + "`\n"
    )
    print(comparison_table(pooled))
    if spread:
        print("\n| model | per-shape median (mesh) | p90 | worst shape | real / synthetic (mesh) |")
        print("|---|---:|---:|---|---:|")
    by_key = {(r.group, r.setting, r.method): r.mean for r in pooled}
    synthetic_group = synthetic[0].group if synthetic else None
    for label, errors in spread.items():
        values = np.array(errors)
        worst = int(np.argmax(values))
        real_mean = by_key[(group, "mesh", label)]
        synth = by_key.get((synthetic_group, "mesh", label), float("nan"))
        print(
            f"| {label} | {np.median(values):.2f} | {np.quantile(values, 0.9):.2f} | "
            f"{shapes[worst].name} {values[worst]:.2f} | {real_mean / synth:.2f} |"
        )

    if args.per_shape:
        chosen = per_shape_errors(args.per_shape_setting)
        print(per_shape_table([shape.name for shape in shapes], chosen, args.per_shape_setting))


def per_shape_table(names: list[str], errors: dict[str, list[float]], setting: str = "mesh") -> str:
    """Markdown: one row per real shape (sorted by the first model's error, worst first), its
    error on ``setting`` under each model."""
    labels = list(errors)
    order = np.argsort(errors[labels[0]])[::-1]
    lines = [
        f"\n| shape ({setting}) | " + " | ".join(labels) + " |",
        "|---|" + "---:|" * len(labels),
    ]
    for index in order:
        cells = " | ".join(f"{errors[label][index]:.2f}" for label in labels)
        lines.append(f"| {names[index]} | {cells} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
