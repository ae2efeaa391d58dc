"""The weight of the network-to-graph agreement in the ``auto`` model choice (issue 14).

``auto`` (the service's default model) registers a shape under every loaded geodesic model and
keeps one. The OOD z-score alone misroutes real humans: FAUST bodies score higher under
``humans`` than under ``quadrupeds`` (BENCHMARKS "auto-routing-cost"). A second signal needs
no training: how far each model's network is from the model's own fusion graph on the shape
(:meth:`Predictor.agreement`), small for a shape of the model's category.
:func:`~litege_core.learned.routing.choose_model` keeps the lowest ``z + w · agreement``.

``w`` comes from **generated shapes only**: procedural quadrupeds and bipeds (held-out seeds),
the static animals of ``data/folder-cal`` and the MakeHuman bodies of ``data/makehuman-cal``,
as meshes, clouds of 300–2,000 points and noisy clouds. It is the median gap in z-score
between a shape's own model and the other one, over the median gap in agreement, so both
signals weigh alike. The real dev sets (``--sets``) are then only measured: how many shapes
each rule routes to their own category's model, and the fused error (the default) under each
choice, against exact geodesics from ``--sources`` farthest points (GT mean 100).

    python scripts/calibrate_routing.py --sets tosca,faust
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import sys
from collections.abc import Sequence
from datetime import UTC, datetime

import numpy as np
import torch

from litege_core.evaluation.geodesic import (
    REAL_SETS,
    EvalShape,
    collection_eval_shapes,
    generated_eval_shapes,
    make_input,
    real_eval_shapes,
    real_shape_paths,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import Predictor, load_shipped
from litege_core.learned.routing import choose_model
from litege_core.metrics import geodesic_error

MODELS = {"quadruped": "quadrupeds", "biped": "humans"}
SETTINGS = ("mesh", "cloud_2000", "cloud_1000", "cloud_500", "cloud_300", "noise_0.01")


@dataclasses.dataclass(frozen=True)
class Routed:
    """One input under every model: ``own`` model, and per model z-score, agreement, error."""

    own: str
    setting: str
    z: dict[str, float]
    agreement: dict[str, float]
    error: dict[str, float]


def measure(
    predictors: dict[str, Predictor], shapes: Sequence[EvalShape], own: str, errors: bool
) -> list[Routed]:
    """Every input of ``shapes`` (each setting) under every model; ``errors``: also the fused
    error of each model's answer (``nan`` otherwise)."""
    out = []
    for setting in SETTINGS:
        for i, shape in enumerate(shapes):
            given = make_input(shape, setting, i)
            z, agreement, error = {}, {}, {}
            for name, predictor in predictors.items():
                state = predictor.register(given.shape)
                z[name] = float(state.ood_score)
                agreement[name] = predictor.agreement(state)
                error[name] = (
                    geodesic_error(predictor.distances(state, given.source_index), given.gt).mean
                    if errors
                    else float("nan")
                )
            out.append(Routed(own, setting, z, agreement, error))
        print(f"{own} {setting}: {len(shapes)} shapes", file=sys.stderr, flush=True)
    return out


def balance_weight(rows: Sequence[Routed]) -> float:
    """Median z gap (other − own) over the median agreement gap (other − own)."""
    other = {name: next(n for n in rows[0].z if n != name) for name in rows[0].z}
    dz = np.median([r.z[other[r.own]] - r.z[r.own] for r in rows])
    da = np.median([r.agreement[other[r.own]] - r.agreement[r.own] for r in rows])
    return float(dz / da)


def routing_table(rows: Sequence[Routed], weight: float, with_errors: bool) -> list[str]:
    """Markdown rows per (own model, setting): shapes, routed right by z and by the combined
    rule, and (``with_errors``) the mean fused error under the own model and each rule."""
    lines = []
    for own in dict.fromkeys(r.own for r in rows):
        for setting in SETTINGS:
            group = [r for r in rows if r.own == own and r.setting == setting]
            if not group:
                continue
            by_z = [choose_model(r.z) for r in group]
            by_both = [choose_model(r.z, r.agreement, weight) for r in group]
            line = (
                f"| {own} | {setting} | {len(group)} | {sum(c == own for c in by_z)} | "
                f"{sum(c == own for c in by_both)} |"
            )
            if with_errors:
                own_error = np.mean([r.error[own] for r in group])
                z_error = np.mean([r.error[c] for r, c in zip(group, by_z, strict=True)])
                both_error = np.mean([r.error[c] for r, c in zip(group, by_both, strict=True)])
                line += f" {own_error:.2f} | {z_error:.2f} | {both_error:.2f} |"
            lines.append(line)
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--synthetic", type=int, default=16, help="procedural shapes per category")
    parser.add_argument("--datasets", default="quadruped=data/folder-cal,biped=data/makehuman-cal")
    parser.add_argument("--sets", default="tosca,faust", help="real dev sets to measure ('' none)")
    parser.add_argument("--sources", type=int, default=4)
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache", help="exact-row cache")
    command = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(command)
    torch.set_num_threads(1)
    predictors = {name: Predictor(load_shipped(name)) for name in MODELS.values()}
    datasets = dict(item.split("=") for item in args.datasets.split(",") if item)
    generated: list[Routed] = []
    for category, name in MODELS.items():
        shapes = generated_eval_shapes(category, args.synthetic, args.sources, cache_dir=args.cache)
        if category in datasets:
            shapes += [
                dataclasses.replace(s, sources=s.sources[: args.sources], gt=s.gt[: args.sources])
                for s in collection_eval_shapes(datasets[category], "test")
            ]
        generated += measure(predictors, shapes, name, errors=False)
    weight = balance_weight(generated)
    real: list[Routed] = []
    for key in [k for k in args.sets.split(",") if k]:
        paths = real_shape_paths(args.eval_data, key)
        shapes = real_eval_shapes(paths, REAL_SETS[key].group, args.sources, args.cache)
        real += measure(predictors, shapes, REAL_SETS[key].model, errors=True)

    hashes = ", ".join(f"{n} {p.bundle.content_hash[:12]}" for n, p in predictors.items())
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; models {hashes} "
        f"(defaults: small head, stride2, graph fusion); agreement: `Predictor.agreement`; "
        f"command `python "
        f"scripts/calibrate_routing.py {' '.join(command)}`\n"
    )
    print(
        f"**Weight from the generated shapes: w = {weight:.1f}** (median z gap over median "
        "agreement gap, own model against the other).\n"
    )
    print("Generated shapes (where `w` comes from): routed to their own category's model\n")
    print("| own model | setting | inputs | by z-score | by z + w · agreement |")
    print("|---|---|---:|---:|---:|")
    print("\n".join(routing_table(generated, weight, with_errors=False)))
    if real:
        print(
            f"\nReal dev shapes (measured, not fitted): routed right, and the mean fused error "
            f"(GT mean 100, {args.sources} sources) under the own model and each rule\n"
        )
        print(
            "| own model | setting | shapes | by z-score | by z + w · agreement | error, own "
            "model | error, by z | error, by z + w · agreement |"
        )
        print("|---|---|---:|---:|---:|---:|---:|---:|")
        print("\n".join(routing_table(real, weight, with_errors=True)))


if __name__ == "__main__":
    main()
