"""``litege train geodesic --config FILE [--resume CHECKPOINT] [--out DIR]`` and
``litege train tnet --config FILE [--out DIR]``.

:func:`add_train_parser` registers the ``train`` command on the CLI's sub-parsers (the CLI
module wires it in); :func:`run_training` is the same thing as a function.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from litege_core.train.config import TrainConfig, load_config

LOG = logging.getLogger("litege.train")


def run_training(
    config: TrainConfig, resume: str | Path | None = None, out: str | Path | None = None
) -> dict[str, Any]:
    """Train (or resume) per ``config`` and export the bundle; returns the bundle manifest.

    Args:
        config: the run configuration.
        resume: a ``checkpoints/last.safetensors`` of an earlier run of the same config.
        out: overrides ``output.dir``.
    """
    from litege_core.train.pipeline import train_geodesic

    if out is not None:
        config = config.replace(output={"dir": str(out)})
    result = train_geodesic(config, resume=resume)
    if result.manifest is None:  # pragma: no cover - a full run always finishes
        raise RuntimeError("training ended without exporting a bundle")
    return result.manifest


def _ensure_console_logging() -> None:
    if not any(isinstance(h, logging.StreamHandler) for h in LOG.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%H:%M:%S"))
        LOG.addHandler(handler)
    LOG.setLevel(logging.INFO)


def _cmd_train_geodesic(args: argparse.Namespace) -> int:
    _ensure_console_logging()
    config = load_config(args.config)
    manifest = run_training(config, resume=args.resume, out=args.out)
    out = Path(args.out or config.output.dir) / "bundle"
    summary = {
        "bundle": str(out),
        "name": manifest["name"],
        "metrics": {k: manifest["metrics"][k] for k in ("val_mean_error", "val_median_error")},
        "best_epoch": manifest["training"]["best_epoch"],
        "steps": manifest["training"]["steps"],
    }
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_train_tnet(args: argparse.Namespace) -> int:
    from litege_core.train.tnet import load_tnet_config, run_tnet_training

    _ensure_console_logging()
    config = load_tnet_config(args.config)
    report = run_tnet_training(config, out=args.out)
    alignment = report["alignment"] or {}
    summary = {
        "weights": report["weights"],
        "best_step": report["training"]["best_step"],
        "best_val": report["training"]["best_val"],
        "steps_per_second": report["training"]["steps_per_second"],
        "alignment": {
            name: {k: stats[k] for k in ("mean", "std", "median", "max", "n_failures", "n")}
            for name, stats in alignment.items()
            if isinstance(stats, dict)
        },
    }
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_train_matching(args: argparse.Namespace) -> int:
    from litege_core.train.matching import load_matching_config, train_matching

    _ensure_console_logging()
    config = load_matching_config(args.config)
    if args.out is not None:
        config = config.replace(output={"dir": str(args.out)})
    manifest = train_matching(config)
    summary = {
        "bundle": str(Path(config.output.dir) / "bundle"),
        "name": manifest["name"],
        "metrics": manifest["metrics"],
        "chosen_first_pass": manifest["training"]["chosen_first_pass"],
    }
    print(json.dumps(summary, indent=2))
    return 0


def add_train_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``train geodesic``, ``train tnet`` and ``train matching`` on ``subparsers``;
    returns the ``train`` parser.

    The handler is stored as ``args.handler`` (returns an exit code), like the other CLI
    commands.
    """
    train = subparsers.add_parser("train", help="train networks")
    commands = train.add_subparsers(dest="train_command", required=True)
    geodesic = commands.add_parser(
        "geodesic",
        help="train the geodesic network from a TOML config and export a model bundle",
    )
    geodesic.add_argument("--config", required=True, help="TOML training config")
    geodesic.add_argument("--resume", default=None, help="checkpoint (RUN/checkpoints/last…)")
    geodesic.add_argument("--out", default=None, help="run directory (overrides output.dir)")
    geodesic.set_defaults(handler=_cmd_train_geodesic)
    tnet = commands.add_parser(
        "tnet",
        help="train the T-Net (shape orientation for matching) on procedural shapes",
    )
    tnet.add_argument("--config", required=True, help="TOML T-Net config (configs/tnet-*.toml)")
    tnet.add_argument("--out", default=None, help="run directory (overrides output.dir)")
    tnet.set_defaults(handler=_cmd_train_tnet)
    matching = commands.add_parser(
        "matching",
        help="train the matching network (needs a T-Net) and export a matching bundle",
    )
    matching.add_argument("--config", required=True, help="TOML config (configs/matching-*.toml)")
    matching.add_argument("--out", default=None, help="run directory (overrides output.dir)")
    matching.set_defaults(handler=_cmd_train_matching)
    return train


__all__ = ["add_train_parser", "run_training"]
