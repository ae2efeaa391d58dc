"""``litege data build``, ``litege data merge`` and ``litege data verify``: ground-truth
geodesic datasets.

``litege data build --shard I/N`` builds worker ``I``'s share of the shard files (``N``
processes or machines over one directory, e.g. the pods of a Kubernetes Indexed Job on a
shared volume); the worker that finds every share built merges ``manifest.json`` (unless
``--no-merge``), and ``litege data merge DIR`` does the same explicitly (optionally waiting
for the other workers). See ``docs/scaling.md``.
"""

from __future__ import annotations

import argparse
import os

from litege_core.cli.common import print_json


def cmd_data_build(args: argparse.Namespace) -> int:
    import dataclasses

    from litege_core.datasets import build_dataset, preset
    from litege_core.datasets.build import merge_dataset, missing_shards
    from litege_core.datasets.factories import factory_for
    from litege_core.datasets.spec import WorkShare, parse_split_counts
    from litege_core.synth.rigged import bent_pose_settings

    if args.category in ("rigged", "makehuman") and args.preset == "matching":
        return _build_species_sets(args)
    spec = preset(args.preset, args.category)
    changes: dict = {}
    if args.shapes is not None:
        changes["n_shapes"] = {**spec.n_shapes, **parse_split_counts(args.shapes)}
    if args.name is not None:
        changes["name"] = args.name
    if args.first_index:
        changes["first_index"] = args.first_index
    spec = dataclasses.replace(spec, **changes)
    directory = args.out or f"data/{spec.name}"
    share = None if args.shard is None else WorkShare.parse(args.shard)
    manifest = build_dataset(
        spec,
        directory,
        factory_for(
            args.category,
            args.train_data,
            bent_pose_settings(args.bend),
            args.steep,
            args.spread,
            args.girth_std,
        ),
        workers=args.workers,
        solver=args.solver,
        part=share,
    )
    summary = {
        "directory": str(directory),
        "counts": manifest["counts"],
        "compute_seconds": round(manifest["compute_seconds"], 1),
    }
    if share is not None:
        summary["shard"] = str(share)
        missing = missing_shards(directory)
        summary["merged"] = False
        summary["missing_shards"] = len(missing)
        if not missing and not args.no_merge:
            merged = merge_dataset(directory)
            summary.update(merged=True, dataset_counts=merged["counts"])
    print_json(summary)
    return 0


def _build_species_sets(args: argparse.Namespace) -> int:
    """``--category rigged|makehuman --preset matching``: one template-kind matching dataset
    per source model (each rigged species, or the MakeHuman body) under ``OUT/NAME``; pairs
    are drawn within one (the species do not share a triangulation)."""
    from pathlib import Path

    from litege_core.datasets import build_dataset
    from litege_core.datasets.factories import species_factory
    from litege_core.datasets.spec import (
        SPECIES_MATCHING_SHAPES,
        parse_split_counts,
        species_matching_spec,
    )
    from litege_core.errors import InputError
    from litege_core.synth.posed_templates import MAKEHUMAN
    from litege_core.synth.rigged import ANIMALS, bent_pose_settings

    if args.shard is not None:
        raise InputError("--shard is not supported with --preset matching of a collection")
    counts = dict(SPECIES_MATCHING_SHAPES)
    if args.shapes is not None:
        counts.update(parse_split_counts(args.shapes))
    name = args.name or f"{args.category}-matching"
    directory = Path(args.out or f"data/{name}")
    summary: dict = {"directory": str(directory), "species": {}}
    for species in ANIMALS if args.category == "rigged" else (MAKEHUMAN,):
        factory = species_factory(species, args.train_data, bent_pose_settings(args.bend))
        spec = species_matching_spec(
            species, factory.category, counts, name=name, first_index=args.first_index
        )
        manifest = build_dataset(
            spec, directory / species, factory, workers=args.workers, solver=args.solver
        )
        summary["species"][species] = {
            "counts": manifest["counts"],
            "compute_seconds": round(manifest["compute_seconds"], 1),
        }
    print_json(summary)
    return 0


def cmd_data_merge(args: argparse.Namespace) -> int:
    from litege_core.datasets.build import merge_dataset

    manifest = merge_dataset(args.directory, wait_s=args.wait, poll_s=args.poll)
    print_json(
        {
            "directory": str(args.directory),
            "shards": len(manifest["shards"]),
            "counts": manifest["counts"],
            "merged_from": manifest.get("merged_from", []),
            "compute_seconds": round(manifest["compute_seconds"], 1),
        }
    )
    return 0


def cmd_data_verify(args: argparse.Namespace) -> int:
    from litege_core.datasets import verify_dataset

    print_json(verify_dataset(args.directory))
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``data build``, ``data merge`` and ``data verify``."""
    data = commands.add_parser("data", help="ground-truth geodesic datasets")
    data_commands = data.add_subparsers(dest="data_command", required=True)
    build = data_commands.add_parser("build", help="build or resume a dataset")
    build.add_argument(
        "--category",
        choices=["quadruped", "biped", "rigged", "makehuman"],
        default="quadruped",
        help="procedural quadrupeds / bipeds, posed rigged animals or MakeHuman bodies (the "
        "last two read their assets from --train-data)",
    )
    build.add_argument(
        "--preset",
        choices=["small", "large", "full", "matching"],
        default="small",
        help="dataset size; --category rigged|makehuman --preset matching builds one matching "
        "dataset per rigged species, or of MakeHuman bodies (posed copies on one "
        "triangulation), under OUT/NAME",
    )
    build.add_argument(
        "--shapes",
        default=None,
        metavar="SPLIT=N,...",
        help="shapes per split instead of the preset's, e.g. train=896,val=48,test=48 "
        "(splits left out keep the preset's count)",
    )
    build.add_argument(
        "--name", default=None, help="dataset name (default CATEGORY-PRESET; kept in the manifest)"
    )
    build.add_argument(
        "--first-index",
        type=int,
        default=0,
        metavar="I",
        help="start every split at shape I of the category's seed sequence, e.g. the train "
        "count of an earlier set to add new shapes of the same distribution (default 0)",
    )
    build.add_argument("--out", default=None, help="directory (default data/NAME)")
    build.add_argument(
        "--bend",
        type=float,
        default=0.0,
        metavar="P",
        help="--category rigged: share of the posed animals bent along the body (curled, head "
        "turned back, arched; litege_core.synth.bend), default 0",
    )
    build.add_argument(
        "--steep",
        type=float,
        default=0.0,
        metavar="P",
        help="--category quadruped / makehuman: share of the shapes posed steep instead of "
        "their drawn pose (quadrupeds rear, leap, sit up or lie on the belly; MakeHuman "
        "bodies bend forward, balance on one leg, lift a knee or raise both arms; "
        "litege_core.synth.poses.steep_pose), default 0",
    )
    build.add_argument(
        "--spread",
        type=float,
        default=1.0,
        metavar="X",
        help="--category quadruped / biped: multiply every family's proportion range (log "
        "standard deviation of limb, girth and trunk factors) by X, e.g. 3 for ±18 %% at 1 σ "
        "instead of ±6 %% (litege_core.synth.shape_space.sample_factors), default 1",
    )
    build.add_argument(
        "--girth-std",
        type=float,
        default=0.0,
        metavar="S",
        help="--category quadruped / biped / rigged: give each shape a lean or stocky build, "
        "one multiplier exp(S·z), z in [-2.5, 1], of its trunk, limb, neck and tail girths "
        "(litege_core.synth.shape_space.GIRTH_FACTORS; rigged: RiggedModel.with_build), "
        "default 0 (none)",
    )
    build.add_argument(
        "--train-data",
        default=None,
        metavar="DIR",
        help="train-data directory of --category rigged / makehuman (default "
        "$LITEGE_TRAIN_DATA or ../shared/train-data)",
    )
    build.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    build.add_argument(
        "--solver",
        choices=["exact", "heat", "heat-fine"],
        default="exact",
        help="ground-truth geodesics: exact MMP (default) or the ~40× cheaper heat method "
        "(heat-fine: a shorter diffusion time, half heat's error at the same cost)",
    )
    build.add_argument(
        "--shard",
        default=None,
        metavar="I/N",
        help="build only worker I's share (0 <= I < N) of the shard files, for N workers "
        "over one directory; resumable and idempotent per worker",
    )
    build.add_argument(
        "--no-merge",
        action="store_true",
        help="with --shard: do not merge manifest.json when every share is built",
    )
    build.set_defaults(handler=cmd_data_build)
    merge = data_commands.add_parser(
        "merge", help="assemble and verify manifest.json of a sharded build"
    )
    merge.add_argument("directory")
    merge.add_argument(
        "--wait",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="wait up to SECONDS for shards still being built (default: fail at once)",
    )
    merge.add_argument(
        "--poll", type=float, default=30.0, metavar="SECONDS", help="check interval while waiting"
    )
    merge.set_defaults(handler=cmd_data_merge)
    verify = data_commands.add_parser("verify", help="verify a dataset directory")
    verify.add_argument("directory")
    verify.set_defaults(handler=cmd_data_verify)


__all__ = ["cmd_data_build", "cmd_data_merge", "cmd_data_verify", "register"]
