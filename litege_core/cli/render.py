"""``litege render`` and ``litege render-match``: PNG figures straight from the library
(Predictor / MatchingModel), offscreen, no server and no display.

::

    litege render dog.obj --source 0 --path 0,1234 -o heat.png    # heatmap + isolines + path
    litege render-match dog.obj cat.obj -o match.png              # colour transfer X → Y
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from litege_core.cli.common import (
    SHAPE_FILE_HELP,
    add_bundle_arguments,
    add_device_argument,
    add_kind_argument,
    parse_indices,
    predictor,
    print_json,
)
from litege_core.errors import InputError
from litege_core.io import load_shape

VIEW_NAMES = ("back", "front", "side", "three_quarter", "top")
"""The names of :data:`litege_core.render.raster.VIEWS`, sorted, spelled out so that building
the ``litege`` parser imports no renderer (a test keeps the two equal)."""


def _size(text: str) -> tuple[int, int]:
    from litege_core.render.figures import parse_size

    try:
        return parse_size(text)
    except ValueError as exc:
        raise InputError(f"--size: {exc}") from None


def _save(image: Any, path: str) -> None:
    try:
        image.save(path, format="PNG", optimize=True)
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror or exc}") from exc


def _pair(text: str) -> tuple[int, int]:
    values = parse_indices(text, "path")
    if len(values) != 2:
        raise InputError(f"--path takes two indices I,J, got {text!r}")
    return values[0], values[1]


def cmd_render(args: argparse.Namespace) -> int:
    from litege_core.render.figures import heatmap_figure

    started = time.perf_counter()
    size = _size(args.size)
    path_ends = _pair(args.path) if args.path else None
    source = args.source if args.source is not None else (path_ends[0] if path_ends else 0)
    shape = load_shape(args.file, kind=args.kind)
    model = predictor(args)
    state = model.register(shape, seed=args.seed)
    distances = np.asarray(model.distance_field(state, source), dtype=np.float64)
    path = model.path(state, *path_ends) if path_ends else None
    name = Path(args.file).name
    subtitle = f"model {model.bundle.name}, OOD score {state.ood_score:.2f}"
    if path_ends is not None and path is not None:
        subtitle += f"; path {path_ends[0]} -> {path_ends[1]}: length {path.length:.4g}"
    figure = heatmap_figure(
        shape.vertices,
        shape.faces,
        distances,
        source_point=shape.vertices[source],
        path=None if path is None else path.points,
        title=f"{name}: geodesic distance from point {source}",
        subtitle=subtitle,
        size=size,
        view=args.view,
        ssaa=args.ssaa,
    )
    _save(figure, args.output)
    summary = {
        "file": str(args.file),
        "model": model.bundle.name,
        "output": str(args.output),
        "size": list(figure.size),
        "source": source,
        "max_distance": float(np.nanmax(distances)),
        "units": "input",
        "ood_score": state.ood_score,
        "seconds": round(time.perf_counter() - started, 2),
    }
    if path_ends is not None and path is not None:
        summary["path"] = {"source": path_ends[0], "target": path_ends[1], "length": path.length}
    print_json(summary)
    return 0


def cmd_render_match(args: argparse.Namespace) -> int:
    from litege_core.matching import MatchingModel
    from litege_core.render.colormap import coordinate_colors
    from litege_core.render.figures import match_figure

    started = time.perf_counter()
    size = _size(args.size)
    shape_x = load_shape(args.x, kind=args.kind)
    shape_y = load_shape(args.y, kind=args.kind)
    model = MatchingModel.load(args.model, device=args.device)
    prepared_x = model.prepare(shape_x, seed=args.seed)
    prepared_y = model.prepare(shape_y, seed=args.seed)
    colors_x = coordinate_colors(np.asarray(prepared_x.aligned, dtype=np.float64))
    result = model.match(prepared_y, prepared_x)  # every point of Y → its match on X
    colors_y = colors_x[np.asarray(result.indices, dtype=np.int64)]
    name_x, name_y = Path(args.x).name, Path(args.y).name
    figure = match_figure(
        shape_x.vertices,
        shape_x.faces,
        colors_x,
        shape_y.vertices,
        shape_y.faces,
        colors_y,
        x_title=f"X: {name_x} (aligned coordinates as colours)",
        y_title=f"Y: {name_y} (colour of its match on X)",
        title=f"Correspondence {name_x} -> {name_y}",
        subtitle=f"matching model {model.name}; {len(result.indices)} points of Y matched",
        size=size,
        view=args.view,
        ssaa=args.ssaa,
    )
    _save(figure, args.output)
    summary = {
        "x": str(args.x),
        "y": str(args.y),
        "model": model.name,
        "output": str(args.output),
        "size": list(figure.size),
        "n_matched": len(result.indices),
        "evaluations": int(result.evaluations),
        "seconds": round(time.perf_counter() - started, 2),
    }
    print_json(summary)
    return 0


def _add_figure_arguments(parser: argparse.ArgumentParser, size: str) -> None:
    parser.add_argument("--view", choices=VIEW_NAMES, default="three_quarter")
    parser.add_argument("--size", default=size, help=f"image size WxH of one view (default {size})")
    parser.add_argument("--ssaa", type=int, default=2, help="supersampling factor (default 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the descriptor samples")
    parser.add_argument("-o", "--output", required=True, help="output .png file")


def register(commands: argparse._SubParsersAction) -> None:
    """Add ``render`` and ``render-match`` to the ``litege`` sub-command parsers."""
    render = commands.add_parser(
        "render",
        help="PNG of the predicted geodesic distance field (heatmap, isolines, optional path)",
        description="Render a distance heatmap (viridis, isolines, colour bar in input units) "
        "from --source, and optionally the geodesic path --path I,J, with the library's "
        "Predictor: offscreen, no server, no display.",
    )
    render.add_argument("file", help=SHAPE_FILE_HELP)
    add_kind_argument(render)
    render.add_argument(
        "--source", type=int, default=None, help="source point (default: I of --path, or 0)"
    )
    render.add_argument("--path", default=None, help="draw the geodesic path I,J")
    add_bundle_arguments(render)
    _add_figure_arguments(render, "640x480")
    render.set_defaults(handler=cmd_render)

    match = commands.add_parser(
        "render-match",
        help="PNG of a correspondence X → Y (colour transfer through the predicted matches)",
        description="Colour X by its normalized aligned coordinates, match every point of Y "
        "on X with the matching model, and draw both side by side (Y in the colour of its "
        "match).",
    )
    match.add_argument("x", help="shape X (mesh or point cloud)")
    match.add_argument("y", help="shape Y (mesh or point cloud)")
    add_kind_argument(match)
    match.add_argument(
        "--model", default="quadrupeds", help="shipped matching model or bundle directory"
    )
    add_device_argument(match)
    _add_figure_arguments(match, "480x400")
    match.set_defaults(handler=cmd_render_match)


__all__ = ["VIEW_NAMES", "cmd_render", "cmd_render_match", "register"]
