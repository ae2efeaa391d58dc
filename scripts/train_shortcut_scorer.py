"""Train the cloud graph's shortcut scorer (:mod:`litege_core.learned.shortcuts`; issue 14) and
report how it ranks and cuts the shortcuts of other sets.

Training clouds: the kept edges (:func:`~litege_core.evaluation.cloud_edges.kept_edges`) of
datasets we build (``--train``: procedural animals in contact poses, never the dev set), each
shape drawn once per ``--train-settings`` setting with cloud seed 1. Evaluation: the same edges
of the ``--eval`` sets (held-out procedural shapes, calibration sets, the real dev set) with
cloud seed 0, per ``--eval-settings`` setting: the AUC and, per threshold, what cutting does to
the graph's error (:func:`~litege_core.evaluation.cloud_edges.shortcut_cut_table`).

The scorer is written to ``--out`` (``--ship``: into the library,
:data:`~litege_core.learned.shortcuts.SHIPPED_SCORER_DIR`; the fusion calibrations that cut
must then be fitted again: ``scripts/calibrate_fusion.py --shortcut-cut``). Every number comes
from this script::

    python scripts/train_shortcut_scorer.py --train data/quadruped-steep-train@quadrupeds \\
        --eval data/quadruped-steep-cal@quadrupeds,data/folder-cal@quadrupeds,tosca,faust
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import pickle
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch

from litege_core.evaluation.cloud_edges import KeptEdges, collect_kept_edges, shortcut_cut_table
from litege_core.evaluation.speed import cpu_name
from litege_core.learned.shortcuts import (
    SHIPPED_SCORER_DIR,
    ScorerWeights,
    save_shortcut_scorer,
    shortcut_probabilities,
)
from litege_core.train.shortcuts import scorer_examples, train_shortcut_scorer


def kept_edges_of(key: str, setting: str, seed: int, args: argparse.Namespace) -> list[KeptEdges]:
    """The kept edges of one set in one setting, read from ``--edges-cache`` when there."""
    name = f"{key.replace('/', '_').replace('@', '_')}-{setting}-{seed}-{args.sources}.pkl"
    path = Path(args.edges_cache) / name if args.edges_cache else None
    if path is not None and path.is_file():
        return pickle.loads(path.read_bytes())
    shapes = collect_kept_edges(
        key, [setting], eval_root=args.eval_root, sources=args.sources, cache=args.cache,
        limit=args.limit, stretch=args.stretch, seed=seed,
    )[setting]  # fmt: skip
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.name}.{os.getpid()}.partial")
        partial.write_bytes(pickle.dumps(shapes))
        os.replace(partial, path)
    return shapes


def scores_of(scorer: ScorerWeights, cloud: KeptEdges) -> np.ndarray:
    """``(E,)`` the scorer's probabilities of a cloud's kept edges."""
    return shortcut_probabilities(
        scorer, cloud.points, cloud.nearest, cloud.spacing, cloud.normals, cloud.thickness,
        cloud.i.astype(np.int64), cloud.j.astype(np.int64),
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--train", default="data/quadruped-steep-train@quadrupeds")
    parser.add_argument("--train-settings", default="cloud_2000")
    parser.add_argument(
        "--eval", default="data/quadruped-steep-cal@quadrupeds,data/folder-cal@quadrupeds,tosca"
    )
    parser.add_argument("--eval-settings", default="cloud_2000,noise_0.01")
    parser.add_argument("--steps", type=int, default=6000)
    parser.add_argument("--width", type=int, default=32)
    parser.add_argument("--negatives", type=float, default=0.15)
    parser.add_argument("--thresholds", default="0.1,0.2,0.3,0.5,0.7")
    parser.add_argument("--stretch", type=float, default=3.0)
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--eval-root", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache", help="exact-row cache")
    parser.add_argument("--edges-cache", default="out/kept-edges", help="'' for none")
    parser.add_argument("--limit", type=int, default=None, help="the first shapes of each set")
    parser.add_argument("--out", default="out/shortcut-scorer")
    parser.add_argument("--ship", action="store_true", help="write into the library instead")
    args = parser.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    train_settings = args.train_settings.split(",")
    training = [
        cloud
        for key in args.train.split(",")
        for setting in train_settings
        for cloud in kept_edges_of(key, setting, 1, args)
    ]
    examples = scorer_examples(training, args.negatives)
    trained = train_shortcut_scorer(examples, args.steps, args.width)
    scorer = trained.weights()
    command = (
        f"python scripts/train_shortcut_scorer.py --train {args.train} --train-settings "
        f"{args.train_settings} --eval {args.eval} --eval-settings {args.eval_settings} "
        f"--steps {args.steps} --width {args.width} --negatives {args.negatives:g}"
        + (" --ship" if args.ship else "")
    )
    out = SHIPPED_SCORER_DIR if args.ship else Path(args.out)
    config = save_shortcut_scorer(
        out,
        trained.state_dict(),
        scorer.neighbours,
        {
            "command": command,
            "train": args.train,
            "train_settings": train_settings,
            "clouds": len(training),
            "edges": int(examples.labels.shape[0]),
            "shortcuts": int(examples.labels.sum()),
            "steps": args.steps,
            "stretch": args.stretch,
            "date": f"{datetime.now(UTC):%Y-%m-%d}",
        },
    )
    print("### The shortcut scorer of the fused cloud graph (issue 14)\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}, one torch thread; "
        f"trained on {args.train} ({len(training)} clouds of {', '.join(train_settings)}, cloud "
        f"seed 1: {examples.labels.shape[0]} edges, {int(examples.labels.sum())} shortcuts) for "
        f"{args.steps} steps of 512, width {args.width}; weights sha256 "
        f"{config['weights_sha256'][:12]}; scored on clouds of seed 0; {args.sources} FPS "
        f"sources per real shape, exact rows, GT mean 100; a shortcut: a kept edge whose true "
        f"geodesic exceeds {args.stretch:g} × its chord; command `{command}`"
    )
    thresholds = [float(t) for t in args.thresholds.split(",")]
    for key in args.eval.split(","):
        for setting in args.eval_settings.split(","):
            clouds = kept_edges_of(key, setting, 0, args)
            tick = time.perf_counter()
            scores = [scores_of(scorer, cloud) for cloud in clouds]
            each = (time.perf_counter() - tick) / max(len(clouds), 1) * 1e3
            table = shortcut_cut_table(f"{key}, {setting}", clouds, scores, thresholds)
            print(f"\n{table}\n\n(scoring: {each:.1f} ms per cloud)")
            sys.stdout.flush()
    print(f"\nwrote {os.path.relpath(out)} ({time.perf_counter() - started:.0f} s in all)")


if __name__ == "__main__":
    main()
