"""Distil the small distance head of a geodesic bundle (issue 17) and measure its agreement.

Usage::

    nice python scripts/distill_head.py --model quadrupeds --out out/distill/quadrupeds \
        [--minutes 15] [--features 128] [--hidden 64] [--threads 1] [--seed 0] \
        [--axis-turn-probability 0.3] [--ship]

Trains a :class:`~litege_core.nets.small_head.SmallHead` on the teacher's head outputs over
procedural shapes generated on the fly (:mod:`litege_core.train.distill`: seeds from
5,000,000, disjoint from every dataset's), then measures student-vs-teacher agreement on
held-out procedural shapes (seeds from 6,000,000; meshes, 2000- and 300-point clouds) and
writes ``head-small.safetensors`` + ``head-small.json`` (config, teacher content hash,
settings, agreement) into ``--out``; ``--ship`` also copies them beside the bundle's own files
(for a shipped model: ``litege_core/models/NAME/``), where ``Predictor(bundle, head="small")``
finds them. Progress goes to ``OUT/distill.log``.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import platform
import shutil
import sys
import time
from pathlib import Path

import torch

from litege_core.learned import Predictor, load_bundle, load_model
from litege_core.learned.cards import write_sidecar_section
from litege_core.learned.small_head import SMALL_HEAD_CONFIG, SMALL_HEAD_WEIGHTS, save_small_head
from litege_core.train.config import AugmentConfig
from litege_core.train.distill import (
    DistillConfig,
    agreement_inputs,
    distill_small_head,
    measure_agreement,
)
from litege_core.train.tnet.shapes import collection_shape_set


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="quadrupeds", help="shipped model or bundle dir")
    parser.add_argument("--out", required=True, help="directory of the sidecar and the log")
    parser.add_argument("--minutes", type=float, default=15.0)
    parser.add_argument("--steps", type=int, default=DistillConfig.steps)
    parser.add_argument("--features", type=int, default=DistillConfig.features, help="m")
    parser.add_argument("--hidden", type=int, default=DistillConfig.hidden, help="k")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--category", default=None, help="procedural category (default: model)")
    parser.add_argument("--agreement-shapes", type=int, default=8)
    parser.add_argument(
        "--extra", default=None, help="collection source of extra views: rigged or makehuman"
    )
    parser.add_argument("--extra-shapes", type=int, default=160, help="posed extra meshes")
    parser.add_argument("--extra-fraction", type=float, default=0.5, help="share of views")
    parser.add_argument(
        "--extra-cache", default="out/tnet-shapes", help="cache of the posed extra meshes"
    )
    parser.add_argument(
        "--axis-turn-probability",
        type=float,
        default=0.0,
        help="share of cloud views whose canonical frame is turned about the long axis, as "
        "in training (augment.axis_turn_probability of the teacher's config)",
    )
    parser.add_argument("--ship", action="store_true", help="copy the sidecar into the bundle")
    args = parser.parse_args()
    torch.set_num_threads(max(1, args.threads))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log_file = open(out / "distill.log", "a", encoding="utf-8")  # noqa: SIM115

    def log(line: str) -> None:
        stamped = f"{time.strftime('%H:%M:%S')} {line}"
        print(stamped, file=log_file, flush=True)
        print(stamped, file=sys.stderr, flush=True)

    bundle = load_model(args.model)
    teacher = Predictor(  # the trained network
        bundle, head="full", descriptor_lattice="full", fusion="none"
    )
    config = DistillConfig(
        features=args.features,
        hidden=args.hidden,
        minutes=args.minutes,
        steps=args.steps,
        seed=args.seed,
        extra_fraction=args.extra_fraction if args.extra else 0.0,
        augment=AugmentConfig(axis_turn_probability=args.axis_turn_probability),
    )
    extra: list = []
    if args.extra:  # the posed collection meshes the T-Net trainer uses (same seeds, cached)
        mark = time.monotonic()
        shapes = collection_shape_set(
            args.extra, "train", args.extra_shapes, cache_dir=args.extra_cache
        )
        extra = list(zip(shapes.vertices, shapes.faces, strict=True))
        log(f"{len(extra)} {args.extra} meshes in {time.monotonic() - mark:.0f} s")
    log(f"distilling {bundle.name} ({bundle.content_hash[:12]}…): {config.to_dict()}")
    result = distill_small_head(
        teacher, config, category=args.category, extra_meshes=extra, log=log
    )
    student = Predictor(bundle, head=result.head, descriptor_lattice="full", fusion="none")
    category = result.settings["category"]
    start = time.monotonic()
    agreement = measure_agreement(
        teacher, student, agreement_inputs(category, args.agreement_shapes)
    )
    log(f"agreement ({time.monotonic() - start:.0f} s): {json.dumps(agreement)}")
    distillation = {
        **result.settings,
        "steps_run": result.steps,
        "views_made": result.views,
        "seconds": round(result.seconds, 1),
        "stopped_by": result.stopped_by,
        "final_loss": result.history[-1][2] if result.history else None,
        "threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
        "torch": torch.__version__,
        "command": "python scripts/distill_head.py " + " ".join(sys.argv[1:]),
    }
    agreement_doc = {
        "what": "|G_small − G_full| pooled in canonical units over the mean G_full, ×100, "
        f"{args.agreement_shapes} held-out procedural {category}s (seeds from 6,000,000), "
        "16 sources to every point",
        **agreement,
    }
    save_small_head(
        out, result.head, bundle.content_hash, distillation=distillation, agreement=agreement_doc
    )
    log(f"wrote {out / SMALL_HEAD_WEIGHTS} and {out / SMALL_HEAD_CONFIG}")
    if args.ship:
        if bundle.path is None:
            raise SystemExit("the bundle has no directory to ship into")
        for name in (SMALL_HEAD_WEIGHTS, SMALL_HEAD_CONFIG):
            shutil.copyfile(out / name, Path(bundle.path) / name)
            (Path(bundle.path) / name).chmod(0o644)
        Predictor(
            load_bundle(bundle.path), head="small", fusion="none"
        )  # verifies the shipped sidecar
        write_sidecar_section(bundle.path)
        log(f"shipped into {bundle.path} (model card's sidecar section rewritten)")


if __name__ == "__main__":
    main()
