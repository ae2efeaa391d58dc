"""Where does the geodesic error on real shapes come from? Helpers of ``scripts/diagnose_real.py``
(issue 14, step 1): body-region labels, per-vertex errors, shape statistics, rank correlation.

**Body regions** (one vocabulary per category, :data:`QUADRUPED_REGIONS`, :data:`BIPED_REGIONS`):

* procedural shapes: the template's part labels (:func:`synthetic_regions`);
* TOSCA animals: the 21 landmarks of ``tosca_landmarks`` (tip of head, head–neck junctions,
  leg tips with their outer and inner junctions, body centre, tail junction) on the class's
  rest pose (``cat0`` …), turned into regions by exact geodesic distance
  (:func:`quadruped_landmark_regions`), then carried to every pose of the class through the
  dense ``corres/*.vts`` correspondences (:func:`transfer_labels`);
* FAUST humans and the leopard: geodesic extremities found automatically
  (:func:`extremity_tips`: farthest-point sampling in geodesic distance from the body centre),
  named by height (:func:`biped_tip_regions`, :func:`quadruped_tip_regions`); FAUST labels are
  computed on ``tr_reg_080`` and carried to the other humans by ``corres``.

A region is "everything within a fraction of the tip-to-junction (or tip-to-centre) geodesic
distance of a tip"; thresholds are stated with each function. They label parts of the surface
for the diagnosis only and never touch a model.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.engines import compute_distances
from litege_core.evaluation.matching_data import read_vts
from litege_core.shape import Shape
from litege_core.validate import triangle_areas

QUADRUPED_REGIONS = ("torso", "head", "ears", "front legs", "hind legs", "tail")
BIPED_REGIONS = ("torso", "head", "arms", "legs")
UNLABELLED = -1

_SYNTH_PARTS = {
    "quadruped": {
        "trunk": "torso",
        "neck": "torso",
        "head": "head",
        "muzzle": "head",
        "jaw": "head",
        "ear_l": "ears",
        "ear_r": "ears",
        "fleg_l": "front legs",
        "fleg_r": "front legs",
        "hleg_l": "hind legs",
        "hleg_r": "hind legs",
        "tail": "tail",
    },
    "biped": {
        "trunk": "torso",
        "neck": "torso",
        "head": "head",
        "arm_l": "arms",
        "arm_r": "arms",
        "leg_l": "legs",
        "leg_r": "legs",
    },
}


def regions_of(category: str) -> tuple[str, ...]:
    return QUADRUPED_REGIONS if category == "quadruped" else BIPED_REGIONS


# --------------------------------------------------------------------------- geometry


def vertex_areas(vertices: ArrayLike, faces: ArrayLike) -> NDArray:
    """``(V,)`` lumped (barycentric) vertex areas: a third of each incident triangle."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    areas = triangle_areas(v, f) / 3.0
    out = np.zeros(v.shape[0])
    for k in range(3):
        np.add.at(out, f[:, k], areas)
    return out


def min_angles_deg(vertices: ArrayLike, faces: ArrayLike) -> NDArray:
    """``(F,)`` smallest interior angle of each triangle, degrees."""
    c = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]
    angles = []
    for k in range(3):
        a = c[:, (k + 1) % 3] - c[:, k]
        b = c[:, (k + 2) % 3] - c[:, k]
        cos = (a * b).sum(1) / np.maximum(
            np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-300
        )
        angles.append(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    return np.min(angles, axis=0)


def density_stats(vertices: ArrayLike, faces: ArrayLike) -> dict[str, float]:
    """Vertex-density variation: coefficient of variation of the lumped vertex areas, the
    ratio of their 90th to 10th percentile, and the mean smallest triangle angle."""
    areas = vertex_areas(vertices, faces)
    p10, p90 = np.percentile(areas, [10, 90])
    return {
        "area_cv": float(areas.std() / areas.mean()),
        "area_p90_p10": float(p90 / max(p10, 1e-300)),
        "min_angle": float(min_angles_deg(vertices, faces).mean()),
    }


def pca_stats(points: ArrayLike) -> dict[str, float]:
    """Eigenvalue ratios ``λ1/λ0``, ``λ2/λ1`` of the centred points (close to 1: two axes
    nearly tie, the PCA frame can swap them) and the sign-rule margins: ``|median projection|
    / std`` along the first two axes (close to 0: the sign rule is a coin toss)."""
    p = np.asarray(points, np.float64)
    c = p - p.mean(axis=0)
    lam, vec = np.linalg.eigh(c.T @ c / (c.shape[0] - 1))
    order = np.argsort(-lam)
    lam, vec = lam[order], vec[:, order]
    proj = c @ vec[:, :2]
    margins = np.abs(np.median(proj, axis=0)) / proj.std(axis=0)
    return {
        "lam1_lam0": float(lam[1] / lam[0]),
        "lam2_lam1": float(lam[2] / lam[1]),
        "median_margin0": float(margins[0]),
        "median_margin1": float(margins[1]),
    }


def geodesic_fields(vertices: ArrayLike, faces: ArrayLike, sources: ArrayLike) -> NDArray:
    """Exact geodesic rows ``(S, V)`` from ``sources``."""
    shape = Shape.from_arrays(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    return compute_distances(shape, np.asarray(sources, np.int64), method="exact").distances


def centre_vertex(vertices: ArrayLike, faces: ArrayLike) -> int:
    """The vertex nearest to the area-weighted centroid of the surface."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    areas = triangle_areas(v, f)
    centroid = (v[f].mean(axis=1) * areas[:, None]).sum(0) / areas.sum()
    return int(np.argmin(np.linalg.norm(v - centroid, axis=1)))


# --------------------------------------------------------------------------- labels


def synthetic_regions(category: str) -> tuple[NDArray, tuple[str, ...]]:
    """``(V,)`` region index of every template vertex of a procedural category."""
    from litege_core import synth

    parts = synth.template(category).parts
    names = regions_of(category)
    mapping = _SYNTH_PARTS[category]
    return np.array([names.index(mapping[p]) for p in parts], dtype=np.int64), names


def quadruped_landmark_regions(
    vertices: ArrayLike, faces: ArrayLike, landmarks: Sequence[int], ear_fraction: float = 0.7
) -> NDArray:
    """Regions of a quadruped in rest pose from the 21 TOSCA landmarks (``CLASS.info``).

    * head: geodesically closer to the head tip (0) than the head–neck junctions (2, 3) are;
    * ears: the two ear tips maximise ``d(v, head tip) + d(v, belly centre 14)`` within
      ``0.6 ×`` (tip-to-neck distance) of the top of the head (1), at least ``1.2 × d(ear tip,
      top)`` apart; an ear is what lies within ``ear_fraction × d(ear tip, top)`` of its tip;
    * each leg: closer to its tip (5, 11 front; 7, 9 hind) than the mean distance of the tip
      to its outer and inner junctions (4/17, 10/18, 6/19, 8/20);
    * tail: the tip is the vertex farthest from the belly centre (14) among those nearer to
      the tail junction (13) than to the back centre (12) and the head tip; the tail is what
      lies closer to that tip than the junction does;
    * torso: the rest (with the neck).
    """
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    lm = np.asarray(landmarks, np.int64)
    d = geodesic_fields(v, f, lm)  # (21, V)
    names = QUADRUPED_REGIONS
    labels = np.full(v.shape[0], names.index("torso"), dtype=np.int64)
    legs_spec = (
        (5, 4, 17, "front legs"),
        (11, 10, 18, "front legs"),
        (7, 6, 19, "hind legs"),
        (9, 8, 20, "hind legs"),
    )
    for tip, outer, inner, name in legs_spec:
        reach = 0.5 * (d[tip, lm[outer]] + d[tip, lm[inner]])
        labels[d[tip] < reach] = names.index(name)
    legs = labels != names.index("torso")
    neck = 0.5 * (d[0, lm[2]] + d[0, lm[3]])
    head = (d[0] < neck) & ~legs
    near_top = np.flatnonzero((d[1] < 0.6 * neck) & ~legs)
    ear_score = d[0] + d[14]  # far from the mouth and from the belly
    ears = np.zeros(v.shape[0], dtype=bool)
    if near_top.size:
        first = int(near_top[np.argmax(ear_score[near_top])])
        tips = [first]
        row = geodesic_fields(v, f, [first])[0]
        rows = [row]
        apart = near_top[row[near_top] > 1.2 * d[1, first]]
        if apart.size:
            second = int(apart[np.argmax(ear_score[apart])])
            tips.append(second)
            rows.append(geodesic_fields(v, f, [second])[0])
        for tip, row in zip(tips, rows, strict=True):
            ears |= (row < ear_fraction * d[1, tip]) & ~legs
    labels[head] = names.index("head")
    labels[ears] = names.index("ears")
    head |= ears
    tail_ok = (d[13] < d[12]) & (d[13] < d[0])
    candidates = np.flatnonzero(tail_ok & ~legs & ~head)
    if candidates.size:
        tip = int(candidates[np.argmax(d[14, candidates])])
        d_tip = geodesic_fields(v, f, [tip])[0]
        tail = (d_tip < d_tip[lm[13]]) & ~legs & ~head
        labels[tail] = names.index("tail")
    return labels


def extremity_tips(
    vertices: ArrayLike, faces: ArrayLike, n_tips: int, centre: int | None = None
) -> tuple[NDArray, NDArray, int]:
    """Geodesic extremities: farthest-point sampling in exact geodesic distance, seeded with the
    body centre (:func:`centre_vertex`). Returns ``(tips (n,), fields (n, V), centre)``; the
    fields are the geodesic rows from the tips."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    centre = centre_vertex(v, f) if centre is None else int(centre)
    nearest = geodesic_fields(v, f, [centre])[0]
    tips, fields = [], []
    for _ in range(n_tips):
        tip = int(np.argmax(np.where(np.isfinite(nearest), nearest, -1.0)))
        row = geodesic_fields(v, f, [tip])[0]
        tips.append(tip)
        fields.append(row)
        nearest = np.minimum(nearest, row)
    return np.array(tips), np.stack(fields), centre


def _tip_regions(
    n_vertices: int,
    tips_fields: NDArray,
    centre_distance: NDArray,
    assignments: Mapping[int, tuple[str, float]],
    names: tuple[str, ...],
) -> NDArray:
    """Vertex ``v`` joins tip ``t``'s region when ``d(v, t) < fraction · d(t, centre)``;
    nearest tip wins where regions overlap."""
    labels = np.full(n_vertices, names.index("torso"), dtype=np.int64)
    best = np.full(n_vertices, np.inf)
    for t, (name, fraction) in assignments.items():
        row = tips_fields[t]
        inside = (row < fraction * centre_distance[t]) & (row < best)
        labels[inside] = names.index(name)
        best[inside] = row[inside]
    return labels


def biped_tip_regions(vertices: ArrayLike, faces: ArrayLike, up_axis: int = 1) -> NDArray:
    """Regions of a standing human: 5 extremity tips; the highest is the head (region:
    ``d < 0.30 ·`` tip-to-centre distance), the two lowest the feet (legs, ``0.85``), the
    others the hands (arms, ``0.52``). The fractions put the cuts near the neck, the shoulders
    and the hips of a standing adult."""
    v = np.asarray(vertices, np.float64)
    tips, fields, centre = extremity_tips(v, faces, 5)
    centre_distance = fields[:, centre]
    height = v[tips, up_axis]
    order = np.argsort(height)
    assign = {int(order[-1]): ("head", 0.30)}
    for k in order[:2]:
        assign[int(k)] = ("legs", 0.85)
    for k in order[2:4]:
        assign[int(k)] = ("arms", 0.52)
    return _tip_regions(v.shape[0], fields, centre_distance, assign, BIPED_REGIONS)


def quadruped_tip_regions(
    vertices: ArrayLike, faces: ArrayLike, up: ArrayLike, forward: ArrayLike, n_tips: int = 8
) -> NDArray:
    """Regions of a quadruped without landmarks (the leopard): ``n_tips`` extremities; the 4
    lowest along ``up`` are paws (legs: ``d < 0.6 ·`` tip-to-centre; front or hind by
    ``forward``), the remaining tip farthest along ``−forward`` is the tail tip (``0.75``), the
    one farthest along ``forward`` the head (``0.30``); further tips near the head are ears
    (``0.15``)."""
    v = np.asarray(vertices, np.float64)
    up, forward = np.asarray(up, np.float64), np.asarray(forward, np.float64)
    tips, fields, centre = extremity_tips(v, faces, n_tips)
    centre_distance = fields[:, centre]
    height = v[tips] @ up
    paws = [int(k) for k in np.argsort(height)[:4]]
    rest = [k for k in range(len(tips)) if k not in paws]
    along = v[tips] @ forward
    body_mid = float(np.median(v @ forward))
    assign: dict[int, tuple[str, float]] = {}
    for k in paws:
        assign[k] = ("front legs" if along[k] > body_mid else "hind legs", 0.6)
    tail = min(rest, key=lambda k: along[k])
    head = max(rest, key=lambda k: along[k])
    assign[tail] = ("tail", 0.75)
    for k in rest:
        if k not in (tail, head) and along[k] > body_mid:
            assign[k] = ("ears", 0.15)
    assign[head] = ("head", 0.30)
    return _tip_regions(v.shape[0], fields, centre_distance, assign, QUADRUPED_REGIONS)


def transfer_labels(
    labels: NDArray,
    reference_map: NDArray,
    target_map: NDArray,
    target_faces: ArrayLike,
    n_target: int,
) -> NDArray:
    """Carry vertex labels through a dense correspondence.

    ``reference_map[k]`` and ``target_map[k]`` are the (0-based) vertices of the reference and
    the target that correspond (``.vts`` rows). Target vertices hit by several rows take the
    most frequent label; vertices hit by none take the label of the nearest labelled vertex
    along mesh edges."""
    out = np.full(n_target, UNLABELLED, dtype=np.int64)
    n_labels = int(labels.max()) + 1
    votes = np.zeros((n_target, n_labels), dtype=np.int64)
    np.add.at(votes, (target_map, labels[reference_map]), 1)
    hit = votes.sum(1) > 0
    out[hit] = votes[hit].argmax(1)
    return fill_unlabelled(out, target_faces)


def fill_unlabelled(labels: NDArray, faces: ArrayLike) -> NDArray:
    """Give every unlabelled vertex the label of its nearest labelled vertex along edges."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    labels = np.asarray(labels, np.int64).copy()
    known = np.flatnonzero(labels != UNLABELLED)
    if known.size == labels.size or known.size == 0:
        return labels
    f = np.asarray(faces, np.int64)
    i = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    j = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    graph = coo_matrix((np.ones(i.size), (i, j)), shape=(labels.size,) * 2).tocsr()
    _, _, sources = dijkstra(
        graph, directed=False, indices=known, min_only=True, return_predecessors=True
    )
    missing = labels == UNLABELLED
    reach = missing & (sources >= 0)
    labels[reach] = labels[sources[reach]]
    return labels


# --------------------------------------------------------------------------- errors, statistics


def per_vertex_error(predicted: NDArray, truth: NDArray, norm: float) -> NDArray:
    """``(V,)`` mean absolute error over the source rows at each vertex, ×100 / ``norm``
    (pairs at distance 0 excluded)."""
    valid = truth > 0
    err = np.where(valid, np.abs(predicted - truth), 0.0)
    count = valid.sum(0)
    return np.where(count > 0, err.sum(0) / np.maximum(count, 1), np.nan) * (100.0 / norm)


def spearman(x: ArrayLike, y: ArrayLike) -> tuple[float, float]:
    """Spearman rank correlation and its two-sided p-value (NaN pairs dropped)."""
    from scipy.stats import spearmanr

    a, b = np.asarray(x, np.float64), np.asarray(y, np.float64)
    keep = np.isfinite(a) & np.isfinite(b)
    if keep.sum() < 4 or np.ptp(a[keep]) == 0 or np.ptp(b[keep]) == 0:
        return float("nan"), float("nan")
    result = spearmanr(a[keep], b[keep])
    return float(result.statistic), float(result.pvalue)


def region_colors(labels: NDArray) -> NDArray:
    """``(V, 3)`` RGB per region index (a fixed qualitative palette) for label figures."""
    palette = np.array(
        [
            [0.75, 0.72, 0.66],
            [0.89, 0.10, 0.11],
            [1.00, 0.50, 0.00],
            [0.22, 0.49, 0.72],
            [0.30, 0.69, 0.29],
            [0.60, 0.31, 0.64],
            [0.40, 0.40, 0.40],
        ]
    )
    return palette[np.clip(labels, 0, len(palette) - 1)]


# --------------------------------------------------------------------------- real-set labels


def _cached_labels(cache_dir, name: str, vertices: NDArray, compute) -> NDArray:
    import hashlib

    if cache_dir is None:
        return compute()
    digest = hashlib.sha256(np.ascontiguousarray(vertices, np.float64).tobytes()).hexdigest()[:16]
    path = Path(cache_dir) / f"labels-{name}-{digest}.npy"
    if path.exists():
        return np.load(path)
    labels = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, labels)
    return labels


def real_region_labels(
    eval_root: str | Path,
    key: str,
    names: Sequence[str],
    meshes: Sequence[tuple[NDArray, NDArray]],
    cache_dir: str | Path | None = None,
) -> list[NDArray]:
    """Region labels of real shapes ``names`` (file stems) of set ``key`` (see the module
    docstring): TOSCA through the class's rest pose and its landmarks, FAUST through
    ``tr_reg_080``, the leopard from its own extremities (y up, head towards +z)."""
    from scipy.spatial import cKDTree

    from litege_core.io import load_shape

    root = Path(eval_root)
    out = []
    references: dict[str, tuple[NDArray, NDArray]] = {}
    for name, (vertices, faces) in zip(names, meshes, strict=True):
        if key == "leopard":
            out.append(
                _cached_labels(
                    cache_dir,
                    name,
                    vertices,
                    lambda v=vertices, f=faces: quadruped_tip_regions(v, f, [0, 1, 0], [0, 0, 1]),
                )
            )
            continue
        if key == "tosca":
            klass = name.rstrip("0123456789")
            folder, ref_name = root / "tosca_5k", f"{klass}0"
        else:
            klass, folder, ref_name = "human", root / "faust_5k", "tr_reg_080"
        if klass not in references:
            ref = load_shape(folder / f"{ref_name}.off")
            assert ref.faces is not None  # the TOSCA / FAUST references are triangle meshes
            if key == "tosca":
                pid = root / "tosca_landmarks" / "corrs" / f"{klass}.pid"
                high = load_shape(root / "tosca_landmarks" / "meshes" / f"{klass}0.off")
                ids = np.loadtxt(pid)[:, 0].astype(np.int64)
                landmarks = cKDTree(ref.vertices).query(high.vertices[ids])[1]
                compute: Callable[[], NDArray] = functools.partial(
                    quadruped_landmark_regions, ref.vertices, ref.faces, landmarks
                )
            else:
                compute = functools.partial(biped_tip_regions, ref.vertices, ref.faces)

            labels = _cached_labels(cache_dir, ref_name, ref.vertices, compute)
            references[klass] = (labels, read_vts(folder / "corres" / f"{ref_name}.vts"))
        labels, ref_map = references[klass]
        target_map = read_vts(folder / "corres" / f"{name}.vts")
        out.append(transfer_labels(labels, ref_map, target_map, faces, vertices.shape[0]))
    return out


__all__ = [
    "BIPED_REGIONS",
    "QUADRUPED_REGIONS",
    "biped_tip_regions",
    "centre_vertex",
    "density_stats",
    "extremity_tips",
    "fill_unlabelled",
    "geodesic_fields",
    "min_angles_deg",
    "pca_stats",
    "per_vertex_error",
    "quadruped_landmark_regions",
    "quadruped_tip_regions",
    "real_region_labels",
    "region_colors",
    "regions_of",
    "spearman",
    "synthetic_regions",
    "transfer_labels",
    "vertex_areas",
]
