"""``litege eval geodesic`` and ``litege eval matching``: a model against the baselines."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from litege_core.cli.common import (
    add_bundle_arguments,
    add_device_argument,
    add_fusion_argument,
    add_head_argument,
    add_precision_argument,
    predictor,
    split_list,
    with_model,
    write_json,
)

if TYPE_CHECKING:
    from litege_core.evaluation.matching import LiteGEVariant, SettingResult


def cmd_eval_geodesic(args: argparse.Namespace) -> int:
    """Each group of shapes against the baselines. Without ``--model`` / ``--bundle`` a real set
    is evaluated with the shipped model of its category (TOSCA and the leopard with
    ``quadrupeds``, FAUST with ``humans``) and a ``--dataset`` with the default model; a named
    model answers every group."""
    from litege_core.evaluation.geodesic import (
        REAL_SETS,
        evaluate,
        parse_settings,
        real_eval_shapes,
        real_shape_paths,
        results_table,
        spread_table,
        synthetic_eval_shapes,
    )

    settings = parse_settings(args.settings)  # checked before any model loads
    named = args.model is not None or args.bundle is not None
    owner_of = {key: None if named else REAL_SETS[key].model for key in args.real}
    owners = ([None] if args.dataset else []) + list(owner_of.values())
    models = {  # every model loads before any shape is read: a bad option fails fast
        owner: predictor(args if owner is None else with_model(args, owner))
        for owner in dict.fromkeys(owners or [None])
    }
    groups: dict[str | None, list] = {owner: [] for owner in models}
    if args.dataset:
        groups[None].extend(synthetic_eval_shapes(args.dataset, args.shapes))
    for key, owner in owner_of.items():
        paths = real_shape_paths(args.eval_data, key, args.real_shapes)
        if not paths:
            folder = Path(args.eval_data) / REAL_SETS[key].folder
            print(f"litege: no {key} shapes under {folder}; skipped", file=sys.stderr)
        groups[owner].extend(real_eval_shapes(paths, REAL_SETS[key].group, args.sources))
    for n, (owner, model) in enumerate(models.items()):
        results = evaluate(groups[owner], model, settings, seed=args.seed)
        print(("\n" if n else "") + f"LiteGE = `{model!r}`\n")
        print(results_table(results))
        print()
        print(spread_table(results))
    return 0


def parse_variants(text: str) -> list[LiteGEVariant]:
    """``--variants``: comma-separated :meth:`LiteGEVariant.parse` texts (``auto``, ``tnet``,
    ``judged+zoomout``, …); a bad one is an argparse error (exit 2) with the library's message."""
    from litege_core.errors import InputError
    from litege_core.evaluation.matching import LiteGEVariant

    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        raise argparse.ArgumentTypeError("give at least one LiteGE variant, e.g. 'auto'")
    try:
        return [LiteGEVariant.parse(item) for item in items]
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def evaluate_matching(
    args: argparse.Namespace, extra_meta: dict[str, str] | None = None
) -> tuple[list[SettingResult], str]:
    """Run the matching evaluation the options of :func:`add_matching_arguments` ask for;
    returns the results and the machine header (``extra_meta`` appended to it)."""
    from litege_core.evaluation.matching import (
        load_matching_model,
        machine_header,
        run_matching_evaluation,
    )
    from litege_core.evaluation.matching_data import REAL_SETS, SYNTHETIC_SETTINGS

    settings = split_list(args.settings, SYNTHETIC_SETTINGS, "settings")
    real = split_list(args.real, REAL_SETS, "real")
    baselines = split_list(args.baselines, ("nn", "zoomout"), "baselines")
    model = load_matching_model(args.model, args.device, args.precision)

    def log(message: str) -> None:
        print(f"litege: {message}", file=sys.stderr, flush=True)

    results = run_matching_evaluation(
        model,
        settings=settings,
        real=real,
        eval_data=args.eval_data,
        n_pairs=args.pairs,
        n_queries=args.queries,
        baselines=baselines,
        seed=args.seed,
        device=args.device,
        rotate_input=not args.no_rotate,
        workers=args.workers,
        log=log,
        variants=args.variants,
    )
    meta = {
        "model": f"{model.name} ({model.content_hash[:12]})",
        "device": str(model.device),
        "precision": model.precision,
        "pairs/set": str(args.pairs),
        "queries/pair": str(args.queries),
        "seed": str(args.seed),
        **(extra_meta or {}),
    }
    return results, machine_header(meta)


def cmd_eval_matching(args: argparse.Namespace) -> int:
    from litege_core.evaluation.matching import results_table

    results, header = evaluate_matching(args)
    print(results_table(results, header))
    if args.json:
        write_json(args.json, {"meta": header, "results": [r.to_dict() for r in results]})
    return 0


def add_matching_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``litege eval matching`` (also used by
    ``scripts/eval_matching_variants.py``)."""
    parser.add_argument(
        "--model", default="quadrupeds", help="matching model: shipped name or bundle directory"
    )
    add_device_argument(parser)
    add_precision_argument(parser, default="float32")  # comparable with earlier tables
    parser.add_argument("--pairs", type=int, default=20, help="pairs per setting / real set")
    parser.add_argument("--queries", type=int, default=100, help="query points per pair")
    parser.add_argument(
        "--settings",
        default="template,remesh5k,aniso10k,broken40,cloud8k,cloud500",
        help="comma-separated synthetic settings ('' for none)",
    )
    parser.add_argument(
        "--real",
        default="tosca,tosca-landmarks,faust",
        help="comma-separated real sets, read from --eval-data when present ('' for none)",
    )
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--baselines", default="nn,zoomout", help="nn, zoomout ('' for none)")
    parser.add_argument(
        "--variants",
        type=parse_variants,
        default="auto",
        help="comma-separated LiteGE rows: a frames token (auto, tnet, judged, intrinsic) "
        "and any of mirror-vote and zoomout or zoomout-hybrid (with 'unsmoothed': no smooth "
        "fit of the refined map; 'unregistered': the fit without its registration to the target's "
        "surface; 'unchecked': no distortion check of the smoothed map), joined by '+', e.g. "
        "'tnet,judged,judged+zoomout' (default: auto, one "
        "LiteGE row)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--no-rotate", action="store_true", help="keep inputs in their frame (default: random)"
    )
    parser.add_argument(
        "--workers", type=int, default=1, help="processes for ground-truth geodesics"
    )
    parser.add_argument("--json", default=None, help="also write the results as JSON")


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``eval geodesic`` and ``eval matching``."""
    evaluation = commands.add_parser("eval", help="evaluate a model against baselines")
    eval_commands = evaluation.add_subparsers(dest="eval_command", required=True)

    geodesic = eval_commands.add_parser(
        "geodesic",
        help="geodesic error vs baselines",
        description="Geodesic error against heat and kNN-graph Dijkstra, per setting, with "
        "the per-shape spread. Without --model / --bundle each real set is evaluated with the "
        "shipped model of its category (TOSCA, leopard: quadrupeds; FAUST: humans).",
    )
    add_bundle_arguments(geodesic)
    add_head_argument(geodesic)
    add_fusion_argument(geodesic)
    geodesic.add_argument("--seed", type=int, default=0)
    geodesic.add_argument("--dataset", help="dataset directory whose test split is evaluated")
    geodesic.add_argument("--shapes", type=int, default=20, help="synthetic shapes to evaluate")
    geodesic.add_argument("--real", nargs="*", default=[], choices=["tosca", "faust", "leopard"])
    geodesic.add_argument("--real-shapes", type=int, default=32)
    geodesic.add_argument("--eval-data", default="../shared/eval-data")
    geodesic.add_argument("--sources", type=int, default=16, help="sources per real shape")
    geodesic.add_argument("--settings", default=None, help="comma-separated subset of settings")
    geodesic.set_defaults(handler=cmd_eval_geodesic)

    matching = eval_commands.add_parser(
        "matching", help="matching error, AUC, flips and time vs NN and ZoomOut baselines"
    )
    add_matching_arguments(matching)
    matching.set_defaults(handler=cmd_eval_matching)


__all__ = [
    "add_matching_arguments",
    "cmd_eval_geodesic",
    "cmd_eval_matching",
    "evaluate_matching",
    "parse_variants",
    "register",
]
