"""How much of the fused cloud error is the graph's shortcuts? (issue 14, diagnosis)

For every real dev shape and cloud setting this script rebuilds the fusion's cloud graph four
ways and reports the graph error (``graph / b``) and the fused error of each:

    shipped    the calibration's graph: k-NN, normal limit, the network's veto
    no veto    k-NN and normal limit only
    oracle     k-NN and normal limit, and every edge cut whose true geodesic exceeds
               ``--oracle-ratio`` × its chord (a diagnosis, not a method: it reads the mesh)
    oracle+net both vetoes
    oracle R   with ``--extra-oracle-ratios R,...``: the oracle cut at other ratios (a low one,
               e.g. 1.5, also cuts the chords through a thin part, not only between parts)
    net veto R with ``--prune-ratios R,...``: the shipped graph with the network's veto cutting
               at R × the chord instead of the calibration's ratio (a method: it reads no truth)

A set is a real dev set (``tosca``, ``faust``, ...) or ``DIR@MODEL``: the test split of a
calibration dataset, a collection or a template one (e.g. ``data/folder-cal@quadrupeds``, or
procedural quadrupeds in steep poses, ``data/quadruped-steep-cal@quadrupeds``), to compare what
the dev set and the data the fusion is fitted on say about the same graph.

and, beside them, ``shipped, best w``: the shipped graph fused with the constant network weight
``w`` (of 0, 0.05, …, 1) that gives each shape its lowest error. That is the fusion rule's
headroom (another diagnosis, it reads the truth): if it is close to the shipped fused error, no
per-shape weight rule can do better, and the error is in both estimators.

The true edge geodesic is the shortest route from one cloud point through a corner of its
triangle, the mesh's two-ring graph (:func:`~litege_core.engines.graph.mesh_ring_graph`) and
a corner of the other point's triangle (an upper bound, within a few percent of the exact
value at these edge lengths). Every number comes from this script::

    python scripts/veto_ceiling.py --sets tosca,faust --sources 12 --cache out/exact-cache
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
from datetime import UTC, datetime

import numpy as np
from numpy.typing import NDArray

from litege_core.engines.graph import dijkstra_rows, knn_neighbours
from litege_core.evaluation.cloud_edges import cloud_input, oracle_edges
from litege_core.evaluation.cloud_edges import relative_error as error
from litege_core.evaluation.geodesic import EvalShape, named_eval_set
from litege_core.evaluation.speed import cpu_name
from litege_core.learned import Predictor
from litege_core.learned.bundle import load_model
from litege_core.learned.cloud_surface import local_surface
from litege_core.learned.fusion import fuse, pruned_knn_graph
from litege_core.shape import Shape

MID_LIMITS: list[float] = []
VARIANTS = ["shipped", "shipped, best w", "no veto", "oracle", "oracle + net"]
EXTRA_RATIOS: list[float] = []
PRUNE_RATIOS: list[float] = []
WEIGHT_GRID = np.linspace(0.0, 1.0, 21)
"""Network weights :func:`best_weight_error` tries."""


def facing_cut(points: NDArray, normals: NDArray, limit: float):
    """``(i, j) → (E,)`` bool: the chord runs along the two ends' mean normal (aligned to
    one sign), ``|n̄ · ĉ| > limit``: a smooth arc's chord is perpendicular to it, a chord
    across a gap between two sheets is not."""

    def cut(i: NDArray, j: NDArray) -> NDArray:
        sign = np.sign(np.einsum("ei,ei->e", normals[i], normals[j]))
        sign[sign == 0] = 1.0
        mean = normals[i] + sign[:, None] * normals[j]
        mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-12)
        chord = points[j] - points[i]
        chord /= np.maximum(np.linalg.norm(chord, axis=1, keepdims=True), 1e-300)
        return np.abs(np.einsum("ei,ei->e", mean, chord)) > limit

    return cut


def best_weight_error(network: NDArray, graph: NDArray, gt: NDArray) -> float:
    """The lowest :func:`error` of ``w · network + (1 − w) · graph`` over ``w`` in
    :data:`WEIGHT_GRID` (``(R, P)`` rows in one unit; ``graph`` already bias-corrected, finite)."""
    return min(error(w * network + (1.0 - w) * graph, gt) for w in WEIGHT_GRID)


def evaluate_shape(predictor, network_only, shape: EvalShape, setting: str, oracle_ratio: float):
    cloud = cloud_input(shape, setting, seed=0)
    state = predictor.register(Shape.from_arrays(cloud.points))
    calibration = predictor.fusion
    points, scale = state.canonical_points, state.transform.scale
    n = points.shape[0]
    k, ratio = calibration.k, calibration.prune_ratio
    neighbours = knn_neighbours(points, calibration.reach)
    flatness, normals = local_surface(points, nearest=neighbours[1])
    roughness = float(np.median(flatness))
    normal_cos = calibration.normal_limit(n)
    network = network_only.distances(state, cloud.sources).astype(np.float64)  # user units
    reach = 8.0 * float(neighbours[0][:, -1].max()) / scale
    truth = oracle_edges(shape, cloud, reach)
    network_veto = predictor._edge_geodesics(state)

    def oracle_at(cut: float):
        # canonical units; scaled so that the calibration's ratio cuts at ``cut``
        return lambda i, j: truth(i, j) * scale * ratio / cut

    oracle = oracle_at(oracle_ratio)

    def both(i, j):
        return np.maximum(oracle(i, j), network_veto(i, j))

    vetoes = {"shipped": network_veto, "no veto": None, "oracle": oracle, "oracle + net": both}
    for extra in EXTRA_RATIOS:
        vetoes[f"oracle {extra}"] = oracle_at(extra)
    for prune in PRUNE_RATIOS:
        vetoes[f"net veto {prune}"] = lambda i, j, r=prune: network_veto(i, j) * ratio / r
    for limit in MID_LIMITS:
        facing = facing_cut(points, normals, limit)
        vetoes[f"mean normal {limit}"] = lambda i, j, f=facing: np.where(f(i, j), np.inf, 0.0)
        vetoes[f"mean normal {limit} + net"] = lambda i, j, f=facing: np.where(
            f(i, j), np.inf, network_veto(i, j)
        )
    weight = calibration.network_weight(state.ood_score, n, roughness)
    out = {}
    for name, veto in vetoes.items():
        graph = pruned_knn_graph(
            points, k, ratio, veto, neighbours, normals, normal_cos, calibration.mutual_k
        )
        rows = dijkstra_rows(graph, cloud.sources) / scale  # user units
        corrected = rows / calibration.graph_bias(n)
        corrected = np.where(np.isfinite(corrected), corrected, network)
        fused = fuse(network, rows, calibration, state.ood_score, n, roughness)
        out[name] = (error(corrected, cloud.gt), error(fused, cloud.gt))
        if name == "shipped":
            out["shipped, best w"] = (
                out[name][0],
                best_weight_error(network, corrected, cloud.gt),
            )
    out["network"] = (error(network, cloud.gt), error(network, cloud.gt))
    return out, weight


def print_table(shapes, results, weights, setting: str, worst: int) -> None:
    """One setting's row (means over shapes) and its ``worst`` shapes (by the shipped fused
    error): graph / fused error of every variant."""

    def cells(rows: list[dict]) -> str:
        return " | ".join(
            f"{np.mean([r[v][0] for r in rows]):.2f} / {np.mean([r[v][1] for r in rows]):.2f}"
            for v in VARIANTS
        )

    network = np.mean([r["network"][0] for r in results])
    print(
        f"| {setting} | {len(shapes)} | {network:.2f} | {cells(results)} "
        f"| {np.median(weights):.2f} |",
        flush=True,
    )
    for i in np.argsort([-r["shipped"][1] for r in results])[:worst]:
        print(
            f"| {setting}: {shapes[i].name} | | {results[i]['network'][0]:.2f} "
            f"| {cells([results[i]])} | {weights[i]:.2f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", default="tosca,faust")
    parser.add_argument("--settings", default="cloud_2000,cloud_300,noise_0.01")
    parser.add_argument("--sources", type=int, default=12)
    parser.add_argument("--eval-root", default="../shared/eval-data")
    parser.add_argument("--cache", default="out/exact-cache")
    parser.add_argument("--oracle-ratio", type=float, default=3.0)
    parser.add_argument(
        "--extra-oracle-ratios", default="", help="oracle cuts at other ratios too, e.g. 1.5,2"
    )
    parser.add_argument(
        "--prune-ratios", default="", help="the network's veto at other ratios too, e.g. 1.1,1.5"
    )
    parser.add_argument("--limit", type=int, default=None, help="the first shapes of each set")
    parser.add_argument("--worst", type=int, default=4)
    parser.add_argument(
        "--mean-normal", default="", help="mean-normal limits to try too, e.g. 0.3,0.5"
    )
    args = parser.parse_args()
    for extra in filter(None, args.extra_oracle_ratios.split(",")):
        EXTRA_RATIOS.append(float(extra))
        VARIANTS.append(f"oracle {float(extra)}")
    for prune in filter(None, args.prune_ratios.split(",")):
        PRUNE_RATIOS.append(float(prune))
        VARIANTS.append(f"net veto {float(prune)}")
    for limit in filter(None, args.mean_normal.split(",")):
        MID_LIMITS.append(float(limit))
        VARIANTS.extend([f"mean normal {float(limit)}", f"mean normal {float(limit)} + net"])
    for key in args.sets.split(","):
        named = named_eval_set(key, args.eval_root, args.sources, args.cache, args.limit)
        shapes, model, group = named.shapes, named.model, named.group
        bundle = load_model(model)
        predictor = Predictor(bundle)  # the shipped defaults: fused
        network_only = Predictor(bundle, fusion="none")
        print(f"\n### {group}, `{model}`: graph / fused error by cloud graph\n")
        print(
            f"- date {datetime.now(UTC):%Y-%m-%d %H:%M} UTC; machine {cpu_name()}; "
            f"{len(shapes)} shapes, {shapes[0].sources.size} FPS sources each, exact rows, GT mean "
            f"100; oracle: edges cut whose geodesic on the mesh exceeds {args.oracle_ratio} × "
            f"the chord; w: the fusion's network weight (median); command `python "
            f"scripts/veto_ceiling.py --sets {key} --settings {args.settings} --sources "
            f"{args.sources} --oracle-ratio {args.oracle_ratio}"
            + (f" --mean-normal {args.mean_normal}" if args.mean_normal else "")
            + (
                f" --extra-oracle-ratios {args.extra_oracle_ratios}"
                if args.extra_oracle_ratios
                else ""
            )
            + (f" --prune-ratios {args.prune_ratios}" if args.prune_ratios else "")
            + "`\n"
        )
        print(
            "| setting | shapes | network | "
            + " | ".join(f"{v}: graph / fused" for v in VARIANTS)
            + " | w |"
        )
        print("|---|---:|---:|" + "---:|" * (len(VARIANTS) + 1))
        for setting in args.settings.split(","):
            results, weights = [], []
            for shape in shapes:
                result, weight = evaluate_shape(
                    predictor, network_only, shape, setting, args.oracle_ratio
                )
                results.append(result)
                weights.append(weight)
            print_table(shapes, results, weights, setting, args.worst)


if __name__ == "__main__":
    main()
