"""Projection of points onto a shape: exact closest point on a triangle mesh, nearest point of a
point cloud.

Used to put user-supplied query points on the surface (:mod:`litege_core.query`) and to keep
the geodesic path tracer on the shape after every gradient step (:mod:`litege_core.learned.paths`).

* :func:`closest_point_on_triangles` is the vectorised closest point of a point to a triangle
  (Ericson, *Real-Time Collision Detection* §5.1.5: Voronoi regions of the corners, the edges
  and the face), over any batch shape.
* :class:`MeshProjector` finds, for each query, the ``K`` triangles with the nearest centroids
  (KD-tree), takes the closest point over them, and **certifies** the answer: a triangle whose
  centroid is farther than the ``K``-th one is at least ``d_K − R`` away, ``R`` being the largest
  centroid-to-corner distance of the mesh. Queries whose best distance exceeds that bound are
  redone with ``4K`` candidates, up to all triangles, so the result is the exact closest point
  (tested against ``trimesh.proximity.closest_point``), whatever the triangle sizes.
* :class:`CloudProjector` snaps to the nearest point of the cloud (the paper's projection,
  reference-spec §6) and estimates unit normals by local PCA when they are first asked for.

All coordinates are float64, in whatever frame the projector was built in (the predictor uses
the canonical frame). Each projector is built once per shape and queried many times.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.arrays import frozen
from litege_core.errors import EmptyShapeError
from litege_core.query import check_points

DEFAULT_CANDIDATES = 16
"""Triangles tried first per query (nearest centroids); the certificate widens it if needed."""

DEFAULT_NORMAL_NEIGHBOURS = 10
"""Neighbours of a cloud point used for its local-PCA normal."""


def as_query_points(points: ArrayLike, name: str = "points") -> NDArray:
    """Validate ``(Q, 3)`` query points (a single ``(3,)`` point becomes ``(1, 3)``); the rule
    of :func:`litege_core.query.check_points`."""
    array = np.asarray(points) if not isinstance(points, np.ndarray) else points
    if array.ndim == 1 and array.shape[0] == 3:
        array = array[None]
    return check_points(array, name)


def closest_point_on_triangles(
    points: NDArray, a: NDArray, b: NDArray, c: NDArray
) -> tuple[NDArray, NDArray]:
    """Closest point of each triangle ``(a, b, c)`` to ``points`` (vectorised Ericson).

    Args:
        points: ``(..., 3)`` query points.
        a, b, c: ``(..., 3)`` triangle corners, broadcastable against ``points``.

    Returns:
        ``closest (..., 3)`` the closest points and ``barycentric (..., 3)`` their weights on
        ``(a, b, c)`` (non-negative, summing to 1). Degenerate triangles (zero area) are handled
        as their edges or corners.
    """
    p, a, b, c = np.broadcast_arrays(points, a, b, c)
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c

    def dot(x: NDArray, y: NDArray) -> NDArray:
        return np.einsum("...i,...i->...", x, y)

    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    def ratio(num: NDArray, den: NDArray) -> NDArray:
        safe = np.where(den != 0.0, den, 1.0)
        return np.clip(np.where(den != 0.0, num / safe, 0.0), 0.0, 1.0)

    t_ab = ratio(d1, d1 - d3)
    t_ac = ratio(d2, d2 - d6)
    t_bc = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
    total = va + vb + vc
    safe_total = np.where(total != 0.0, total, 1.0)
    v_in, w_in = vb / safe_total, vc / safe_total

    zero, one = np.zeros_like(d1), np.ones_like(d1)
    # Ericson's tests in his order: the first region that matches wins.
    conditions = [
        (d1 <= 0) & (d2 <= 0),  # corner a
        (d3 >= 0) & (d4 <= d3),  # corner b
        (vc <= 0) & (d1 >= 0) & (d3 <= 0),  # edge ab
        (d6 >= 0) & (d5 <= d6),  # corner c
        (vb <= 0) & (d2 >= 0) & (d6 <= 0),  # edge ac
        (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0),  # edge bc
    ]
    weight_b = np.select(conditions, [zero, one, t_ab, zero, zero, 1.0 - t_bc], v_in)
    weight_c = np.select(conditions, [zero, zero, zero, one, t_ac, t_bc], w_in)
    # A degenerate triangle that reaches the face case (total == 0) has no interior: fall back
    # to the best of its three edges, computed directly.
    degenerate = (total == 0.0) & ~np.any(conditions, axis=0)
    if degenerate.any():
        weight_b, weight_c = _degenerate_fallback(p, a, b, c, degenerate, weight_b, weight_c)
    weight_a = 1.0 - weight_b - weight_c
    barycentric = np.stack([weight_a, weight_b, weight_c], axis=-1)
    # the weighted sum (not a + v·ab + w·ac) returns corners exactly
    closest = weight_a[..., None] * a + weight_b[..., None] * b + weight_c[..., None] * c
    return closest, barycentric


def _segment_param(p: NDArray, x: NDArray, y: NDArray) -> tuple[NDArray, NDArray]:
    d = y - x
    length2 = np.einsum("...i,...i->...", d, d)
    t = np.einsum("...i,...i->...", p - x, d) / np.where(length2 > 0, length2, 1.0)
    t = np.clip(np.where(length2 > 0, t, 0.0), 0.0, 1.0)
    q = x + t[..., None] * d
    return t, np.einsum("...i,...i->...", p - q, p - q)


def _degenerate_fallback(
    p: NDArray,
    a: NDArray,
    b: NDArray,
    c: NDArray,
    mask: NDArray,
    weight_b: NDArray,
    weight_c: NDArray,
) -> tuple[NDArray, NDArray]:
    pm, am, bm, cm = p[mask], a[mask], b[mask], c[mask]
    t_ab, e_ab = _segment_param(pm, am, bm)
    t_ac, e_ac = _segment_param(pm, am, cm)
    t_bc, e_bc = _segment_param(pm, bm, cm)
    best = np.argmin(np.stack([e_ab, e_ac, e_bc]), axis=0)
    wb = np.choose(best, [t_ab, np.zeros_like(t_ab), 1.0 - t_bc])
    wc = np.choose(best, [np.zeros_like(t_ab), t_ac, t_bc])
    weight_b, weight_c = weight_b.copy(), weight_c.copy()
    weight_b[mask], weight_c[mask] = wb, wc
    return weight_b, weight_c


@dataclass(frozen=True)
class SurfaceProjection:
    """Query points projected onto a shape.

    Attributes:
        points: ``(Q, 3)`` float64 projected points (on the surface / cloud).
        distance: ``(Q,)`` float64 distance from each query to its projection.
        normals: ``(Q, 3)`` float64 unit normals at the projections (face normal of a mesh,
            local-PCA normal of a cloud; orientation arbitrary for clouds).
        face_index: ``(Q,)`` int64 triangle of each projection (meshes), ``None`` for clouds.
        barycentric: ``(Q, 3)`` weights on that triangle's corners (meshes), ``None`` for clouds.
        point_index: ``(Q,)`` int64 nearest cloud point (clouds), ``None`` for meshes.
    """

    points: NDArray
    distance: NDArray
    normals: NDArray
    face_index: NDArray | None = None
    barycentric: NDArray | None = None
    point_index: NDArray | None = None


class MeshProjector:
    """Exact closest point on a triangle mesh (see the module docstring).

    Args:
        vertices: ``(V, 3)`` float64 vertices.
        faces: ``(F, 3)`` int64 triangles.
        candidates: ``K``, triangles tried first per query.
    """

    def __init__(
        self, vertices: ArrayLike, faces: ArrayLike, candidates: int = DEFAULT_CANDIDATES
    ) -> None:
        self.vertices = frozen(np.asarray(vertices, dtype=np.float64))
        self.faces = frozen(np.asarray(faces, dtype=np.int64))
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or self.faces.shape[0] == 0:
            raise EmptyShapeError("a mesh projector needs at least one triangle")
        corners = self.vertices[self.faces]  # (F, 3, 3)
        self._a, self._b, self._c = (np.ascontiguousarray(corners[:, i]) for i in range(3))
        centroids = corners.mean(axis=1)
        self.max_radius = float(np.linalg.norm(corners - centroids[:, None], axis=2).max())
        from scipy.spatial import cKDTree  # imported on first use (CLI start-up)

        self._tree = cKDTree(centroids)
        self.candidates = max(1, min(int(candidates), self.n_faces))
        normals = np.cross(self._b - self._a, self._c - self._a)
        norms = np.linalg.norm(normals, axis=1, keepdims=True)
        self.face_normals = frozen(normals / np.where(norms > 0, norms, 1.0))

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @cached_property
    def mean_edge_length(self) -> float:
        """Mean length of the unique edges (same units as the vertices)."""
        half = np.concatenate([self.faces[:, [0, 1]], self.faces[:, [1, 2]], self.faces[:, [2, 0]]])
        edges = np.unique(np.sort(half, axis=1), axis=0)
        lengths = np.linalg.norm(self.vertices[edges[:, 0]] - self.vertices[edges[:, 1]], axis=1)
        return float(lengths.mean())

    def _best_of(self, points: NDArray, face_ids: NDArray) -> tuple[NDArray, ...]:
        """Best triangle among ``face_ids (Q, K)`` for each of ``points (Q, 3)``."""
        closest, bary = closest_point_on_triangles(
            points[:, None], self._a[face_ids], self._b[face_ids], self._c[face_ids]
        )
        sq = np.einsum("qki,qki->qk", closest - points[:, None], closest - points[:, None])
        best = np.argmin(sq, axis=1)
        rows = np.arange(points.shape[0])
        return closest[rows, best], bary[rows, best], face_ids[rows, best], np.sqrt(sq[rows, best])

    def project(self, points: ArrayLike) -> SurfaceProjection:
        """Closest points on the mesh of ``points (Q, 3)`` (exact; see the class docstring)."""
        query = as_query_points(points)
        n = query.shape[0]
        out_points = np.empty((n, 3))
        out_bary = np.empty((n, 3))
        out_face = np.empty(n, dtype=np.int64)
        out_dist = np.empty(n)
        pending = np.arange(n)
        k = self.candidates
        while pending.size:
            if k >= self.n_faces:  # brute force over every triangle: exact by construction
                face_ids = np.broadcast_to(np.arange(self.n_faces), (pending.size, self.n_faces))
                certified = np.ones(pending.size, dtype=bool)
                closest, bary, face, dist = self._best_of(query[pending], face_ids)
            else:
                centroid_dist, face_ids = self._tree.query(query[pending], k=k)
                face_ids = np.asarray(face_ids, dtype=np.int64).reshape(pending.size, k)
                closest, bary, face, dist = self._best_of(query[pending], face_ids)
                bound = np.asarray(centroid_dist).reshape(pending.size, k)[:, -1]
                certified = dist <= bound - self.max_radius
            done = pending[certified]
            out_points[done] = closest[certified]
            out_bary[done] = bary[certified]
            out_face[done] = face[certified]
            out_dist[done] = dist[certified]
            pending = pending[~certified]
            k *= 4
        return SurfaceProjection(
            points=out_points,
            distance=out_dist,
            normals=self.face_normals[out_face],
            face_index=out_face,
            barycentric=out_bary,
        )


class CloudProjector:
    """Nearest point of a point cloud, with local-PCA normals built on first use.

    Args:
        points: ``(N, 3)`` float64 cloud.
        normal_neighbours: neighbours (including the point) of each local-PCA normal.
    """

    def __init__(
        self, points: ArrayLike, normal_neighbours: int = DEFAULT_NORMAL_NEIGHBOURS
    ) -> None:
        self.points = frozen(np.asarray(points, dtype=np.float64))
        if self.points.ndim != 2 or self.points.shape[1] != 3 or self.points.shape[0] < 2:
            raise EmptyShapeError("a cloud projector needs at least two points")
        from scipy.spatial import cKDTree  # imported on first use (CLI start-up)

        self._tree = cKDTree(self.points)
        self.normal_neighbours = max(3, min(int(normal_neighbours), self.points.shape[0]))

    @cached_property
    def mean_spacing(self) -> float:
        """Mean distance from each point to its nearest other point at another position
        (repeated points count once: a cloud whose every point is sent twice keeps its
        spacing, not 0); 0 only when all points coincide."""
        distances, _ = self._tree.query(self.points, k=2)
        if np.all(distances[:, 1] > 0):
            return float(distances[:, 1].mean())
        from scipy.spatial import cKDTree

        distinct = np.unique(self.points, axis=0)
        if distinct.shape[0] < 2:
            return 0.0
        distances, _ = cKDTree(distinct).query(distinct, k=2)
        return float(distances[:, 1].mean())

    @cached_property
    def normals(self) -> NDArray:
        """``(N, 3)`` unit normals: smallest principal axis of each point's neighbourhood."""
        _, neighbours = self._tree.query(self.points, k=self.normal_neighbours)
        local = self.points[neighbours]  # (N, k, 3)
        local = local - local.mean(axis=1, keepdims=True)
        covariance = np.einsum("nki,nkj->nij", local, local)
        _, vectors = np.linalg.eigh(covariance)
        return frozen(vectors[:, :, 0])

    def neighbours(self, points: ArrayLike, k: int) -> tuple[NDArray, NDArray]:
        """``(distance (Q, k), index (Q, k) int64)`` of the ``k`` nearest cloud points."""
        query = as_query_points(points)
        k = max(1, min(int(k), self.points.shape[0]))
        distance, index = self._tree.query(query, k=k)
        shape = (query.shape[0], k)
        return (
            np.asarray(distance, dtype=np.float64).reshape(shape),
            np.asarray(index, dtype=np.int64).reshape(shape),
        )

    def nearest(self, points: ArrayLike) -> tuple[NDArray, NDArray]:
        """``(distance (Q,), index (Q,) int64)`` of the nearest cloud point to each query."""
        query = as_query_points(points)
        distance, index = self._tree.query(query, k=1)
        return np.asarray(distance, dtype=np.float64), np.asarray(index, dtype=np.int64)

    def project(self, points: ArrayLike) -> SurfaceProjection:
        """Snap ``points (Q, 3)`` to their nearest cloud points."""
        distance, index = self.nearest(points)
        return SurfaceProjection(
            points=self.points[index].copy(),
            distance=distance,
            normals=self.normals[index],
            point_index=index,
        )


Projector = MeshProjector | CloudProjector


@dataclass(frozen=True)
class SnappedPoints:
    """Query points put on a shape by :func:`snap`.

    Attributes:
        points: ``(Q, 3)`` float64 points on the surface, in the projector's frame.
        indices: ``(Q,)`` int64 cloud point of each (clouds), ``None`` on meshes, where the
            snapped points are new surface points.
    """

    points: NDArray
    indices: NDArray | None


def snap(projector: Projector, points: ArrayLike) -> SnappedPoints:
    """The one rule that puts xyz query points on a shape: the exact closest point on a
    mesh's triangles, the nearest point of a cloud. ``points (Q, 3)`` are in the projector's
    frame (any similarity transform of the shape's own frame gives the same answer)."""
    if isinstance(projector, CloudProjector):
        _, index = projector.nearest(points)
        return SnappedPoints(projector.points[index], index)
    return SnappedPoints(projector.project(points).points, None)


__all__ = [
    "DEFAULT_CANDIDATES",
    "DEFAULT_NORMAL_NEIGHBOURS",
    "CloudProjector",
    "MeshProjector",
    "Projector",
    "SnappedPoints",
    "SurfaceProjection",
    "as_query_points",
    "closest_point_on_triangles",
    "snap",
]
