"""Which geodesic model answers a shape when none is named (``auto``), without torch.

Every loaded model registers the shape; the OOD z-score says how far the shape's descriptor is
from the model's training shapes, and :func:`graph_agreement` how far the model's network is
from its own fusion graph on the shape (small for a shape of the model's category: the graph
knows the surface, the network knows its families). :func:`choose_model` weighs the two. Used
by the service's ``auto`` (where no category router is confident) and by ``litege geodesic
--model auto``; the predictors compute the agreement (``Predictor.agreement``,
``NumpyPredictor.agreement``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError

if TYPE_CHECKING:
    from litege_core.learned.fusion_calibration import FusionCalibration
    from litege_core.learned.veto_graph import EdgeGeodesics

AGREEMENT_SOURCES = 4
"""Source rows of an agreement (farthest points from point 0, every point as target)."""

AGREEMENT_WEIGHT = 42.0
"""Weight of a model's agreement beside its OOD z-score in :func:`choose_model`: the median gap
in z-score between a generated shape's own model and the other one, over the median gap in
agreement (procedural quadrupeds and bipeds, static animals, MakeHuman bodies; meshes, clouds
of 300–2,000 points, noise), so both weigh alike. Fitted by ``scripts/calibrate_routing.py`` on
generated shapes only (BENCHMARKS "routing-agreement")."""


def graph_agreement(network: NDArray, graph: NDArray, bias: float) -> float:
    """Mean ``|network − graph / bias|`` over the pairs the graph joins, divided by the mean of
    ``graph / bias`` (unitless); ``nan`` where the graph joins no pair.

    Args:
        network: ``(S, N)`` the network's distances from the sources.
        graph: ``(S, N)`` the fusion graph's Dijkstra rows (same units; ``inf``: not joined).
        bias: the graph's calibrated over-estimate at this shape's size or mesh.
    """
    corrected = np.asarray(graph, dtype=np.float64) / bias
    joined = np.isfinite(corrected)
    if not joined.any() or not corrected[joined].mean() > 0:
        return math.nan
    gap = np.abs(np.asarray(network, dtype=np.float64)[joined] - corrected[joined])
    return float(gap.mean() / corrected[joined].mean())


def shape_agreement(
    network_rows: Callable[[NDArray], NDArray],
    points: NDArray,
    faces: NDArray | None,
    calibration: FusionCalibration,
    kept: dict[str, Any],
    edge_geodesics: EdgeGeodesics,
    veto_key: str,
    z_score: float,
    n_sources: int = AGREEMENT_SOURCES,
) -> float:
    """A predictor's agreement on one shape: :func:`graph_agreement` of the rows of
    ``n_sources`` farthest points (from point 0; every point as target).

    Args:
        network_rows: ``sources (S,) → (S, N)`` the network's distances (canonical units).
        points, faces, calibration, kept, edge_geodesics, veto_key, z_score: the shape and
            its fusion, as :func:`~litege_core.learned.fusion.shape_graph` (the graph is kept
            in ``kept``, where the fused queries find it).
    """
    from litege_core.learned.fusion import graph_faces, graph_rows, shape_graph
    from litege_core.sampling import farthest_point_sampling

    sources = farthest_point_sampling(points, min(n_sources, points.shape[0]))
    network = network_rows(sources)  # first: a predictor keeps the feature table the veto reads
    faces = graph_faces(points, faces, calibration, kept)
    graph, roughness, _, _ = shape_graph(points, faces, calibration, kept, veto_key, z_score)
    every = np.arange(points.shape[0])
    rows = graph_rows(
        graph,
        points,
        (sources, points[sources]),
        (every, points),
        calibration.k,
        None,
        edge_geodesics,
    )
    bias = calibration.graph_bias(points.shape[0], faces is not None, roughness)
    return graph_agreement(network, rows, bias)


def choose_model(
    scores: Mapping[str, float],
    agreements: Mapping[str, float] | None = None,
    weight: float = AGREEMENT_WEIGHT,
) -> str:
    """The ``auto`` model of a shape among ``scores`` (model → OOD z-score, in loading order):
    the lowest ``z + weight · agreement`` where every model has a finite agreement, else the
    lowest z-score; a non-finite score ranks last, ties go to the first model."""
    if not scores:
        raise InputError("no model to choose from")

    def rank(value: float) -> float:
        return value if math.isfinite(value) else math.inf

    names = list(scores)
    if agreements is not None and all(math.isfinite(agreements.get(n, math.nan)) for n in names):
        return min(names, key=lambda n: rank(scores[n] + weight * agreements[n]))
    return min(names, key=lambda n: rank(scores[n]))


__all__ = [
    "AGREEMENT_SOURCES",
    "AGREEMENT_WEIGHT",
    "choose_model",
    "graph_agreement",
    "shape_agreement",
]
