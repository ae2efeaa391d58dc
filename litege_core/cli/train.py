"""``litege train geodesic|tnet|orientation|matching --config FILE``: train a network from a
TOML config and export it (a bundle, or the T-Net or orientation weights); a JSON summary goes to
stdout, progress to stderr.

``litege train geodesic --meshes DIR --out BUNDLE [--init MODEL] [--time-budget MINUTES]
[--workers N]`` trains on a folder of meshes in one command (ground truth, training,
held-out comparison, bundle with model card; :mod:`litege_core.train.from_meshes`).
``litege train matching --meshes DIR --out BUNDLE [--init quadrupeds] [--time-budget MINUTES]
[--workers N] [--poses]`` does the same for matching when the meshes share one topology (vertex
``i`` corresponds; a clear error otherwise; :mod:`litege_core.train.matching_from_meshes`), or
with ``--poses`` from the poses of rigged, animated glTF files (one character is enough).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from litege_core.cli.common import print_json

LOG = logging.getLogger("litege.train")


def _ensure_console_logging() -> None:
    if not any(isinstance(h, logging.StreamHandler) for h in LOG.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%H:%M:%S"))
        LOG.addHandler(handler)
    LOG.setLevel(logging.INFO)


def _vertex_range(text: str) -> tuple[int, int]:
    from litege_core.datasets.spec import is_count
    from litege_core.errors import InputError

    low, sep, high = text.partition(",")
    if not (sep and is_count(low.strip()) and is_count(high.strip())):
        raise InputError(f"--vertices must be MIN,MAX (e.g. 2000,4000), got {text!r}")
    return int(low), int(high)


def cmd_train_geodesic_meshes(args: argparse.Namespace) -> int:
    from litege_core.errors import InputError
    from litege_core.train.from_meshes import FolderTrainOptions, train_from_meshes

    if args.out is None:
        raise InputError("--meshes needs --out BUNDLE_DIR (where the bundle is written)")
    if args.resume is not None:
        raise InputError("--resume belongs to --config runs; rerun --meshes to resume its data")
    _ensure_console_logging()
    options = FolderTrainOptions(
        meshes=Path(args.meshes),
        out=Path(args.out),
        work=Path(args.work) if args.work else None,
        init=args.init,
        time_budget_s=None if args.time_budget is None else 60.0 * args.time_budget,
        workers=args.workers,
        seed=args.seed,
        shapes_per_mesh=args.shapes_per_mesh,
        eval_shapes_per_mesh=args.eval_shapes_per_mesh,
        vertex_range=_vertex_range(args.vertices),
        poses=args.poses,
        solver=args.solver,
        config=args.config,
        name=args.name,
    )
    print_json(train_from_meshes(options))
    return 0


def cmd_train_geodesic(args: argparse.Namespace) -> int:
    from litege_core.errors import InputError
    from litege_core.train.command import run_training
    from litege_core.train.config import load_config

    if args.meshes is not None:
        return cmd_train_geodesic_meshes(args)
    if args.config is None:
        raise InputError("give --config FILE (a dataset run) or --meshes DIR (a folder of meshes)")
    _ensure_console_logging()
    config = load_config(args.config)
    manifest = run_training(
        config,
        resume=args.resume,
        out=args.out,
        init=args.init,
        time_budget_s=None if args.time_budget is None else 60.0 * args.time_budget,
    )
    out = Path(args.out or config.output.dir) / "bundle"
    print_json(
        {
            "bundle": str(out),
            "name": manifest["name"],
            "metrics": {k: manifest["metrics"][k] for k in ("val_mean_error", "val_median_error")},
            "best_epoch": manifest["training"]["best_epoch"],
            "steps": manifest["training"]["steps"],
        }
    )
    return 0


def cmd_train_orientation(args: argparse.Namespace) -> int:
    from litege_core.train.orientation import OrientationTrainConfig, run_orientation_training

    _ensure_console_logging()
    config = OrientationTrainConfig.load(args.config)
    if args.time_budget is not None:
        config = config.replace(train={"time_budget_minutes": args.time_budget})
    print_json(run_orientation_training(config, out=args.out))
    return 0


def cmd_train_tnet(args: argparse.Namespace) -> int:
    from litege_core.train.tnet import load_tnet_config, run_tnet_training

    _ensure_console_logging()
    config = load_tnet_config(args.config)
    if args.workers is not None:
        config = config.replace(
            data={"workers": args.workers}, train={"loader_workers": args.workers}
        )
    if args.time_budget is not None:
        config = config.replace(train={"time_budget_minutes": args.time_budget})
    if args.init is not None:
        config = config.replace(train={"init": args.init})
    report = run_tnet_training(config, out=args.out)
    alignment = report["alignment"] or {}
    print_json(
        {
            "weights": report["weights"],
            "best_step": report["training"]["best_step"],
            "best_val": report["training"]["best_val"],
            "steps_per_second": report["training"]["steps_per_second"],
            "steps_run": report["training"]["steps_run"],
            "alignment": {
                name: {k: stats[k] for k in ("mean", "std", "median", "max", "n_failures", "n")}
                for name, stats in alignment.items()
                if isinstance(stats, dict)
            },
        }
    )
    return 0


def cmd_train_matching_meshes(args: argparse.Namespace) -> int:
    from litege_core.errors import InputError
    from litege_core.train.matching_from_meshes import (
        DEFAULT_INIT,
        MatchingFolderOptions,
        train_matching_from_meshes,
    )

    if args.out is None:
        raise InputError("--meshes needs --out BUNDLE_DIR (where the bundle is written)")
    _ensure_console_logging()
    options = MatchingFolderOptions(
        meshes=Path(args.meshes),
        out=Path(args.out),
        work=Path(args.work) if args.work else None,
        init=args.init or DEFAULT_INIT,
        time_budget_s=None if args.time_budget is None else 60.0 * args.time_budget,
        workers=args.workers,
        seed=args.seed,
        shapes_per_mesh=args.shapes_per_mesh,
        eval_shapes_per_mesh=args.eval_shapes_per_mesh,
        config=args.config,
        name=args.name,
        poses=args.poses,
        tnet_steps=args.tnet_steps,
    )
    print_json(train_matching_from_meshes(options))
    return 0


def cmd_train_matching(args: argparse.Namespace) -> int:
    from litege_core.errors import InputError
    from litege_core.train.matching import load_matching_config, train_matching

    if args.meshes is not None:
        return cmd_train_matching_meshes(args)
    if args.config is None:
        raise InputError("give --config FILE (configs/matching-*.toml)")
    _ensure_console_logging()
    config = load_matching_config(args.config)
    if args.out is not None:
        config = config.replace(output={"dir": str(args.out)})
    manifest = train_matching(config)
    print_json(
        {
            "bundle": str(Path(config.output.dir) / "bundle"),
            "name": manifest["name"],
            "metrics": manifest["metrics"],
            "chosen_first_pass": manifest["training"]["chosen_first_pass"],
        }
    )
    return 0


class _TrainParser(argparse.ArgumentParser):
    """A ``train`` sub-command parser that needs one of the options named in its
    ``one_of`` default (``--config`` or ``--meshes``), checked at parse time."""

    def parse_known_args(self, args=None, namespace=None):
        parsed, extras = super().parse_known_args(args, namespace)
        one_of = getattr(parsed, "one_of", ())
        if one_of and all(getattr(parsed, name) is None for name in one_of):
            self.error("one of " + " or ".join(f"--{name}" for name in one_of) + " is required")
        return parsed, extras


def add_train_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Register ``train geodesic``, ``train tnet`` and ``train matching`` on ``subparsers``
    (handlers in ``args.handler``, returning an exit code); returns the ``train`` parser."""
    train = subparsers.add_parser("train", help="train networks")
    commands = train.add_subparsers(dest="train_command", required=True, parser_class=_TrainParser)
    geodesic = commands.add_parser(
        "geodesic",
        help="train the geodesic network from a TOML config, or from a folder of meshes "
        "(--meshes), and export a model bundle",
    )
    geodesic.add_argument(
        "--config",
        default=None,
        help="TOML training config (with --meshes: optional, overrides hyper-parameters)",
    )
    geodesic.add_argument(
        "--meshes",
        default=None,
        help="a folder of meshes (obj, ply, off, stl, glb, gltf): ground truth, training, "
        "held-out comparison and a bundle with its model card in --out, in one command",
    )
    geodesic.add_argument("--resume", default=None, help="checkpoint (RUN/checkpoints/last…)")
    geodesic.add_argument(
        "--out",
        default=None,
        help="run directory (overrides output.dir); with --meshes: the bundle directory",
    )
    geodesic.add_argument(
        "--init",
        default=None,
        help="warm start: a shipped model name (quadrupeds, humans) or a bundle directory",
    )
    geodesic.add_argument(
        "--time-budget",
        type=float,
        default=None,
        metavar="MINUTES",
        help="wall-clock budget: with --meshes of the whole command (data, training, "
        "evaluation); with --config of the training (the best checkpoint is exported)",
    )
    folder = geodesic.add_argument_group("--meshes runs")
    folder.add_argument("--workers", type=int, default=1, help="ground-truth processes")
    folder.add_argument("--work", default=None, help="dataset and run directory (OUT/work)")
    folder.add_argument("--seed", type=int, default=0, help="seed of the file split and run")
    folder.add_argument("--name", default=None, help="bundle name (default: the folder name)")
    folder.add_argument(
        "--shapes-per-mesh",
        type=int,
        default=None,
        help="augmented shapes per training file (default 10; with --poses and fewer than 3 "
        "files, 120 in all)",
    )
    folder.add_argument(
        "--eval-shapes-per-mesh",
        type=int,
        default=None,
        help="shapes per val / test file (default 2; with --poses and fewer than 3 files, 8 "
        "in all)",
    )
    folder.add_argument(
        "--vertices", default="2000,4000", help="vertex counts of the remeshed shapes: MIN,MAX"
    )
    folder.add_argument(
        "--poses",
        action="store_true",
        help="pose each rigged, animated glTF file by its own clips (each shape at a time "
        "drawn in one of them; default: every file in its stored pose)",
    )
    folder.add_argument(
        "--solver",
        choices=("exact", "heat", "heat-fine"),
        default="exact",
        help="ground truth: exact MMP, or the heat method (heat-fine: a shorter diffusion "
        "time, half the error at the same cost)",
    )
    geodesic.set_defaults(handler=cmd_train_geodesic, one_of=("config", "meshes"))
    tnet = commands.add_parser(
        "tnet",
        help="train the T-Net (shape orientation for matching) on procedural shapes",
    )
    tnet.add_argument("--config", required=True, help="TOML T-Net config (configs/tnet-*.toml)")
    tnet.add_argument("--out", default=None, help="run directory (overrides output.dir)")
    tnet.add_argument(
        "--workers",
        type=int,
        default=None,
        help="processes generating the shapes and sampling the batches "
        "(overrides data.workers and train.loader_workers)",
    )
    tnet.add_argument(
        "--time-budget",
        type=float,
        default=None,
        metavar="MINUTES",
        help="fit the run to this many minutes of training (train.time_budget_minutes); "
        "the report comes on top",
    )
    tnet.add_argument(
        "--init",
        default=None,
        metavar="TNET",
        help="start from this T-Net (a weights file, or a matching model name or bundle "
        "directory; overrides train.init)",
    )
    tnet.set_defaults(handler=cmd_train_tnet)
    orientation = commands.add_parser(
        "orientation",
        help="train the orientation network (which cube turn of a frame is canonical) that "
        "weighs a matching bundle's candidate frames",
    )
    orientation.add_argument(
        "--config", required=True, help="TOML config (configs/orientation-*.toml)"
    )
    orientation.add_argument("--out", default=None, help="run directory (overrides output.dir)")
    orientation.add_argument(
        "--time-budget",
        type=float,
        default=None,
        metavar="MINUTES",
        help="stop after this many minutes of training (train.time_budget_minutes)",
    )
    orientation.set_defaults(handler=cmd_train_orientation)
    matching = commands.add_parser(
        "matching",
        help="train the matching network (needs a T-Net) and export a matching bundle",
    )
    matching.add_argument(
        "--config",
        default=None,
        help="TOML config (configs/matching-*.toml); with --meshes: optional overrides",
    )
    matching.add_argument(
        "--meshes",
        default=None,
        help="a folder of meshes sharing one topology (same vertex count and faces, vertex i "
        "corresponds): dataset, training and a matching bundle in --out, in one command",
    )
    matching.add_argument(
        "--out",
        default=None,
        help="run directory (overrides output.dir); with --meshes: the bundle directory",
    )
    matching.add_argument(
        "--init",
        default=None,
        help="with --meshes: the matching bundle whose T-Net is reused (default quadrupeds)",
    )
    mfolder = matching.add_argument_group("--meshes runs")
    mfolder.add_argument(
        "--time-budget",
        type=float,
        default=None,
        metavar="MINUTES",
        help="wall-clock budget: the training schedule is sized to the time left after the data",
    )
    mfolder.add_argument("--workers", type=int, default=1, help="ground-truth processes")
    mfolder.add_argument("--work", default=None, help="dataset and run directory (OUT/work)")
    mfolder.add_argument("--seed", type=int, default=0, help="seed of the file split and run")
    mfolder.add_argument("--name", default=None, help="bundle name (default: the folder name)")
    mfolder.add_argument(
        "--shapes-per-mesh",
        type=int,
        default=None,
        help="stretched shapes per training file (default 20; with --poses and fewer than 3 "
        "files, 120 in all)",
    )
    mfolder.add_argument(
        "--eval-shapes-per-mesh",
        type=int,
        default=None,
        help="shapes per val / test file (default 2; with --poses and fewer than 3 files, 8 "
        "in all)",
    )
    mfolder.add_argument(
        "--poses",
        action="store_true",
        help="the files are rigged, animated glTF/GLB files of one topology (one is enough): "
        "each shape is a pose from the file's own clips; with fewer than 3 files every split "
        "holds every file and differs by its poses",
    )
    mfolder.add_argument(
        "--tnet-steps",
        type=int,
        default=None,
        help="fine-tuning steps of the --init T-Net on the collection (default 600, fewer when "
        "30 %% of the budget left after the data does not fit them; 0: keep it as it is)",
    )
    matching.set_defaults(handler=cmd_train_matching, one_of=("config", "meshes"))
    return train


register = add_train_parser

__all__ = [
    "add_train_parser",
    "cmd_train_geodesic",
    "cmd_train_geodesic_meshes",
    "cmd_train_matching",
    "cmd_train_matching_meshes",
    "cmd_train_orientation",
    "cmd_train_tnet",
    "register",
]
