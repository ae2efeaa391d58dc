"""How the service's ``auto`` model choice routes the real dev shapes (issue 14).

Usage: python scripts/eval_routing.py [--quadrupeds NAME_OR_DIR] [--humans NAME_OR_DIR]
    [--eval-data ../shared/eval-data]

``LITEGE_DEFAULT_MODEL=auto`` registers an upload under every loaded geodesic model and keeps
the one with the lowest OOD z-score. This registers every TOSCA animal, the leopard and every
FAUST human under a quadrupeds and a humans bundle (shipped by default; a candidate bundle
directory before it ships) and counts the shapes routed to the other category's model, with
the median z-score under the shape's own model. Prints a markdown section.
"""

from __future__ import annotations

import argparse
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from litege_core.evaluation.geodesic import real_shape_paths
from litege_core.io import load_shape
from litege_core.learned import Predictor, load_bundle, load_shipped

OWN_MODEL = {"tosca": "quadrupeds", "leopard": "quadrupeds", "faust": "humans"}


def predictor(name_or_dir: str) -> Predictor:
    """A CPU predictor of a shipped model name or a bundle directory."""
    bundle = load_bundle(name_or_dir) if Path(name_or_dir).is_dir() else load_shipped(name_or_dir)
    return Predictor(bundle)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quadrupeds", default="quadrupeds")
    parser.add_argument("--humans", default="humans")
    parser.add_argument("--eval-data", default="../shared/eval-data")
    args = parser.parse_args()
    models = {"quadrupeds": predictor(args.quadrupeds), "humans": predictor(args.humans)}
    print("### `auto` model routing of the real dev shapes\n")
    print(
        f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; quadrupeds = `{args.quadrupeds}` "
        f"({models['quadrupeds'].bundle.content_hash[:12]}), humans = `{args.humans}` "
        f"({models['humans'].bundle.content_hash[:12]}); each mesh registered under both, "
        "routed to the lower OOD z-score; command `python scripts/eval_routing.py "
        f"--quadrupeds {args.quadrupeds} --humans {args.humans}`\n"
    )
    print("| set | shapes | routed to the other model | median z, own model | median z, other |")
    print("|---|---:|---:|---:|---:|")
    for set_name, own in OWN_MODEL.items():
        other = "humans" if own == "quadrupeds" else "quadrupeds"
        scores = []
        for path in real_shape_paths(args.eval_data, set_name):
            shape = load_shape(path)
            scores.append({n: m.register(shape).ood_score for n, m in models.items()})
        wrong = sum(min(z, key=z.__getitem__) != own for z in scores)
        own_z = np.median([z[own] for z in scores])
        other_z = np.median([z[other] for z in scores])
        print(f"| {set_name} | {len(scores)} | {wrong} | {own_z:.2f} | {other_z:.2f} |")


if __name__ == "__main__":
    main()
