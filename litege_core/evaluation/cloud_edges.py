"""Clouds sampled from an evaluation mesh, and the true geodesics of their graph edges (issue 14,
diagnosis of the fusion's cloud graph: ``scripts/veto_ceiling.py``, ``scripts/shortcut_edges.py``).

A cloud point keeps the mesh triangle it was sampled on, so an edge ``(i, j)`` between two cloud
points has a true geodesic to compare its chord with: the shortest route from point ``i``
through a corner of its triangle, the mesh's two-ring graph
(:func:`~litege_core.engines.graph.mesh_ring_graph`) and a corner of point ``j``'s triangle (an
upper bound, within a few percent of the exact value at cloud-edge lengths), or the chord itself
where the two triangles share a corner (there the route through corners is far too long for a
short edge). An edge whose true
geodesic is several times its chord is a *shortcut*: it joins parts that touch in space, or
runs through a thin part."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from litege_core.engines.graph import mesh_ring_graph
from litege_core.evaluation.geodesic import EvalShape
from litege_core.sampling import sample_surface
from litege_core.variants import add_noise

if TYPE_CHECKING:
    from litege_core.learned import Predictor

CLOUD_SETTINGS = ("cloud_N", "noise_S")
"""The settings :func:`cloud_input` draws: ``cloud_N`` (``N`` area-weighted points) and
``noise_S`` (2000 points with Gaussian noise of standard deviation ``S``, unit-area units)."""


@dataclass
class CloudInput:
    """A cloud drawn from an :class:`~litege_core.evaluation.geodesic.EvalShape`.

    Attributes:
        points: ``(P, 3)`` the input cloud (unit-area units).
        clean: ``(P, 3)`` the same points before any noise (where they lie on their
            triangles; ``points`` itself when the setting adds none).
        faces: ``(P,)`` the mesh triangle each point was sampled on.
        sources: ``(R,)`` source indices into ``points`` (the shape's sources come first).
        gt: ``(R, P)`` exact geodesics from each source to each point.
    """

    points: NDArray
    faces: NDArray
    sources: NDArray
    gt: NDArray
    clean: NDArray


def cloud_input(shape: EvalShape, setting: str, seed: int) -> CloudInput:
    """As :func:`~litege_core.evaluation.geodesic.make_input` for clouds and noise
    (:data:`CLOUD_SETTINGS`), keeping each point's triangle (a source keeps one of its vertex's
    triangles); the shape's sources are the cloud's first points."""
    n_points = int(setting[6:]) if setting.startswith("cloud_") else 2000
    n_sources = shape.sources.size
    samples = sample_surface(shape.vertices, shape.faces, n_points - n_sources, seed)
    corner_gt = shape.gt[:, shape.faces[samples.face_index]]
    sample_gt = np.einsum("rnk,nk->rn", corner_gt, samples.barycentric)
    clean = np.concatenate([shape.vertices[shape.sources], samples.points])
    gt = np.concatenate([shape.gt[:, shape.sources], sample_gt], axis=1)
    points = clean
    if setting.startswith("noise_"):
        points = add_noise(clean, float(setting[6:]), seed)
    source_faces = np.array([np.flatnonzero((shape.faces == v).any(1))[0] for v in shape.sources])
    faces = np.concatenate([source_faces, samples.face_index])
    return CloudInput(points, faces, np.arange(n_sources), gt, clean)


def oracle_edges(
    shape: EvalShape, cloud: CloudInput, reach: float, bound: str = "upper"
) -> Callable[[NDArray, NDArray], NDArray]:
    """``(i, j) → (E,)`` true-ish geodesics between cloud points (unit-area units, ``inf``
    beyond ``reach``), through the corners of their triangles on the mesh's two-ring graph, or
    the chord between points whose triangles share a corner, both read on the points before
    any noise (``cloud.clean``, where they lie on their triangles).
    ``bound="lower"``: instead, what the triangle inequality leaves at least between them, the
    largest ``d(corner_i, corner_j) − |p_i − corner_i| − |p_j − corner_j|`` (at least the
    chord): a short edge between triangles a few rings apart reads as a detour of several
    chords by the upper route, but only a true detour does by this one."""
    if bound not in ("upper", "lower"):
        raise ValueError(f"bound must be 'upper' or 'lower', got {bound!r}")
    from scipy.sparse.csgraph import dijkstra

    graph = mesh_ring_graph(shape.vertices, shape.faces, 2)
    table = dijkstra(graph, directed=False, limit=reach).astype(np.float32)  # (V, V)
    clean, corners = cloud.clean, shape.faces[cloud.faces]  # (P, 3) each
    to_corner = np.linalg.norm(shape.vertices[corners] - clean[:, None], axis=-1)  # (P, 3)

    def geodesics(i: NDArray, j: NDArray) -> NDArray:
        chords = np.linalg.norm(clean[i] - clean[j], axis=1)
        if bound == "lower":
            best = chords.copy()
            for a in range(3):
                for b in range(3):
                    d = table[corners[i, a], corners[j, b]] - to_corner[i, a] - to_corner[j, b]
                    best = np.maximum(best, np.where(np.isfinite(d), d, np.inf))
            return best
        best = np.full(i.shape[0], np.inf)
        for a in range(3):
            for b in range(3):
                d = to_corner[i, a] + table[corners[i, a], corners[j, b]] + to_corner[j, b]
                best = np.minimum(best, d)
        # on one triangle or two that share a corner the route through corners is far too
        # long for short edges; the chord is the geodesic there, up to the fold between them
        near = (corners[i, :, None] == corners[j, None, :]).any(axis=(1, 2))
        best[near] = chords[near]
        return best

    return geodesics


SURFACE_NEIGHBOURS = 16
"""Neighbours of a cloud point :func:`kept_edges` keeps at least (the normals' and thickness's
k-NN covariance reads 16, itself included)."""


@dataclass
class KeptEdges:
    """The edges the shipped fusion keeps in one evaluation cloud's graph (the mutual k-NN graph,
    normal cut, network veto where the calibration's OOD limit lets it run) before any learned
    shortcut cut (these are what :mod:`~litege_core.learned.shortcuts` scores), measured
    against the mesh: :func:`kept_edges`.

    Attributes:
        cloud: the input cloud.
        points: ``(P, 3)`` its points in the canonical frame (canonical units).
        scale: canonical units per unit-area unit.
        nearest: ``(P, K)`` each point's nearest other points, nearest first (``K`` ≥ 16).
        spacing: the median distance to the 8th nearest point (canonical units).
        thickness: ``(P,)`` ``sqrt(λ_min / λ_max)`` of each point's 16-NN covariance.
        normals: ``(P, 3)`` the unoriented normals of that covariance.
        i, j: ``(E,)`` the kept edges' end points; chord: ``(E,)`` their lengths (canonical).
        predicted: ``(E,)`` the veto head's geodesic of each (canonical; read even where the
            shipped graph runs no veto).
        shortcut: ``(E,)`` whether the edge's true geodesic surely exceeds ``stretch`` × its
            chord (:func:`oracle_edges`, its lower bound).
        bias: the calibration's graph bias ``b(P)``.
    """

    cloud: CloudInput
    points: NDArray
    scale: float
    nearest: NDArray
    spacing: float
    thickness: NDArray
    normals: NDArray
    i: NDArray
    j: NDArray
    chord: NDArray
    predicted: NDArray
    shortcut: NDArray
    bias: float

    def graph_error(self, keep: NDArray | None = None) -> float:
        """The error (GT mean 100) of Dijkstra rows from the cloud's sources over the ``keep``
        ``(E,)`` edges (default all) over the bias; pairs the graph no longer joins are left
        out (``nan`` when it joins no source to another point)."""
        import scipy.sparse as sp

        from litege_core.engines.graph import dijkstra_rows

        keep = np.ones(self.chord.size, bool) if keep is None else keep
        n = self.points.shape[0]
        graph = sp.csr_array((self.chord[keep], (self.i[keep], self.j[keep])), shape=(n, n))
        rows = dijkstra_rows(graph, self.cloud.sources) / self.scale / self.bias
        finite = np.isfinite(rows)
        if not np.any(self.cloud.gt[finite] > 0):
            return float("nan")
        return relative_error(rows[finite], self.cloud.gt[finite])


def kept_edges(
    predictor: Predictor,
    shape: EvalShape,
    setting: str,
    stretch: float = 3.0,
    seed: int = 0,
    neighbours: int = SURFACE_NEIGHBOURS,
) -> KeptEdges:
    """Build the fused cloud graph of ``shape`` in ``setting`` (:func:`cloud_input`) as
    ``predictor``'s calibration does and measure its kept edges (:class:`KeptEdges`);
    ``neighbours``: how many nearest points :attr:`KeptEdges.nearest` holds per point at least
    (it holds 16 and the calibration's reach in any case)."""
    from litege_core.engines.graph import knn_neighbours
    from litege_core.learned.cloud_surface import local_surface
    from litege_core.learned.fusion import pruned_knn_graph
    from litege_core.learned.shortcuts import cloud_spacing
    from litege_core.shape import Shape

    calibration = predictor.fusion
    if calibration is None:
        raise ValueError("kept_edges needs a fused predictor")
    cloud = cloud_input(shape, setting, seed=seed)
    state = predictor.register(Shape.from_arrays(cloud.points))
    points, scale = state.canonical_points, state.transform.scale
    n = points.shape[0]
    lengths, nearest = knn_neighbours(
        points, max(calibration.reach, SURFACE_NEIGHBOURS, neighbours)
    )
    thickness, normals = local_surface(points, nearest=nearest)
    reach = calibration.reach + 1
    candidate = pruned_knn_graph(
        points,
        calibration.k,
        calibration.prune_ratio,
        None,
        (lengths[:, :reach], nearest[:, :reach]),
        normals,
        calibration.normal_limit(n),
        calibration.mutual_k,
    ).tocoo()
    i, j, chord = candidate.row, candidate.col, candidate.data
    predicted = predictor._edge_geodesics(state)(i, j)
    kept = predicted <= calibration.prune_ratio * chord
    if not calibration.vetoes(state.ood_score):  # beyond the calibration's OOD limit
        kept[:] = True
    i, j, chord, predicted = i[kept], j[kept], chord[kept], predicted[kept]
    truth = oracle_edges(shape, cloud, 8.0 * float(lengths[:, -1].max()) / scale, bound="lower")
    return KeptEdges(
        cloud=cloud,
        points=points,
        scale=float(scale),
        nearest=nearest[:, 1:],
        spacing=cloud_spacing(lengths),
        thickness=thickness,
        normals=normals,
        i=i,
        j=j,
        chord=chord,
        predicted=predicted,
        shortcut=truth(i, j) * scale > stretch * chord,
        bias=float(calibration.graph_bias(n)),
    )


def collect_kept_edges(
    key: str,
    settings: Sequence[str],
    *,
    eval_root: str,
    sources: int,
    cache: str | None,
    limit: int | None = None,
    stretch: float = 3.0,
    seed: int = 0,
    neighbours: int = SURFACE_NEIGHBOURS,
) -> dict[str, list[KeptEdges]]:
    """The :func:`kept_edges` of every shape of one named set
    (:func:`~litege_core.evaluation.geodesic.named_eval_set`: a real set or ``DATASET@MODEL``)
    under its model's shipped fused predictor, per setting."""
    from litege_core.evaluation.geodesic import named_eval_set
    from litege_core.learned import Predictor
    from litege_core.learned.bundle import load_model

    named = named_eval_set(key, eval_root, sources, cache, limit)
    predictor = Predictor(load_model(named.model))
    return {
        setting: [
            kept_edges(predictor, shape, setting, stretch, seed, neighbours=neighbours)
            for shape in named.shapes
        ]
        for setting in settings
    }


def shortcut_cut_table(
    label: str, shapes: Sequence[KeptEdges], scores: Sequence[NDArray], thresholds: Sequence[float]
) -> str:
    """Markdown: a scorer's ranking of one set's shortcuts (its AUC beside the thickness's)
    and, per threshold, the share of edges it scores above it, recall, precision and the graph
    error with them cut as the fusion cuts them (the edges that rejoin what the cut would
    split kept: :func:`~litege_core.learned.shortcuts.keep_connected`; mean over shapes,
    :meth:`KeptEdges.graph_error`) beside the uncut graph's and the oracle's (no shortcut).
    ``scores``: ``(E,)`` per shape in ``[0, 1]``, higher: more likely a shortcut."""
    from litege_core.learned.shortcuts import keep_connected
    from litege_core.metrics import ranking_auc

    shortcut = np.concatenate([s.shortcut for s in shapes])
    score = np.concatenate(scores)
    thickness = np.concatenate([np.maximum(s.thickness[s.i], s.thickness[s.j]) for s in shapes])

    def mean_error(keeps: list[NDArray | None]) -> float:
        errors = [s.graph_error(k) for s, k in zip(shapes, keeps, strict=True)]
        finite = [e for e in errors if np.isfinite(e)]  # a graph that joins no source: left out
        return float(np.mean(finite)) if finite else float("nan")

    lines = [
        f"**{label}**: {len(shapes)} shapes, {shortcut.sum()} shortcuts among {shortcut.size} "
        f"kept edges ({100 * shortcut.mean():.2f} %); AUC: scorer "
        f"{ranking_auc(score, shortcut):.3f}, thickness alone "
        f"{ranking_auc(thickness, shortcut):.3f}; graph error "
        f"{mean_error([None] * len(shapes)):.2f} uncut, "
        f"{mean_error([~s.shortcut for s in shapes]):.2f} without the shortcuts (oracle)",
        "",
        "| cut: score above | edges cut | recall | precision | graph error |",
        "|---:|---:|---:|---:|---:|",
    ]
    for threshold in thresholds:
        cut = score > threshold
        hits = int(np.sum(cut & shortcut))
        recall, precision = hits / max(int(shortcut.sum()), 1), hits / max(int(cut.sum()), 1)
        error = mean_error(
            [
                keep_connected(p <= threshold, s.i, s.j, p, s.points.shape[0])
                for s, p in zip(shapes, scores, strict=True)
            ]
        )
        lines.append(
            f"| {threshold:g} | {100 * cut.mean():.2f} % | {recall:.2f} | {precision:.2f} "
            f"| {error:.2f} |"
        )
    return "\n".join(lines)


def relative_error(rows: NDArray, gt: NDArray) -> float:
    """Mean ``|rows − gt|`` with the ground truth's mean scaled to 100 (one shape's rows)."""
    return float(np.mean(np.abs(rows - gt)) / np.mean(gt) * 100.0)


__all__ = [
    "CLOUD_SETTINGS",
    "SURFACE_NEIGHBOURS",
    "CloudInput",
    "KeptEdges",
    "cloud_input",
    "collect_kept_edges",
    "kept_edges",
    "oracle_edges",
    "relative_error",
    "shortcut_cut_table",
]
