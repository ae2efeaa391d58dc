"""How far can refinement take LiteGE's matches on procedural template pairs (issue 15)?

The template-pair target (error ≤ 3.0, AUC@0.1 ≥ 75) is measured against the template's vertex
identity, and two procedural animals of different proportions are not isometric. This script
separates what limits the refined map (``match(refine="zoomout")``) on those pairs, all on the
pairs and queries of ``litege eval matching --settings template`` (same seed, same pool):

1. **Refinement settings**: LiteGE's map refined with each ``--grid`` entry of
   :class:`~litege_core.matching.refine.ZoomOutSettings`
   (``k_init:n_eigen[:step[:smoothing[:registration_rounds[:registration_anchor]]]]``;
   smoothing 0: the spectral map alone, without the smooth displacement fit; registration
   rounds 0: the fit without its registration to Y's surface).
2. **The seed**: ZoomOut started from the *ground truth* (each farthest-point sample of X
   mapped to the same template vertex of Y) at each ``--truth-k-init``, grown to ``n_eigen``.
   If it ends where LiteGE's seed ends, the seed is not what limits the refined map: ZoomOut
   converges to the most isometric map, not to the template's identity.
3. **The network at fine scale**: for each query, the ``K`` Y vertices nearest to its refined
   match in the spectral embedding; the best of them (an oracle: what a perfect re-ranking
   would reach) and the one the matching network scores lowest, alone and blended with the
   spectral distance (``spectral / median + λ · network / median``).

Run::

    python scripts/zoomout_floor.py --model quadrupeds --pairs 12 --queries 100 --seed 0
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import platform
import shlex
import sys
from collections.abc import Sequence
from datetime import UTC, datetime

import numpy as np
import torch
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from litege_core.evaluation import matching_data as data
from litege_core.evaluation.matching import (
    auc_threshold,
    auc_x100,
    load_matching_model,
    mean_error_x100,
)
from litege_core.evaluation.speed import cpu_name
from litege_core.matching.refine import (
    ZoomOutSettings,
    pointwise_matches,
    spectrum,
    zoomout_map,
)

SETTING = "template"


GRID_FIELDS = (
    ("k_init", int),
    ("n_eigen", int),
    ("step", int),
    ("smoothing", float),
    ("registration_rounds", int),
    ("registration_anchor", float),
)
"""The ``:``-separated fields of a ``--grid`` entry, in order (the first two required)."""


def parse_grid(text: str) -> list[ZoomOutSettings]:
    """``"20:100,50:150:5,20:100:5:0,20:100:5:3e-6:0"`` → settings
    (``k_init:n_eigen[:step[:smoothing[:registration_rounds[:registration_anchor]]]]`` each; the
    defaults of :class:`ZoomOutSettings` where not given)."""
    usage = ":".join(name for name, _ in GRID_FIELDS)
    grid = []
    for item in text.split(","):
        fields = item.split(":")
        if not 2 <= len(fields) <= len(GRID_FIELDS):
            raise SystemExit(f"bad --grid entry {item!r}: {usage} (the first two required)")
        values = {name: kind(v) for (name, kind), v in zip(GRID_FIELDS, fields, strict=False)}
        grid.append(ZoomOutSettings(**values))
    return grid


def parse_list(text: str, kind: type) -> list:
    """``"1,2"`` → ``[kind(1), kind(2)]``; ``""`` → ``[]``."""
    return [kind(v) for v in text.split(",") if v.strip()]


def rerank(spectral: NDArray, network: NDArray, weight: float | None) -> NDArray:
    """``(N,)`` column of each row's kept candidate.

    Args:
        spectral: ``(N, K)`` spectral-embedding distances of each query's K candidates
            (column 0 is the refined match itself).
        network: ``(N, K)`` the matching network's predicted cross-shape distances of them.
        weight: λ of ``spectral / median + λ · network / median``; ``None``: network only.
    """
    if weight is None:
        return network.argmin(axis=1)
    cost = spectral / np.median(spectral) + weight * network / np.median(network)
    return cost.argmin(axis=1)


def label(settings: ZoomOutSettings) -> str:
    text = (
        f"k_init {settings.k_init}, n_eigen {settings.n_eigen}, step {settings.step}, "
        f"smoothing {settings.smoothing:g}"
    )
    if settings.smoothing and settings.registration_rounds:  # smoothing 0 skips it too
        text += (
            f", registration {settings.registration_rounds} rounds, "
            f"anchor {settings.registration_anchor:g}"
        )
    return text


def row(name: str, errors: Sequence[NDArray], threshold: float) -> str:
    pooled = np.concatenate(errors)
    per_pair = np.array([e.mean() for e in errors]) * 100
    return (
        f"| {name} | {mean_error_x100(pooled):.2f} | {auc_x100(pooled, threshold):.1f} | "
        f"{np.median(pooled) * 100:.2f} | {np.quantile(pooled, 0.9) * 100:.2f} | "
        f"{per_pair.max():.2f} |"
    )


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", default="quadrupeds", help="matching model")
    parser.add_argument("--pairs", type=int, default=12)
    parser.add_argument("--queries", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", default="judged", help="prepare(frames=…)")
    parser.add_argument("--grid", default="20:100,30:100,20:150,15:100,20:100:2")
    parser.add_argument("--truth-k-init", default="20,50,100", help="k_init of the truth seed")
    parser.add_argument("--candidates", default="8,32,128", help="K of the re-ranking")
    parser.add_argument("--weights", default="0.5,1,2", help="λ of the blended re-ranking")
    parser.add_argument("--workers", type=int, default=1)
    command = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(command)

    model = load_matching_model(args.model)
    category = "biped" if "human" in args.model else "quadruped"
    pool = data.SyntheticPool(category, args.pairs, args.queries, args.seed, True, args.workers)
    pairs = pool.pairs(SETTING)
    threshold = auc_threshold(SETTING)
    default = ZoomOutSettings()
    grid = parse_grid(args.grid)
    truth_k = parse_list(args.truth_k_init, int)
    counts = parse_list(args.candidates, int)
    weights = parse_list(args.weights, float)

    found: dict[str, list[NDArray]] = {}

    def add(name: str, errors: NDArray) -> None:
        found.setdefault(name, []).append(errors)

    for pair in pairs:
        x = model.prepare(pair.x.shape, seed=args.seed, frames=args.frames)
        y = model.prepare(pair.y.shape, seed=args.seed, frames=args.frames)
        rows = np.asarray(pair.queries, dtype=np.int64)
        add("LiteGE, unrefined", pair.errors(model.match(x, y, rows).indices)[0])
        for settings in grid:
            refined = model.match(x, y, rows, refine="zoomout", zoomout=settings).indices
            add(f"LiteGE + ZoomOut ({label(settings)})", pair.errors(refined)[0])
        source, target = spectrum(x, default), spectrum(y, default)
        truth_seed = source.samples  # template pairs: vertex i is the same body point
        for k_init in truth_k:
            settings = ZoomOutSettings(k_init=k_init, n_eigen=default.n_eigen, smoothing=0.0)
            fmap = zoomout_map(truth_seed, source, target, settings)
            add(
                f"truth + ZoomOut (k_init {k_init}, n_eigen {default.n_eigen})",
                pair.errors(pointwise_matches(fmap, source, target, rows))[0],
            )
        # the map that match(refine="zoomout") used with the default settings (kept on x)
        fmap = model._refined_map(x, y, y, "zoomout", default, None, False)[0].fmap
        k2, k1 = fmap.shape
        tree = cKDTree(target.eigenvectors[:, :k1] @ fmap.T)
        query_features = model._query_features(x, rows)
        score = model._score_fn(query_features, model.features(y))
        for count in counts:
            spectral, candidates = tree.query(source.eigenvectors[rows, :k2], k=count)
            with torch.no_grad():
                network = score(torch.arange(rows.size), torch.from_numpy(candidates))
            network = network.float().cpu().numpy()
            errors = np.stack([pair.errors(candidates[:, j])[0] for j in range(count)], axis=1)
            pick = np.arange(rows.size)
            add(f"{count} spectral candidates: the best (oracle)", errors.min(axis=1))
            by_network = rerank(spectral, network, None)
            add(f"{count} spectral candidates: network only", errors[pick, by_network])
            for weight in weights:
                kept = rerank(spectral, network, weight)
                add(f"{count} candidates: spectral + {weight:g} × network", errors[pick, kept])

    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    print(
        f"- date {when}; machine {cpu_name() or platform.processor()}, {os.cpu_count()} cpus, "
        f"torch threads {torch.get_num_threads()}; model {args.model} "
        f"({model.content_hash[:12]}), frames {args.frames}; {len(pairs)} template pairs × "
        f"{args.queries} queries, seed {args.seed}; error ×100 on the unit-area target, AUC "
        f"@{threshold:g}; command `python scripts/zoomout_floor.py {shlex.join(command)}`\n"
    )
    print("| map | mean error ×100 | AUC | median ×100 | p90 ×100 | worst pair ×100 |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, errors in found.items():
        print(row(name, errors, threshold))


if __name__ == "__main__":
    main()
