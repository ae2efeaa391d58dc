"""Write a copy of a matching bundle whose T-Net is another trained one (issue 15, step 1).

Usage:
    python scripts/swap_tnet.py quadrupeds out/tnet-quadrupeds-gpu/tnet.safetensors \
        --out out/matching-tnet-gpu

The networks, the frame judge's networks, the orientation network, basis, pipeline and search
settings are copied unchanged (so judged frames differ only by the T-Net); the T-Net comes from a
``litege train tnet`` weights file; the manifest's training summary gains a ``tnet_swap`` entry
(source file and that T-Net's own training summary) and the bundle gets a new content hash;
its weights are written in float16, as in the shipped bundles.
The copy's ``metrics`` are the original bundle's: re-measure before shipping it
(``litege eval matching``, ``scripts/frame_report.py``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from litege_core.matching import MatchingModel
from litege_core.matching.bundle import save_matching_bundle
from litege_core.train.tnet import load_tnet, read_tnet_metadata


def main(argv: list[str] | None = None) -> dict:
    """Write the bundle; returns ``{"out", "content_hash"}`` (also printed as JSON)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="shipped matching model name or bundle directory")
    parser.add_argument("tnet", help="T-Net weights file (litege train tnet)")
    parser.add_argument("--out", required=True, help="directory of the new bundle")
    args = parser.parse_args(argv)
    bundle = MatchingModel.load(args.model).bundle
    tnet = load_tnet(args.tnet)
    training = dict(bundle.manifest.get("training") or {})
    training["tnet_swap"] = {
        "source": str(args.tnet),
        "replaced": bundle.manifest["tnet"],
        "tnet_training": read_tnet_metadata(args.tnet)["training"],
    }
    manifest = save_matching_bundle(
        args.out,
        name=bundle.name,
        category=bundle.manifest["category"],
        basis=bundle.basis,
        tnet=tnet,
        networks=list(bundle.networks),
        judge_networks=list(bundle.judge_networks),
        orientation=bundle.orientation,
        pipeline=bundle.pipeline,
        search=bundle.search,
        version=bundle.manifest.get("version", "0.1.0"),
        training=training,
        metrics=bundle.manifest.get("metrics"),
        weights_dtype=torch.float16,
    )
    summary = {"out": str(Path(args.out)), "content_hash": manifest["content_hash"]}
    print(json.dumps(summary))
    return summary


if __name__ == "__main__":
    main()
