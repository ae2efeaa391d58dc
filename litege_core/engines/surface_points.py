"""Exact geodesics between arbitrary surface points, by inserting them into the mesh.

A surface point is a triangle index and barycentric weights (what
:func:`litege_core.sampling.sample_surface` returns). :func:`insert_surface_points` makes each
point a vertex of a refined mesh:

* weights below ``snap_tol`` are set to 0 (and the rest renormalised), so a point within
  ``snap_tol`` of an edge lies on it and one within ``snap_tol`` of a corner *is* the corner;
* a point at a corner reuses that vertex (no new vertex);
* a point on an edge splits every triangle incident to that edge into two;
* an interior point splits its triangle into three.

Points are inserted one by one; the points still waiting in a triangle that gets split are
re-expressed in the child that contains them, so several points per triangle or per edge and
coincident points (which end up sharing one vertex) are handled. The refinement does not move
the surface: every new vertex lies in the plane of its triangle, so exact geodesics between
original vertices are unchanged. :func:`surface_point_distances` then runs the exact engine
on the refined mesh.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.engines.base import ParamValue
from litege_core.engines.exact import DEFAULT_EXACT_BACKEND, ExactGeodesicEngine
from litege_core.errors import ArrayShapeError, InputError, NonFiniteError
from litege_core.query import parse_indices
from litege_core.shape import Shape
from litege_core.validate import ShapeLimits

DEFAULT_SNAP_TOL = 1e-9
_BARYCENTRIC_SLACK = 1e-6  # accepted error on input weights: min >= -slack, |sum - 1| <= slack


class RefinedMesh(NamedTuple):
    """A mesh with surface points inserted as vertices.

    Attributes:
        vertices: ``(N + K, 3)`` float64; the ``N`` original vertices first, unchanged, then
            the ``K <= P`` inserted points in insertion order.
        faces: ``(F + 2·interior + edge-splits, 3)`` int64 triangles, orientation kept.
        point_vertex: ``(P,)`` int64, the vertex of each input point (an original vertex when
            the point snapped to a corner; shared by coincident points).
        parent_face: ``(F',)`` int64, the original triangle each refined triangle lies in.
    """

    vertices: NDArray
    faces: NDArray
    point_vertex: NDArray
    parent_face: NDArray


class SurfacePointDistances(NamedTuple):
    """Exact geodesic distances between surface points.

    Attributes:
        distances: ``(P, P)`` float64 point-to-point distances in the mesh's units; 0 on the
            diagonal, ``+inf`` between disconnected components.
        to_vertices: ``(P, N)`` float64 distances from each point to every original vertex,
            or ``None`` when not requested.
        refined: the :class:`RefinedMesh` the distances were computed on.
        method: ``"exact_surface_points"``.
        params: ``{"backend": ..., "snap_tol": ...}``.
    """

    distances: NDArray
    to_vertices: NDArray | None
    refined: RefinedMesh
    method: str
    params: Mapping[str, ParamValue]


def check_surface_points(
    face_index: ArrayLike, barycentric: ArrayLike, faces: NDArray, snap_tol: float
) -> tuple[NDArray, NDArray]:
    """Validate surface points and snap their weights.

    Args:
        face_index: ``(P,)`` int triangle indices into ``faces``.
        barycentric: ``(P, 3)`` float weights of the triangle corners; each row must be
            ``>= -1e-6`` and sum to 1 within ``1e-6``.
        faces: ``(F, 3)`` int64 triangles.
        snap_tol: weights below it become 0.

    Returns:
        ``face_index (P,)`` int64 and ``barycentric (P, 3)`` float64, clipped, snapped and
        renormalised.

    Raises:
        InputError: no point, bad weights, or a point on a triangle with a repeated corner;
        IndexOutOfRangeError: a face index outside ``[0, F)``; ArrayShapeError / NonFiniteError.
    """
    if not (np.isfinite(snap_tol) and 0 <= snap_tol < 1 / 3):
        raise InputError(f"snap_tol must be in [0, 1/3), got {snap_tol!r}")
    index = parse_indices(face_index, faces.shape[0], what="face")
    weights = np.asarray(barycentric)
    if weights.dtype == object or not np.issubdtype(weights.dtype, np.number):
        raise ArrayShapeError(f"barycentric weights must be numeric, got dtype {weights.dtype}")
    weights = weights.astype(np.float64)
    if weights.shape != (index.size, 3):
        raise ArrayShapeError(
            f"barycentric must have shape ({index.size}, 3) to match face_index, "
            f"got {weights.shape}"
        )
    if not np.isfinite(weights).all():
        raise NonFiniteError("barycentric weights contain NaN or inf")
    bad = (weights.min(axis=1) < -_BARYCENTRIC_SLACK) | (
        np.abs(weights.sum(axis=1) - 1.0) > _BARYCENTRIC_SLACK
    )
    if bad.any():
        first = int(np.flatnonzero(bad)[0])
        raise InputError(
            f"{int(bad.sum())} barycentric rows are not non-negative weights summing to 1 "
            f"(first: row {first} = {weights[first].tolist()})",
            first_index=first,
        )
    corners = faces[index]
    degenerate = (
        (corners[:, 0] == corners[:, 1])
        | (corners[:, 1] == corners[:, 2])
        | (corners[:, 2] == corners[:, 0])
    )
    if degenerate.any():
        first = int(np.flatnonzero(degenerate)[0])
        raise InputError(
            f"point {first} lies on face {int(index[first])}, which has a repeated corner",
            first_index=first,
        )
    return index, _snap(weights, snap_tol)


def _snap(weights: NDArray, snap_tol: float) -> NDArray:
    """Zero weights below ``snap_tol`` and renormalise the rows of ``(..., 3)`` weights."""
    weights = np.where(weights < snap_tol, 0.0, weights)
    return weights / weights.sum(axis=-1, keepdims=True)


class _EdgeFaces:
    """Edge → incident faces, for a mesh that is being refined.

    The original mesh is indexed once with sorted numpy keys; every edge touched by a split
    is copied into an overlay dictionary, which is authoritative from then on.
    """

    def __init__(self, faces: NDArray, n_vertices: int) -> None:
        half = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]], axis=2).reshape(-1, 2)
        keys = half[:, 0] * n_vertices + half[:, 1]
        order = np.argsort(keys, kind="stable")
        self._keys = keys[order]
        self._faces = np.repeat(np.arange(faces.shape[0]), 3)[order]
        self._n = n_vertices
        self._overlay: dict[tuple[int, int], list[int]] = {}

    def get(self, a: int, b: int) -> list[int]:
        edge = (a, b) if a < b else (b, a)
        found = self._overlay.get(edge)
        if found is not None:
            return found
        found = []
        if edge[1] < self._n:  # edges with a new vertex only live in the overlay
            key = edge[0] * self._n + edge[1]
            lo, hi = np.searchsorted(self._keys, [key, key + 1])
            found = self._faces[lo:hi].tolist()
        self._overlay[edge] = found
        return found

    def remove_face(self, face: int, corners: list[int]) -> None:
        for s in range(3):
            self.get(corners[s], corners[(s + 1) % 3]).remove(face)

    def add_face(self, face: int, corners: list[int]) -> None:
        for s in range(3):
            self.get(corners[s], corners[(s + 1) % 3]).append(face)


def insert_surface_points(
    vertices: NDArray,
    faces: NDArray,
    face_index: ArrayLike,
    barycentric: ArrayLike,
    snap_tol: float = DEFAULT_SNAP_TOL,
) -> RefinedMesh:
    """Insert surface points into a triangle mesh as vertices (see the module docstring).

    Args:
        vertices: ``(N, 3)`` float64 mesh vertices.
        faces: ``(F, 3)`` int64 triangles.
        face_index: ``(P,)`` int triangle of each point.
        barycentric: ``(P, 3)`` float weights of that triangle's corners.
        snap_tol: barycentric weights below this are snapped to 0 (default 1e-9), both on
            input and when a point is re-expressed in a child triangle.

    Returns:
        :class:`RefinedMesh`. Cost: O(F log F) set-up plus O(1) per point (plus the number of
        points sharing a triangle), in Python.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    index, weights = check_surface_points(face_index, barycentric, faces, snap_tol)
    n0 = vertices.shape[0]
    positions = np.einsum("pk,pkd->pd", weights, vertices[faces[index]])

    mesh_faces: list[list[int]] = faces.tolist()
    parent: list[int] = list(range(faces.shape[0]))
    edge_faces = _EdgeFaces(faces, n0)
    current_face = index.tolist()
    current_weights = list(weights)
    waiting: defaultdict[int, list[int]] = defaultdict(list)
    for point, face in enumerate(current_face):
        waiting[face].append(point)
    point_vertex = np.empty(index.size, dtype=np.int64)
    new_positions: list[NDArray] = []

    def split(face: int, mu: NDArray, vertex: int) -> None:
        """Split ``face`` at ``vertex`` (weights ``mu`` on its corners; zero weight = the
        vertex lies on the opposite edge, that child is skipped) and re-home its points."""
        corners = mesh_faces[face]
        children: list[tuple[int, int]] = []  # (face id, corner slot replaced by vertex)
        edge_faces.remove_face(face, corners)
        for slot in np.flatnonzero(mu > 0).tolist():
            child = list(corners)
            child[slot] = vertex
            child_id = face if not children else len(mesh_faces)
            if child_id == face:
                mesh_faces[face] = child
            else:
                mesh_faces.append(child)
                parent.append(parent[face])
            edge_faces.add_face(child_id, child)
            children.append((child_id, slot))
        pending, waiting[face] = waiting[face], []
        for point in pending:
            beta = current_weights[point]
            best: tuple[float, int, NDArray] | None = None
            for child_id, slot in children:
                ratio = beta[slot] / mu[slot]
                lam = beta - ratio * mu
                lam[slot] = ratio
                score = float(lam.min())
                if best is None or score > best[0]:
                    best = (score, child_id, lam)
            assert best is not None
            current_face[point] = best[1]
            current_weights[point] = best[2]
            waiting[best[1]].append(point)

    for point in range(index.size):
        face = current_face[point]
        beta = _snap(np.maximum(current_weights[point], 0.0), snap_tol)
        corners = mesh_faces[face]
        waiting[face].remove(point)
        nonzero = np.flatnonzero(beta > 0).tolist()
        if len(nonzero) == 1:
            point_vertex[point] = corners[nonzero[0]]
            continue
        vertex = n0 + len(new_positions)
        new_positions.append(positions[point])
        point_vertex[point] = vertex
        if len(nonzero) == 3:
            split(face, beta, vertex)
            continue
        a, b = corners[nonzero[0]], corners[nonzero[1]]
        for incident in list(edge_faces.get(a, b)):
            around = mesh_faces[incident]
            mu = np.zeros(3)
            mu[around.index(a)] = beta[nonzero[0]]
            mu[around.index(b)] = beta[nonzero[1]]
            split(incident, mu, vertex)

    all_vertices = np.vstack([vertices, *new_positions]) if new_positions else vertices.copy()
    return RefinedMesh(
        vertices=all_vertices,
        faces=np.asarray(mesh_faces, dtype=np.int64).reshape(-1, 3),
        point_vertex=point_vertex,
        parent_face=np.asarray(parent, dtype=np.int64),
    )


def surface_point_distances(
    shape: Shape,
    face_index: ArrayLike,
    barycentric: ArrayLike,
    *,
    to_vertices: bool = False,
    backend: str = DEFAULT_EXACT_BACKEND,
    snap_tol: float = DEFAULT_SNAP_TOL,
    n_workers: int = 1,
) -> SurfacePointDistances:
    """Exact geodesic distances between surface points of a mesh.

    Args:
        shape: a mesh :class:`~litege_core.shape.Shape`.
        face_index: ``(P,)`` int triangle of each point.
        barycentric: ``(P, 3)`` float weights of that triangle's corners (rows sum to 1).
        to_vertices: also return the ``(P, N)`` distances to every original vertex.
        backend: exact backend (``"pygeodesic"`` or ``"gdist"``).
        snap_tol: barycentric snapping tolerance (see :func:`insert_surface_points`).
        n_workers: worker processes for the exact rows.

    Returns:
        :class:`SurfacePointDistances`; one exact propagation per distinct point vertex.

    Raises:
        InputError: a point cloud, or bad points (see :func:`check_surface_points`), or a
            non-manifold mesh (see :class:`ExactGeodesicEngine`).
    """
    if not isinstance(shape, Shape) or not shape.is_mesh:
        raise InputError("surface-point geodesics need a triangle mesh Shape")
    assert shape.faces is not None
    refined = insert_surface_points(shape.vertices, shape.faces, face_index, barycentric, snap_tol)
    limits = ShapeLimits(max_vertices=refined.vertices.shape[0], max_faces=refined.faces.shape[0])
    refined_shape = Shape.from_arrays(refined.vertices, refined.faces, limits=limits)
    engine = ExactGeodesicEngine(refined_shape, backend=backend, n_workers=n_workers)
    unique, inverse = np.unique(refined.point_vertex, return_inverse=True)
    rows = engine.distances(unique).distances[inverse]
    distances = rows[:, refined.point_vertex]
    np.fill_diagonal(distances, 0.0)
    return SurfacePointDistances(
        distances=distances,
        to_vertices=rows[:, : shape.n_points].copy() if to_vertices else None,
        refined=refined,
        method="exact_surface_points",
        params={"backend": backend, "snap_tol": float(snap_tol)},
    )


__all__ = [
    "DEFAULT_SNAP_TOL",
    "RefinedMesh",
    "SurfacePointDistances",
    "check_surface_points",
    "insert_surface_points",
    "surface_point_distances",
]
