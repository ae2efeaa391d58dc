"""A triangle mesh's edges, its boundary, its seams, its winding and its vertex normals.

A mesh can store one surface position as several vertices: a triangle soup (every corner its own
vertex), or an OBJ split along its UV seams. Its faces then do not join across the seams, so
every reader of the connectivity (the geodesic engines, the ring graph of the fusion, the path
router, the boundary test of matching) welds them first, by one rule: :func:`seam_welds`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.sampling import first_copies


def unique_edges(faces: NDArray) -> tuple[NDArray, NDArray]:
    """Undirected edges of a triangle list and how many faces use each.

    Args:
        faces: ``(F, 3)`` int64 triangles.

    Returns:
        ``edges (E, 2)`` int64 with ``edges[:, 0] < edges[:, 1]``, sorted lexicographically,
        and ``counts (E,)`` int64, the number of faces incident to each edge.
    """
    half = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    half = np.sort(half, axis=1)
    edges, counts = np.unique(half, axis=0, return_counts=True)
    return edges.astype(np.int64), counts.astype(np.int64)


def boundary_vertices(faces: NDArray, n: int) -> NDArray:
    """``(n,)`` bool: the vertices on an edge that borders exactly one of ``faces``."""
    edges, counts = unique_edges(np.asarray(faces, dtype=np.int64))
    rim = np.zeros(n, dtype=bool)
    rim[edges[counts == 1].reshape(-1)] = True
    return rim


def seam_welds(points: NDArray, faces: NDArray) -> NDArray:
    """``(N,)`` int64: each vertex's welded index. A vertex stored more than once at one
    position (:func:`~litege_core.sampling.first_copies`) is welded to the first copy when
    both lie on a boundary edge: the seams of a triangle soup or of an OBJ split along its UV
    seams. Coincident vertices inside a closed surface stay apart (their own index): they are
    where two parts touch (FAUST's remeshed bodies have one to three)."""
    n = points.shape[0]
    first = first_copies(points)
    copies = np.flatnonzero(first != np.arange(n))
    if copies.size:
        rim = boundary_vertices(faces, n)
        unwelded = copies[~(rim[copies] & rim[first[copies]])]
        first[unwelded] = unwelded
    return first


def boundary_edge_fraction(faces: NDArray, vertices: NDArray | None = None) -> float:
    """Fraction of a triangle mesh's undirected edges that border exactly one face; with
    ``vertices``, of the mesh with its seams welded (:func:`seam_welds`: a soup of a closed
    surface has none)."""
    faces = np.asarray(faces, dtype=np.int64)
    if vertices is not None:
        faces = seam_welds(np.asarray(vertices, dtype=np.float64), faces)[faces]
    _, counts = unique_edges(faces)
    return float((counts == 1).sum() / max(counts.size, 1))


__all__ = ["boundary_edge_fraction", "boundary_vertices", "seam_welds", "unique_edges"]


def consistently_wound(faces: NDArray) -> bool:
    """Whether no two faces walk an edge in the same direction: faces that share an edge
    agree on which side is out, so their normals summed at a vertex do not cancel. A boundary
    edge (one face) does not count against it; an edge of three faces or more (non-manifold)
    does."""
    half = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    if half.shape[0] < 2:
        return True
    keys = np.sort(half[:, 0] * (int(half.max()) + 1) + half[:, 1])  # one int per directed edge
    return bool((np.diff(keys) != 0).all())


def vertex_normals(vertices: ArrayLike, faces: ArrayLike) -> NDArray:
    """``(N, 3)`` area-weighted unit vertex normals (zero for unreferenced vertices)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    corners = f.reshape(-1)
    normals = np.stack(
        [np.bincount(corners, np.repeat(face_n[:, i], 3), v.shape[0]) for i in range(3)], axis=1
    )
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
