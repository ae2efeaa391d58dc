"""Store a bundle's basis components as int8 (half the basis bytes), in place.

The networks are kept; the descriptor moves by the int8 rounding (BENCHMARKS.md ``basis-int8``
measures it; ``--measure`` prints the change on random blobs). The manifest is re-hashed, so
the bundle's content hash changes: the small head's sidecar is re-linked to the new hash (its
weights do not depend on the basis storage; the old hash is kept as
``teacher_requantized_from``) and the model card is written again
(``ship_model.rendered_card``). A graph-fusion calibration names the bundle it was fitted on and
must be fitted again (``scripts/calibrate_fusion.py --write``); this script says so.

Usage:
    python scripts/quantize_basis.py litege_core/models/quadrupeds [more bundles] [--measure]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from ship_model import rendered_card  # scripts/ is sys.path[0]

from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.files import write_json_atomic
from litege_core.learned.fusion_calibration import FUSION_CONFIG
from litege_core.learned.manifest import (
    BASIS_FILE,
    SMALL_HEAD_CONFIG,
    read_verified_manifest,
    replace_basis,
)

CARD = "MODEL_CARD.md"


def descriptor_change(old: UdfPcaBasis, new: UdfPcaBasis, seed: int = 0) -> dict[str, float]:
    """Largest and mean change of the codes of 16 random unit-area-scale blobs, relative to
    the largest code: what the rounding does to a descriptor."""
    rng = np.random.default_rng(seed)
    changes, peaks = [], []
    for _ in range(16):
        points = rng.normal(size=(2000, 3)) * rng.uniform(0.1, 0.4, 3)
        a, b = old.describe(points.astype(np.float32)), new.describe(points.astype(np.float32))
        changes.append(np.abs(a - b))
        peaks.append(np.abs(a).max())
    change = np.stack(changes)
    return {
        "max_relative": float(change.max() / max(peaks)),
        "mean_relative": float(change.mean() / np.mean(peaks)),
    }


def quantize(directory: Path, measure: bool) -> dict[str, object]:
    before = read_verified_manifest(directory)
    old = UdfPcaBasis.load(directory / BASIS_FILE)
    if old.component_storage == "int8":
        return {"bundle": str(directory), "skipped": "already int8"}
    new = old.with_component_storage("int8")
    after = replace_basis(directory, new)
    old_hash, new_hash = before["content_hash"], after["content_hash"]
    report: dict[str, object] = {
        "bundle": str(directory),
        "basis_bytes": [old.nbytes_on_disk, new.nbytes_on_disk],
        "content_hash": [old_hash, new_hash],
    }
    if measure:
        report["descriptor_change"] = descriptor_change(old, new)
    head = directory / SMALL_HEAD_CONFIG
    if head.is_file():
        config = json.loads(head.read_text())
        if config.get("teacher_content_hash") == old_hash:
            config["teacher_content_hash"] = new_hash
            config["teacher_requantized_from"] = old_hash
            write_json_atomic(head, config)
            report["small_head"] = "re-linked"
    fusion = directory / FUSION_CONFIG
    if fusion.is_file() and json.loads(fusion.read_text()).get("bundle_hash") != new_hash:
        report["fusion"] = "stale: run scripts/calibrate_fusion.py --write for this bundle"
    if (directory / CARD).is_file():
        (directory / CARD).write_text(rendered_card(directory))
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundles", nargs="+", type=Path)
    parser.add_argument("--measure", action="store_true", help="report the descriptor change")
    args = parser.parse_args()
    for directory in args.bundles:
        print(json.dumps(quantize(directory, args.measure)))


if __name__ == "__main__":
    main()
