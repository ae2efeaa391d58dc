"""How the OOD z-score rule routes the real dev shapes, and what a wrong choice costs, for the
networks alone (issue 14). Since 2026-11-29 the service's ``auto`` also weighs each model's
network-to-graph agreement and answers fused: ``scripts/calibrate_routing.py`` measures that
rule (BENCHMARKS "routing-agreement").

Usage: python scripts/eval_routing.py [--quadrupeds NAME_OR_DIR] [--humans NAME_OR_DIR]
    [--sets tosca,faust] [--settings mesh,cloud_2000,cloud_300] [--sources 12]
    [--eval-data ../shared/eval-data] [--router none|shipped|DIR]

The z-score rule registers an upload under every loaded geodesic model and keeps the one
with the lowest OOD z-score. This registers every TOSCA animal, the
leopard and every FAUST human, as each input setting of ``litege eval geodesic`` (the mesh,
sparse clouds, ...), under a quadrupeds and a humans bundle (shipped by default; a candidate
bundle directory before it ships). Per set and setting: the shapes routed to the other
category's model, the median z-score under each model and, against exact geodesics from
``--sources`` farthest-point sources (GT mean 100), the mean error of the shape's own model,
of the model ``auto`` picks and of the other one. Prints a markdown section.
"""

from __future__ import annotations

import argparse
from datetime import UTC, datetime

import numpy as np

from litege_core.evaluation.geodesic import make_input, real_eval_shapes, real_shape_paths
from litege_core.learned import Predictor, load_model
from litege_core.learned.router import first_of_each_category, load_router

OWN_MODEL = {"tosca": "quadrupeds", "leopard": "quadrupeds", "faust": "humans"}


def predictor(name_or_dir: str) -> Predictor:
    """A CPU predictor of a shipped model name or a bundle directory."""
    return Predictor(load_model(name_or_dir), fusion="none")


def relative_error(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Mean absolute error with the true distances rescaled to mean 100."""
    return float(np.abs(predicted - truth).mean() / truth.mean() * 100)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quadrupeds", default="quadrupeds")
    parser.add_argument("--humans", default="humans")
    parser.add_argument("--sets", default="tosca,faust", help="of tosca, leopard, faust")
    parser.add_argument("--settings", default="mesh,cloud_2000,cloud_300")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache", help="exact-row cache")
    parser.add_argument(
        "--router", default="none", help="category router: none, shipped or a directory"
    )
    args = parser.parse_args()
    models = {"quadrupeds": predictor(args.quadrupeds), "humans": predictor(args.humans)}
    router = (
        None
        if args.router == "none"
        else load_router(None if args.router == "shipped" else args.router)
    )
    if args.router != "none" and router is None:
        parser.error("no shipped router")
    settings = [s.strip() for s in args.settings.split(",") if s.strip()]
    print("### `auto` model routing of the real dev shapes\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; quadrupeds = `{args.quadrupeds}` "
        f"({models['quadrupeds'].bundle.content_hash[:12]}), humans = `{args.humans}` "
        f"({models['humans'].bundle.content_hash[:12]}); each input registered under both, "
        f"routed to the lower OOD z-score; errors against exact rows from {args.sources} "
        "sources, GT mean 100; command `python scripts/eval_routing.py "
        f"--quadrupeds {args.quadrupeds} --humans {args.humans} --sets {args.sets} "
        f"--settings {args.settings} "
        f"--sources {args.sources} --router {args.router}`"
    )
    if router is not None:
        print(
            f"- router `{args.router}` ({router.metadata.get('command', '')}): its choice where "
            f"its probability ≥ {router.min_probability}, else the lower z-score (the "
            "service's `auto` with that router)"
        )
    with_router = router is not None
    print(
        "\n| set | setting | shapes | routed to the other model | median z, own model | "
        "median z, other | error, own model | error, `auto` | error, other model |"
        + (" routed to the other, router | error, router |" if with_router else "")
    )
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|" + ("---:|---:|" if with_router else ""))
    for set_name in [s.strip() for s in args.sets.split(",") if s.strip()]:
        own = OWN_MODEL[set_name]
        other = "humans" if own == "quadrupeds" else "quadrupeds"
        paths = real_shape_paths(args.eval_data, set_name)
        shapes = real_eval_shapes(paths, set_name, args.sources, args.cache)
        for setting in settings:
            z: dict[str, list[float]] = {own: [], other: []}
            errors: dict[str, list[float]] = {own: [], other: [], "auto": [], "router": []}
            wrong = wrong_routed = 0
            for k, shape in enumerate(shapes):
                item = make_input(shape, setting, k)
                scored = {}
                for name in (own, other):
                    state = models[name].register(item.shape)
                    predicted = models[name].distances(state, item.source_index)
                    scored[name] = (state.ood_score, relative_error(predicted, item.gt))
                    z[name].append(state.ood_score)
                    errors[name].append(scored[name][1])
                chosen = own if scored[own][0] <= scored[other][0] else other
                errors["auto"].append(scored[chosen][1])
                wrong += chosen != own
                if router is not None:
                    categories = {name: m.bundle.category for name, m in models.items()}
                    routed = router.route([item.shape], first_of_each_category(categories))[0]
                    routed = routed or chosen
                    errors["router"].append(scored[routed][1])
                    wrong_routed += routed != own
            row = (
                f"| {set_name} | {setting} | {len(shapes)} | {wrong} | "
                f"{np.median(z[own]):.2f} | {np.median(z[other]):.2f} | "
                f"{np.mean(errors[own]):.2f} | {np.mean(errors['auto']):.2f} | "
                f"{np.mean(errors[other]):.2f} |"
            )
            if router is not None:
                row += f" {wrong_routed} | {np.mean(errors['router']):.2f} |"
            print(row)


if __name__ == "__main__":
    main()
