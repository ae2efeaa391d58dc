"""A matching model trained on the poses of one rigged character, beside the shipped one, on
held-out poses of that character (``litege train matching --meshes DIR --poses``).

1. **Training.** The rig (a rigged, animated glTF or GLB) is linked alone into ``OUT/rig`` and
   ``train_matching_from_meshes`` runs on it with ``poses=True`` and ``--budget`` minutes
   (``OUT/bundle``; its data and run in ``OUT/bundle/work``: a rerun resumes the data). One
   file: every split holds the rig, and the splits differ by their poses (seeds).
2. **Held-out poses.** The test split's shapes (poses the training never drew; vertex ``i`` the
   same point of the body on every pose), each turned by a seeded random rotation, as a user's
   scans come. Pairs ``(k, k + 1)``; ``--queries`` seeded random vertices of the source, whose
   true matches are the same vertices of the target.
3. **Side by side** (``litege_core.evaluation.matching.evaluate_pairs``): the trained bundle
   (its frames: the T-Net reused from ``--init``), the shipped ``quadrupeds`` matching model
   (judged frames, its default) and the nearest neighbour in each one's aligned frame. Errors
   are exact geodesics on the target (unit area) × 100, as ``litege eval matching`` reports.

Prints a markdown block (also ``OUT/section.md``); progress goes to stderr.

Usage:
    nice .venv/bin/python scripts/bench_rig_matching.py \\
        --rig ../shared/train-data/quaternius-uaa/Wolf.gltf [--budget 15] [--pairs 12] \\
        [--queries 200] [--seed 0] [--out out/bench-rig-matching] 2> log.txt
"""

from __future__ import annotations

import argparse
import itertools
import logging
import sys
import time
from pathlib import Path

import numpy as np

from litege_core.shape import Shape
from litege_core.variants import random_rotation


def link_rig(rig: Path, folder: Path) -> Path:
    """``folder`` holding only a link to ``rig`` (made once)."""
    folder.mkdir(parents=True, exist_ok=True)
    link = folder / rig.name
    if not link.exists():
        link.symlink_to(rig.resolve())
    return folder


def held_out_pairs(dataset_dir: Path, n_pairs: int, n_queries: int, seed: int) -> list:
    """:class:`~litege_core.evaluation.matching_data.MatchPair` of consecutive test-split poses,
    each pose turned by its own seeded rotation; truth: the query vertices themselves."""
    from litege_core.datasets import GeodesicDataset
    from litege_core.evaluation.matching_data import EvalShape, ExactRows, MatchPair

    dataset = GeodesicDataset(dataset_dir)
    faces = np.asarray(dataset.faces, dtype=np.int64)
    poses = np.asarray(dataset.load_split("test")["vertices"], dtype=np.float64)
    shapes = []
    for k, vertices in enumerate(poses[: n_pairs + 1]):
        turned = vertices @ random_rotation([seed, k]).T
        shapes.append(
            EvalShape(
                name=f"pose{k}",
                shape=Shape.from_arrays(turned, faces),
                anchors=np.arange(len(vertices)),
                rows=ExactRows(vertices, faces),
            )
        )
    rng = np.random.default_rng([seed, 0xB16])
    pairs = []
    for x, y in itertools.pairwise(shapes):
        queries = np.sort(rng.choice(x.shape.n_points, n_queries, replace=False))
        pairs.append(MatchPair("held-out poses", x, y, queries, queries, None))
    return pairs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", required=True, help="a rigged, animated .glb or .gltf file")
    parser.add_argument("--out", default="out/bench-rig-matching")
    parser.add_argument("--budget", type=float, default=15.0, help="training minutes")
    parser.add_argument("--shapes", type=int, default=240, help="training poses")
    parser.add_argument("--pairs", type=int, default=12, help="held-out pose pairs")
    parser.add_argument("--queries", type=int, default=200, help="queries per pair")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--init", default="quadrupeds", help="matching bundle of the T-Net")
    parser.add_argument(
        "--tnet-steps", type=int, default=None, help="T-Net fine-tuning steps (0: none)"
    )
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(asctime)s %(message)s")

    from litege_core.evaluation.matching import (
        LiteGEMethod,
        NearestNeighbourMethod,
        evaluate_pairs,
        load_matching_model,
        machine_header,
        results_table,
    )
    from litege_core.train.matching_from_meshes import (
        MatchingFolderOptions,
        train_matching_from_meshes,
    )

    out = Path(args.out)
    rig = Path(args.rig)
    start = time.monotonic()
    summary = train_matching_from_meshes(
        MatchingFolderOptions(
            meshes=link_rig(rig, out / "rig"),
            out=out / "bundle",
            init=args.init,
            time_budget_s=60.0 * args.budget,
            seed=args.seed,
            shapes_per_mesh=args.shapes,
            eval_shapes_per_mesh=args.pairs + 1,
            name=f"rig-{rig.stem.lower()}",
            progress=False,
            poses=True,
            tnet_steps=args.tnet_steps,
        )
    )
    trained_s = time.monotonic() - start
    tuned = summary["data"]["tnet"]
    pairs = held_out_pairs(Path(summary["data"]["dir"]), args.pairs, args.queries, args.seed)
    trained = load_matching_model(str(out / "bundle"))
    shipped = load_matching_model(args.init)
    methods = [
        LiteGEMethod(trained, args.seed),
        NearestNeighbourMethod(trained, args.seed),
        LiteGEMethod(shipped, args.seed),
        NearestNeighbourMethod(shipped, args.seed),
    ]
    for method, label in zip(
        methods,
        ("trained on the rig", "nn, trained's frame", f"shipped {args.init}", "nn, shipped frame"),
        strict=True,
    ):
        method.name = label
    results = evaluate_pairs("held-out poses", pairs, methods, log=print_err)
    n_vertices = summary["data"]["n_vertices"]
    lines = [
        f"### Matching held-out poses of `{rig.name}` ({n_vertices} vertices)",
        "",
        f"- command `python scripts/bench_rig_matching.py --rig {rig.name} "
        f"--budget {args.budget:g} --shapes {args.shapes} --pairs {args.pairs} "
        f"--queries {args.queries} --seed {args.seed} --init {args.init}"
        + ("" if args.tnet_steps is None else f" --tnet-steps {args.tnet_steps}")
        + "` (the rig's path shortened to its name); "
        f"{summary['data']['shapes']} poses (heat ground truth), training "
        f"{summary['training']['steps']} steps + 2 × {summary['training']['first_pass_steps']} "
        f"first-pass steps, {trained_s / 60:.1f} min in all; "
        + (
            "T-Net not tuned"
            if tuned is None
            else f"T-Net tuned {tuned['steps']} steps (turned training shapes brought to one "
            f"frame: {100 * tuned['agreement_before']:.0f} % → "
            f"{100 * tuned['agreement_after']:.0f} %)"
        ),
        "",
        machine_header({"init": args.init}),
        "",
        results_table(results),
    ]
    section = "\n".join(lines) + "\n"
    (out / "section.md").write_text(section)
    print(section)


def print_err(message: str) -> None:
    print(message, file=sys.stderr)


if __name__ == "__main__":
    main()
