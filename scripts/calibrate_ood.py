"""Calibrate the out-of-distribution threshold on the real dev shapes (issue 13 item 7).

Usage: python scripts/calibrate_ood.py [--eval-data ../shared/eval-data] [--sources 12]

For every real dev shape (TOSCA animals, FAUST humans, the leopard) it registers the mesh under
both shipped geodesic models and records the OOD z-score of each, and under the shape's own
category model the per-shape LiteGE error (exact MMP rows from farthest-point sources, unit
area, ground-truth mean 100). For thresholds T it reports how many shapes of the *other*
category are flagged (z > T: a human under `quadrupeds`, an animal under `humans`), how many
of the shape's own category are flagged, and the mean error of the flagged and unflagged ones.
The recommended T is the largest threshold that flags at least 90 % of the cross-category
registrations; it is the value of ``litege_core.learned.state.OOD_Z_THRESHOLD``.
"""

from __future__ import annotations

import argparse
import platform
from datetime import UTC, datetime

import numpy as np
import torch

from litege_core.evaluation.geodesic import REAL_SETS, real_eval_shapes, real_shape_paths
from litege_core.learned import OOD_Z_THRESHOLD, Predictor, load_shipped
from litege_core.metrics import geodesic_error
from litege_core.shape import Shape

OWN_MODEL = {"tosca": "quadrupeds", "leopard": "quadrupeds", "faust": "humans"}
THRESHOLDS = (0.5, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)
CROSS_RECALL = 0.9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--cache", default="out/diagnose/cache", help="exact-row cache")
    args = parser.parse_args()
    torch.set_num_threads(1)
    predictors = {
        name: Predictor(load_shipped(name), fusion="none") for name in ("quadrupeds", "humans")
    }
    rows = []  # (set, own z, cross z, own error)
    for key in OWN_MODEL:
        paths = real_shape_paths(args.eval_data, key)
        if not paths:
            continue
        group = REAL_SETS[key].group
        for shape in real_eval_shapes(paths, group, args.sources, cache_dir=args.cache):
            mesh = Shape.from_arrays(shape.vertices, shape.faces)
            own = OWN_MODEL[key]
            other = "humans" if own == "quadrupeds" else "quadrupeds"
            state = predictors[own].register(mesh)
            predicted = predictors[own].distances(state, shape.sources)
            error = geodesic_error(predicted, shape.gt).mean
            cross = predictors[other].register(mesh).ood_score
            rows.append((key, state.ood_score, cross, error))
    if not rows:
        print("no real dev shapes found: nothing to calibrate")
        return
    own_z = np.array([r[1] for r in rows])
    cross_z = np.array([r[2] for r in rows])
    errors = np.array([r[3] for r in rows])
    print("### OOD threshold calibrated on the real dev shapes\n")
    machine = platform.processor() or platform.machine()
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {machine}; "
        f"command `python scripts/calibrate_ood.py --sources {args.sources}`"
    )
    counts = {k: sum(r[0] == k for r in rows) for k in OWN_MODEL}
    print(
        f"- shapes: {counts}; each registered under both shipped models; error: per-shape LiteGE "
        f"mesh error under its own model (exact rows from {args.sources} FPS sources, unit area, "
        "GT mean 100)\n"
    )
    print(
        "| threshold T | other-category registrations flagged | own-category flagged | "
        "mean error flagged | mean error not flagged |"
    )
    print("|---:|---:|---:|---:|---:|")
    recommended = None
    for t in THRESHOLDS:
        flagged = own_z > t
        recall = float((cross_z > t).mean())
        if recall >= CROSS_RECALL:
            recommended = t
        print(
            f"| {t:g} | {recall:.0%} | {flagged.mean():.0%} | "
            f"{errors[flagged].mean() if flagged.any() else float('nan'):.2f} | "
            f"{errors[~flagged].mean() if (~flagged).any() else float('nan'):.2f} |"
        )
    print(
        f"\nRecommended threshold (largest T flagging ≥ {CROSS_RECALL:.0%} of the other-category "
        f"registrations): **{recommended}**; the library uses "
        f"`OOD_Z_THRESHOLD = {OOD_Z_THRESHOLD}`."
    )


if __name__ == "__main__":
    main()
