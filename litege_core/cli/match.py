"""``litege match X Y``: for each query point of X, the matched point of Y."""

from __future__ import annotations

import argparse

from litege_core.cli.common import (
    add_device_argument,
    add_kind_argument,
    add_precision_argument,
    parse_indices,
    print_json,
    save_npy,
)
from litege_core.io import load_shape


def cmd_match(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from litege_core.device import resolve_device
    from litege_core.matching import MatchingModel

    queries = None if args.queries.strip() == "all" else parse_indices(args.queries, "queries")
    start = time.perf_counter()
    source = load_shape(args.x_file, kind=args.x_kind)
    target = load_shape(args.y_file, kind=args.y_kind)
    model = MatchingModel.load(
        args.bundle or args.model, resolve_device(args.device), args.precision
    )
    x, y = model.prepare_many(
        [source, target], seed=args.seed, scaling=args.scaling, frames=args.frames
    )
    from litege_core.matching.refine import ZoomOutSettings

    chosen = {
        name: value
        for name, value in (
            ("smoothing", args.smoothing),
            ("registration_rounds", args.registration_rounds),
            ("distortion_tolerance", args.distortion_tolerance),
        )
        if value is not None
    }
    zoomout = ZoomOutSettings(**chosen)
    result = model.match(x, y, queries, beams=args.beams, refine=args.refine, zoomout=zoomout)
    save_npy(args.output, result.indices.astype(np.int64))
    print_json(
        {
            "x_file": str(args.x_file),
            "y_file": str(args.y_file),
            "model": model.name,
            "output": str(args.output),
            "n_queries": int(result.indices.size),
            "scaling": [x.scaling, y.scaling],
            "frames": [x.frame, y.frame],
            "frame_checks": [x.frame_check, y.frame_check],
            "refinement": result.refinement,
            "evaluations": result.evaluations,
            "mean_predicted_distance": float(result.distance.mean()),
            "seconds": round(time.perf_counter() - start, 3),
        }
    )
    return 0


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``match``."""
    match = commands.add_parser(
        "match",
        help="match points of X to Y: int64 (N,) indices into Y's vertices/points",
        description="For each query point of X, the vertex/point of Y minimizing the predicted "
        "cross-shape geodesic (coarse-to-fine search), in Y's original indexing.",
    )
    match.add_argument("x_file", help="source shape X (mesh or point cloud file)")
    match.add_argument("y_file", help="target shape Y (mesh or point cloud file)")
    match.add_argument("--queries", default="all", help="'all' (default) or i,j,... of X")
    which = match.add_mutually_exclusive_group()
    which.add_argument("--model", default="quadrupeds", help="shipped matching model name")
    which.add_argument("--bundle", default=None, help="matching bundle directory")
    add_device_argument(match)
    add_precision_argument(match)
    add_kind_argument(match, "--x-kind")
    add_kind_argument(match, "--y-kind")
    match.add_argument(
        "--scaling",
        default="auto",
        choices=["auto", "unit_area", "broken_mesh", "cloud_8k", "cloud_500"],
        help="how both shapes are scaled (auto: from mesh boundary / cloud size)",
    )
    match.add_argument("--beams", type=int, default=None, help="candidates kept per coarse tier")
    match.add_argument(
        "--frames",
        choices=["auto", "tnet", "judged", "intrinsic"],
        default="auto",
        help="canonical frame: the T-Net's, or (judged) where the T-Net's turned runs disagree "
        "the best of it and the principal-axis frames, judged by the matching network against "
        "reference animals, or (intrinsic; meshes, needs pyFM, seconds per shape) where those "
        "runs disagree the frame of reference animals' functional maps onto the mesh (auto: "
        "the model's default)",
    )
    match.add_argument(
        "--refine",
        choices=["none", "zoomout", "zoomout-hybrid"],
        default="none",
        help="meshes only: refine the learned map with ZoomOut (needs pyFM, the 'eval' extra)",
    )
    match.add_argument(
        "--smoothing",
        type=float,
        default=None,
        help="with --refine: weight of the smooth displacement fitted to the refined map and "
        "then registered to the target's surface (unit-area frame, area² units; 0: the "
        "spectral map alone, neither fit nor registration; default: the library's)",
    )
    match.add_argument(
        "--registration-rounds",
        type=int,
        default=None,
        help="with --refine: closest-point rounds registering that displacement to the "
        "target's surface (0: the fitted displacement alone, which suits near-isometric pairs "
        "such as one body in two poses; default: the library's)",
    )
    match.add_argument(
        "--distortion-tolerance",
        type=float,
        default=None,
        help="with --refine zoomout-hybrid: keep the smoothed map only where its geodesic "
        "distortion is at most this multiple of the spectral map's (inf: always; default: "
        "the model's category default, 1.1 for humans, inf for quadrupeds)",
    )
    match.add_argument("--seed", type=int, default=0, help="seed of the samples")
    match.add_argument("-o", "--output", required=True, help="output .npy file")
    match.set_defaults(handler=cmd_match)


__all__ = ["cmd_match", "register"]
