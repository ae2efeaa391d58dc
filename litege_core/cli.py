"""The ``litege`` command line.

Sub-commands:
    litege info FILE          load and validate a shape; print kind, counts, area, content hash
    litege data build ...     build (or resume) a ground-truth geodesic dataset
    litege data verify DIR    check a dataset's shard hashes and arrays
    litege serve [...]        start the HTTP service (needs the ``service`` extra)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Sequence

from litege_core import __version__
from litege_core.errors import LiteGEError, MissingDependencyError
from litege_core.io import load_shape


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
    manifest = build_dataset(spec, directory, factory_for(args.category), workers=args.workers)
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


def _cmd_serve(args: argparse.Namespace) -> int:
    try:
        # The CLI is the one place that reaches from the core into the service package, and
        # only lazily, so the core stays importable without the service extra.
        from service.server import run
    except ImportError as exc:
        raise MissingDependencyError(
            "the service is not installed; install with: pip install 'litege[service]'"
        ) from exc
    run(host=args.host, port=args.port)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="litege", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"litege {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)

    info = commands.add_parser("info", help="validate a shape file and print its summary")
    info.add_argument("file")
    info.add_argument("--kind", choices=["mesh", "point_cloud"], default=None)
    info.set_defaults(handler=_cmd_info)

    data = commands.add_parser("data", help="ground-truth geodesic datasets")
    data_commands = data.add_subparsers(dest="data_command", required=True)
    build = data_commands.add_parser("build", help="build or resume a dataset")
    build.add_argument("--category", choices=["quadruped", "biped"], default="quadruped")
    build.add_argument("--preset", choices=["small", "full"], default="small")
    build.add_argument("--out", default=None, help="directory (default data/CATEGORY-PRESET)")
    build.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    build.set_defaults(handler=_cmd_data_build)
    verify = data_commands.add_parser("verify", help="verify a dataset directory")
    verify.add_argument("directory")
    verify.set_defaults(handler=_cmd_data_verify)

    serve = commands.add_parser("serve", help="start the HTTP service")
    serve.add_argument("--host", default="127.0.0.1")
    serve.add_argument("--port", type=int, default=8000)
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
