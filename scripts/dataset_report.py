"""Summarize built ground-truth datasets from their manifests (written by the builder).

Usage: python scripts/dataset_report.py docs/datasets/*.manifest.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main() -> None:
    print("### Ground-truth geodesic datasets (small presets)\n")
    print(
        "Figures from each dataset's manifest, as written by `litege data build`. "
        "Wall time covers the whole build; other CPU-heavy jobs shared the 2 cores during "
        "both builds (see the note under the table).\n"
    )
    print(
        "| dataset | shapes (train/val/test) | source rows | distances dtype "
        "(train / eval) | workers | wall min | compute s per shape | built |"
    )
    print("|---|---|---:|---|---:|---:|---:|---|")
    for path in sys.argv[1:]:
        m = json.loads(Path(path).read_text())
        counts, spec = m["counts"], m["spec"]
        total = sum(counts.values())
        rows = spec["n_shared_sources"] + spec["n_extra_sources"]
        print(
            f"| {spec['name']} | {counts['train']}/{counts['val']}/{counts['test']} | "
            f"{rows} | {m['distance_dtype']['train']} / "
            f"{m['distance_dtype']['test']} | {m['host']['workers']} | "
            f"{m['wall_seconds_last_run'] / 60:.1f} | {m['compute_seconds'] / total:.2f} | "
            f"{m['updated'][:10]} |"
        )


if __name__ == "__main__":
    main()
