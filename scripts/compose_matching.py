"""Write a matching bundle from the networks of one or more bundles and a chosen frame judge
(issue 15: the paper's ensemble of two; a continued network judging its own frames).

Usage:
    python scripts/compose_matching.py quadrupeds out/train/matching-quadrupeds-species/bundle \
        --out out/matching-ensemble              # ensemble, the first bundle's judge
    python scripts/compose_matching.py out/train/matching-quadrupeds-species/bundle \
        --judge own --out out/matching-self-judged  # the network judges its own frames
    python scripts/compose_matching.py quadrupeds --orientation \
        out/orientation-quadrupeds/orientation.safetensors --out out/matching-q-orient

The bundles must share their frame and descriptor (a continuation shares its start's: same
T-Net, basis and pipeline; refused otherwise). The new bundle takes those and the networks of
every bundle in order (the search averages their outputs, ``ensemble_score_fn``). Its frame
judge is the first bundle's (``--judge first``, the default: frames stay the first bundle's)
or the new bundle's own networks (``--judge own``). Its orientation network (which weighs the
candidate frames instead of the judge where present) is the first bundle's, or the one of
``--orientation FILE`` (``litege train orientation``; ``none`` drops it). The manifest's
training summary names the members and the judge; ``metrics`` are the first bundle's: re-measure
before shipping (``litege eval matching``, ``scripts/frame_report.py``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from litege_core.errors import InputError
from litege_core.matching import MatchingModel
from litege_core.matching.bundle import save_matching_bundle
from litege_core.nets import state_to_tensors
from litege_core.train.orientation import load_orientation


def _same_weights(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    left, right = state_to_tensors(a), state_to_tensors(b)
    return left.keys() == right.keys() and all(torch.equal(left[k], right[k]) for k in left)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="matching model names or bundle directories")
    parser.add_argument("--out", required=True, help="directory of the new bundle")
    parser.add_argument(
        "--judge",
        choices=["first", "own"],
        default="first",
        help="frame judge: the first bundle's (default) or the new bundle's networks",
    )
    parser.add_argument(
        "--orientation",
        default=None,
        metavar="FILE",
        help="orientation network weights (litege train orientation), or 'none' to drop it "
        "(default: the first bundle's)",
    )
    args = parser.parse_args(argv)
    if len(args.models) < 2 and args.judge == "first" and args.orientation is None:
        raise InputError(
            "one bundle with its own judge is itself: give two bundles, --judge own "
            "or --orientation"
        )
    bundles = [MatchingModel.load(m).bundle for m in args.models]
    first = bundles[0]
    for model, bundle in zip(args.models[1:], bundles[1:], strict=True):
        if bundle.basis.content_hash != first.basis.content_hash:
            raise InputError(f"{model} has another descriptor basis than {args.models[0]}")
        if bundle.pipeline != first.pipeline or not _same_weights(bundle.tnet, first.tnet):
            raise InputError(f"{model} has another frame (T-Net or pipeline) than {args.models[0]}")
    training = dict(first.manifest.get("training") or {})
    training["ensemble"] = [
        {"model": str(m), "content_hash": b.content_hash}
        for m, b in zip(args.models, bundles, strict=True)
    ]
    orientation = first.orientation
    if args.orientation is not None:
        orientation = None if args.orientation == "none" else load_orientation(args.orientation)
        training["orientation"] = str(args.orientation)
    training["judge"] = (
        f"{args.models[0]}'s frame judge" if args.judge == "first" else "its matching networks"
    )
    manifest = save_matching_bundle(
        args.out,
        name=first.name,
        category=first.manifest["category"],
        basis=first.basis,
        tnet=first.tnet,
        networks=[net for bundle in bundles for net in bundle.networks],
        pipeline=first.pipeline,
        search=first.search,
        version=first.manifest.get("version", "0.1.0"),
        training=training,
        metrics=first.manifest.get("metrics"),
        weights_dtype=torch.float16,
        judge_networks=list(first.frame_judge_networks) if args.judge == "first" else [],
        orientation=orientation,
    )
    summary = {"out": str(Path(args.out)), "content_hash": manifest["content_hash"]}
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
