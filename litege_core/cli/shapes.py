"""``litege info``, ``litege geodesic`` and ``litege path``: one shape file in, a summary on
stdout and (for the last two) a ``.npy`` file out."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from litege_core.cli.common import (
    ROUTES,
    add_fusion_argument,
    add_head_argument,
    add_kind_argument,
    add_model_arguments,
    numpy_predictor,
    parse_indices,
    predictor,
    print_json,
    save_npy,
    with_model,
)
from litege_core.errors import InputError
from litege_core.io import load_shape


def cmd_info(args: argparse.Namespace) -> int:
    shape = load_shape(args.file, kind=args.kind)
    report: dict[str, Any] = {
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
    if Path(args.file).suffix.lower() in {".glb", ".gltf"}:
        report["rig"] = _rig_report(str(args.file))
    print_json(report)
    return 0


def _rig_report(path: str) -> dict[str, Any] | None:
    """The clips and joints of a rigged, animated glTF, which training on a folder poses
    (:mod:`litege_core.synth.folder`); ``None`` for a glTF it keeps in its stored pose."""
    from litege_core.synth.folder import rigged_model

    rig = rigged_model(path)
    if rig is None:
        return None
    return {"clips": [clip.name for clip in rig.clips], "joints": int(rig.mesh.joint_nodes.size)}


METHODS = ("learned", "heat", "exact", "graph")


def _classical(args: argparse.Namespace, shape: Any) -> Any:
    from litege_core.engines import ClassicalSolver

    return ClassicalSolver(shape, args.method, max_exact_vertices=args.max_exact_vertices)


RUNTIMES = ("auto", "numpy", "torch")


def _numpy_runtime(args: argparse.Namespace) -> bool:
    """Whether ``litege geodesic`` runs the torch-free :class:`~litege_core.learned.
    numpy_predictor.NumpyPredictor`: ``--runtime numpy``, or ``auto`` (default) on a CPU (it
    implements either head, any lattice and every fusion). Raises :class:`InputError` for
    ``--runtime numpy`` on another device."""
    if args.runtime == "numpy" and args.device != "cpu":
        raise InputError(f"--runtime numpy does not implement --device {args.device}")
    return args.runtime == "numpy" or (args.runtime == "auto" and args.device == "cpu")


AUTO_MODEL = "auto"
"""``--model auto``: every shipped model registers the shape and
:func:`~litege_core.learned.routing.choose_model` picks one (as the service's ``auto``)."""


def _auto_models() -> list[str]:
    """The shipped geodesic models, the default one first (it wins ties)."""
    from litege_core.learned.manifest import DEFAULT_MODEL, shipped_bundles

    return sorted(shipped_bundles(), key=lambda name: name != DEFAULT_MODEL)


def cmd_geodesic(args: argparse.Namespace) -> int:
    import numpy as np

    sources = parse_indices(args.sources, "sources")
    targets = None if args.targets.strip() == "all" else parse_indices(args.targets, "targets")
    shape = load_shape(args.file, kind=args.kind)
    report: dict[str, Any] = {"file": str(args.file), "method": args.method}
    if args.method == "learned":
        numpy_runtime = _numpy_runtime(args)
        make = numpy_predictor if numpy_runtime else predictor
        runtimes: dict[str, Any] = {}  # model → runtime (one, or every shipped one for auto)
        if args.model == AUTO_MODEL and args.bundle is None:
            for name in _auto_models():
                runtimes[name] = make(with_model(args, name))
        else:
            runtimes[args.model or ""] = make(args)
        states = {name: r.register(shape, seed=args.seed) for name, r in runtimes.items()}
        chosen = next(iter(runtimes))
        if len(runtimes) > 1:
            from litege_core.learned.routing import choose_model

            scores = {name: float(state.ood_score) for name, state in states.items()}
            agreements = {name: runtimes[name].agreement(states[name]) for name in runtimes}
            chosen = choose_model(scores, agreements)
            report["model_scores"] = scores
        runtime, state = runtimes[chosen], states[chosen]
        distances = np.asarray(runtime.distances(state, sources, targets), dtype=np.float32)
        report.update(
            engine="learned",
            runtime="numpy" if numpy_runtime else "torch",
            model=runtime.name if numpy_runtime else runtime.bundle.name,
            head=runtime.head,
            fusion="none" if runtime.fusion is None else "graph",
            ood_score=state.ood_score,
        )
        if numpy_runtime:
            report["lattice"] = runtime.lattice
    else:
        solver = _classical(args, shape)
        distances = solver.distances(sources, targets)
        report["engine"] = solver.engine
    save_npy(args.output, distances)
    report.update(output=str(args.output), shape=list(distances.shape), units="input")
    print_json(report)
    return 0


def cmd_path(args: argparse.Namespace) -> int:
    import numpy as np

    shape = load_shape(args.file, kind=args.kind)
    report: dict[str, Any] = {"file": str(args.file), "method": args.method}
    if args.method == "learned":
        model = predictor(args)
        state = model.register(shape, seed=args.seed)
        path = model.path(state, args.source, args.target, route=args.route)
        points = path.points
        report.update(
            engine="learned",
            model=model.bundle.name,
            head=model.head,
            fusion="none" if model.fusion is None else "graph",
            route=args.route,
            length=path.length,
            predicted_distance=path.predicted_distance,
            n_steps=path.n_steps,
            converged=path.converged,
            segments=[list(segment) for segment in path.segments],
        )
    else:
        solver = _classical(args, shape)
        found = solver.path(args.source, args.target)
        points = found.points
        report.update(
            engine=found.engine,
            length=found.length,
            distance=found.distance,
            segments=[list(segment) for segment in found.segments],
        )
    save_npy(args.output, np.asarray(points, dtype=np.float32))
    report.update(output=str(args.output), n_points=int(points.shape[0]))
    print_json(report)
    return 0


def _add_method_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--method",
        choices=METHODS,
        default="learned",
        help="learned (default: the model), heat (mesh heat method; point-cloud heat on "
        "clouds), exact (MMP, meshes only) or graph (kNN-graph Dijkstra)",
    )
    parser.add_argument(
        "--max-exact-vertices",
        type=int,
        default=20_000,
        help="refuse --method exact above this many vertices (default 20000)",
    )


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``info``, ``geodesic`` and ``path``."""
    info = commands.add_parser("info", help="validate a shape file and print its summary")
    info.add_argument("file")
    add_kind_argument(info)
    info.set_defaults(handler=cmd_info)

    geodesic = commands.add_parser(
        "geodesic",
        help="geodesic distances, float32 (S, T), in the input's units",
        description="Geodesic distances, float32 (S, T), in the input's units. --model auto: "
        "every shipped model registers the shape and the one of lowest OOD score, weighed with "
        "its network-to-graph agreement, answers (as the service's auto); the report names it "
        "and gives every model_scores.",
    )
    add_model_arguments(geodesic)
    geodesic.add_argument("--sources", required=True, help="comma-separated indices: 0,17,42")
    geodesic.add_argument("--targets", default="all", help="'all' (default) or i,j,...")
    geodesic.add_argument(
        "--runtime",
        choices=RUNTIMES,
        default="auto",
        help="auto (default: numpy on a CPU, else torch), numpy (torch-free, CPU only: the "
        "fastest start) or torch",
    )
    add_head_argument(geodesic)
    add_fusion_argument(geodesic)
    _add_method_arguments(geodesic)
    geodesic.set_defaults(handler=cmd_geodesic)

    path = commands.add_parser(
        "path", help="geodesic path on the surface, float32 (L, 3) polyline source → target"
    )
    add_model_arguments(path)
    path.add_argument("--source", required=True, type=int, help="source vertex/point index")
    path.add_argument("--target", required=True, type=int, help="target vertex/point index")
    add_head_argument(path)
    add_fusion_argument(path)
    path.add_argument(
        "--route",
        choices=ROUTES,
        default="auto",
        help="learned paths: auto (default: surface where the model fuses, as the shipped ones "
        "do, else learned), learned (a walk down the network's distance, finished on the "
        "surface where it stalls) or surface (the on-surface route the fused distances follow: "
        "an edge-flip geodesic on a mesh, the vetoed k-NN graph's shortest path on a cloud)",
    )
    _add_method_arguments(path)
    path.set_defaults(handler=cmd_path)


__all__ = ["RUNTIMES", "cmd_geodesic", "cmd_info", "cmd_path", "register"]
