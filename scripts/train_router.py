"""Train the category router that picks the geodesic model of an upload (issue 14, ``auto``).

Usage: python scripts/train_router.py --out out/router [--minutes 12] [--procedural 240]
           [--collection 160] [--steep 0.3] [--bend 0.7] [--human-steep 0.4]
           [--cache out/tnet-shapes] [--ship]

Meshes (generated, never the dev set; cached as the T-Net trainer caches them, same seeds):
``--procedural`` procedural quadrupeds and as many procedural bipeds (train split), and
``--collection`` posed rigged animals and as many posed MakeHuman bodies
(``../shared/train-data``); validation: a quarter as many of each from the val split.
``--steep`` / ``--human-steep``: the share of procedural quadrupeds / MakeHuman bodies in
steep poses (rearing, sitting up, lying; bending, balancing, arms overhead), ``--bend``: of
rigged animals bent along the body; an upright animal must not pass for a human.
Categories (the bundles' own): ``quadruped`` (procedural quadrupeds, rigged animals: the
``quadrupeds`` model), ``biped`` (procedural bipeds, MakeHuman bodies: the ``humans``
model). Training: :mod:`litege_core.train.router`. Writes ``router.safetensors`` and
``router.json`` into ``--out`` (``--ship``: also into ``litege_core/models/router``) and prints
the summary.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import torch

from litege_core.learned.router import SHIPPED_ROUTER, CategoryRouter
from litege_core.train.router import RouterTrainConfig, train_router
from litege_core.train.tnet import generate_shape_set
from litege_core.train.tnet.shapes import collection_shape_set

CATEGORIES = ("quadruped", "biped")  # the bundles' categories (quadrupeds, humans)
SOURCES = (  # (label, kind, name): procedural category or collection source
    (0, "procedural", "quadruped"),
    (1, "procedural", "biped"),
    (0, "collection", "rigged"),
    (1, "collection", "makehuman"),
)


def labelled_meshes(
    split: str, procedural: int, collection: int, cache: str, poses: argparse.Namespace
) -> list:
    """``((vertices, faces), label)`` of every mesh of ``split``; ``poses``: the steep shares
    and the rigged bend share (``--steep``, ``--human-steep``, ``--bend``)."""
    out = []
    for label, kind, name in SOURCES:
        if kind == "procedural":
            steep = poses.steep if name == "quadruped" else 0.0
            shapes = generate_shape_set(name, split, procedural, cache, steep_share=steep)
        else:
            shapes = collection_shape_set(
                name,
                split,
                collection,
                cache_dir=cache,
                bend=poses.bend if name == "rigged" else 0.0,
                steep_share=poses.human_steep if name == "makehuman" else 0.0,
            )
        out += [((v, f), label) for v, f in zip(shapes.vertices, shapes.faces, strict=True)]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--minutes", type=float, default=12.0)
    parser.add_argument("--steps", type=int, default=RouterTrainConfig.steps)
    parser.add_argument("--procedural", type=int, default=240)
    parser.add_argument("--collection", type=int, default=160)
    parser.add_argument("--cache", default="out/tnet-shapes")
    parser.add_argument(
        "--steep", type=float, default=0.0, help="procedural quadrupeds in the steep modes"
    )
    parser.add_argument("--bend", type=float, default=0.0, help="rigged animals bent")
    parser.add_argument(
        "--human-steep", type=float, default=0.0, help="MakeHuman bodies in steep poses"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ship", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)

    def log(line: str) -> None:
        print(f"{time.strftime('%H:%M:%S')} {line}", file=sys.stderr, flush=True)

    mark = time.monotonic()
    train = labelled_meshes("train", args.procedural, args.collection, args.cache, args)
    val = labelled_meshes("val", args.procedural // 4, args.collection // 4, args.cache, args)
    log(f"{len(train)} train and {len(val)} val meshes in {time.monotonic() - mark:.0f} s")
    config = RouterTrainConfig(steps=args.steps, minutes=args.minutes, seed=args.seed)
    result = train_router(train, val, len(CATEGORIES), config, log)
    metadata = {
        "config": dataclasses.asdict(config),
        "train_meshes": {
            f"{kind} {name}": count
            for (_, kind, name), count in zip(
                SOURCES,
                [args.procedural, args.procedural, args.collection, args.collection],
                strict=True,
            )
        },
        "val_meshes": len(val),
        "steep_share": {"quadruped": args.steep, "makehuman": args.human_steep},
        "rigged_bend": args.bend,
        "steps_run": result.steps,
        "seconds": round(result.seconds, 1),
        "best_val_accuracy": result.best_val_accuracy,
        "best_step": result.best_step,
        "command": "python scripts/train_router.py " + " ".join(sys.argv[1:]),
    }
    router = CategoryRouter(result.net, CATEGORIES, metadata=metadata)
    config_written = router.save(args.out)
    if args.ship:
        SHIPPED_ROUTER.mkdir(parents=True, exist_ok=True)
        for name in ("router.safetensors", "router.json"):
            shutil.copy2(Path(args.out) / name, SHIPPED_ROUTER / name)
    print(json.dumps(config_written, indent=2))


if __name__ == "__main__":
    main()
