"""The shortcuts the fused cloud graph keeps, and what could tell them apart (issue 14, diagnosis).

For every shape of a set and cloud setting this script builds the shipped fusion's cloud graph
(the mutual k-NN graph, normal cut, network veto where the calibration's OOD limit lets it run)
and measures every kept edge against its true geodesic
(:func:`~litege_core.evaluation.cloud_edges.oracle_edges`, its lower bound: what the triangle
inequality leaves at least). A kept edge whose geodesic surely exceeds ``--stretch`` × its chord
is a *shortcut* (parts that touch, or a thin part crossed). It reports, per set and setting:

* how many kept edges are shortcuts, and the graph error (``graph / b``, GT mean 100) with them
  and with them removed (an oracle: what a veto that saw them would give);
* four edge features, as the median over shortcuts and over the other kept edges, and as the
  AUC with which each alone ranks shortcuts above the other edges (0.5: blind): the chord over
  the cloud's median 8-NN spacing, the *thickness* at the thicker end (``sqrt(λ_min / λ_max)``
  of its 16-NN covariance, :func:`~litege_core.learned.cloud_surface.local_surface`), the
  chord's normal cosine ``|n · ĉ|`` (what the normal cut reads) and the veto head's predicted
  geodesic over the chord (what the network veto reads);
* with ``--frustration``, a candidate rule: the normals oriented over the cloud's 16-NN graph
  (the leading eigenvector of the signed adjacency ``n_i · n_j``), every kept edge cut whose
  oriented normals point apart (``s_i s_j n_i · n_j < 0``: two sheets facing each other), its
  recall of the shortcuts, its cuts of other edges and its graph error.

``--render DIR`` draws, for the ``--worst`` shapes, the mesh beside the cloud coloured by how
many shortcuts leave each point (PNGs; research-only meshes: keep them out of the repository).
Every number comes from this script::

    python scripts/shortcut_edges.py --sets tosca --settings cloud_2000,cloud_300,noise_0.01
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.evaluation.cloud_edges import kept_edges
from litege_core.evaluation.geodesic import EvalShape, named_eval_set
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import Predictor
from litege_core.learned.bundle import load_model
from litege_core.learned.cloud_surface import normal_cosines
from litege_core.metrics import ranking_auc

FEATURES = ("chord / spacing", "thickness", "normal cosine", "veto ratio")
ORIENTATION_NEIGHBOURS = 16


@dataclasses.dataclass
class ShapeEdges:
    """One shape's kept cloud edges: features ``(E, 4)`` (:data:`FEATURES`), ``shortcut``
    ``(E,)``, the frustration rule's cuts ``(E,)`` (or ``None``) and the graph errors."""

    name: str
    features: NDArray
    shortcut: NDArray
    frustrated: NDArray | None
    errors: dict[str, float]
    counts: NDArray  # (P,) shortcuts leaving each point
    points: NDArray  # (P, 3) the input cloud


def oriented_signs(points: NDArray, normals: NDArray, neighbours: NDArray) -> NDArray:
    """``(P,)`` ±1 per point: the signs that best orient the unoriented ``normals`` over the
    k-NN graph ``neighbours`` ``(P, k)`` (the leading eigenvector of the symmetric signed
    adjacency ``n_i · n_j``, a spectral relaxation of maximising the agreement)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import eigsh

    n, k = neighbours.shape
    rows = np.repeat(np.arange(n), k)
    cols = neighbours.reshape(-1)
    dots = np.einsum("ij,ij->i", normals[rows], normals[cols])
    adjacency = sp.coo_array((dots, (rows, cols)), shape=(n, n)).tocsr()
    adjacency = (adjacency + adjacency.T) * 0.5
    _, vectors = eigsh(adjacency, k=1, which="LA", v0=np.ones(n))
    return np.where(vectors[:, 0] >= 0, 1.0, -1.0)


def shape_edges(
    predictor: Predictor, shape: EvalShape, setting: str, stretch: float, frustration: bool
) -> ShapeEdges:
    """Build the shipped cloud graph of one shape and measure its kept edges."""
    edges = kept_edges(predictor, shape, setting, stretch, neighbours=ORIENTATION_NEIGHBOURS)
    i, j, chord, shortcut = edges.i, edges.j, edges.chord, edges.shortcut
    features = np.column_stack(
        [
            chord / edges.spacing,
            np.maximum(edges.thickness[i], edges.thickness[j]),
            normal_cosines(edges.points, edges.normals, i, j, chord),
            edges.predicted / np.maximum(chord, 1e-12),
        ]
    )
    errors = {"shipped": edges.graph_error(), "oracle": edges.graph_error(~shortcut)}
    frustrated = None
    if frustration:
        nearest = edges.nearest[:, :ORIENTATION_NEIGHBOURS]
        signs = oriented_signs(edges.points, edges.normals, nearest)
        agreement = signs[i] * signs[j] * np.einsum("ij,ij->i", edges.normals[i], edges.normals[j])
        frustrated = agreement < 0.0
        errors["frustration"] = edges.graph_error(~frustrated)
    n = edges.points.shape[0]
    counts = np.bincount(i[shortcut], minlength=n) + np.bincount(j[shortcut], minlength=n)
    return ShapeEdges(
        shape.name, features, shortcut, frustrated, errors, counts, edges.cloud.points.copy()
    )


def print_setting(results: list[ShapeEdges], setting: str, frustration: bool, worst: int) -> None:
    features = np.concatenate([r.features for r in results])
    shortcut = np.concatenate([r.shortcut for r in results])
    mean = {k: float(np.nanmean([r.errors[k] for r in results])) for k in results[0].errors}
    print(
        f"\n**{setting}**: {shortcut.sum()} shortcuts among {shortcut.size} kept edges "
        f"({100 * shortcut.mean():.1f} %); graph error {mean['shipped']:.2f} with them, "
        f"{mean['oracle']:.2f} without (oracle)"
        + (f", {mean['frustration']:.2f} after the frustration cut" if frustration else "")
        + "\n"
    )
    print("| feature | shortcuts: median | other edges: median | AUC |")
    print("|---|---:|---:|---:|")
    for column, name in enumerate(FEATURES):
        values = features[:, column]
        print(
            f"| {name} | {np.median(values[shortcut]):.2f} | {np.median(values[~shortcut]):.2f} "
            f"| {ranking_auc(values, shortcut):.2f} |"
        )
    if frustration:
        cut = np.concatenate([r.frustrated for r in results if r.frustrated is not None])
        hits = int(np.sum(cut & shortcut))
        print(
            f"\nfrustration cut: {cut.sum()} edges ({100 * cut.mean():.1f} %), "
            f"{hits} of them shortcuts: recall {hits / max(shortcut.sum(), 1):.2f}, "
            f"precision {hits / max(cut.sum(), 1):.2f}"
        )
    order = sorted(results, key=lambda r: -r.errors["shipped"])[:worst]
    if order:
        columns = ["shipped", "oracle"] + (["frustration"] if frustration else [])
        print(
            "\n| shape | shortcuts | share | " + " | ".join(f"graph: {c}" for c in columns) + " |"
        )
        print("|---|---:|---:|" + "---:|" * len(columns))
        for r in order:
            cells = " | ".join(f"{r.errors[c]:.2f}" for c in columns)
            print(f"| {r.name} | {r.shortcut.sum()} | {100 * r.shortcut.mean():.1f} % | {cells} |")


def render(
    results: list[ShapeEdges], shapes: dict[str, EvalShape], out: Path, setting: str, worst: int
) -> None:
    from litege_core.render.figures import render_surface, side_by_side, titled

    out.mkdir(parents=True, exist_ok=True)
    for r in sorted(results, key=lambda r: -r.errors["shipped"])[:worst]:
        shape = shapes[r.name]
        images = [render_surface(shape.vertices, shape.faces, size=(480, 360))]
        images.append(
            render_surface(
                r.points,
                None,
                scalar=np.minimum(r.counts, 5),
                vmin=0,
                vmax=5,
                isoline_step=0,
                size=(480, 360),
            )
        )
        title = f"{r.name}, {setting}: {r.shortcut.sum()} shortcuts (yellow: 5 or more at a point)"
        titled(side_by_side(images), title).save(out / f"{r.name}-{setting}.png")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", default="tosca", help="real sets or DIR@MODEL datasets")
    parser.add_argument("--settings", default="cloud_2000,cloud_300,noise_0.01")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--eval-root", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache")
    parser.add_argument("--stretch", type=float, default=3.0)
    parser.add_argument("--limit", type=int, default=None, help="the first shapes of each set")
    parser.add_argument("--worst", type=int, default=4)
    parser.add_argument("--frustration", action="store_true")
    parser.add_argument("--render", default=None, help="folder for PNGs of the worst shapes")
    args = parser.parse_args()
    for key in args.sets.split(","):
        named = named_eval_set(key, args.eval_root, args.sources, args.cache, args.limit)
        shapes, model, group = named.shapes, named.model, named.group
        predictor = Predictor(load_model(model))  # the shipped defaults: fused
        print(f"\n### {group}, `{model}`: the shortcuts its cloud graph keeps\n")
        print(
            f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; {len(shapes)} "
            f"shapes, {shapes[0].sources.size} FPS sources each, exact rows, GT mean 100; a "
            f"shortcut: a kept edge whose true geodesic exceeds {args.stretch} × its chord; "
            f"command `python scripts/shortcut_edges.py --sets {key} --settings {args.settings} "
            f"--stretch {args.stretch}" + (" --frustration" if args.frustration else "") + "`"
        )
        for setting in args.settings.split(","):
            results = [
                shape_edges(predictor, shape, setting, args.stretch, args.frustration)
                for shape in shapes
            ]
            print_setting(results, setting, args.frustration, args.worst)
            if args.render:
                named = {s.name: s for s in shapes}
                render(results, named, Path(args.render), setting, args.worst)


if __name__ == "__main__":
    main()
