"""Write a matching bundle whose search averages the networks of several bundles (issue 15,
step 3: the paper's ensemble of two).

Usage:
    python scripts/ensemble_matching.py quadrupeds out/train/matching-quadrupeds-species/bundle \
        --out out/matching-ensemble

The bundles must share their frame and descriptor (a continuation shares its start's: same
T-Net, basis and pipeline; refused otherwise). The new bundle takes those, the networks of every
bundle in order (the search averages their outputs, ``ensemble_score_fn``) and the first
bundle's frame judge, so its frames are the first bundle's. The manifest's training summary
names the members; ``metrics`` are the first bundle's: re-measure before shipping
(``litege eval matching``).
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


def _same_weights(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    left, right = state_to_tensors(a), state_to_tensors(b)
    return left.keys() == right.keys() and all(torch.equal(left[k], right[k]) for k in left)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("models", nargs="+", help="matching model names or bundle directories")
    parser.add_argument("--out", required=True, help="directory of the new bundle")
    args = parser.parse_args(argv)
    if len(args.models) < 2:
        raise InputError("an ensemble needs at least two bundles")
    bundles = [MatchingModel.load(m).bundle for m in args.models]
    first = bundles[0]
    for model, bundle in zip(args.models[1:], bundles[1:], strict=True):
        if bundle.basis.content_hash != first.basis.content_hash:
            raise InputError(f"{model} has another descriptor basis than {args.models[0]}")
        if bundle.pipeline != first.pipeline or not _same_weights(bundle.tnet, first.tnet):
            raise InputError(f"{model} has another frame (T-Net or pipeline) than {args.models[0]}")
    training = dict(first.manifest.get("training") or {})
    training["ensemble"] = [
        {"model": str(m), "content_hash": b.content_hash} for m, b in zip(args.models, bundles)
    ]
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
        judge_networks=list(first.frame_judge_networks),
    )
    summary = {"out": str(Path(args.out)), "content_hash": manifest["content_hash"]}
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
