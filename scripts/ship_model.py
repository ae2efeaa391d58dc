"""Copy a trained bundle into the package with its model card: a geodesic bundle into
``litege_core/models/NAME``, a matching bundle into ``litege_core/models/NAME-matching``.

The card is generated from the bundle manifest (data, configuration, training, metrics), the
git commit the bundle was trained at, and optionally an evaluation table (markdown file written
by ``litege eval geodesic`` / ``litege eval matching``) and, for matching bundles, the T-Net's
alignment report (``report.json`` of ``litege train tnet``). Checks the 30 MB budget of all
shipped bundles together. ``--card-only`` rewrites the card of a bundle already shipped with a
new evaluation table (e.g. after its fusion calibration was fitted again), nothing else.

Usage:
    python scripts/ship_model.py out/train/geodesic-quadrupeds/bundle [--eval FILE.md]
    python scripts/ship_model.py litege_core/models/humans --card-only --eval FILE.md
    python scripts/ship_model.py out/train/matching-quadrupeds/bundle --eval FILE.md \
        --tnet-report out/tnet-quadrupeds/report.json
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
from pathlib import Path

from litege_core.descriptor.basis import UdfPcaBasis
from litege_core.learned import load_bundle
from litege_core.learned.bundle import BASIS_FILE, MANIFEST, SHIPPED_DIR
from litege_core.learned.cards import model_card, sidecar_section
from litege_core.matching.bundle import SUFFIX, load_matching_bundle

BUDGET_BYTES = 30 * 1024 * 1024


def git_commit() -> str:
    result = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True)
    return result.stdout.strip() or "unknown"


def _copy_bundle(source: Path, target: Path) -> None:
    if target.exists():
        shutil.rmtree(target)
    target.mkdir(parents=True)
    for item in source.iterdir():
        if item.is_file():
            shutil.copy2(item, target / item.name)
            (target / item.name).chmod(0o644)  # safetensors writes 0600; the service user reads


def ship(args: argparse.Namespace) -> Path:
    """Verify, copy and document one bundle; returns the shipped directory."""
    kind = json.loads((Path(args.bundle) / MANIFEST).read_text()).get("kind", "geodesic")
    if args.tnet_report and kind != "matching":
        raise SystemExit("--tnet-report documents the T-Net of a matching bundle")
    load = load_matching_bundle if kind == "matching" else load_bundle
    bundle = load(args.bundle)  # verifies hashes before anything is copied
    target = SHIPPED_DIR / (f"{bundle.name}{SUFFIX}" if kind == "matching" else bundle.name)
    _copy_bundle(Path(args.bundle), target)
    manifest = json.loads((target / MANIFEST).read_text())
    manifest["training"].setdefault("commit", git_commit())
    evaluation = Path(args.eval).read_text() if args.eval else None
    report = json.loads(Path(args.tnet_report).read_text()) if args.tnet_report else None
    storage = bundle.basis.component_storage
    card = model_card(manifest, evaluation, report, sidecar_section(target), storage)
    (target / "MODEL_CARD.md").write_text(card)
    load(target)
    return target


def _card_section(card: str, title_start: str) -> str | None:
    match = re.search(rf"\n## {re.escape(title_start)}[^\n]*\n\n(.*?)\n\n## ", card, re.S)
    return match.group(1) if match else None


def rendered_card(directory: Path, evaluation: str | None = None) -> str:
    """The card of a shipped bundle written again from its manifest and basis, with the parts
    only the card holds (shipping commit, evaluation table, T-Net report) read from its
    current ``MODEL_CARD.md``: equal to that file unless the bundle changed. ``evaluation``
    replaces the card's evaluation table."""
    card = (directory / "MODEL_CARD.md").read_text()
    manifest = json.loads((directory / MANIFEST).read_text())
    commit = re.search(r"shipped at commit `([^`]*)`", card)
    if commit:
        manifest["training"].setdefault("commit", commit.group(1))
    tnet = _card_section(card, "T-Net alignment")
    report = json.loads(tnet.removeprefix("```json\n").removesuffix("\n```")) if tnet else None
    storage = UdfPcaBasis.load(directory / BASIS_FILE).component_storage
    return model_card(
        manifest,
        _card_section(card, "Evaluation") if evaluation is None else evaluation,
        report,
        sidecar_section(directory),
        storage,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bundle")
    parser.add_argument("--eval", default=None, help="markdown evaluation table to embed")
    parser.add_argument("--tnet-report", default=None, help="T-Net report.json (matching)")
    parser.add_argument(
        "--card-only", action="store_true", help="rewrite a shipped bundle's card with --eval"
    )
    args = parser.parse_args()
    if args.card_only:
        if not args.eval:
            raise SystemExit("--card-only needs --eval")
        target = Path(args.bundle)
        (target / "MODEL_CARD.md").write_text(rendered_card(target, Path(args.eval).read_text()))
        print(f"rewrote the card of {target}")
        return
    target = ship(args)
    total = sum(f.stat().st_size for f in SHIPPED_DIR.rglob("*") if f.is_file())
    print(f"shipped {target.name} → {target}; all shipped bundles: {total / 2**20:.1f} MiB")
    if total > BUDGET_BYTES:
        raise SystemExit(f"shipped bundles exceed the 30 MiB budget ({total / 2**20:.1f} MiB)")


if __name__ == "__main__":
    main()
