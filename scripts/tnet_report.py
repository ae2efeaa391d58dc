"""Alignment-error report of the T-Net inside a matching bundle (or of a T-Net weights file).

The same distributions as ``litege train tnet`` writes at the end of training: train shapes
with one seeded random rotation each (the rejection filter's view), val shapes as meshes, as
500-point clouds and as broken meshes (40 % of faces removed); mean/std/median/max angle (rad)
and the failures above 0.66 rad.

Usage:
    python scripts/tnet_report.py quadrupeds [--train 600 --val 40] [--out report.json]
    python scripts/tnet_report.py out/tnet-quadrupeds/tnet.safetensors
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from litege_core.matching import MatchingModel
from litege_core.train.tnet import (
    TNetReportConfig,
    alignment_report,
    generate_shape_set,
    load_tnet,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", help="matching model name / bundle directory, or tnet file")
    parser.add_argument("--category", default="quadruped")
    parser.add_argument("--train", type=int, default=600)
    parser.add_argument("--val", type=int, default=40)
    parser.add_argument("--cache", default="out/tnet-shapes", help="shape cache directory")
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.source.endswith(".safetensors"):
        net = load_tnet(args.source)
    else:
        net = MatchingModel.load(args.source).bundle.tnet.float().eval()
    train = generate_shape_set(args.category, "train", args.train, args.cache)
    val = generate_shape_set(args.category, "val", args.val, args.cache)
    report = alignment_report(net, train, val, TNetReportConfig())
    report.pop("failed_train_indices", None)
    report["train"].pop("failed_keys", None)
    report["source"] = args.source
    report["network"] = net.config()
    text = json.dumps(report, indent=1, sort_keys=True)
    if args.out:
        Path(args.out).write_text(text + "\n")
    summary = {
        name: {k: report[name][k] for k in ("mean", "std", "median", "max", "n_failures", "n")}
        for name in ("train", "val", "val_cloud500", "val_broken")
        if name in report
    }
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
