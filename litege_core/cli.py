"""The ``litege`` command line.

Sub-commands:
    litege info FILE          load and validate a shape; print kind, counts, area, content hash
    litege geodesic FILE      predicted geodesic distances (sources × targets) to a .npy file
    litege path FILE          predicted geodesic path (polyline) to a .npy file
    litege match X Y          for each query point of X, the matched point of Y (.npy, int64)
    litege data build ...     build (or resume) a ground-truth geodesic dataset
    litege data verify DIR    check a dataset's shard hashes and arrays
    litege train geodesic     train a geodesic model from a TOML config
    litege train tnet         train the T-Net (shape orientation for matching)
    litege train matching     train the matching network and export a matching bundle
    litege eval geodesic      evaluate a model against the classical baselines
    litege eval matching      evaluate a matching model against NN and ZoomOut baselines
    litege render FILE        PNG heatmap of predicted distances (isolines, path), offscreen
    litege render-match X Y   PNG of a correspondence X → Y (colour transfer), offscreen
    litege serve [...]        start the REST + gRPC service (needs the ``service`` extra)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from litege_core import __version__
from litege_core.errors import InputError, LiteGEError, MissingDependencyError
from litege_core.io import load_shape

if TYPE_CHECKING:
    from litege_core.predictor import Predictor


def _cmd_info(args: argparse.Namespace) -> int:
    shape = load_shape(args.file, kind=args.kind)
    report = {
        "file": str(args.file),
        "kind": shape.kind.value,
        "n_points": shape.n_points,
        "n_faces": shape.n_faces,
        "content_hash": shape.content_hash,
        "bbox_min": shape.vertices.min(axis=0).tolist(),
        "bbox_max": shape.vertices.max(axis=0).tolist(),
    }
    if shape.is_mesh:
        report["area"] = shape.area
    print(json.dumps(report, indent=2))
    return 0


def _cmd_data_build(args: argparse.Namespace) -> int:
    from litege_core.datasets import build_dataset, preset
    from litege_core.datasets.factories import factory_for

    spec = preset(args.preset, args.category)
    directory = args.out or f"data/{spec.name}"
    manifest = build_dataset(
        spec, directory, factory_for(args.category), workers=args.workers, solver=args.solver
    )
    print(
        json.dumps(
            {
                "directory": str(directory),
                "counts": manifest["counts"],
                "compute_seconds": round(manifest["compute_seconds"], 1),
            },
            indent=2,
        )
    )
    return 0


def _cmd_data_verify(args: argparse.Namespace) -> int:
    from litege_core.datasets import verify_dataset

    print(json.dumps(verify_dataset(args.directory), indent=2))
    return 0


def _parse_indices(text: str, what: str) -> list[int]:
    """``"0,17,42"`` → ``[0, 17, 42]``; anything else is an :class:`InputError`."""
    items = [item.strip() for item in text.split(",")]
    try:
        return [int(item) for item in items]
    except ValueError:
        raise InputError(
            f"--{what} must be comma-separated integer indices, got {text!r}"
        ) from None


def _predictor(args: argparse.Namespace) -> Predictor:
    from litege_core.bundle import DEFAULT_MODEL, load_bundle, load_shipped
    from litege_core.device import resolve_device
    from litege_core.predictor import Predictor

    device = resolve_device(args.device)
    if args.bundle is not None:
        bundle = load_bundle(args.bundle, device)
    else:
        bundle = load_shipped(args.model or DEFAULT_MODEL, device)
    return Predictor(bundle, device)


def _save_npy(path: str, array) -> None:
    import numpy as np

    try:
        with open(path, "wb") as handle:  # exactly this path (np.save would add ".npy")
            np.save(handle, array)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror}") from exc


def _cmd_geodesic(args: argparse.Namespace) -> int:
    import numpy as np

    sources = _parse_indices(args.sources, "sources")
    targets = None if args.targets.strip() == "all" else _parse_indices(args.targets, "targets")
    shape = load_shape(args.file, kind=args.kind)
    predictor = _predictor(args)
    state = predictor.register(shape, seed=args.seed)
    distances = predictor.distances(state, sources, targets).astype(np.float32)
    _save_npy(args.output, distances)
    summary = {
        "file": str(args.file),
        "model": predictor.bundle.name,
        "output": str(args.output),
        "shape": list(distances.shape),
        "units": "input",
        "ood_score": state.ood_score,
    }
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_path(args: argparse.Namespace) -> int:
    import numpy as np

    shape = load_shape(args.file, kind=args.kind)
    predictor = _predictor(args)
    state = predictor.register(shape, seed=args.seed)
    path = predictor.path(state, args.source, args.target)
    _save_npy(args.output, np.asarray(path.points, dtype=np.float32))
    summary = {
        "file": str(args.file),
        "model": predictor.bundle.name,
        "output": str(args.output),
        "n_points": int(path.points.shape[0]),
        "length": path.length,
        "predicted_distance": path.predicted_distance,
        "n_steps": path.n_steps,
        "converged": path.converged,
    }
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_match(args: argparse.Namespace) -> int:
    import time

    import numpy as np

    from litege_core.device import resolve_device
    from litege_core.matching import MatchingModel

    queries = None if args.queries.strip() == "all" else _parse_indices(args.queries, "queries")
    start = time.perf_counter()
    source = load_shape(args.x_file, kind=args.x_kind)
    target = load_shape(args.y_file, kind=args.y_kind)
    model = MatchingModel.load(args.bundle or args.model, resolve_device(args.device))
    x, y = model.prepare_many([source, target], seed=args.seed, scaling=args.scaling)
    result = model.match(x, y, queries, beams=args.beams)
    _save_npy(args.output, result.indices.astype(np.int64))
    summary = {
        "x_file": str(args.x_file),
        "y_file": str(args.y_file),
        "model": model.name,
        "output": str(args.output),
        "n_queries": int(result.indices.size),
        "scaling": [x.scaling, y.scaling],
        "evaluations": result.evaluations,
        "mean_predicted_distance": float(result.distance.mean()),
        "seconds": round(time.perf_counter() - start, 3),
    }
    print(json.dumps(summary, indent=2))
    return 0


def _add_bundle_arguments(parser: argparse.ArgumentParser) -> None:
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--model", default=None, help="shipped model name (default: quadrupeds)")
    which.add_argument("--bundle", default=None, help="model bundle directory")
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto")


def _add_model_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="mesh or point-cloud file (OBJ, PLY, OFF, STL, GLB, XYZ, NPY)")
    parser.add_argument("--kind", choices=["mesh", "point_cloud"], default=None)
    _add_bundle_arguments(parser)
    parser.add_argument("--seed", type=int, default=0, help="seed of the descriptor samples")
    parser.add_argument("-o", "--output", required=True, help="output .npy file")


def _cmd_eval_geodesic(args: argparse.Namespace) -> int:
    from pathlib import Path

    from litege_core.evaluation.geodesic import (
        SETTINGS,
        evaluate,
        real_eval_shapes,
        results_table,
        synthetic_eval_shapes,
    )

    predictor = _predictor(args)
    shapes = []
    if args.dataset:
        shapes += synthetic_eval_shapes(args.dataset, args.shapes)
    eval_root = Path(args.eval_data)
    real = {
        "tosca": ("tosca_5k", "TOSCA animals (real)"),
        "faust": ("faust_5k", "FAUST humans (real)"),
    }
    for key in args.real:
        folder, group = real[key]
        paths = sorted((eval_root / folder).glob("*.off"))[: args.real_shapes]
        if not paths:
            print(f"litege: no {key} shapes under {eval_root / folder}; skipped", file=sys.stderr)
        shapes += real_eval_shapes(paths, group, args.sources)
    settings = args.settings.split(",") if args.settings else SETTINGS
    results = evaluate(shapes, predictor, settings, seed=args.seed)
    print(results_table(results))
    return 0


def _split_list(text: str | None, allowed: Sequence[str], what: str) -> list[str]:
    """``"a,b"`` → ``["a", "b"]`` checked against ``allowed`` (``""`` → none)."""
    items = [item.strip() for item in (text or "").split(",") if item.strip()]
    unknown = [item for item in items if item not in allowed]
    if unknown:
        raise InputError(f"--{what}: unknown {unknown}; expected a subset of {list(allowed)}")
    return items


def _cmd_eval_matching(args: argparse.Namespace) -> int:
    from litege_core.evaluation.matching import (
        load_matching_model,
        machine_header,
        results_table,
        run_matching_evaluation,
    )
    from litege_core.evaluation.matching_data import REAL_SETS, SYNTHETIC_SETTINGS

    settings = _split_list(args.settings, SYNTHETIC_SETTINGS, "settings")
    real = _split_list(args.real, REAL_SETS, "real")
    baselines = _split_list(args.baselines, ("nn", "zoomout"), "baselines")
    model = load_matching_model(args.model, args.device)

    def log(message: str) -> None:
        print(f"litege: {message}", file=sys.stderr, flush=True)

    results = run_matching_evaluation(
        model,
        settings=settings,
        real=real,
        eval_data=args.eval_data,
        n_pairs=args.pairs,
        n_queries=args.queries,
        baselines=baselines,
        seed=args.seed,
        device=args.device,
        rotate_input=not args.no_rotate,
        workers=args.workers,
        log=log,
    )
    meta = {
        "model": f"{model.name} ({model.content_hash[:12]})",
        "device": str(model.device),
        "pairs/set": str(args.pairs),
        "queries/pair": str(args.queries),
        "seed": str(args.seed),
    }
    header = machine_header(meta)
    print(results_table(results, header))
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8") as handle:
                json.dump(
                    {"meta": header, "results": [r.to_dict() for r in results]}, handle, indent=2
                )
        except OSError as exc:
            raise InputError(f"cannot write {args.json}: {exc.strerror}") from exc
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    try:
        # The CLI is the one place that reaches from the core into the service package, and
        # only lazily, so the core stays importable without the service extra.
        from service.server import run
    except ImportError as exc:
        raise MissingDependencyError(
            "the service is not installed; install with: pip install 'litege[service]'"
        ) from exc
    run(args.host, args.port, args.grpc_port, rest=not args.no_rest, grpc=not args.no_grpc)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="litege", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"litege {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    info = commands.add_parser("info", help="validate a shape file and print its summary")
    info.add_argument("file")
    info.add_argument("--kind", choices=["mesh", "point_cloud"], default=None)
    info.set_defaults(handler=_cmd_info)

    geodesic = commands.add_parser(
        "geodesic", help="predicted geodesic distances, float32 (S, T), in the input's units"
    )
    _add_model_arguments(geodesic)
    geodesic.add_argument("--sources", required=True, help="comma-separated indices: 0,17,42")
    geodesic.add_argument("--targets", default="all", help="'all' (default) or i,j,...")
    geodesic.set_defaults(handler=_cmd_geodesic)

    path = commands.add_parser(
        "path", help="predicted geodesic path, float32 (L, 3) polyline target → source"
    )
    _add_model_arguments(path)
    path.add_argument("--source", required=True, type=int, help="source vertex/point index")
    path.add_argument("--target", required=True, type=int, help="target vertex/point index")
    path.set_defaults(handler=_cmd_path)

    data = commands.add_parser("data", help="ground-truth geodesic datasets")
    data_commands = data.add_subparsers(dest="data_command", required=True)
    build = data_commands.add_parser("build", help="build or resume a dataset")
    build.add_argument("--category", choices=["quadruped", "biped"], default="quadruped")
    build.add_argument("--preset", choices=["small", "full", "matching"], default="small")
    build.add_argument("--out", default=None, help="directory (default data/CATEGORY-PRESET)")
    build.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    build.add_argument(
        "--solver",
        choices=["exact", "heat"],
        default="exact",
        help="ground-truth geodesics: exact MMP (default) or the ~80× faster heat method",
    )
    build.set_defaults(handler=_cmd_data_build)
    verify = data_commands.add_parser("verify", help="verify a dataset directory")
    verify.add_argument("directory")
    verify.set_defaults(handler=_cmd_data_verify)

    evaluation = commands.add_parser("eval", help="evaluate a model against baselines")
    eval_commands = evaluation.add_subparsers(dest="eval_command", required=True)
    eval_geo = eval_commands.add_parser("geodesic", help="geodesic error vs baselines")
    _add_bundle_arguments(eval_geo)
    eval_geo.add_argument("--seed", type=int, default=0)
    eval_geo.add_argument("--dataset", help="dataset directory whose test split is evaluated")
    eval_geo.add_argument("--shapes", type=int, default=20, help="synthetic shapes to evaluate")
    eval_geo.add_argument("--real", nargs="*", default=[], choices=["tosca", "faust"])
    eval_geo.add_argument("--real-shapes", type=int, default=32)
    eval_geo.add_argument("--eval-data", default="../shared/eval-data")
    eval_geo.add_argument("--sources", type=int, default=16, help="sources per real shape")
    eval_geo.add_argument("--settings", default=None, help="comma-separated subset of settings")
    eval_geo.set_defaults(handler=_cmd_eval_geodesic)

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
    match.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto")
    match.add_argument("--x-kind", choices=["mesh", "point_cloud"], default=None)
    match.add_argument("--y-kind", choices=["mesh", "point_cloud"], default=None)
    match.add_argument(
        "--scaling",
        default="auto",
        choices=["auto", "unit_area", "broken_mesh", "cloud_8k", "cloud_500"],
        help="how both shapes are scaled (auto: from mesh boundary / cloud size)",
    )
    match.add_argument("--beams", type=int, default=None, help="candidates kept per coarse tier")
    match.add_argument("--seed", type=int, default=0, help="seed of the samples")
    match.add_argument("-o", "--output", required=True, help="output .npy file")
    match.set_defaults(handler=_cmd_match)

    eval_match = eval_commands.add_parser(
        "matching", help="matching error, AUC, flips and time vs NN and ZoomOut baselines"
    )
    eval_match.add_argument(
        "--model", default="quadrupeds", help="matching model: shipped name or bundle directory"
    )
    eval_match.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto")
    eval_match.add_argument("--pairs", type=int, default=20, help="pairs per setting / real set")
    eval_match.add_argument("--queries", type=int, default=100, help="query points per pair")
    eval_match.add_argument(
        "--settings",
        default="template,remesh5k,aniso10k,broken40,cloud8k,cloud500",
        help="comma-separated synthetic settings ('' for none)",
    )
    eval_match.add_argument(
        "--real",
        default="tosca,tosca-landmarks,faust",
        help="comma-separated real sets, read from --eval-data when present ('' for none)",
    )
    eval_match.add_argument("--eval-data", default="../shared/eval-data")
    eval_match.add_argument("--baselines", default="nn,zoomout", help="nn, zoomout ('' for none)")
    eval_match.add_argument("--seed", type=int, default=0)
    eval_match.add_argument(
        "--no-rotate", action="store_true", help="keep inputs in their frame (default: random)"
    )
    eval_match.add_argument(
        "--workers", type=int, default=1, help="processes for ground-truth geodesics"
    )
    eval_match.add_argument("--json", default=None, help="also write the results as JSON")
    eval_match.set_defaults(handler=_cmd_eval_matching)

    from litege_core.train.command import add_train_parser

    add_train_parser(commands)

    from litege_core.render.commands import add_render_parsers

    add_render_parsers(commands)  # render, render-match (litege_core/render/commands.py)

    serve = commands.add_parser(
        "serve",
        help="start the REST and gRPC service",
        description="Start the REST (FastAPI) and gRPC servers in one process. Every setting "
        "comes from LITEGE_* environment variables (see README); these flags override them.",
    )
    serve.add_argument("--host", default=None, help="bind address (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=None, help="REST port (default 8000)")
    serve.add_argument("--grpc-port", type=int, default=None, help="gRPC port (default 50051)")
    serve.add_argument("--no-rest", action="store_true", help="serve gRPC only")
    serve.add_argument("--no-grpc", action="store_true", help="serve REST only")
    serve.set_defaults(handler=_cmd_serve)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except LiteGEError as exc:
        print(f"litege: error [{exc.code}]: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
